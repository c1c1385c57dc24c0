"""The per-frame algorithm: one trapezoidal frame to a height map, with its masks and QA.

:func:`measure_frame` is the NumPy reference chain (hue -> hue table -> code phase -> phase
difference -> height); the fused kernel (:mod:`huefringe.kernel`) reproduces it bit for bit and
shares its compiled pieces (:func:`sigma_from_slope`, :func:`capture_noise`,
:func:`shadow_mask`). The workflow's stages (:mod:`huefringe.stages`) call one or the other.
"""

from __future__ import annotations

from ._measure import (  # noqa: F401
    FrameError,
    FrameResult,
    measure_frame,
)
from ._edges import (  # noqa: F401
    shadow_mask,
    shadow_masks,
    shadow_side,
    step_edge_mask,
    _noise_map,
    _pair_jump,
    _edge_kernel,
    EDGE_TESTS,
    plane_edge_mask,
    _plane_drop,
    _plane_edge_kernel,
    _masked,
    _finite_keys,
    remove_step_edges,
    clipped_mask,
)
from ._noise import (  # noqa: F401
    height_noise,
    _height_noise_kernel,
    phase_sigma,
    capture_noise,
    sigma_from_slope,
    _phase_sigma_map,
    _RATIO2_BOUNDS,
    OWN_TRUSTED_RAD,
    noise_ratio2,
    _ratio2_kernel,
    sensor_model,
    frame_hue_noise,
    _hue_noise_kernel,
    WEIGHT_BLUR_PX,
    WEIGHT_BLUR_SHAPE,
    WEIGHT_BLUR_SHAPES,
    fringe_angle,
    fringe_kernel,
    weight_blur_angle,
    ratio_over,
    smoothed_signal,
    weight_noise,
    weight_noise_of,
)
from ._stats import (  # noqa: F401
    frame_stats,
    _qa_record,
    reference_frame_stats,
    _reference_counts,
    _select_key,
    _key_value,
    _median_keys,
)

__all__ = [
    "FrameError",
    "FrameResult",
    "capture_noise",
    "clipped_mask",
    "frame_hue_noise",
    "height_noise",
    "noise_ratio2",
    "frame_stats",
    "fringe_angle",
    "fringe_kernel",
    "measure_frame",
    "phase_sigma",
    "plane_edge_mask",
    "reference_frame_stats",
    "remove_step_edges",
    "sensor_model",
    "shadow_mask",
    "shadow_masks",
    "shadow_side",
    "sigma_from_slope",
    "step_edge_mask",
    "weight_noise",
]
