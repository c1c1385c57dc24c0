"""Wrapped phase, phase differences, unwrapping and three-step phase shifting.

Two ways to unwrap the object's phase are offered:

``reference``
    The phase difference to the reference plane, wrapped to (-pi, pi], *is* the answer when the
    object stays within the unambiguous depth (``|dphi|`` < pi everywhere). No spatial unwrapping,
    so isolated regions and steps are measured independently and exactly.
``spatial``
    Quality-guided spatial unwrapping of the wrapped difference with scikit-image's
    :func:`~skimage.restoration.unwrap_phase`, for objects deeper than the unambiguous range but
    continuous. Each connected region gets the 2 pi offset that puts its lowest percentile inside
    (-pi, pi] (the object stands on the plate); regions other than the largest are flagged as isolated because that choice is an
    assumption.
"""

from __future__ import annotations

from ._unwrap import (  # noqa: F401
    UnwrapMode,
    wrap,
    three_step_phase,
    Unwrapped,
    _wrap_flags,
    unwrap,
    unwrap_rows,
)
from ._passes import (  # noqa: F401
    denoise_weight,
    _denoise_weights,
    _denoise_row,
    _denoise_kernel,
    _denoise_kernel_carry,
    _own_row,
    _own_side,
    _window_sums,
    _box_sums,
    window_sums,
    _table_row,
    _plane_tables,
    _box,
    _plane_box,
    _plane_slope,
    _adaptive_pass,
)
from ._denoise import (  # noqa: F401
    denoise_phase,
    denoise_weight_sums,
    denoise_weighted,
    adaptive_kwargs,
    band_floor,
    first_pass,
)

__all__ = [
    "UnwrapMode",
    "Unwrapped",
    "adaptive_kwargs",
    "band_floor",
    "denoise_phase",
    "denoise_weight",
    "denoise_weight_sums",
    "denoise_weighted",
    "first_pass",
    "three_step_phase",
    "unwrap",
    "unwrap_rows",
    "window_sums",
    "wrap",
]
