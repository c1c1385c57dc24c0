"""Colour measures of captured fringe images: hue (HSI and hexcone), saturation, intensity.

Two hue models are offered:

``"hsi"``
    Paper eqs. 1-2 (Gonzalez & Woods): ``H = arccos(num / den)`` with
    ``num = ((R - G) + (R - B)) / 2`` and ``den = sqrt((R - G)^2 + (R - B)(G - B))``, then
    ``H -> 2 pi - H`` when ``B >= G``. ``num`` and ``den`` are the Cartesian components and the
    length of the colour in the chromaticity plane, ``x = R - (G + B) / 2``,
    ``y = sqrt(3) / 2 (G - B)`` with ``den = hypot(x, y)``, so eqs. 1-2 are *exactly*
    ``atan2(y, x)`` taken modulo 2 pi (the branch of eq. 2 picks the sign of ``y``; on the ray
    ``G == B`` both give 0 for reddish and pi for cyanish colours once 2 pi is wrapped to 0).
    :func:`hue_hsi` evaluates the ``atan2`` form, which needs no clamp of the arccos argument and
    keeps full precision near H = 0 and H = pi where ``arccos`` loses half of the digits;
    :func:`hue_hsi_arccos` is the literal eq. 1-2 form (clamped), kept as a reference.
    On the trapezoid of eq. 3 the HSI hue is only *nearly* linear in the code phase (about
    0.02 rad peak deviation, see :func:`hue_linearity`).

``"hexcone"``
    The HSV hue (Smith's hexcone). On the trapezoid of eq. 3 it equals the code phase exactly,
    so it is the default model of the library.

Undefined hue
    Hue is undefined for grey (R = G = B) colours and meaningless for colours that are nearly grey
    or nearly black. :func:`hue` returns **NaN** there: where the saturation is ``<=
    min_saturation`` (so exact greys are always NaN, also with the default 0) or the intensity is
    ``< min_intensity``. :func:`chromatic_mask` returns the complementary boolean mask
    (True = hue defined) when a mask is more convenient. The model-specific functions
    :func:`hue_hsi` and :func:`hue_hexcone` return NaN only for exact greys.

All functions are vectorised over any leading shape ``(..., 3)``, accept float arrays (or ints,
converted), and return ``float32``. Float32 inputs are computed in float32 (fast path used by the
calibration), float64 inputs in float64 and rounded at the end. Hues are in [0, 2 pi).
"""

from __future__ import annotations

import math
from typing import Literal

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .patterns import TWO_PI, trapezoid_rgb

HueModel = Literal["hexcone", "hsi"]
HUE_MODELS: tuple[str, ...] = ("hexcone", "hsi")

_TWO_PI_F32 = np.float32(TWO_PI)  # 6.2831855, rounds *above* the true 2 pi
_SQRT3_2 = np.sqrt(3.0) / 2.0

__all__ = [
    "HUE_MODELS",
    "any_channel_at_least",
    "balanced_hue",
    "HueModel",
    "chromatic_mask",
    "hue",
    "hue_hexcone",
    "hue_hsi",
    "hue_hsi_arccos",
    "hue_linearity",
    "intensity",
    "saturation",
    "white_balance",
    "white_gains",
    "wrap_2pi",
    "wrap_pi",
]


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
def _as_rgb(rgb: ArrayLike) -> NDArray[np.floating]:
    a = np.asarray(rgb)
    if a.shape[-1:] != (3,):
        raise ValueError(f"expected an array of shape (..., 3), got {a.shape}")
    if a.dtype == np.float32 or a.dtype == np.float64:
        return a
    return a.astype(np.float64)


def wrap_2pi(angle: ArrayLike) -> NDArray[np.float32]:
    """Angles modulo 2 pi as ``float32`` in [0, 2 pi) (NaN stays NaN).

    The float32 rounding of a value just below 2 pi can give exactly ``float32(2 pi)``; such
    values are mapped to 0 so that the half-open interval holds in float32 too.
    """
    a = np.asarray(angle)
    work = a if a.dtype == np.float32 else a.astype(np.float64)
    out = np.asarray(np.mod(work, work.dtype.type(TWO_PI)), dtype=np.float32)
    out[out >= _TWO_PI_F32] = 0.0
    return out


def wrap_pi(angle: ArrayLike) -> NDArray[np.float64]:
    """Angles wrapped to [-pi, pi) (float64), e.g. circular differences of phases."""
    a = np.asarray(angle, dtype=np.float64)
    return np.mod(a + np.pi, TWO_PI) - np.pi


# --------------------------------------------------------------------------------------------
# hue models
# --------------------------------------------------------------------------------------------
def hue_hsi(rgb: ArrayLike) -> NDArray[np.float32]:
    """HSI hue of paper eqs. 1-2 in [0, 2 pi), evaluated in its exact ``atan2`` form.

    Parameters
    ----------
    rgb : array_like, shape (..., 3)
        R, G, B (any non-negative scale; hue is scale invariant).

    Returns
    -------
    ndarray of float32, shape (...)
        Hue in [0, 2 pi); NaN where R = G = B (grey, eq. 1 is 0/0).

    Notes
    -----
    ``theta = arccos(num / den)`` of eq. 1 equals ``|atan2(y, x)|`` with
    ``x = num = R - (G + B) / 2`` and ``y = sqrt(3) / 2 (G - B)``, because
    ``x^2 + y^2 = (R - G)^2 + (R - B)(G - B) = den^2``. Eq. 2 keeps ``theta`` when ``B < G``
    (``y > 0``) and takes ``2 pi - theta`` when ``B >= G``; that is ``atan2(y, x) mod 2 pi``.
    """
    a = _as_rgb(rgb)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    x = r - 0.5 * (g + b)
    y = a.dtype.type(_SQRT3_2) * (g - b)
    h = wrap_2pi(np.arctan2(y, x))
    h[(x == 0) & (y == 0)] = np.nan
    return h


def hue_hsi_arccos(rgb: ArrayLike) -> NDArray[np.float32]:
    """Literal paper eqs. 1-2 (reference implementation of :func:`hue_hsi`).

    Computed in float64; the arccos argument is clamped to [-1, 1] (rounding can push
    ``|num / den|`` a few ulps above 1 on the ``G == B`` ray). Eq. 2's ``B >= G`` branch maps a
    red hue of 0 to 2 pi, which is wrapped to 0. NaN for greys (``den == 0``).
    """
    a = np.asarray(_as_rgb(rgb), dtype=np.float64)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    num = 0.5 * ((r - g) + (r - b))
    den = np.sqrt(np.maximum((r - g) ** 2 + (r - b) * (g - b), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        theta = np.arccos(np.clip(num / den, -1.0, 1.0))
    h = np.where(b < g, theta, TWO_PI - theta)
    h = wrap_2pi(h)
    h[den == 0] = np.nan
    return h


def hue_hexcone(rgb: ArrayLike) -> NDArray[np.float32]:
    """Hexcone (HSV) hue in [0, 2 pi); exactly the code phase on the trapezoid of eq. 3.

    Parameters
    ----------
    rgb : array_like, shape (..., 3)

    Returns
    -------
    ndarray of float32, shape (...)
        ``pi / 3 * h6`` with ``h6 = (G - B) / C`` (mod 6) where R is the maximum,
        ``(B - R) / C + 2`` where G is, ``(R - G) / C + 4`` where B is; ``C = max - min``.
        Ties between maxima pick R, then G (the hue is continuous there). NaN where ``C == 0``.
    """
    a = _as_rgb(rgb)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    mx = np.maximum(np.maximum(r, g), b)
    c = mx - np.minimum(np.minimum(r, g), b)
    grey = c == 0
    c_safe = np.where(grey, a.dtype.type(1), c)
    h6 = np.where(mx == r, (g - b) / c_safe, np.where(mx == g, (b - r) / c_safe + 2, (r - g) / c_safe + 4))
    h = wrap_2pi(h6 * a.dtype.type(np.pi / 3.0))
    h[grey] = np.nan
    return h


def hue(
    rgb: ArrayLike,
    model: HueModel = "hexcone",
    *,
    min_saturation: float = 0.0,
    min_intensity: float = 0.0,
) -> NDArray[np.float32]:
    """Hue of the chosen model, NaN where it is undefined or unreliable.

    Parameters
    ----------
    rgb : array_like, shape (..., 3)
    model : {"hexcone", "hsi"}
    min_saturation : float
        NaN where ``saturation(rgb, model) <= min_saturation`` (greys are always NaN).
    min_intensity : float
        NaN where ``intensity(rgb) < min_intensity``.

    Returns
    -------
    ndarray of float32, shape (...)
        Hue in [0, 2 pi) or NaN.
    """
    if model == "hexcone":
        h = hue_hexcone(rgb)
    elif model == "hsi":
        h = hue_hsi(rgb)
    else:
        raise ValueError(f"unknown hue model {model!r}; expected one of {HUE_MODELS}")
    if min_saturation > 0.0 or min_intensity > 0.0:
        h[~chromatic_mask(rgb, model, min_saturation=min_saturation, min_intensity=min_intensity)] = np.nan
    return h


def saturation(rgb: ArrayLike, model: HueModel = "hexcone") -> NDArray[np.float32]:
    """Saturation in [0, 1]: ``C / max`` (hexcone/HSV) or ``1 - 3 min / (R + G + B)`` (HSI).

    Black (all zero) has saturation 0 in both models.
    """
    a = _as_rgb(rgb)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    mx = np.maximum(np.maximum(r, g), b)
    mn = np.minimum(np.minimum(r, g), b)
    if model == "hexcone":
        num, den = mx - mn, mx
    elif model == "hsi":
        den = r + g + b
        num = den - 3 * mn
    else:
        raise ValueError(f"unknown hue model {model!r}; expected one of {HUE_MODELS}")
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(den > 0, num / np.where(den > 0, den, 1), 0)
    return np.asarray(s, dtype=np.float32)


def intensity(rgb: ArrayLike) -> NDArray[np.float32]:
    """HSI intensity ``(R + G + B) / 3`` as float32."""
    a = _as_rgb(rgb)
    return np.asarray((a[..., 0] + a[..., 1] + a[..., 2]) / 3.0, dtype=np.float32)


def chromatic_mask(
    rgb: ArrayLike,
    model: HueModel = "hexcone",
    *,
    min_saturation: float = 0.0,
    min_intensity: float = 0.0,
) -> NDArray[np.bool_]:
    """True where the hue is defined: saturation > ``min_saturation`` and intensity >= ``min_intensity``."""
    ok = saturation(rgb, model) > min_saturation
    if min_intensity > 0.0:
        ok &= intensity(rgb) >= min_intensity
    return ok


# --------------------------------------------------------------------------------------------
# white balance
# --------------------------------------------------------------------------------------------
def white_gains(white: ArrayLike, floor: float = 1.0 / 255.0) -> NDArray[np.float32]:
    """Per-pixel, per-channel white-balance gains ``1 / max(white, floor)`` (float32 (H, W, 3)).

    ``floor`` bounds the gain at ``1 / floor`` on dark or shadowed pixels, where the white image is
    close to 0 and its inverse would only amplify noise (or divide by zero).
    """
    if floor <= 0:
        raise ValueError("floor must be > 0")
    w = np.asarray(white, dtype=np.float32)
    if w.shape[-1:] != (3,):
        raise ValueError(f"white must have shape (..., 3), got {w.shape}")
    return (np.float32(1.0) / np.maximum(w, np.float32(floor))).astype(np.float32, copy=False)


def white_balance(rgb: ArrayLike, white: ArrayLike, floor: float = 1.0 / 255.0) -> NDArray[np.float32]:
    """White-balance an image with the capture of the full-white projection (paper sect. 2.3).

    Parameters
    ----------
    rgb : array_like, shape (H, W, 3)
        Captured image in [0, 1].
    white : array_like, shape (H, W, 3)
        Capture of the white (255, 255, 255) projection on the same scene.
    floor : float
        Lower bound on ``white`` before inversion (default one 8-bit count).

    Returns
    -------
    ndarray of float32, shape (H, W, 3)
        ``rgb / max(white, floor)`` per pixel and channel. Where the white image is well exposed
        the result is in about [0, 1] (1 = the white response); it is not clipped, so noise above
        the white level is kept (hue is scale invariant). This removes the per-pixel, per-channel
        gains ``alpha_k r_k`` of eqs. 7-8 (and the white level of the projector gamma), but not
        the gamma curve itself, nor crosstalk or ambient light: those are what the hue tables of
        :mod:`huefringe.huetable` calibrate.
    """
    return np.multiply(np.asarray(rgb, dtype=np.float32), white_gains(white, floor), dtype=np.float32)


# --------------------------------------------------------------------------------------------
# QA: linearity of the hue models on the ideal pattern
# --------------------------------------------------------------------------------------------
def hue_linearity(model: HueModel, n_samples: int = 6 * 1024) -> dict[str, float]:
    """How linear a hue model is on the ideal trapezoid of eq. 3.

    Samples ``n_samples`` code phases uniformly over one period, computes
    ``hue(trapezoid_rgb(phi)) - phi`` (wrapped to [-pi, pi)) and reports it.

    Returns
    -------
    dict
        ``{"model", "max_rad", "rms_rad", "n_samples"}``. The hexcone hue is exact (errors at the
        float32 rounding level, ~1e-7 rad); the HSI hue deviates by about 0.02 rad peak
        (paper eqs. 4-5 are a small-angle approximation).
    """
    phi = TWO_PI * (np.arange(n_samples) + 0.5) / n_samples
    h = hue(trapezoid_rgb(phi), model).astype(np.float64)
    err = wrap_pi(h - phi)
    return {
        "model": model,
        "max_rad": float(np.max(np.abs(err))),
        "rms_rad": float(np.sqrt(np.mean(err**2))),
        "n_samples": int(n_samples),
    }


# --------------------------------------------------------------------------------------------
# fused fast path (used by the streamed calibration)
# --------------------------------------------------------------------------------------------
@numba.njit(cache=True, parallel=False, nogil=True)
def _balanced_hue_kernel(rgb, gains, hsi, min_saturation, out):  # pragma: no cover - numba
    h, w, _ = rgb.shape
    third = math.pi / 3.0
    two_pi = 2.0 * math.pi
    two_pi_f32 = np.float32(two_pi)
    k = math.sqrt(3.0) / 2.0
    for v in range(h):
        for u in range(w):
            r = np.float64(rgb[v, u, 0]) * gains[v, u, 0]
            g = np.float64(rgb[v, u, 1]) * gains[v, u, 1]
            b = np.float64(rgb[v, u, 2]) * gains[v, u, 2]
            mx = max(r, g, b)
            mn = min(r, g, b)
            c = mx - mn
            if hsi:
                tot = r + g + b
                sat = (tot - 3.0 * mn) / tot if tot > 0 else 0.0
            else:
                sat = c / mx if mx > 0 else 0.0
            if c == 0.0 or sat <= min_saturation:
                out[v, u] = np.nan
                continue
            if hsi:
                x = math.atan2(k * (g - b), r - 0.5 * (g + b))
            elif mx == r:
                x = third * ((g - b) / c)
            elif mx == g:
                x = third * ((b - r) / c + 2.0)
            else:
                x = third * ((r - g) / c + 4.0)
            if x < 0.0:
                x += two_pi
            y = np.float32(x)
            if y >= two_pi_f32:
                y = np.float32(0.0)
            out[v, u] = y


def balanced_hue(
    rgb: NDArray[np.floating],
    gains: NDArray[np.floating],
    model: HueModel = "hexcone",
    *,
    min_saturation: float = 0.0,
    out: NDArray[np.float32] | None = None,
) -> NDArray[np.float32]:
    """Fused white balance and hue of an ``(H, W, 3)`` image (compiled, one pass, no temporaries).

    Equals ``hue(rgb * gains, model, min_saturation=min_saturation)`` up to float32 rounding
    (the kernel works in float64 per pixel). ``gains`` are from :func:`white_gains`.
    """
    if model not in HUE_MODELS:
        raise ValueError(f"unknown hue model {model!r}; expected one of {HUE_MODELS}")
    rgb = np.ascontiguousarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected (H, W, 3), got {rgb.shape}")
    if rgb.dtype not in (np.float32, np.float64):
        rgb = rgb.astype(np.float32)
    gains = np.ascontiguousarray(gains, dtype=np.float32)
    if gains.shape != rgb.shape:
        raise ValueError(f"gains {gains.shape} and image {rgb.shape} differ")
    if out is None:
        out = np.empty(rgb.shape[:2], dtype=np.float32)
    _balanced_hue_kernel(rgb, gains, model == "hsi", float(min_saturation), out)
    return out


def any_channel_at_least(rgb: ArrayLike, top: float) -> NDArray[np.bool_]:
    """Pixels of an ``(H, W, C)`` image with any channel ``>= top`` (a clipped sensor code):
    ``np.any(rgb >= top, axis=-1)``, channel by channel (NumPy's reduction over a last axis of 3
    takes about 4 ms at 640 x 480; the comparisons and ors a fraction of that)."""
    a = np.asarray(rgb)
    out = a[..., 0] >= top
    for c in range(1, a.shape[-1]):
        out |= a[..., c] >= top
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _hue_noise_kernel(rgb, scale, gains, hsi, model, fallback, out):  # pragma: no cover - compiled
    """Per-pixel hue noise (rad) of a capture from its own signal: each channel's variance
    ``model[0, c] * signal_c + model[1, c]`` (shot + read, full scale 1; ``rgb`` codes times ``scale``)
    times the white-balance gain squared, through the hue formula's first derivatives; ``fallback``
    where that is not finite and positive. :func:`huefringe.perframe.frame_hue_noise`'s loop (the
    fused kernel and the hue table's sensor-noise fit call it too); branch-free rows (selects), so
    that LLVM vectorises them."""
    h, w, _ = rgb.shape
    k0, k1, k2 = model[0, 0], model[0, 1], model[0, 2]
    r0, r1, r2 = model[1, 0], model[1, 1], model[1, 2]
    k3 = np.float32(math.sqrt(3.0) / 2.0)
    half = np.float32(0.5)
    zero = np.float32(0.0)
    third2 = np.float32((np.pi / 3.0) ** 2)
    for v in range(h):
        px = rgb[v].reshape(-1)
        gn = gains[v].reshape(-1)
        fb = fallback[v]
        ov = out[v]
        for u in range(w):
            f0 = np.float32(px[3 * u]) * scale
            f1 = np.float32(px[3 * u + 1]) * scale
            f2 = np.float32(px[3 * u + 2]) * scale
            g0, g1, g2 = gn[3 * u], gn[3 * u + 1], gn[3 * u + 2]
            r = f0 * g0
            g = f1 * g1
            bl = f2 * g2
            vr = (k0 * f0 + r0) * (g0 * g0)
            vg = (k1 * f1 + r1) * (g1 * g1)
            vb = (k2 * f2 + r2) * (g2 * g2)
            if hsi:
                xx = r - half * (g + bl)
                yy = k3 * (g - bl)
                q = xx * xx + yy * yy
                dg = xx * k3 + half * yy
                db = half * yy - xx * k3
                var = (yy * yy * vr + dg * dg * vg + db * db * vb) / (q * q)
            else:
                mx = max(max(r, g), bl)
                mn = min(min(r, g), bl)
                c = mx - mn
                mid = ((r + g) + bl) - mx - mn
                hi2 = (mid - mn) * (mid - mn)  # weight of the maximum's variance
                lo2 = (mx - mid) * (mx - mid)  # of the minimum's
                c2 = c * c
                wr = hi2 if r == mx else (lo2 if r == mn else c2)
                wg = hi2 if g == mx else (lo2 if g == mn else c2)
                wb = hi2 if bl == mx else (lo2 if bl == mn else c2)
                var = third2 * (wr * vr + wg * vg + wb * vb) / (c2 * c2)
            s = np.sqrt(np.float64(var))
            ov[u] = s if (s - s == 0) & (var > zero) else fb[u]
