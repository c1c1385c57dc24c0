"""The per-frame noise: the phase and height sigma, the capture's own shot + read noise, the frame's hue noise."""

from __future__ import annotations

from typing import Any

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from huefringe.colour import _hue_noise_kernel  # noqa: F401  (the fused kernel imports it from here)
from huefringe.huetable import HueTable, HueTableError


def height_noise(dphi: NDArray[np.floating], sumw: NDArray[np.floating], valid: NDArray[np.bool_],
                 a: NDArray[np.floating], b: NDArray[np.floating]) -> NDArray[np.float32]:
    """Standard deviation (mm) of each height from the capture noise alone: ``|dh/dphi| / sqrt(sumw)``.

    ``sumw`` is the phase filter's sum of inverse-variance weights (``1 / sigma^2`` of the pixel
    itself without the filter), ``sigma`` each pixel's per-capture phase noise from the hue
    table's per-pixel noise (:func:`phase_sigma`); ``h = dphi / (a + b dphi)`` gives
    ``dh/dphi = a / (a + b dphi)^2``. NaN where not ``valid`` or without weight. What the
    step-edge tests (:func:`remove_step_edges`) hold a jump against; both chains compute it from
    the same float32 maps, in this compiled loop.
    """
    out = np.empty(np.shape(dphi), np.float32)
    _height_noise_kernel(np.ascontiguousarray(dphi, np.float32), np.ascontiguousarray(sumw, np.float32),
                         np.ascontiguousarray(valid, bool), np.ascontiguousarray(a, np.float32),
                         np.ascontiguousarray(b, np.float32), out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _height_noise_kernel(dphi, sumw, valid, a, b, out):  # pragma: no cover - numba
    """:func:`height_noise`'s loop (float32)."""
    h, w = dphi.shape
    nan = np.float32(np.nan)
    for v in range(h):
        for u in range(w):
            sw = sumw[v, u]
            q = a[v, u] + b[v, u] * dphi[v, u]
            s = abs(a[v, u]) / (q * q) / np.sqrt(sw)
            out[v, u] = s if valid[v, u] and sw > 0 and s - s == 0 else nan


def phase_sigma(table: HueTable, slope: NDArray[np.floating], floor_slope: float = 0.05,
                noise: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Per-pixel standard deviation (rad) of the code phase decoded from one capture.

    ``sigma_hue / slope``: the hue noise of one capture over the local slope d(captured
    hue)/d(code phase) of the pixel's table (:meth:`HueTable.hue_slope` at the captured hue),
    floored at ``floor_slope``. ``noise`` is the hue noise (rad) per pixel, e.g. the frame's own
    (:func:`frame_hue_noise`); default the table's pooled figure (:func:`capture_noise`).
    """
    slope = np.where(np.isfinite(slope), slope, 1.0)  # (invalid pixels only: the kernel leaves them out)
    if noise is None:
        noise = capture_noise(table)
    out = np.empty(noise.shape, np.float64)
    _phase_sigma_map(noise, np.ascontiguousarray(slope, dtype=np.float64), float(floor_slope), out)
    return out


def capture_noise(table: HueTable) -> NDArray[np.float64]:
    """Per-pixel hue noise (rad) of one capture, from the table's band statistics.

    The standard error of the bands' mean hue times ``sqrt(repeats)``: the repeats' spread, or
    with one repeat the second difference along the bands (``stats["noise_rad"]["source"]``,
    :data:`huefringe.huetable.NOISE_SOURCES`). Pixels without a finite, positive figure (masked
    table pixels, which are never measured) get the median of the others. A table without any
    figure is refused (:class:`~huefringe.huetable.HueTableError`): no noise is ever assumed.
    Used by :func:`phase_sigma` and by the fused kernel (:func:`huefringe.kernel.prepare`).
    """
    repeats = int(table.stats.get("repeats", 1) or 1)
    noise = np.asarray(table.noise_rad, np.float64) * np.sqrt(repeats)
    known = np.isfinite(noise) & (noise > 0)
    if not known.any():
        raise HueTableError("the hue table has no per-pixel noise figure (noise_rad is NaN or 0 everywhere: a table "
                            "written by a build that did not estimate it from a single repeat); rebuild the hue table")
    return np.ascontiguousarray(np.where(known, noise, float(np.median(noise[known]))))


@numba.njit(cache=True, nogil=True)
def sigma_from_slope(noise, slope, floor_slope):  # pragma: no cover - compiled
    """One pixel's code-phase standard deviation ``noise / max(slope, floor_slope)`` (compiled, for
    :func:`phase_sigma` and the fused kernel alike; a branch-free expression, so that it stays
    vectorised in the kernel's row loop)."""
    return noise / max(slope, floor_slope)


@numba.njit(cache=True, nogil=True)
def _phase_sigma_map(noise, slope, floor_slope, out):  # pragma: no cover - compiled
    """:func:`sigma_from_slope` of every pixel."""
    h, w = noise.shape
    for v in range(h):
        for u in range(w):
            out[v, u] = sigma_from_slope(noise[v, u], slope[v, u], floor_slope)


# --------------------------------------------------------------------------- sensor noise


#: Bounds of :func:`noise_ratio2`: never less than 1e-6 nor more than 1e6 times the table's figure
#: (keeps the filter's float32 sums finite).
_RATIO2_BOUNDS = (1e-6, 1e6)
#: Own-signal hue noise (rad) up to which its first-order propagation (:func:`frame_hue_noise`) is
#: trusted below the table's pooled figure. On hexcone hues with Gaussian channel noise the
#: propagation is within 4 % of the hue's spread up to 0.08 rad and reads it low beyond 0.1 rad
#: (median 0.95 of it at 0.2-0.4 rad, as low as 0.72 at 0.4-1 rad;
#: ``benchmarks/hue_noise_first_order.py``; docs/uncertainty.md, "The noise ratio"): where the
#: chroma is small the table's measured per-pixel figure is kept (with the model alone there,
#: |e| <= 2u held for 0.71 of the dark half of photo_sensor with two repeats, docs/noise.md).
OWN_TRUSTED_RAD = 0.05


def noise_ratio2(own: NDArray[np.floating], pooled: NDArray[np.floating]) -> NDArray[np.float32]:
    """How much the frame's own-signal noise variance differs from the table's measured per-pixel
    one that weights the phase filter (:func:`capture_noise`), float32: ``s^2 / pooled^2`` with

        s^2 = own^2 + lam * max(pooled^2 - own^2, 0),  lam = clip(own / OWN_TRUSTED_RAD - 1, 0, 1)

    clipped to :data:`_RATIO2_BOUNDS` (NaN -> 1). Above the pooled figure the own one counts
    (a frame darker than the bands); below it, the own one counts where its first-order
    propagation holds (``own <= OWN_TRUSTED_RAD``), the pooled one where it does not (``own >=
    2 OWN_TRUSTED_RAD``: the propagation reads a small chroma's noise low), linearly between. The
    pooled figure is one number per pixel over all the hue bands, while a hue's noise depends on
    its chroma: on a high-chroma hue it is below the pooled figure (Table 1 at 100 px, the top's
    hues 0.021-0.025 rad against 0.040 pooled). The filter sums ``w`` times it
    (:func:`huefringe.phase.denoise_phase`'s ``ratio``), so that the uncertainty follows the
    frame's signal while the weights, and so the heights, do not."""
    o = np.ascontiguousarray(own, np.float64)
    out = np.empty(o.shape, np.float32)
    _ratio2_kernel(o.reshape(-1), np.ascontiguousarray(pooled, np.float64).reshape(-1), _RATIO2_BOUNDS[0],
                   _RATIO2_BOUNDS[1], OWN_TRUSTED_RAD, out.reshape(-1))
    return out


def ratio_over(r: NDArray[np.float32], r_w: NDArray[np.float32]) -> NDArray[np.float32]:
    """``r / r_w`` (float32), clipped to :data:`_RATIO2_BOUNDS`: the frame's own noise variance
    against the one that weights the filter (:func:`weight_noise`), both as ratios to the pooled one."""
    return np.clip(np.asarray(r, np.float32) / np.asarray(r_w, np.float32), np.float32(_RATIO2_BOUNDS[0]),
                   np.float32(_RATIO2_BOUNDS[1])).astype(np.float32)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _ratio2_kernel(own, pooled, lo, hi, trusted, out):  # pragma: no cover - compiled
    """:func:`noise_ratio2`'s loop (NaN -> 1, then clipped)."""
    for i in range(own.size):
        o = own[i]
        p2 = pooled[i] * pooled[i]
        lam = min(max(o / trusted - 1.0, 0.0), 1.0)
        s2 = o * o + lam * max(p2 - o * o, 0.0)
        r = s2 / p2
        r = r if r == r else 1.0
        out[i] = np.float32(min(max(r, lo), hi))


#: Gaussian sigma (px) of the signal that the phase filter's weights read the frame's own noise
#: from (``measurement.weight_blur_px``; :func:`weight_noise`).
WEIGHT_BLUR_PX = 2.0
#: The shapes of that Gaussian (``measurement.weight_blur_shape``): isotropic (the default), which
#: mixes the hues of a fringe's neighbouring phases into the signal and reads the noise high where
#: the fringe is short, or along the fringe only (the reference phase's iso-phase direction,
#: :func:`fringe_angle`), which keeps the pixel's hue.
WEIGHT_BLUR_SHAPES: tuple[str, ...] = ("isotropic", "along_fringe")
WEIGHT_BLUR_SHAPE = "isotropic"


def fringe_angle(phi_ref: NDArray[np.floating]) -> float | None:
    """The direction (rad, ``atan2(dy, dx)`` in image axes) of the reference phase's gradient:
    the fringes run perpendicular to it.

    The median of the wrapped differences of ``phi_ref`` (read as float32, as the fused kernel
    holds it) along the rows and along the columns, over the pixels where both are finite. One
    direction for the session: the fringes' local direction on an object departs from it by its
    slope's deformation of the fringe. None where the reference phase has no finite difference
    or no gradient."""
    p = np.asarray(phi_ref, np.float32).astype(np.float64)
    dx = np.angle(np.exp(1j * (p[:, 1:] - p[:, :-1])))
    dy = np.angle(np.exp(1j * (p[1:] - p[:-1])))
    dx, dy = dx[np.isfinite(dx)], dy[np.isfinite(dy)]
    if dx.size == 0 or dy.size == 0:
        return None
    gx, gy = float(np.median(dx)), float(np.median(dy))
    if gx == 0.0 and gy == 0.0:
        return None
    return float(np.arctan2(gy, gx))


def weight_blur_angle(phi_ref: NDArray[np.floating], shape: str) -> float | None:
    """The direction the weights' Gaussian needs for ``shape`` (``measurement.weight_blur_shape``,
    one of :data:`WEIGHT_BLUR_SHAPES`): :func:`fringe_angle` of ``phi_ref`` for ``along_fringe``,
    None (isotropic) for ``isotropic``; any other shape is refused (ValueError)."""
    if shape not in WEIGHT_BLUR_SHAPES:
        raise ValueError(f"weight_blur_shape {shape!r}: expected one of {', '.join(WEIGHT_BLUR_SHAPES)}")
    return fringe_angle(phi_ref) if shape == "along_fringe" else None


def fringe_kernel(blur_px: float, angle: float) -> NDArray[np.float32]:
    """A one-dimensional Gaussian of sigma ``blur_px`` along the fringe (perpendicular to the
    phase gradient's direction ``angle``, :func:`fringe_angle`), out to 3 sigma, drawn on the
    pixel grid with linear interpolation across the line (``max(0, 1 - distance)``), normalised
    to a sum of 1; rows and columns without weight trimmed (float32, odd sizes, centred). With
    the fringes along a column it is that column's Gaussian alone."""
    r = int(np.ceil(3.0 * float(blur_px)))
    tx, ty = -np.sin(angle), np.cos(angle)  # along the fringe
    rx, ry = int(np.ceil(r * abs(tx))) + 1, int(np.ceil(r * abs(ty))) + 1
    y, x = np.mgrid[-ry:ry + 1, -rx:rx + 1].astype(np.float64)
    along = x * tx + y * ty
    across = np.abs(x * ty - y * tx)
    k = np.exp(-0.5 * (along / float(blur_px)) ** 2) * np.maximum(0.0, 1.0 - across) * (np.abs(along) <= r + 0.5)
    keep_y = np.flatnonzero(k.any(axis=1))
    keep_x = np.flatnonzero(k.any(axis=0))
    cy = max(ry - keep_y[0], keep_y[-1] - ry)  # symmetric trim: the kernel stays centred
    cx = max(rx - keep_x[0], keep_x[-1] - rx)
    k = k[ry - cy:ry + cy + 1, rx - cx:rx + cx + 1]
    return np.ascontiguousarray(k / k.sum(), np.float32)


def smoothed_signal(rgb: NDArray[Any], blur_px: float, scale: float = 1.0,
                    angle: float | None = None) -> NDArray[np.float32]:
    """The capture as the filter's weights read it: float32 ``rgb`` times ``scale`` (codes as the
    fused kernel receives them, or float in [0, 1] with ``scale`` 1: the same float32 values),
    smoothed by a Gaussian of ``blur_px`` (OpenCV, reflected border), ``(H, W, 3)``: along the
    fringe (:func:`fringe_kernel` through ``cv2.filter2D``) when ``angle`` (the phase gradient's
    direction, :func:`fringe_angle`) is given, else isotropic (``cv2.GaussianBlur``)."""
    x = np.asarray(rgb, np.float32)
    if float(scale) != 1.0:
        x = x * np.float32(scale)
    x = np.ascontiguousarray(x)
    if angle is None:
        out = cv2.GaussianBlur(x, (0, 0), float(blur_px), borderType=cv2.BORDER_REFLECT_101)
    else:
        out = cv2.filter2D(x, -1, fringe_kernel(blur_px, angle), borderType=cv2.BORDER_REFLECT_101)
    return np.ascontiguousarray(out, np.float32)


def weight_noise(table: HueTable, rgb: NDArray[Any], gains: NDArray[np.float32], hue_model: str, blur_px: float,
                 scale: float = 1.0,
                 angle: float | None = None) -> tuple[NDArray[np.float64], NDArray[np.float32]] | None:
    """The hue noise (rad) that weights the phase filter, and its ratio to the pooled figure.

    The table's pooled per-pixel figure (:func:`capture_noise`) scaled by the frame's own signal,
    ``pooled sqrt(r_w)`` with ``r_w`` :func:`noise_ratio2` of :func:`frame_hue_noise` of the
    capture smoothed by a Gaussian of ``blur_px`` (:func:`smoothed_signal`; along the fringe when
    ``angle``, the reference phase's gradient direction, is given: :func:`fringe_angle`): a hue's
    noise depends on its chroma and signal, which the pooled figure (one per pixel over all
    bands) does not follow, and the smoothed signal keeps a pixel's weight from following its own
    noise (the weights of the unsmoothed own figure correlate with the noise they weight and
    bias the mean). Along the fringe the smoothing keeps the pixel's hue; an isotropic Gaussian
    mixes in the neighbouring phases' hues, whose mean has less chroma, and reads the noise high.
    Returns ``(noise, r_w)``; None where the table has no sensor model or ``blur_px`` is not
    positive (the pooled figure weights the filter)."""
    model = sensor_model(table)
    if model is None or not float(blur_px) > 0:
        return None
    return weight_noise_of(capture_noise(table), model, rgb, gains, hue_model == "hsi", blur_px, scale, angle)


def weight_noise_of(pooled: NDArray[np.float64], model: NDArray[np.float32], rgb: NDArray[Any],
                    gains: NDArray[np.float32], hsi: bool, blur_px: float,
                    scale: float = 1.0,
                    angle: float | None = None) -> tuple[NDArray[np.float64], NDArray[np.float32]]:
    """:func:`weight_noise` from the pooled figure and the sensor model (the fused kernel's
    prepared arrays): the same operations, so both chains weight with the same bits."""
    own_w = np.empty(pooled.shape, np.float64)
    _hue_noise_kernel(smoothed_signal(rgb, blur_px, scale, angle), np.float32(1.0),
                      np.ascontiguousarray(gains, np.float32), bool(hsi), model, pooled, own_w)
    r_w = noise_ratio2(own_w, pooled)
    return pooled * np.sqrt(r_w.astype(np.float64)), r_w


def sensor_model(table: HueTable) -> NDArray[np.float32] | None:
    """The table's shot + read noise model as float32 ``(2, 3)``: per channel ``gain`` (row 0)
    and ``read`` (row 1) of ``variance = gain * signal + read`` (full scale 1), fitted on the
    hue bands' captured hue when the table was built (:func:`huefringe.huetable.fit_hue_noise`:
    the repeats' hue spread, or with one repeat the hue's third differences along the bands);
    None when the table has none (one repeat and no run of four bands in a sextant, fewer than 1,000
    usable samples, or a table built before the model existed)."""
    m = (table.stats or {}).get("sensor_noise")
    if not m:
        return None
    return np.ascontiguousarray(np.array([m["gain"], m["read"]], np.float32))


def frame_hue_noise(table: HueTable, rgb: NDArray[Any], gains: NDArray[np.float32], hue_model: str,
                    scale: float = 1.0, pooled: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Per-pixel hue noise (rad) of this capture, from its own signal and the sensor-noise model.

    Each channel's variance ``gain_c * signal_c + read_c`` (:func:`sensor_model`), times the
    white-balance gain squared, propagated through the hue formula by its first derivatives
    (hexcone: ``(pi/3)^2 (v_mid C^2 + v_max (mid - min)^2 + v_min (max - mid)^2) / C^4``,
    ``C = max - min``; HSI: the gradient of ``atan2(y, x)``). Where the table has no model, or
    the hue is undefined, the table's pooled figure (:func:`capture_noise`). ``rgb``: the frame
    as the kernel receives it (float in [0, 1], or integer codes with their ``scale``); the
    fused kernel calls the same compiled loop, so both agree bit for bit. ``pooled``: the table's
    :func:`capture_noise` when the caller has it already.
    """
    fallback = capture_noise(table) if pooled is None else pooled
    model = sensor_model(table)
    if model is None:
        return fallback
    out = np.empty(fallback.shape, np.float64)
    _hue_noise_kernel(np.ascontiguousarray(rgb), np.float32(scale), np.ascontiguousarray(gains, np.float32),
                      hue_model == "hsi", model, fallback, out)
    return out
