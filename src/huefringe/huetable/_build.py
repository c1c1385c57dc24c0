"""Building the hue table from the projected hue bands: accumulate, smooth, finalise."""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable, Sequence
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from .. import colour
from ..patterns import TWO_PI, band_sextants, single_repeat_problem
from ..session import read_rgb
from ._noise import BAND_DIFFERENCE_ORDER, _HueNoiseStats, _band_noise_kernel
from ._store import HueTable, NOISE_SOURCES, REASONS, _R_LOW_SAT, _R_LOW_SIGNAL, _Reader


def band_smoothing_matrix(n_bands: int, window: int, order: int = 2) -> NDArray[np.float64]:
    """Coefficients of the along-band local-polynomial smoother, one row per band (a new array;
    the coefficients are computed once per ``(n_bands, window, order)`` in a process).

    Row ``i`` holds the weights of bands ``i - m .. i + m`` (``m = window // 2``) that
    evaluate at band ``i`` a least-squares polynomial of degree ``order`` (Savitzky-Golay). The
    support never crosses a sextant boundary of the code, ``c = k pi / 3``, where the trapezoid of
    eq. 3 switches channel and the captured hue curve has a kink (per-channel gamma makes the
    slope jump there); near a boundary the window is one-sided instead (c = 0 is a boundary, so no
    window wraps round). ``window <= 1`` gives the identity.
    """
    return _band_smoothing(int(n_bands), int(window), int(order)).copy()


def smoothing_window(n_bands: int, window: int) -> int:
    """The along-band smoothing window a table of ``n_bands`` bands takes for a requested
    ``window``: at most the largest odd number <= ``n_bands`` (a session may hold fewer bands
    than the default window). :func:`build_table` smooths with it and records it;
    :func:`huefringe.uncertainty.table_variance_factor` assumes it."""
    return min(int(window), int(n_bands) - (1 - int(n_bands) % 2))


@functools.lru_cache(maxsize=16)
def _band_smoothing(n_bands: int, window: int, order: int) -> NDArray[np.float64]:
    """:func:`band_smoothing_matrix`, computed (a per-session constant that frames ask for)."""
    m = max(0, int(window) // 2)
    if window > 1 and window % 2 == 0:
        raise ValueError("smooth_window must be odd")
    if 2 * m + 1 > n_bands:
        raise ValueError("smooth_window must be <= N")
    coef = np.zeros((n_bands, 2 * m + 1), dtype=np.float64)
    if m == 0:
        coef[:, 0] = 1.0
        return coef
    seg = band_sextants(n_bands)
    for i in range(n_bands):
        left = 0
        while left < m and i - left - 1 >= 0 and seg[i - left - 1] == seg[i]:
            left += 1
        right = 0
        while right < m and i + right + 1 < n_bands and seg[i + right + 1] == seg[i]:
            right += 1
        x = np.arange(-left, right + 1, dtype=np.float64)
        deg = min(order, x.size - 1)
        vander = np.vander(x, deg + 1, increasing=True)  # columns 1, x, x^2, ...
        w = np.linalg.pinv(vander)[0]  # weights giving the fitted value at x = 0
        coef[i, m - left : m + right + 1] = w
    return coef


# =============================================================================================
# numba kernels
# =============================================================================================
@numba.njit(cache=True, parallel=False, nogil=True)
def _accumulate_kernel(hues, plane, var_sum, dof, missing):  # pragma: no cover - numba
    """Mean direction of one band's repeats into a uint16 plane; spread into the accumulators.

    The mean direction is the arithmetic mean of the repeats unwrapped about the first valid one,
    ``x0 + mean(wrap(x_r - x0))``: for concentrated samples it equals the circular mean
    ``atan2(sum sin, sum cos)`` to third order in the spread (1e-5 rad at a 0.1 rad spread, below
    the table's 4.8e-5 rad quantisation) and needs no trigonometry.
    """
    n_rep, h, w = hues.shape
    two_pi = 2.0 * np.pi
    scale = 65536.0 / two_pi
    for v in range(h):
        for u in range(w):
            x0 = 0.0
            acc = 0.0
            cnt = 0
            for r in range(n_rep):
                x = np.float64(hues[r, v, u])
                if x == x:
                    if cnt == 0:
                        x0 = x
                    else:
                        d = x - x0
                        if d >= np.pi:
                            d -= two_pi
                        elif d < -np.pi:
                            d += two_pi
                        acc += d
                    cnt += 1
            if cnt == 0:
                missing[v, u] = True
                plane[v, u] = 0
                continue
            m = x0 + acc / cnt
            if cnt >= 2:
                ss = 0.0
                for r in range(n_rep):
                    x = np.float64(hues[r, v, u])
                    if x == x:
                        d = x - m
                        if d >= np.pi:
                            d -= two_pi
                        elif d < -np.pi:
                            d += two_pi
                        ss += d * d
                var_sum[v, u] += ss
                dof[v, u] += cnt - 1
            q = int(math.floor(m * scale + 0.5))
            while q < 0:
                q += 65536
            while q >= 65536:
                q -= 65536
            plane[v, u] = q


@numba.njit(cache=True, parallel=False)
def _finalise_kernel(table, sigma, reason, start, coef, max_noise, max_gap, order_tol_min, order_sigmas):  # pragma: no cover - numba
    """Per-pixel checks, band-axis smoothing, monotone fix and requantisation (in place)."""
    n, h, w = table.shape
    two_pi = 2.0 * np.pi
    rad = two_pi / 65536.0
    step = two_pi / n
    half = coef.shape[1] // 2
    hh = np.empty(n)
    s = np.empty(n)
    d = np.empty(n)
    us = np.empty(n)
    f = np.empty(n)
    q = np.empty(n, dtype=np.int64)
    for v in range(h):
        for u in range(w):
            if reason[v, u] != 0:
                continue
            sig = sigma[v, u]
            if sig == sig and sig > max_noise:
                reason[v, u] = 3
                continue
            for i in range(n):
                hh[i] = table[i, v, u] * rad
            total = 0.0
            smax = -1e9
            smin = 1e9
            for i in range(n):
                j = i + 1 if i + 1 < n else 0
                x = hh[j] - hh[i]
                x = x - two_pi * math.floor((x + np.pi) / two_pi)
                s[i] = x
                total += x
                if x > smax:
                    smax = x
                if x < smin:
                    smin = x
            if abs(total - two_pi) > np.pi or smax > max_gap:
                reason[v, u] = 4
                continue
            tol = order_tol_min
            if sig == sig and order_sigmas * math.sqrt(2.0) * sig > tol:
                tol = order_sigmas * math.sqrt(2.0) * sig
            if smin < -tol:
                reason[v, u] = 5
                continue
            # unwrapped curve and its distortion d = U - c (2 pi periodic)
            acc = hh[0]
            for i in range(n):
                d[i] = acc - i * step
                acc += s[i]
            # largest fall below the running maximum (over 2 turns, so that a reversal across
            # band 0 is seen): a slow reversal spread over many bands is as bad as a jump back
            top = -1e300
            drop = 0.0
            for k in range(2 * n):
                i = k if k < n else k - n
                x = d[i] + i * step + (0.0 if k < n else two_pi)
                if x > top:
                    top = x
                elif top - x > drop:
                    drop = top - x
            if drop > tol:
                reason[v, u] = 5
                continue
            # local polynomial smoothing along the band axis (one coefficient row per band)
            for i in range(n):
                x = 0.0
                for k in range(coef.shape[1]):
                    ck = coef[i, k]
                    if ck != 0.0:
                        jj = i + k - half
                        if jj < 0:
                            jj += n
                        elif jj >= n:
                            jj -= n
                        x += ck * d[jj]
                us[i] = i * step + x
            # monotone fix: mean of running max and reversed running min (bounded by one turn)
            top = us[0] + two_pi
            m = us[0]
            for i in range(n):
                if us[i] > m:
                    m = us[i]
                f[i] = m if m < top else top
            m = top
            for i in range(n - 1, -1, -1):
                if us[i] < m:
                    m = us[i]
                f[i] = 0.5 * (f[i] + m)
            # quantise; f[0] is the minimum: keep the whole curve within one turn (in counts, so
            # that rounding cannot push the last band past the first one)
            q0 = int(math.floor(f[0] / rad + 0.5))
            for i in range(n):
                qi = int(math.floor(f[i] / rad + 0.5))
                if qi > q0 + 65536:
                    qi = q0 + 65536
                q[i] = qi % 65536
            desc = 0
            first = 0
            for i in range(n):
                prev = q[i - 1] if i > 0 else q[n - 1]
                if q[i] < prev:
                    desc += 1
                    first = i
            if desc != 1:
                reason[v, u] = 5
                continue
            start[v, u] = first
            for i in range(n):
                table[i, v, u] = q[i]


def white_balance_floor(min_intensity: float) -> float:
    """The white-balance floor :func:`build_table` uses by default: half the table's
    ``min_intensity`` (pixels whose white image is below it in a channel are masked anyway), one
    8-bit count (``1 / 255``) when ``min_intensity`` is 0.

    Parameters
    ----------
    min_intensity : float
        The table's minimum white-image level (0..1).

    Returns
    -------
    float
        The floor on the white image before its inversion (:func:`huefringe.colour.white_gains`).
    """
    return 0.5 * min_intensity if min_intensity > 0 else 1.0 / 255.0


def build_table(
    band_paths: Sequence[Sequence[str | os.PathLike[str]]],
    white: NDArray[np.floating],
    *,
    model: colour.HueModel = "hexcone",
    read: Callable[[Any], NDArray[np.floating]] = read_rgb,
    min_saturation: float = 0.05,
    min_intensity: float = 0.02,
    floor: float | None = None,
    smooth_window: int = 15,
    smooth_order: int = 2,
    max_noise_steps: float = 2.0,
    max_gap: float = np.pi / 3.0,
    order_steps: float = 2.0,
    order_sigmas: float = 6.0,
    out: NDArray[np.uint16] | None = None,
    prefetch: int = 0,
    progress: bool = False,
    on_image: Callable[[int, int, NDArray[np.floating]], None] | None = None,
    on_hue: Callable[[int, int, NDArray[np.float32]], None] | None = None,
) -> HueTable:
    """Build a per-pixel hue table from ``N`` bands x ``R`` repeats, streaming the images.

    Parameters
    ----------
    band_paths : sequence of sequences
        ``band_paths[i][r]`` is band ``i`` (code phase ``2 pi i / N``), repeat ``r``; every band
        must have the same number of repeats ``R >= 1``. Anything ``read`` accepts.
    white : ndarray, shape (H, W, 3)
        Capture of the white projection on the same scene (float in [0, 1]).
    model : {"hexcone", "hsi"}
        Hue model.
    read : callable
        ``read(path) -> (H, W, 3)`` float image in [0, 1]; called once per image, band by band,
        repeat by repeat, in order.
    min_saturation : float
        Repeats whose white-balanced saturation is ``<= min_saturation`` give no hue.
    min_intensity : float
        Pixels whose white image is below this in any channel are masked ``low_signal``.
    floor : float, optional
        White-balance floor (see :func:`huefringe.colour.white_balance`); default
        :func:`white_balance_floor` of ``min_intensity`` (``min_intensity / 2``).
    smooth_window, smooth_order : int
        Local-polynomial window (odd, in bands) and degree along the band axis, not crossing the
        code's sextant boundaries (:func:`band_smoothing_matrix`); window <= 1 disables. A window
        wider than the table's ``N`` bands takes the largest odd number <= N
        (:func:`smoothing_window`, which the stats record).
    max_noise_steps : float
        Mask ``noise`` when the standard error of a band mean (from the repeats, or with one
        repeat from the third difference along the bands) exceeds this many band steps.
    max_gap : float
        Mask ``coverage`` when two consecutive bands are more than this apart in captured hue.
    order_steps, order_sigmas : float
        Mask ``order`` when the captured hue falls back below its running maximum over the bands
        by more than ``max(order_steps * 2 pi / N, order_sigmas * sqrt(2) * noise)``, ``noise`` the
        pixel's pooled standard error of a band mean. Noise is not the same in every band (in
        the flat stretches that gamma makes at the start of each sextant it is up to ~3x the
        pooled value), hence the large default of 6; smaller reversals are harmless after the
        monotone fix (they act like noise).
    out : ndarray of uint16, shape (N, H, W), optional
        Preallocated table (e.g. a ``numpy.lib.format.open_memmap``) to fill instead of a new one.
    prefetch : int
        Bands to read ahead in background threads (PNG decoding releases the GIL, so reading
        overlaps the hue computation); 0 (default) reads strictly one image after the other in
        the calling thread. At most ``(prefetch + 1) R`` images are alive at a time.
    progress : bool
        Show a tqdm progress bar over bands.
    on_image : callable, optional
        ``on_image(i, r, image)`` with every image as read (band ``i``, repeat ``r``), before it
        is reduced: a caller's own statistics of the same images without reading them again.
    on_hue : callable, optional
        ``on_hue(i, r, hue)`` with every image's white-balanced hue as the table takes it
        (``colour.balanced_hue`` with ``floor`` and ``min_saturation``; float32 ``(H, W)``, NaN
        where no hue), valid only during the call: a caller's statistics of the table's own hue
        without computing it again.

    Returns
    -------
    HueTable

    Notes
    -----
    Images are read one at a time and reduced at once to a hue plane; only one band's ``R`` hue
    planes are alive at a time. Memory is the table (``2 N H W`` bytes) plus
    ``~ (4 R + 70) H W`` bytes of work planes and the sensor-noise fit's samples (56 bytes for each
    of at most ``N ceil(H / 3) ceil(W / 3)`` and 400,000, about three times that while fitting: at
    most 90 MB). The per-band mean is the mean direction of the repeats (see
    ``_accumulate_kernel``: equal to the circular mean to third order in the spread).
    """
    n = len(band_paths)
    if n < 6:
        raise ValueError(f"need at least 6 hue bands, got {n}")
    reps = {len(b) for b in band_paths}
    if len(reps) != 1 or 0 in reps:
        raise ValueError(f"every band needs the same number (>= 1) of repeats, got {sorted(reps)}")
    n_rep = reps.pop()
    too_few = single_repeat_problem(n, n_rep)
    if too_few:
        raise ValueError(too_few)
    if model not in colour.HUE_MODELS:
        raise ValueError(f"unknown hue model {model!r}")
    white = np.asarray(white, dtype=np.float32)
    if white.ndim != 3 or white.shape[2] != 3:
        raise ValueError(f"white must be (H, W, 3), got {white.shape}")
    h, w = white.shape[:2]
    if floor is None:
        floor = white_balance_floor(min_intensity)
    if out is None:
        table = np.empty((n, h, w), dtype=np.uint16)
    else:
        if out.shape != (n, h, w) or out.dtype != np.uint16:
            raise ValueError(f"out must be uint16 {(n, h, w)}, got {out.dtype} {out.shape}")
        table = out
    tab = np.asarray(table)  # plain ndarray view (also of a memmap) for the compiled kernels
    gains = colour.white_gains(white, floor)
    reason = np.zeros((h, w), dtype=np.uint8)
    reason[np.min(white, axis=2) < min_intensity] = _R_LOW_SIGNAL
    missing = np.zeros((h, w), dtype=bool)
    var_sum = np.zeros((h, w), dtype=np.float64)
    dof_map = np.zeros((h, w), dtype=np.int32)
    hues = np.empty((n_rep, h, w), dtype=np.float32)

    bands: Any = range(n)
    if progress:
        from tqdm import tqdm

        bands = tqdm(bands, desc="hue bands", unit="band")
    noise_stats = _HueNoiseStats(h, w, n, n_rep, gains, model)  # the sensor's shot + read model, on the hue
    with _Reader(read, band_paths, prefetch) as reader:
        for i in bands:
            for r, path in enumerate(band_paths[i]):
                img = np.asarray(reader.get(i, r))
                if img.shape != (h, w, 3):
                    raise ValueError(f"{path}: image shape {img.shape} differs from white {white.shape}")
                colour.balanced_hue(img, gains, model, min_saturation=min_saturation, out=hues[r])
                if on_hue is not None:
                    on_hue(i, r, hues[r])
                noise_stats.add(img, hues[r])
                if on_image is not None:
                    on_image(i, r, img)
                del img
            _accumulate_kernel(hues, tab[i], var_sum, dof_map, missing)
            noise_stats.end_band()
    del hues

    reason[(reason == 0) & missing] = _R_LOW_SAT
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.where(dof_map > 0, np.sqrt(var_sum / np.maximum(dof_map, 1)) / math.sqrt(n_rep), np.nan).astype(np.float64)
    del var_sum, dof_map
    if n_rep == 1:  # no repeats: the noise from the single repeat's differences along the bands
        sigma = np.empty((h, w), np.float64)
        _band_noise_kernel(tab, reason, BAND_DIFFERENCE_ORDER, sigma)
    step = TWO_PI / n
    if smooth_window % 2 == 1:  # fewer bands than the window (an even one is refused below)
        smooth_window = smoothing_window(n, smooth_window)
    coef = band_smoothing_matrix(n, smooth_window, smooth_order)
    start = np.zeros((h, w), dtype=np.uint16)
    _finalise_kernel(tab, sigma, reason, start, coef, float(max_noise_steps * step), float(max_gap),
                     float(order_steps * step), float(order_sigmas))
    valid = reason == 0
    noise = sigma.astype(np.float32)
    counts = np.bincount(reason.ravel(), minlength=len(REASONS))
    sv = noise[valid & np.isfinite(noise)]
    stats: dict[str, Any] = {
        "n_bands": n,
        "repeats": n_rep,
        "shape": [h, w],
        "model": model,
        "n_pixels": int(h * w),
        "n_valid": int(counts[0]),
        "valid_fraction": float(counts[0] / (h * w)),
        "masked_by_reason": {REASONS[k]: int(counts[k]) for k in range(1, len(REASONS))},
        "noise_rad": {
            "median": float(np.median(sv)) if sv.size else None,
            "p95": float(np.percentile(sv, 95)) if sv.size else None,
            "source": NOISE_SOURCES[0] if n_rep >= 2 else NOISE_SOURCES[1],
        },
        "sensor_noise": noise_stats.fit(),
        "table_bytes": int(table.nbytes),
        "params": {
            "min_saturation": float(min_saturation),
            "min_intensity": float(min_intensity),
            "floor": float(floor),
            "smooth_window": int(smooth_window),
            "smooth_order": int(smooth_order),
            "max_noise_steps": float(max_noise_steps),
            "max_gap": float(max_gap),
            "order_steps": float(order_steps),
            "order_sigmas": float(order_sigmas),
        },
    }
    return HueTable(model=model, n_bands=n, table=table, valid=valid, start=start, reason=reason, noise_rad=noise, stats=stats)
