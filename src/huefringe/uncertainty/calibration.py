"""The calibration terms of the per-pixel height uncertainty, once per session: the table's and
the planes' terms, the interpolation bins, the pixel budget (:class:`PixelBudget`) and the
noise correlation of re-demosaiced captures.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, cast

import numba
import numpy as np
from numba import prange
from numpy.typing import NDArray
from scipy.ndimage import uniform_filter

from huefringe.huetable import band_smoothing_matrix, smoothing_window

__all__ = ["PixelBudget", "TERMS", "calibration_terms", "common_interpolation", "curvature_noise_factors",
           "interpolation_at", "interpolation_bins", "interval_curvature", "phase_error_residual_rad", "pixel_budget",
           "table_interpolation_rad", "table_variance_factor"]


TERMS = ("noise", "table", "interpolation", "reference", "model")
"""Names of the per-pixel terms, in the order of :func:`split_terms`."""
GROUPS = {"noise": "independent", "table": "pixel", "interpolation": "pixel", "reference": "correlated",
          "model": "correlated"}

#: Phase bins of the interpolation term: each pixel's error is taken in the bin its phase falls in.
INTERP_BINS = 12
#: Log code of the binned interpolation errors (uint8): ``q > 0`` means ``E0 2^(q / 16)`` rad.
_INTERP_E0 = 1e-5
_INTERP_LUT = np.concatenate([[0.0], _INTERP_E0 * 2.0 ** (np.arange(1, 256) / 16.0)]).astype(np.float32)

#: Side (px) of the box over which the planes' residuals are averaged to tell their systematic
#: part (a calibration error) from their pixel noise.
RESIDUAL_BOX_PX = 31


# calibration terms (once per session)
def _box_mean(x: NDArray[np.floating], valid: NDArray[np.bool_], size: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mean of ``x`` over the valid pixels of a ``size`` box around each pixel, and their count."""
    from scipy import ndimage

    v = valid & np.isfinite(x)
    s = ndimage.uniform_filter(np.where(v, x, 0.0).astype(np.float64), size, mode="constant")
    c = ndimage.uniform_filter(v.astype(np.float64), size, mode="constant")
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(c > 0, s / c, np.nan), c * size * size


def systematic_rms(residual: NDArray[np.floating], valid: NDArray[np.bool_], *, n_terms: int,
                   size: int = RESIDUAL_BOX_PX) -> tuple[NDArray[np.float64], float]:
    """Per-pixel uncertainty of a smoothed (polynomial-fitted) map from the raw map's residual.

    ``residual`` = raw - fitted. Its box mean over ``size`` pixels is the fit's local misfit
    (systematic, kept) plus the pixel noise that leaks through the box (``sigma^2 / n``,
    removed in quadrature); the polynomial's own noise adds ``sigma^2 n_terms / N`` (its mean
    leverage over ``N`` valid pixels). ``sigma`` is the robust spread of the residual about its
    box mean. Returns the map (rad, NaN where no valid pixel is near) and ``sigma``.
    """
    r = np.where(valid, np.asarray(residual, np.float64), np.nan)
    mean, count = _box_mean(r, valid, size)
    dev = (r - mean)[np.isfinite(r) & np.isfinite(mean)]
    sigma = float(1.4826 * np.median(np.abs(dev))) if dev.size else 0.0
    n = max(int(np.count_nonzero(np.isfinite(r))), 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        sys2 = np.maximum(mean**2 - sigma**2 / np.maximum(count, 1.0), 0.0)
    return np.sqrt(sys2 + sigma**2 * n_terms / n), sigma


def calibration_terms(
    solve: Any,
    dphis: Mapping[float, NDArray[np.floating]],
    u_dphi: Mapping[float, NDArray[np.floating]],
    *,
    eps: float = 1e-4,
) -> dict[str, NDArray[np.float32]]:
    """Covariance of the per-pixel model parameters ``(a, b)`` from the planes' phase errors.

    ``solve(dphis) -> (a, b)`` is the fit of :func:`huefringe.height.calibrate_planes`; its
    Jacobian with respect to each plane's phase difference is taken by forward differences
    (``eps`` rad, the model is smooth), and ``C = sum_j g_j g_j^T u_j^2`` (planes independent).
    """
    a0, b0 = solve(dphis)
    caa = np.zeros(np.shape(a0))
    cab = np.zeros_like(caa)
    cbb = np.zeros_like(caa)
    for z in dphis:
        moved = dict(dphis)
        moved[z] = np.asarray(dphis[z], np.float64) + eps
        a1, b1 = solve(moved)
        ga, gb = (a1 - a0) / eps, (b1 - b0) / eps
        u2 = np.nan_to_num(np.asarray(u_dphi[z], np.float64)) ** 2
        caa += ga * ga * u2
        cab += ga * gb * u2
        cbb += gb * gb * u2
    return {"cov_aa": caa.astype(np.float32), "cov_ab": cab.astype(np.float32), "cov_bb": cbb.astype(np.float32)}


def table_variance_factor(n_bands: int, window: int, order: int, repeats: int) -> float:
    """Variance of a smoothed table entry over the variance of one capture's hue.

    An entry is the mean of ``repeats`` captures (variance / R), smoothed along the band axis by
    :func:`huefringe.huetable.band_smoothing_matrix` (variance times the sum of its squared
    coefficients; the mean over the bands, since the windows are one-sided near sextant
    boundaries). Interpolating between two neighbouring entries, whose smoothing windows share
    almost all bands, keeps that variance.
    """
    window = smoothing_window(n_bands, window)  # the window the table was smoothed with
    if window > 1:
        coef = band_smoothing_matrix(int(n_bands), int(window), int(order))
        g = float(np.mean(np.sum(coef**2, axis=1)))
    else:
        g = 1.0
    return g / max(int(repeats), 1)


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _interval_errors(t, i, n, v, u, step, s120):  # pragma: no cover - compiled
    """Interval ``i``'s (entries ``i``, ``i + 1``, circular) two chord errors at one pixel: with
    the second difference at entry ``i + 1`` and with the mean of those at its two entries, each
    ``|D2| / D1 * step / sqrt(120)`` (0 where ``D1 <= 0``), capped at one step; and ``D1`` and
    the mean second difference (hue counts) for :func:`_interval_signal2`."""
    c0 = np.int64(t[(i - 1) % n, v, u])
    c1 = np.int64(t[i, v, u])
    c2 = np.int64(t[(i + 1) % n, v, u])
    c3 = np.int64(t[(i + 2) % n, v, u])
    dm = (c1 - c0 + 32768) % 65536 - 32768  # the interval before
    d1 = (c2 - c1 + 32768) % 65536 - 32768  # hue counts of interval i
    dp = (c3 - c2 + 32768) % 65536 - 32768  # the interval after
    d2 = dp - d1  # the second difference at entry i + 1
    curv = 0.5 * ((d1 - dm) + d2)  # the mean of the second differences at entries i, i + 1
    e = min((abs(d2) / d1 if d1 > 0 else 0.0) * step / s120, step)
    eb = min((abs(curv) / d1 if d1 > 0 else 0.0) * step / s120, step)
    return e, eb, d1, curv


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _interval_signal2(d1, curv, i, step, s120, vcurv, sig2, common, cresid2):  # pragma: no cover - compiled
    """Interval ``i``'s squared chord error (rad^2) from the part of its curvature the table's noise
    does not explain and the phase-error table does not remove: with ``r = curv / D1`` (the mean
    of the second differences at its two entries over its first difference, hue counts,
    :func:`_interval_errors`), ``max((r - common_i)^2 - vcurv_i sig2 / D1^2, 0) (step /
    sqrt(120))^2`` (formed as ``max((curv - common_i D1)^2 - vcurv_i sig2, 0) / D1^2``), at most one
    step squared, plus ``cresid2_i``; ``cresid2_i`` alone where ``D1 <= 0``."""
    if d1 <= 0:
        return cresid2[i]
    d = np.float64(d1)
    x = curv - common[i] * d  # (r - common) D1: one division below, no root
    kk = (step / s120) * (step / s120)
    return min(max(x * x - vcurv[i] * sig2, 0.0) / (d * d) * kk, step * step) + cresid2[i]


@numba.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _interp_kernel(t, which, counts, cover, want_bins, out_rad, out_bins, noise_free, vcurv, sig, common,
                   cresid2):  # pragma: no cover - compiled
    """:func:`table_interpolation_rad` (``out_rad``) and, with ``want_bins``,
    :func:`interpolation_bins` (``out_bins``) in one pass over the band-major table ``t``
    ``(N, H, W)`` uint16: per row, the bands in order and the row's pixels inner (contiguous),
    each pixel's squares summed in float64 in band order (NumPy's order of a reduction over the
    first axis), then ``sqrt(sum / count)`` rounded to float32. A bin that no interval starts in
    (``counts`` 0: fewer bands than bins) takes the interval ``cover`` holds for it. With
    ``noise_free`` the bins hold :func:`_interval_signal2` instead (``sig``: the pixel's band-mean
    noise in hue counts)."""
    n, h, w = t.shape
    nb = counts.shape[0]
    step = 2.0 * np.pi / n
    s120 = math.sqrt(120.0)
    for v in prange(h):
        acc = np.zeros(w)
        accb = np.zeros((nb, w))
        for i in range(n):
            j = which[i]
            if want_bins and noise_free:  # (each case its own loop, so that the rows stay branch-light)
                for u in range(w):
                    e, eb, d1, curv = _interval_errors(t, i, n, v, u, step, s120)
                    acc[u] += e * e
                    sg = sig[v, u]
                    accb[j, u] += _interval_signal2(d1, curv, i, step, s120, vcurv, sg * sg, common, cresid2)
            elif want_bins:
                for u in range(w):
                    e, eb, d1, curv = _interval_errors(t, i, n, v, u, step, s120)
                    acc[u] += e * e
                    accb[j, u] += eb * eb
            else:
                for u in range(w):
                    e, eb, d1, curv = _interval_errors(t, i, n, v, u, step, s120)
                    acc[u] += e * e
        for u in range(w):
            out_rad[v, u] = np.float32(np.sqrt(acc[u] / n))
            if want_bins:
                for b in range(nb):
                    if counts[b] > 0:
                        out_bins[v, u, b] = np.float32(np.sqrt(accb[b, u] / counts[b]))
                    elif noise_free:
                        sg = sig[v, u]
                        _, _, d1, curv = _interval_errors(t, cover[b], n, v, u, step, s120)
                        out_bins[v, u, b] = np.float32(np.sqrt(_interval_signal2(d1, curv, cover[b], step, s120, vcurv,
                                                                                 sg * sg, common, cresid2)))
                    else:
                        out_bins[v, u, b] = np.float32(_interval_errors(t, cover[b], n, v, u, step, s120)[1])


def curvature_noise_factors(n_bands: int, window: int, order: int) -> NDArray[np.float64]:
    """Variance of each interval's curvature (the mean of the second differences at its two
    entries, :func:`interpolation_bins`) over the variance of one band mean, for a table smoothed
    along the bands (:func:`huefringe.huetable.band_smoothing_matrix` with the window the table
    took): ``sum_j (C M)_kj^2``, ``M`` the smoother, ``C`` the curvature of interval ``k``
    (``(t[k+2] - t[k+1] - t[k] + t[k-1]) / 2``, circular)."""
    n = int(n_bands)
    coef = band_smoothing_matrix(n, smoothing_window(n, int(window)), int(order))
    m = coef.shape[1] // 2
    rows = np.arange(n)[:, None] + np.arange(-m, m + 1)[None, :]
    smooth = np.zeros((n, n))
    np.add.at(smooth, (np.repeat(np.arange(n), 2 * m + 1), np.mod(rows, n).ravel()), coef.ravel())
    curv = np.zeros((n, n))
    k = np.arange(n)
    for off, c in ((2, 0.5), (1, -0.5), (0, -0.5), (-1, 0.5)):
        np.add.at(curv, (k, (k + off) % n), c)
    return np.sum((curv @ smooth) ** 2, axis=1)


def interval_curvature(counts: NDArray[np.integer]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Each band interval's first difference ``D1`` and the mean ``curv`` of the second differences
    at its two entries (hue counts, circular, wrapped at 65536), of a band-major table ``(N, ...)``:
    the NumPy form of what :func:`interpolation_bins` takes per interval (``curv / D1`` its
    curvature ratio)."""
    t = np.asarray(counts).astype(np.int64)
    d1 = np.mod(np.roll(t, -1, axis=0) - t + 32768, 65536) - 32768
    return d1, 0.5 * ((d1 - np.roll(d1, 1, axis=0)) + (np.roll(d1, -1, axis=0) - d1))


def common_interpolation(table: Any, smoothing_rad: float, samples: int = 16) -> dict[str, NDArray[np.float64]]:
    """The interpolation error the phase-error table takes out, from the reference plate's table.

    The phase-error table (:mod:`huefringe.phase_error`) is the planes' median error per decoded
    phase, smoothed by a Gaussian of ``smoothing_rad``: the part of the chord error that every
    pixel of the plate shares (projector gamma, the same for every pixel) goes with it. Per
    interval ``k``: ``interp_common`` the median over the plate's valid pixels of its curvature
    ratio ``r = curv / D1`` (:func:`interpolation_bins`; intervals with ``D1 <= 0`` left out), and
    ``interp_common_resid_rad`` the rms over the interval of what the table's smoothing leaves of
    that shared chord error ``-f (1 - f) r step / 2`` (``samples`` points an interval, the Gaussian
    periodic in code phase). :func:`pixel_budget` subtracts the first from each pixel's ratio and
    adds the second."""
    from scipy.ndimage import gaussian_filter1d

    d1, curv = interval_curvature(np.asarray(table.table)[:, np.asarray(table.valid, bool)])
    n = d1.shape[0]
    with np.errstate(divide="ignore", invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an interval with no D1 > 0 anywhere: 0 below
        common = np.nan_to_num(np.nanmedian(np.where(d1 > 0, curv / d1, np.nan), axis=1))
    step = 2.0 * np.pi / n
    f = (np.arange(samples) + 0.5) / samples
    chord = (-(f * (1.0 - f) / 2.0)[None, :] * common[:, None] * step).ravel()
    left = chord
    if smoothing_rad > 0:
        left = chord - gaussian_filter1d(chord, float(smoothing_rad) / (step / samples), mode="wrap")
    return {"interp_common": common, "interp_common_resid_rad": np.sqrt(np.mean(left.reshape(n, samples) ** 2, axis=1))}


def _interp_errors(table: Any, bins: int, *, noise_free: bool = False,
                   common: NDArray[np.floating] | None = None,
                   common_resid: NDArray[np.floating] | None = None) -> tuple[NDArray[np.float32], NDArray[np.float32] | None]:
    """Both interpolation errors of ``table`` from one compiled pass (``bins`` 0: the rms alone),
    0 where the table is not valid. ``noise_free``: the bins from :func:`_interval_signal2`, the
    table's noise (its per-pixel ``noise_rad``, its smoothing) taken out of each interval's
    curvature and ``common`` (per interval, default 0) out of its ratio, ``common_resid`` (rad,
    default 0) added (:func:`pixel_budget`)."""
    t = np.ascontiguousarray(np.asarray(table.table), np.uint16)
    n, h, w = t.shape
    nb = max(int(bins), 1)
    which = ((np.arange(n) * nb) // n).astype(np.int64)  # interval k's bin: the one its start lies in
    counts = np.bincount(which, minlength=nb).astype(np.float64)
    cover = (np.arange(nb) * n // nb).astype(np.int64)  # the interval that holds each bin's start
    out_rad = np.empty((h, w), np.float32)
    out_bins = np.empty((h, w, bins) if bins > 0 else (1, 1, 1), np.float32)
    if noise_free:
        st = table.stats or {}
        p = st.get("params", {}) if isinstance(st.get("params"), dict) else {}
        vcurv = curvature_noise_factors(n, int(p.get("smooth_window", 15)), int(p.get("smooth_order", 2)))
        sig = np.ascontiguousarray(np.nan_to_num(np.asarray(table.noise_rad, np.float64)) * (65536.0 / (2.0 * np.pi)))
        cm = np.zeros(n) if common is None else np.ascontiguousarray(common, np.float64)
        cr2 = np.zeros(n) if common_resid is None else np.ascontiguousarray(common_resid, np.float64) ** 2
    else:
        vcurv, sig, cm, cr2 = np.zeros(1), np.zeros((1, 1)), np.zeros(1), np.zeros(1)
    _interp_kernel(t, which, counts, cover, bins > 0, out_rad, out_bins, bool(noise_free), vcurv, sig, cm, cr2)
    valid = np.asarray(table.valid, bool)
    out_rad[~valid] = 0.0
    if bins == 0:
        return out_rad, None
    out_bins[~valid] = 0.0
    return out_rad, out_bins


def table_interpolation_rad(table: Any) -> NDArray[np.float32]:
    """Per-pixel rms error (rad) of interpolating the hue table linearly between bands.

    Between two bands, a curved hue curve departs from its chord by ``f (1 - f) D2 / 2`` (``f``
    the fraction of the band width, ``D2`` the second difference of the entries); over a uniform
    ``f`` that has rms ``D2 / sqrt(120)``, which in code phase is ``D2 / D1 * step / sqrt(120)``
    (``D1`` the first difference: hue counts per band, circular; an interval with ``D1 <= 0``
    counts 0), each interval's error capped at one band step. The rms over the pixel's bands, 0
    where the table is not valid.
    """
    return _interp_errors(table, 0)[0]


def interpolation_bins(table: Any, *, bins: int = INTERP_BINS, noise_free: bool = False) -> NDArray[np.float32]:
    """Per-pixel rms linear-interpolation error (rad) in each of ``bins`` equal code-phase bins,
    ``(H, W, bins)``: the error of interval ``k`` (between entries ``k`` and ``k + 1``) is
    ``|D2| / D1 * step / sqrt(120)`` with ``D2`` the mean of the second differences at its two
    entries (see :func:`table_interpolation_rad`), and a bin holds the rms over its intervals
    (interval ``k`` in bin ``k bins // N``, the bin its start lies in); with fewer bands than bins,
    a bin that no interval starts in holds the interval its own start lies in.
    A pixel's term is then the value of the bin its phase falls in (:func:`interpolation_at`), not
    the rms over its whole table (where a few flattened bands near the sextant starts would
    dominate). ``noise_free``: each interval's curvature less what the table's own noise explains
    (the positive part of ``(D2 / D1)^2 - var(D2) / D1^2``, the pixel's ``noise_rad`` through the
    table's smoothing: :func:`curvature_noise_factors`), as :func:`pixel_budget` takes it without
    a phase-error table (the table term holds that noise)."""
    if int(bins) < 1:
        raise ValueError(f"interpolation bins must be at least 1, got {bins}")
    return cast(NDArray[np.float32], _interp_errors(table, int(bins), noise_free=bool(noise_free))[1])


def interpolation_at(bins: NDArray[np.floating], code_phase: NDArray[np.floating]) -> NDArray[np.float64]:
    """Each pixel's value of :func:`interpolation_bins` in the bin its code phase (rad, the
    table's: band ``k`` at ``2 pi k / N``) falls in, ``floor(K (phase mod 2 pi) / 2 pi)`` of ``K``
    bins; 0 where the phase is not finite."""
    b = np.asarray(bins)
    k = b.shape[-1]
    ph = np.asarray(code_phase, np.float64)
    ok = np.isfinite(ph)
    kb = np.minimum((np.mod(np.where(ok, ph, 0.0), 2.0 * np.pi) * (k / (2.0 * np.pi))).astype(np.int64), k - 1)
    return np.where(ok, np.take_along_axis(b, kb[..., None], axis=-1)[..., 0].astype(np.float64), 0.0)


def _encode_interp(e: NDArray[np.floating]) -> NDArray[np.uint8]:
    """Log code of :data:`_INTERP_LUT` (4.4 % steps; 0 below ``E0``), nearest in log."""
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.rint(16.0 * np.log2(np.asarray(e, np.float64) / _INTERP_E0))
    return np.clip(np.nan_to_num(q, nan=0.0, neginf=0.0), 0, 255).astype(np.uint8)


def phase_error_residual_rad(stats: Mapping[str, Any] | None) -> float:
    """What the phase-error table leaves on the planes (rad), from its QA figures: the rms over
    the bins of the median plane residual after the correction (``binned_rms_after_rad``),
    less in quadrature its noise part (a median of ``samples / bins`` residuals of rms
    ``residual_rms_after_rad``: variance ``(pi / 2) s^2 bins / samples``). Reported in
    ``planes.json``; not added to u (``docs/uncertainty.md``: on the bench it over-predicts,
    the planes' spatial misfit that the reference and model terms carry shows in its bins)."""
    if not stats:
        return 0.0
    b = float(stats.get("binned_rms_after_rad", 0.0))
    s = float(stats.get("residual_rms_after_rad", 0.0))
    leak = 0.5 * math.pi * s * s * float(stats.get("bins", 0)) / max(float(stats.get("samples", 0)), 1.0)
    return math.sqrt(max(b * b - leak, 0.0))


@dataclass(eq=False)
class PixelBudget:
    """Per-session inputs of the per-pixel budget: ``terms`` ``(5, H, W)`` float32 (planes, so
    that the kernel's rows vectorise) holding the
    reference phase's uncertainty (rad), the (a, b) covariance ``aa, ab, bb`` and the table's
    interpolation error (rad); ``table_factor`` (:func:`table_variance_factor`)."""

    terms: NDArray[np.float32]
    table_factor: float
    interp_bins: NDArray[np.uint8] | None = None
    """``(H, W, INTERP_BINS)`` log codes of :func:`interpolation_bins` (None: ``terms[4]`` for
    every phase)."""
    phi_ref: NDArray[np.float32] | None = None
    """The reference phase: a pixel's code phase is ``phi_ref + dphi``, which picks its bin."""
    noise_factor: float = 1.0
    """Variance factor of the noise and table terms for noise correlated between neighbours (a
    re-demosaiced Bayer session: :func:`noise_correlation`, the table's ``noise_correlation``
    stats); the filter's ``1 / sum w`` assumes independent pixels. 1 for a three-chip camera."""

    @property
    def u_ref_rad(self) -> NDArray[np.float32]:
        return self.terms[0]

    @property
    def u_interp_rad(self) -> NDArray[np.float32]:
        return self.terms[4]


def pixel_budget(table: Any, cal: Any) -> PixelBudget:
    """The per-pixel budget's session inputs from the object's hue table and the plane calibration.

    ``cal.budget`` (written by :func:`huefringe.height.calibrate_planes`) gives the reference and
    model terms; a calibration without it (an older model file) gives zeros for them.

    The interpolation term's bins are the chord errors of the curvature that is not the table's
    noise (:func:`curvature_noise_factors` and the pixel's ``noise_rad``: the table term holds
    that) and, where the calibration applied a phase-error table, not the plate's shared curvature
    that the table takes out (``cal.budget``'s ``interp_common`` and ``interp_common_resid_rad``,
    :func:`common_interpolation`); ``terms[4]`` is their rms over the intervals.
    """
    h, w = table.shape
    terms = np.zeros((5, h, w), np.float32)
    bud = getattr(cal, "budget", None) or {}
    for k, name in enumerate(("u_ref_rad", "cov_aa", "cov_ab", "cov_bb")):
        if name in bud:
            terms[k] = np.nan_to_num(np.asarray(bud[name], np.float32))
    n = int(table.n_bands)
    common = {k: np.asarray(bud[k], np.float64) for k in ("interp_common", "interp_common_resid_rad")
              if k in bud and np.size(bud[k]) == n}
    _, interp = _interp_errors(table, INTERP_BINS, noise_free=True, common=common.get("interp_common"),
                               common_resid=common.get("interp_common_resid_rad"))
    share = np.bincount((np.arange(n) * INTERP_BINS) // n, minlength=INTERP_BINS) / n  # intervals per bin
    terms[4] = np.sqrt(np.einsum("hwb,b->hw", interp.astype(np.float64) ** 2, share))  # rms over the intervals
    bins = _encode_interp(interp)
    st = table.stats or {}
    opts = st.get("params", {}) if isinstance(st.get("params"), dict) else {}
    window = int(opts.get("smooth_window", 15))
    order = int(opts.get("smooth_order", 2))
    factor = table_variance_factor(table.n_bands, window, order, int(st.get("repeats", 1) or 1))
    corr = st.get("noise_correlation") or {}
    return PixelBudget(np.ascontiguousarray(terms), factor, np.ascontiguousarray(bins),
                       np.ascontiguousarray(cal.phi_ref, np.float32), max(1.0, float(corr.get("factor", 1.0))))


def noise_correlation(differences: Sequence[NDArray[np.floating]], box: int = 5) -> dict[str, Any]:
    """How much less a box mean of neighbours averages noise than independent pixels would.

    ``differences``: hue differences (rad) between two repeats of the same band (pure noise; NaN
    where undefined). Per image, pixels beyond 5 MADs are left out; the factor is
    ``box^2 var(box mean) / var(pixel)`` over the pixels whose whole ``box x box`` window is
    used, the median over the images (1 for independent noise; a re-demosaiced Bayer capture reads
    1.66 for 5 x 5, docs/accuracy-cameras.md). Returns ``factor``, ``box``, ``images``.
    """
    vals = []
    for d in differences:
        d = np.asarray(d, np.float64)
        ok = np.isfinite(d)
        if ok.sum() < 100:
            continue
        d = d - np.median(d[ok])
        mad = 1.4826 * np.median(np.abs(d[ok]))
        ok &= np.abs(d) <= 5.0 * max(mad, 1e-12)
        x = np.where(ok, d, 0.0)
        full = uniform_filter(ok.astype(np.float64), box, mode="constant") > 1.0 - 1e-9
        if full.sum() < 100:
            continue
        mean = uniform_filter(x, box, mode="constant")
        vals.append(float(box * box * np.mean(mean[full] ** 2) / np.mean(x[ok] ** 2)))
    return {"factor": float(np.median(vals)) if vals else 1.0, "box": int(box), "images": len(vals)}
