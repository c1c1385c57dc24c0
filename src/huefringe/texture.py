"""Texture-edge correction: undo what the camera's lens blur does to a fringe after a textured surface.

The camera images ``B_c = G * (R_c F_c)`` (lens blur ``G`` after the surface's reflectance ``R_c``)
and the object's white image ``W_c = G * R_c``. To first order in the blur's variance ``sigma^2``
(px^2) the normalised fringe is

    B_c / W_c = F_c + sigma^2 grad ln R_c . grad F_c + (sigma^2 / 2) lap F_c,

so at a reflectance edge each pixel's fringe leans towards its brighter neighbours' (the middle
term); the last term is the same on the white plate and the phase-error table holds it. Since
``grad ln W_c ~ grad ln R_c``, the capture is corrected, per channel, as

    B'_c = B_c - sigma^2 grad W_c . grad (B_c / W_c)                        (:func:`correct`)

which makes ``B'_c / W_c = F_c`` to first order.

Light that carries no fringe breaks the product form: the ambient light the surface reflects, the
camera's stray light and the projector's black level add ``Q_c`` to capture and white alike
(``B_c = G * (R_c F_c) + Q_c``), and on a dark pixel ``Q_c`` is a large part of the white. The
fringe-carrying light is then ``B_c - Q_c`` over ``W_c - Q_c``, and the correction is formed from it
(``offset`` = ``Q``, :func:`projector_off_light`: the captures of the hue bands in which the
channel's code is 0; docs/uncertainty.md, "Dark pixels of a textured relief", measures it). The
blur itself is estimated from the correction without the offset (:func:`blur_from_phases`): with
it, on noisy frames, the frames' predicted corrections lose their correlation and the estimate is
refused (docs/design.md). ``sigma^2`` is the camera's blur, which a
session does not record; :func:`blur_from_phases` finds it from the session's own object frames
measured with and without the correction: the true surface does not follow the texture, so the
``sigma^2`` that removes the phase's texture-correlated fine structure is the blur
(``huefringe.pipeline.session_texture_blur`` runs it). Where that estimate is refused (a surface
with little texture, e.g. gauge blocks: a few sharp coating edges, too few for the phase's
statistics) or the session has one frame, :func:`blur_from_white` reads the blur from the white
image's sharp edges instead. Pure functions, no I/O.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from numba import njit, prange
from scipy import ndimage

from huefringe import _threads  # noqa: F401  (numba's threading layer, before any parallel launch)

__all__ = ["blur_from_phases", "blur_from_white", "blur_uncertainty", "correct", "correct_pair", "lean",
           "projector_off_light", "white_floor"]

#: white level (full scale 1) below which the normalised fringe is not formed (noise, shadow)
WHITE_FLOOR = 0.02

#: largest camera blur variance (px^2) the estimate accepts: sigma 3 px is a camera out of focus
MAX_BLUR_PX2 = 9.0


def white_floor(white: NDArray[np.floating]) -> NDArray[np.float64]:
    """The white image (H, W, 3) in [0, 1], floored at :data:`WHITE_FLOOR` (float64)."""
    return np.maximum(np.asarray(white, np.float64), WHITE_FLOOR)


def projector_off_light(captures: Iterable[tuple[NDArray[np.floating], NDArray[np.floating]]]) -> NDArray[np.float32]:
    """The light a scene sends the camera with the projector's code at 0 (ambient light reflected,
    stray light, the projector's black level), per pixel and channel, from uniform captures.

    Parameters
    ----------
    captures : iterable of (rgb, code)
        Uniform-colour captures (H, W, 3) in [0, 1] (``read_rgb``, through the same camera
        corrections as the frames) with their projected code (3,) in [0, 1], e.g. the object's
        hue bands and ``patterns.band_rgb``: each channel is averaged over the captures whose
        code is 0 in that channel (a third of the trapezoid's bands).

    Returns
    -------
    ndarray of float32 (H, W, 3)
        ``Q``, the ``offset`` of :func:`correct` and :func:`correct_pair`.

    Raises
    ------
    ValueError
        When no capture has a channel at code 0, or the captures differ in shape.
    """
    acc: NDArray[np.float64] | None = None
    count = np.zeros(3, np.int64)
    for rgb, code in captures:
        zero = np.flatnonzero(np.asarray(code, np.float64).reshape(3) == 0.0)
        if zero.size == 0:
            continue
        img = np.asarray(rgb)
        if acc is None:
            acc = np.zeros(img.shape, np.float64)
        if img.shape != acc.shape or img.ndim != 3:
            raise ValueError(f"capture of shape {img.shape}, expected {acc.shape} (H, W, 3)")
        for c in zero:
            acc[..., c] += img[..., c]
        count[zero] += 1
    if acc is None or np.any(count == 0):
        raise ValueError(f"no capture at code 0 in every channel (captures per channel: {count.tolist()})")
    return (acc / count).astype(np.float32)


def _fringe_light(rgb: NDArray[np.floating], white: NDArray[np.floating],
                  offset: NDArray[np.floating] | None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Capture and floored white less ``offset`` (the fringe-carrying light), float64."""
    b = np.asarray(rgb, np.float64)
    if offset is None:
        return b, white_floor(white)
    q = np.asarray(offset, np.float64)
    return b - q, white_floor(np.asarray(white, np.float64) - q)


def lean(rgb: NDArray[np.floating], white: NDArray[np.floating],
         offset: NDArray[np.floating] | None = None) -> NDArray[np.float64]:
    """``grad W_c . grad (B_c / W_c)`` per channel (central differences; 0 on the border rows and
    columns): the capture's change per unit ``sigma^2`` that :func:`correct` removes.

    Parameters
    ----------
    rgb, white : ndarray (H, W, 3)
        A fringe capture and the object's white image, both in [0, 1] (``read_rgb``).
    offset : ndarray (H, W, 3), optional
        The light that carries no fringe (:func:`projector_off_light`), taken out of both first.
    """
    b, w = _fringe_light(rgb, white, offset)
    y = b / w
    out = np.zeros(w.shape, np.float64)
    # central differences: (f[+1] - f[-1]) / 2 along each axis, the pixel's own value left out
    out[1:-1, :, :] += (w[2:] - w[:-2]) * (y[2:] - y[:-2]) / 4.0
    out[:, 1:-1, :] += (w[:, 2:] - w[:, :-2]) * (y[:, 2:] - y[:, :-2]) / 4.0
    return out


def correct(rgb: NDArray[np.floating], white: NDArray[np.floating], sigma2_px2: float,
            clipped: NDArray[np.bool_] | None = None,
            offset: NDArray[np.floating] | None = None) -> NDArray[np.float32]:
    """The capture with the texture-edge lean removed, ``B - sigma^2 grad W . grad (B / W)``.

    Parameters
    ----------
    rgb, white : ndarray (H, W, 3)
        A fringe capture and the object's white image in [0, 1].
    sigma2_px2 : float
        The camera's blur variance (px^2); 0 returns the capture unchanged (as float32).
    clipped : ndarray of bool (H, W), optional
        Pixels left unchanged (saturated sensor: the chain marks them invalid by their code).
    offset : ndarray (H, W, 3), optional
        The light that carries no fringe (:func:`projector_off_light`): the lean is formed from
        the capture and the white less it (:func:`lean`).

    Returns
    -------
    ndarray of float32 (H, W, 3)
        The corrected capture, clipped to [0, 1].
    """
    b = np.asarray(rgb, np.float64)
    if sigma2_px2 == 0:
        return b.astype(np.float32)
    out = np.clip(b - sigma2_px2 * lean(b, white, offset), 0.0, 1.0)
    if clipped is not None:
        out[clipped] = b[clipped]
    return out.astype(np.float32)


@njit(cache=True, nogil=True, inline="always")
def _ratio_row(b, w, q, v, wr, yr):  # pragma: no cover - compiled
    """Row ``v`` of the floored white ``wr = max(W - Q, floor)`` and of the ratio ``yr = (B - Q) /
    wr`` (:func:`lean`'s ``w`` and ``y``; ``Q`` 0 when ``q`` is None), flattened (u, c)."""
    floor = WHITE_FLOOR
    bv, wv = b[v], w[v]
    if q is None:
        for i in range(bv.shape[0]):
            x = max(np.float64(wv[i]), floor)
            wr[i] = x
            yr[i] = np.float64(bv[i]) / x
    else:
        qv = q[v]
        for i in range(bv.shape[0]):
            x = max(np.float64(wv[i]) - qv[i], floor)
            wr[i] = x
            yr[i] = (np.float64(bv[i]) - qv[i]) / x


@njit(cache=True, nogil=True, parallel=True)
def _correct_pair(b, w, s1, s2, clipped, use_clip, out1, out2, want2, q, nc):  # pragma: no cover - compiled
    """:func:`lean` of every pixel (float64, the same operations in the same order; of ``b - q``
    and ``w - q`` unless ``q`` is None, a case compiled on its own) and the two corrections
    ``clip(b - s lean, 0, 1)`` (float32; clipped pixels as captured), in blocks of rows in
    parallel. ``b``, ``w``, ``q``, ``out1``, ``out2``: ``(H, W x nc)``, each pixel's ``nc``
    channels side by side; ``b`` and ``w`` float32 or float64, read as float64. Each pixel's
    floored white and ratio are formed once, for its four neighbours (a ring of three rows per
    block), and the stencil runs along the row's flattened channels (SIMD)."""
    h, n = b.shape
    block = 32
    for blk in prange((h + block - 1) // block):
        v0 = blk * block
        v1 = min(v0 + block, h)
        wr = np.empty((3, n))  # rows v - 1, v, v + 1 in slots (row + 1) % 3
        yr = np.empty((3, n))
        g = np.empty(n)
        if v0 > 0:
            _ratio_row(b, w, q, v0 - 1, wr[v0 % 3], yr[v0 % 3])
        _ratio_row(b, w, q, v0, wr[(v0 + 1) % 3], yr[(v0 + 1) % 3])
        for v in range(v0, v1):
            if v + 1 < h:
                _ratio_row(b, w, q, v + 1, wr[(v + 2) % 3], yr[(v + 2) % 3])
            wc, yc = wr[(v + 1) % 3], yr[(v + 1) % 3]
            for i in range(n):
                g[i] = 0.0
            if 0 < v < h - 1:
                wa, ya, wb, yb = wr[(v + 2) % 3], yr[(v + 2) % 3], wr[v % 3], yr[v % 3]
                for i in range(n):
                    g[i] += (wa[i] - wb[i]) * (ya[i] - yb[i]) / 4.0
            for i in range(nc, n - nc):
                g[i] += (wc[i + nc] - wc[i - nc]) * (yc[i + nc] - yc[i - nc]) / 4.0
            bv, o1, o2 = b[v], out1[v], out2[v if want2 else 0]
            for i in range(n):
                o1[i] = np.float32(min(max(np.float64(bv[i]) - s1 * g[i], 0.0), 1.0))
            if want2:
                for i in range(n):
                    o2[i] = np.float32(min(max(np.float64(bv[i]) - s2 * g[i], 0.0), 1.0))
            if use_clip:  # clipped pixels as captured
                for u in range(n // nc):
                    if clipped[v, u]:
                        for c in range(nc):
                            o1[u * nc + c] = np.float32(bv[u * nc + c])
                            if want2:
                                o2[u * nc + c] = np.float32(bv[u * nc + c])


def correct_pair(rgb: NDArray[np.floating], white: NDArray[np.floating], sigma2_px2: float,
                 moved_px2: float | None, clipped: NDArray[np.bool_] | None = None,
                 offset: NDArray[np.floating] | None = None,
                 ) -> tuple[NDArray[np.float32], NDArray[np.float32] | None]:
    """:func:`correct` at ``sigma2_px2`` and at ``moved_px2`` (None: not wanted) from one pass of
    :func:`lean` over the capture (compiled, rows in parallel): the arrays two calls of
    :func:`correct` return (with the same ``offset``)."""
    # float32 or float64 as given (read as float64 inside, exactly as a float64 copy), others as float64
    b = np.ascontiguousarray(rgb)
    b = b if b.dtype in (np.float32, np.float64) else b.astype(np.float64)
    if sigma2_px2 == 0 and moved_px2 is None:
        return b.astype(np.float32), None
    w = np.ascontiguousarray(white)
    w = w if w.dtype in (np.float32, np.float64) else w.astype(np.float64)
    if b.ndim != 3 or w.shape != b.shape:
        raise ValueError(f"capture {b.shape} and white image {w.shape} must be the same (H, W, 3)")
    out1 = np.empty(b.shape, np.float32)
    out2 = np.empty(b.shape if moved_px2 is not None else (1, 1, 1), np.float32)
    clip = np.ascontiguousarray(clipped, bool) if clipped is not None else np.zeros((1, 1), bool)
    q = None
    if offset is not None:  # the fringe-carrying light
        q = np.ascontiguousarray(offset, np.float64)
        if q.shape != b.shape:
            raise ValueError(f"capture {b.shape} and offset {q.shape} must be the same (H, W, 3)")
    h, wd, nc = b.shape
    flat = (h, wd * nc)  # each pixel's channels side by side along the row
    _correct_pair(b.reshape(flat), w.reshape(flat), float(sigma2_px2), float(moved_px2 or 0.0), clip,
                  clipped is not None, out1.reshape(flat), out2.reshape(flat if moved_px2 is not None else (1, 1)),
                  moved_px2 is not None, q.reshape(flat) if q is not None else None, nc)
    return out1, (out2 if moved_px2 is not None else None)


def _fine(a: NDArray[np.float64], ok: NDArray[np.bool_], smooth_px: float) -> NDArray[np.float64]:
    """``a`` minus its normalised Gaussian average over the pixels ``ok`` (NaN elsewhere)."""
    a0 = np.where(ok, a, 0.0)
    wgt = ndimage.gaussian_filter(ok.astype(np.float64), smooth_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = a - ndimage.gaussian_filter(a0, smooth_px) / wgt
    return np.where(ok & (wgt > 0.2), out, np.nan)


def blur_from_phases(plain: Sequence[NDArray[np.floating]], unit: Sequence[NDArray[np.floating]], *,
                     smooth_px: float = 2.0, band: tuple[float, float] = (0.5, 0.9),
                     max_change_rad: float = 0.5, strips: int = 8, min_t: float = 3.0,
                     max_sigma2_px2: float = MAX_BLUR_PX2) -> dict[str, Any]:
    """The camera's blur variance (px^2) from the raw (unfiltered) phase of object frames measured
    as captured (``plain``) and after :func:`correct` with ``sigma^2 = 1`` (``unit``).

    The correction is linear in ``sigma^2``, so the phase it makes is ``phi_0 + sigma^2 g`` with
    ``g = unit - plain``; the right ``sigma^2`` leaves a phase without the texture's fine
    structure, so the fine structure (minus a Gaussian of ``smooth_px``) of ``phi_0`` is
    ``-sigma^2`` times that of ``g``. The slope is an instrumental-variable estimate between two
    frames, ``-(sum g_b phi_a + sum g_a phi_b) / (2 sum g_a g_b)`` (the frames share the texture's
    lean, not their noise, which would bias a plain regression towards 0), over the pixels whose
    ``|g|`` lies between the ``band`` quantiles: the first-order lean over-predicts at the
    sharpest edges (there the slope measured falls to 0.1-0.4 of the blur), and the weakest
    carry no signal. Frames are paired in order (an odd last one pairs with the first).

    On a surface with little texture both sums are near zero and their ratio is noise (0.0 and
    42.8 px^2 were read on two untextured sessions one grey level apart). The estimate is
    therefore accepted only when it is significant: its jackknife standard error over ``strips``
    horizontal strips of the image must be at most ``1 / min_t`` of it, and it must not exceed
    ``max_sigma2_px2`` (a lens that blurs by more than that is not a focused camera). Otherwise the
    result is 0 (no correction) and ``rejected`` says why.

    Returns
    -------
    dict
        ``sigma2_px2`` (>= 0, 0 without usable pixels or when rejected), ``raw_px2`` (the slope
        before the checks), ``stderr_px2`` (jackknife), ``samples``, ``pairs`` and, when the
        estimate was not used, ``rejected``.
    """
    if len(plain) != len(unit) or len(plain) < 2:
        raise ValueError(f"blur_from_phases: {len(plain)} plain and {len(unit)} corrected phases (two or more pairs needed)")
    ys, gs = [], []
    for p, q in zip(plain, unit, strict=True):
        p = np.asarray(p, np.float64)
        g = np.asarray(q, np.float64) - p
        ok = np.isfinite(p) & np.isfinite(g) & (np.abs(g) < max_change_rad)
        ys.append(_fine(p, ok, smooth_px))
        gs.append(_fine(g, ok, smooth_px))
    num = np.zeros(strips)
    den = np.zeros(strips)
    samples = pairs = 0
    idx = list(range(len(ys)))
    for a, b in zip(idx[0::2], idx[1::2] + ([idx[0]] if len(idx) % 2 else [])):
        ok = np.isfinite(ys[a]) & np.isfinite(ys[b]) & np.isfinite(gs[a]) & np.isfinite(gs[b])
        if ok.sum() < 100:
            continue
        rows = np.nonzero(ok)[0] * strips // ok.shape[0]
        ga, gb, ya, yb = gs[a][ok], gs[b][ok], ys[a][ok], ys[b][ok]
        mag = np.abs(ga + gb)
        lo, hi = np.quantile(mag, band)
        k = (mag >= lo) & (mag <= hi)
        num += np.bincount(rows[k], weights=gb[k] * ya[k] + ga[k] * yb[k], minlength=strips)
        den += np.bincount(rows[k], weights=2.0 * ga[k] * gb[k], minlength=strips)
        samples += int(k.sum())
        pairs += 1
    out: dict[str, Any] = {"sigma2_px2": 0.0, "raw_px2": 0.0, "stderr_px2": None, "samples": samples, "pairs": pairs}
    total = float(den.sum())
    if total <= 0:
        if pairs:
            out["rejected"] = "no texture signal (the frames' predicted corrections do not correlate)"
        return out
    s2 = -float(num.sum()) / total
    used = den != 0
    with np.errstate(divide="ignore", invalid="ignore"):
        loo = -(num.sum() - num[used]) / (total - den[used])  # leave one strip out
    m = int(used.sum())
    se = float(np.sqrt((m - 1) / m * np.sum((loo - loo.mean()) ** 2))) if m > 1 and np.all(np.isfinite(loo)) else float("inf")
    out.update(raw_px2=s2, stderr_px2=se)
    if s2 <= 0:
        out["rejected"] = f"slope {s2:.3g} px^2 is not positive"
    elif se * min_t > s2:
        out["rejected"] = f"not significant: {s2:.3g} +- {se:.2g} px^2 (needs {min_t:g} standard errors)"
    elif s2 > max_sigma2_px2:
        out["rejected"] = f"{s2:.3g} px^2 exceeds {max_sigma2_px2:g} px^2 (a camera in focus blurs less)"
    else:
        out["sigma2_px2"] = s2
    return out


def _edge_moments(lum: NDArray[np.float64], axis: int, half: int, min_contrast: float,
                  flat_tol: float) -> NDArray[np.float64]:
    """Second central moments (px^2) of the difference profiles of the single edges along ``axis``."""
    d = np.moveaxis(np.diff(lum, axis=axis), axis, -1)  # d[..., k] = lum[k + 1] - lum[k]
    n = d.shape[-1]
    ad = np.abs(d)
    peak = np.zeros(ad.shape, bool)  # local maxima of |d| along the axis, a window inside the image
    peak[..., half:n - half] = ((ad[..., half:n - half] >= ad[..., half - 1:n - half - 1])
                                & (ad[..., half:n - half] > ad[..., half + 1:n - half + 1]))
    idx = np.nonzero(peak)
    offs = np.arange(-half, half + 1)
    lead = tuple(np.repeat(i[:, None], offs.size, axis=1) for i in idx[:-1])
    dw = d[lead + (idx[-1][:, None] + offs[None, :],)]
    dw = dw * np.sign(dw[:, half])[:, None]
    contrast = dw.sum(axis=1)
    # one edge in the window: the profile never turns back by more than a fraction of its peak
    ok = (contrast >= min_contrast) & np.all(dw >= -flat_tol * dw[:, half:half + 1], axis=1)
    dw = np.clip(dw[ok], 0.0, None)
    m0 = dw.sum(axis=1)
    c = (dw * offs).sum(axis=1) / m0
    return (dw * (offs[None, :] - c[:, None]) ** 2).sum(axis=1) / m0


def blur_from_white(white: NDArray[np.floating], *, half_px: int = 3, min_contrast: float = 0.08,
                    flat_tol: float = 0.05, quantile: float = 0.25, min_edges: int = 50,
                    max_sigma2_px2: float = 1.5, max_spread: float = 1.6) -> dict[str, Any]:
    """The camera's blur variance (px^2) from the sharp edges of the object's white image.

    A reflectance step blurred by the lens is, across the edge, the integral of the blur's line
    spread function, so the differences of ``W`` along a row (or column) across the edge are that
    line spread, whose second central moment is the blur variance ``sigma^2`` (plus 1/12 px^2 for a
    step inside a pixel, which the camera's pixel integration adds to the blur the correction
    sees). Every local maximum of ``|diff W|`` along u and along v (the mean of the three channels,
    divided by its 99th percentile) whose window of ``2 half_px + 1`` differences holds one edge of
    contrast ``min_contrast`` or more (the differences never turn back by more than ``flat_tol`` of
    the peak) gives one moment; the estimate is their lower ``quantile``: noise and reflectance
    edges that are themselves soft (a photograph's) only widen an edge, never sharpen it. So on a
    smooth texture it reads too much (1.6 and 2.0 px^2 on the bench's photograph and tooth, where the
    phase estimate reads the true 0.81); it is the fallback of :func:`blur_from_phases`, for the
    surfaces that estimate cannot see: a few sharp coating edges (gauge blocks: 0.83 px^2, true
    0.81; the demo: 0.40, true 0.36 + 0.06 for its 2 x 2 sub-pixels). The window of 3 px holds a
    blur up to about sigma 1.2 px (1.4 px^2; a wider one reads low), so an estimate above
    ``max_sigma2_px2`` is refused, and so is one whose edges disagree: a lens gives every sharp
    edge the same width, so the upper quartile of the moments must lie within ``max_spread`` times
    the lower one (gauge blocks 1.19, the demo 1.40; the bench's tooth 1.77 and photograph 2.0,
    whose white images are smooth shading and texture, are refused by both tests).

    Returns
    -------
    dict
        ``sigma2_px2`` (0 when refused), ``edges`` (how many), ``quartiles_px2`` and, when fewer than
        ``min_edges`` edges were found, the estimate exceeds ``max_sigma2_px2`` or the quartiles
        lie further apart than ``max_spread``, ``rejected``.
    """
    w = np.asarray(white, np.float64)
    lum = w.mean(axis=-1) if w.ndim == 3 else w
    scale = float(np.percentile(lum, 99))
    out: dict[str, Any] = {"sigma2_px2": 0.0, "edges": 0, "quartiles_px2": None}
    if not scale > 0:
        out["rejected"] = "the white image is black"
        return out
    lum = lum / scale
    v = np.concatenate([_edge_moments(lum, ax, half_px, min_contrast, flat_tol) for ax in (0, 1)])
    out["edges"] = int(v.size)
    if v.size < min_edges:
        out["rejected"] = f"{v.size} sharp edges in the white image (needs {min_edges})"
        return out
    q = [float(x) for x in np.quantile(v, [0.25, 0.5, 0.75])]
    out["quartiles_px2"] = q
    s2 = float(np.quantile(v, quantile))
    if s2 > max_sigma2_px2:
        out["rejected"] = f"{s2:.3g} px^2 exceeds {max_sigma2_px2:g} px^2 (wider than the edge window measures)"
    elif q[2] > max_spread * q[0]:
        out["rejected"] = (f"the edges disagree: quartiles {q[0]:.3g} / {q[2]:.3g} px^2 (a lens gives every sharp "
                           f"edge one width; at most {max_spread:g} x)")
    else:
        out["sigma2_px2"] = s2
    return out


def blur_uncertainty(info: dict[str, Any], *, min_t: float = 3.0) -> float:
    """Standard uncertainty (px^2) of the blur variance the correction used, from the record of
    :func:`blur_from_phases` (``calib/planes.json`` ``texture_blur``).

    Accepted (``sigma2_px2`` used): the estimate's jackknife standard error ``stderr_px2``.
    Refused (0 used: the correction off): the blur is somewhere between 0 and the largest value
    the significance test could not tell from noise, ``max(raw_px2, 0) + min_t stderr_px2``, but
    never above :data:`MAX_BLUR_PX2` (no camera in focus blurs more; a noise-dominated estimate's
    standard error can be hundreds of px^2: 409 on photo_sensor with two repeats, docs/noise.md);
    taken as rectangular on that interval, the error of the 0 used has rms
    ``min(max(raw, 0) + min_t se, MAX_BLUR_PX2) / sqrt(3)`` (GUM 4.3.7). A record without a standard error (a blur given in the config, one
    frame, no texture signal) gives 0: no uncertainty is known.

    Read from the white image's edges instead (the phase estimate refused or one frame; the record's
    ``white_edges``, :func:`blur_from_white`, used): its estimate is the lower quartile of the edges'
    moments, and the truth is taken as rectangular between that and their median, ``(q50 - q25) /
    sqrt(3)`` (edges wider than the lens's own, soft or noisy ones, only raise the upper quantiles).
    """
    edges = info.get("white_edges")
    if isinstance(edges, dict) and "rejected" not in edges and edges.get("quartiles_px2"):
        q25, q50 = (float(x) for x in edges["quartiles_px2"][:2])
        return float(max(q50 - q25, 0.0) / np.sqrt(3.0))
    se = info.get("stderr_px2")
    if se is None or not np.isfinite(float(se)):
        return 0.0
    se = float(se)
    if "rejected" in info:
        return float(min(max(float(info.get("raw_px2", 0.0) or 0.0), 0.0) + min_t * se, MAX_BLUR_PX2) / np.sqrt(3.0))
    return se
