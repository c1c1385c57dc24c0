"""Texture-edge correction: undo what the camera's lens blur does to a fringe after a textured surface.

The camera images ``B_c = G * (R_c F_c)`` (lens blur ``G`` after the surface's reflectance ``R_c``)
and the object's white image ``W_c = G * R_c``. To first order in the blur's variance ``sigma^2``
(px^2) the normalised fringe is

    B_c / W_c = F_c + sigma^2 grad ln R_c . grad F_c + (sigma^2 / 2) lap F_c,

so at a reflectance edge each pixel's fringe leans towards its brighter neighbours' (the middle
term); the last term is the same on the white plate and the phase-error table holds it. Since
``grad ln W_c ~ grad ln R_c``, the capture is corrected, per channel, as

    B'_c = B_c - sigma^2 grad W_c . grad (B_c / W_c)                        (:func:`correct`)

which makes ``B'_c / W_c = F_c`` to first order. ``sigma^2`` is the camera's blur, which a
session does not record; :func:`estimate_blur` finds it from the session's own object frames:
the normalised fringe's fine structure ``y - smooth(y)`` is regressed on the predicted lean's
``x - smooth(x)`` (``y = B/W``, ``x = grad W . grad y / W``) over the textured pixels. The true
fringe does not follow the texture, so the slope is ``sigma^2``; the central differences of
``x`` leave out the pixel's own noise, so the noise does not bias it. Pure functions, no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

__all__ = ["correct", "estimate_blur", "lean", "white_floor"]

#: white level (full scale 1) below which the normalised fringe is not formed (noise, shadow)
WHITE_FLOOR = 0.02


def white_floor(white: NDArray[np.floating]) -> NDArray[np.float64]:
    """The white image (H, W, 3) in [0, 1], floored at :data:`WHITE_FLOOR` (float64)."""
    return np.maximum(np.asarray(white, np.float64), WHITE_FLOOR)


def lean(rgb: NDArray[np.floating], white: NDArray[np.floating]) -> NDArray[np.float64]:
    """``grad W_c . grad (B_c / W_c)`` per channel (central differences; 0 on the border rows and
    columns): the capture's change per unit ``sigma^2`` that :func:`correct` removes.

    Parameters
    ----------
    rgb, white : ndarray (H, W, 3)
        A fringe capture and the object's white image, both in [0, 1] (``read_rgb``).
    """
    w = white_floor(white)
    y = np.asarray(rgb, np.float64) / w
    out = np.zeros(w.shape, np.float64)
    # central differences: (f[+1] - f[-1]) / 2 along each axis, the pixel's own value left out
    out[1:-1, :, :] += (w[2:] - w[:-2]) * (y[2:] - y[:-2]) / 4.0
    out[:, 1:-1, :] += (w[:, 2:] - w[:, :-2]) * (y[:, 2:] - y[:, :-2]) / 4.0
    return out


def correct(rgb: NDArray[np.floating], white: NDArray[np.floating], sigma2_px2: float,
            clipped: NDArray[np.bool_] | None = None) -> NDArray[np.float32]:
    """The capture with the texture-edge lean removed, ``B - sigma^2 grad W . grad (B / W)``.

    Parameters
    ----------
    rgb, white : ndarray (H, W, 3)
        A fringe capture and the object's white image in [0, 1].
    sigma2_px2 : float
        The camera's blur variance (px^2); 0 returns the capture unchanged (as float32).
    clipped : ndarray of bool (H, W), optional
        Pixels left unchanged (saturated sensor: the chain marks them invalid by their code).

    Returns
    -------
    ndarray of float32 (H, W, 3)
        The corrected capture, clipped to [0, 1].
    """
    b = np.asarray(rgb, np.float64)
    if sigma2_px2 == 0:
        return b.astype(np.float32)
    out = np.clip(b - sigma2_px2 * lean(b, white), 0.0, 1.0)
    if clipped is not None:
        out[clipped] = b[clipped]
    return out.astype(np.float32)


def estimate_blur(frames: Sequence[NDArray[np.floating]], white: NDArray[np.floating], *,
                  smooth_px: float = 2.0, min_white: float = 0.04, texture_quantile: float = 0.8,
                  clip: float = 4.0) -> dict[str, Any]:
    """The camera's blur variance ``sigma^2`` (px^2) from object frames and the object's white image.

    Per channel and frame, ``y = B / W`` and ``x = grad W . grad y / W`` (:func:`lean` over
    ``W``); their fine structure (minus a Gaussian of ``smooth_px``) is regressed through the
    origin, ``y_f = sigma^2 x_f``, over the pixels with ``W >= min_white`` whose ``|x_f|`` is in the
    top ``1 - texture_quantile`` (the texture edges, where the lean is), with residuals beyond
    ``clip`` robust standard deviations dropped (one pass).

    Returns
    -------
    dict
        ``sigma2_px2`` (>= 0; 0 when the object has no texture to measure it on), ``samples``
        (pixels used), ``stderr_px2`` (the slope's standard error), ``per_channel``.
    """
    w = white_floor(white)
    xs: list[list[NDArray[np.float64]]] = [[], [], []]
    ys: list[list[NDArray[np.float64]]] = [[], [], []]
    for f in frames:
        b = np.asarray(f, np.float64)
        y = b / w
        x = lean(b, white) / w
        for c in range(3):
            ok = np.asarray(white, np.float64)[..., c] >= min_white
            ok[[0, -1], :] = False
            ok[:, [0, -1]] = False
            yf = y[..., c] - ndimage.gaussian_filter(y[..., c], smooth_px)
            xf = x[..., c] - ndimage.gaussian_filter(x[..., c], smooth_px)
            xs[c].append(xf[ok])
            ys[c].append(yf[ok])
    per_channel = []
    xa_all, ya_all = [], []
    for c in range(3):
        if not xs[c] or not sum(v.size for v in xs[c]):
            continue
        xa, ya = np.concatenate(xs[c]), np.concatenate(ys[c])
        if xa.size < 100:
            continue
        keep = np.abs(xa) >= np.quantile(np.abs(xa), texture_quantile)
        xa_all.append(xa[keep])
        ya_all.append(ya[keep])
        per_channel.append(float(np.sum(xa[keep] * ya[keep]) / max(np.sum(xa[keep] ** 2), 1e-300)))
    if not xa_all:
        return {"sigma2_px2": 0.0, "samples": 0, "stderr_px2": None, "per_channel": per_channel}
    xa, ya = np.concatenate(xa_all), np.concatenate(ya_all)
    s = float(np.sum(xa * ya) / max(np.sum(xa**2), 1e-300))
    r = ya - s * xa
    mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    if mad > 0:
        keep = np.abs(r) <= clip * mad
        xa, ya = xa[keep], ya[keep]
        s = float(np.sum(xa * ya) / max(np.sum(xa**2), 1e-300))
    r = ya - s * xa
    se = float(np.sqrt(np.sum(r**2) / max(xa.size - 1, 1) / max(np.sum(xa**2), 1e-300)))
    return {"sigma2_px2": max(s, 0.0), "samples": int(xa.size), "stderr_px2": se, "per_channel": per_channel}
