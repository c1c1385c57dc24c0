"""Per-pixel multi-band hue calibration (paper sect. 2.3, Figs. 5-7).

The calibration projects ``N`` uniform hue bands (band ``i`` is the trapezoid of eq. 3 at code
phase ``c_i = 2 pi i / N``), ``R`` times each, on the scene. Per pixel, the circular mean (mean
direction) of the white-balanced captured hue over the repeats gives a *hue table* ``T[i] = captured hue of code
c_i``; its inverse maps a captured hue back to the projected code phase, removing the projector
gamma, the surface colour, the camera crosstalk and ambient light (eqs. 6-9) pixel by pixel.

Table format
------------
``HueTable.table`` is a ``uint16`` array of shape ``(N, H, W)`` (band-major, so each band is one
contiguous plane written once during the streamed build): hue ``= count * 2 pi / 65536``
(resolution 9.6e-5 rad, rounding error <= 4.8e-5 rad). Size in memory and on disk:
``2 * N * H * W`` bytes, e.g. 403 MB for 256 bands at 1024 x 768, 194 MB at 768 x 494, plus per
pixel ``start`` (uint16), ``reason`` (uint8), ``noise_rad`` (float32) and ``valid`` (bool):
``8 * H * W`` bytes more. Building needs the table plus a few ``(H, W)`` work planes, the ``R``
hue planes of one band and the image being decoded: peak ``~ 2 N H W + (4 R + 70) H W`` bytes
(measured: 214 MB traced for 256 bands at 768 x 494, table 194 MB).

For every valid pixel the final table is circularly non-decreasing: read from band ``start``
onwards (modulo N) it is sorted ascending in [0, 65536) with exactly one wrap. The inverse lookup
is then a binary search in that rotated sorted column.

Noise reduction (no spatial mixing)
-----------------------------------
Tables are smoothed only *along the band axis* of each pixel: the distortion curve
``d(c_i) = U(c_i) - c_i`` (``U`` the unwrapped captured hue, ``d`` is 2 pi periodic) is filtered
with a local polynomial (Savitzky-Golay) of order ``smooth_order`` over ``smooth_window`` bands
(defaults 2 and 15), whose support never crosses a sextant boundary ``k pi / 3`` of the code, where
eq. 3 switches channel and per-channel gamma puts a kink in the curve (one-sided windows there;
:func:`band_smoothing_matrix`). No pixel ever borrows data from a neighbour, so tables cannot
bleed across surface-colour edges, whatever the edge contrast. Interior noise gain of the default
filter: 0.39 (variance 0.15). Afterwards the curve is made monotone (mean of the running maximum
and the reversed running minimum) so that the inverse exists.

Masking
-------
Pixels are masked for the first failing reason, in this order (``REASONS``):

``low_signal``
    the white image is below ``min_intensity`` in some channel (shadow, black, a colour that
    reflects almost nothing of one primary);
``low_saturation``
    in some band no repeat had a defined hue (white-balanced saturation <= ``min_saturation``);
``noise``
    the standard error of a band's mean hue (RMS spread over repeats / sqrt(R); with one repeat
    the third difference along the bands, see below) exceeds ``max_noise_steps`` band steps
    ``2 pi / N``;
``coverage``
    the captured hues do not wind exactly once round the circle, or leave a gap larger than
    ``max_gap`` between consecutive bands;
``order``
    the captured hue falls back below its running maximum (over any run of bands, so slow
    reversals count as much as jumps) by more than ``max(order_steps band steps, order_sigmas
    sqrt(2) noise)`` (defaults 2 and 6), or the final quantised table is not circularly sorted.

Per-pixel noise
---------------
``HueTable.noise_rad`` is always estimated, never assumed (``stats["noise_rad"]["source"]``,
:data:`NOISE_SOURCES`): with ``R >= 2`` repeats the pooled spread of the repeats about their mean
over all bands (``R - 1`` degrees of freedom per band), as the standard error of a band mean; with
one repeat the third difference along the bands of each sextant (:func:`_band_noise_kernel`),
which removes the captured-hue curve's level, slope and curvature and leaves ``20 sigma^2``:
within 0.94-0.98 of six repeats' figure in every white-level bin of the bench's ``photo_sensor``
(docs/noise.md).

``stats["sensor_noise"]`` is the sensor's shot + read model ``var_c = gain_c * signal_c + read_c``
that each frame's own hue noise is propagated through (:func:`huefringe.perframe.frame_hue_noise`),
fitted on the bands' captured hue (:func:`fit_hue_noise`, :data:`SENSOR_SOURCES`): the repeats'
hue spread, or with one repeat the hue's third differences along the bands; None with one repeat
and fewer than four bands in every sextant, or with fewer than 1,000 usable samples.

The Fig. 6 compensation of the projected pattern and the calibration QA figures are in
:mod:`huefringe.compensation`, built on these tables.
"""

from __future__ import annotations

from ._store import (  # noqa: F401
    HueTableError,
    COUNTS,
    RAD_PER_COUNT,
    REASONS,
    _R_LOW_SIGNAL,
    _R_LOW_SAT,
    _FORMAT,
    NOISE_SOURCES,
    _TWO_PI_F32,
    table_nbytes,
    hue_band_paths,
    _column_entry,
    _to_phase_kernel,
    HueTable,
    _base,
    _to_phase_numpy,
    _Reader,
)
from ._noise import (  # noqa: F401
    BAND_DIFFERENCE_ORDER,
    _band_noise_kernel,
    _NOISE_STRIDE,
    _HueNoiseStats,
    SENSOR_SOURCES,
    fit_hue_noise,
)
from ._build import (  # noqa: F401
    band_smoothing_matrix,
    _accumulate_kernel,
    _finalise_kernel,
    build_table,
    smoothing_window,
    white_balance_floor,
)

__all__ = [
    "COUNTS",
    "HueTableError",
    "RAD_PER_COUNT",
    "NOISE_SOURCES",
    "SENSOR_SOURCES",
    "REASONS",
    "HueTable",
    "band_smoothing_matrix",
    "build_table",
    "fit_hue_noise",
    "hue_band_paths",
    "smoothing_window",
    "table_nbytes",
    "white_balance_floor",
]
