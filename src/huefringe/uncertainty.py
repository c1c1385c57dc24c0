"""Per-pixel height uncertainty (GUM), and its propagation into step heights.

The height of a pixel is ``h = dphi / (a + b dphi)`` with ``dphi = phi - phi_ref`` (filtered).
Its standard uncertainty combines five terms (``docs/uncertainty.md`` has the formulas and their
sizes on the demo), kept in three groups because they average differently:

=============  =================================================  ==================================
group          terms                                              averages over
=============  =================================================  ==================================
independent    ``noise``: sensor (shot + read) noise of the       pixels (by the effective number of
               frame through the hue, the table slope and the     independent pixels) and frames
               phase filter (``1 / sum w``)
pixel          ``table``: noise of the smoothed table entries;    pixels, not frames (the table is
               ``interpolation``: linear interpolation            the same for every frame)
               between bands
correlated     ``reference``: the z = 0 plane's smoothed          neither (shared by the pixels of a
               phase; ``model``: the (a, b) fit of the planes     region and by every frame)
=============  =================================================  ==================================

With the height's sensitivity ``G = dh/ddphi = a / (a + b dphi)^2`` and the parameter
sensitivities ``J = (dh/da, dh/db) = -(dphi, dphi^2) / (a + b dphi)^2``::

    u_noise = G sqrt(sum w r) / sum w  the filter's weights w = 1/sigma^2 it used (pooled
                                       noise), r = own-signal / pooled noise variance
    u_table = u_noise sqrt(f_table)    f_table = smoothed entry variance / one capture's
    u_interp = G u_interp_rad          rms linear-interpolation error of the pixel's table in
                                       the code-phase bin of its own phase (12 bins)
    u_ref = G u_ref_rad                smoothed-reference error (fit noise + unmodelled misfit)
    u_model = sqrt(J C J^T)            C = covariance of (a, b) from the planes' errors

The frame's hue noise (behind ``r``) comes from its own RGB signal through a shot + read noise
model fitted on the hue bands' repeats (:func:`huefringe.perframe.frame_hue_noise`); the weights
stay the table's pooled noise, so that the heights do not depend on it. After the
root sum of squares, :func:`edge_floor` raises mixed pixels (steps, shadow borders) to the local
scatter of the heights about their 3 x 3 plane.

This module is pure: it never reads files and never imports the bench.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numba
import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import uniform_filter

from huefringe.huetable import band_smoothing_matrix

__all__ = [
    "TERMS", "PixelBudget", "calibration_terms", "conformance", "edge_floor", "height_uncertainty", "add_lateral", "coating_term", "lateral_term", "texture_term",
    "interpolation_bins", "phase_error_residual_rad", "pixel_budget", "reliability", "split_terms", "step_budget",
    "table_interpolation_rad", "table_variance_factor",
]

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


# --------------------------------------------------------------------------------------------
# calibration terms (once per session)
# --------------------------------------------------------------------------------------------
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
    window = min(int(window), int(n_bands) - (1 - int(n_bands) % 2))  # the smoother never exceeds N
    if window > 1:
        coef = band_smoothing_matrix(int(n_bands), int(window), int(order))
        g = float(np.mean(np.sum(coef**2, axis=1)))
    else:
        g = 1.0
    return g / max(int(repeats), 1)


def table_interpolation_rad(table: Any, *, rows: int = 64) -> NDArray[np.float32]:
    """Per-pixel rms error (rad) of interpolating the hue table linearly between bands.

    Between two bands, a curved hue curve departs from its chord by ``f (1 - f) D2 / 2`` (``f``
    the fraction of the band width, ``D2`` the second difference of the entries); over a uniform
    ``f`` that has rms ``D2 / sqrt(120)``, which in code phase is ``D2 / D1 * step / sqrt(120)``
    (``D1`` the first difference: hue counts per band). The rms over the pixel's bands.
    """
    t = np.asarray(table.table)
    n = t.shape[0]
    step = 2.0 * np.pi / n
    out = np.zeros(t.shape[1:], np.float32)
    for v0 in range(0, t.shape[1], rows):
        c = t[:, v0 : v0 + rows].astype(np.int32)
        d1 = np.mod(np.roll(c, -1, axis=0) - c + 32768, 65536) - 32768  # counts per band, circular
        d2 = np.roll(d1, -1, axis=0) - d1
        with np.errstate(divide="ignore", invalid="ignore"):
            e = np.where(d1 > 0, np.abs(d2) / d1, 0.0) * step / math.sqrt(120.0)
        out[v0 : v0 + rows] = np.sqrt(np.mean(np.minimum(e, step) ** 2, axis=0))
    return np.where(np.asarray(table.valid, bool), out, 0.0).astype(np.float32)


def interpolation_bins(table: Any, *, bins: int = INTERP_BINS, rows: int = 64) -> NDArray[np.float32]:
    """Per-pixel rms linear-interpolation error (rad) in each of ``bins`` equal code-phase bins,
    ``(H, W, bins)``: the error of interval ``k`` (between entries ``k`` and ``k + 1``) is
    ``|D2| / D1 * step / sqrt(120)`` with ``D2`` the mean of the second differences at its two
    entries (see :func:`table_interpolation_rad`), and a bin holds the rms over its intervals.
    A pixel's term is then the value of the bin its phase falls in, not the rms over its whole
    table (where a few flattened bands near the sextant starts would dominate)."""
    t = np.asarray(table.table)
    n = t.shape[0]
    step = 2.0 * np.pi / n
    which = (np.arange(n) * bins) // n
    out = np.zeros((*t.shape[1:], bins), np.float32)
    for v0 in range(0, t.shape[1], rows):
        c = t[:, v0 : v0 + rows].astype(np.int32)
        d1 = np.mod(np.roll(c, -1, axis=0) - c + 32768, 65536) - 32768  # interval k: entries k, k + 1
        d2 = np.roll(d1, -1, axis=0) - d1  # at entry k + 1
        curv = 0.5 * (np.roll(d2, 1, axis=0) + d2)  # at the interval's two entries
        with np.errstate(divide="ignore", invalid="ignore"):
            e = np.minimum(np.where(d1 > 0, np.abs(curv) / d1, 0.0) * step / math.sqrt(120.0), step)
        for j in range(bins):
            out[v0 : v0 + rows, :, j] = np.sqrt(np.mean(e[which == j] ** 2, axis=0))
    return np.where(np.asarray(table.valid, bool)[..., None], out, 0.0).astype(np.float32)


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
    """
    h, w = table.shape
    terms = np.zeros((5, h, w), np.float32)
    bud = getattr(cal, "budget", None) or {}
    for k, name in enumerate(("u_ref_rad", "cov_aa", "cov_ab", "cov_bb")):
        if name in bud:
            terms[k] = np.nan_to_num(np.asarray(bud[name], np.float32))
    terms[4] = table_interpolation_rad(table)
    bins = _encode_interp(interpolation_bins(table))
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


def _interp_of(dphi: NDArray[np.floating], budget: PixelBudget) -> NDArray[np.float64]:
    """Interpolation error (rad) at each pixel's phase, as the kernel picks it (float32 bin)."""
    if budget.interp_bins is None:
        return budget.terms[4].astype(np.float64)
    k = budget.interp_bins.shape[-1]
    d = np.nan_to_num(np.asarray(dphi, np.float32))
    t = (budget.phi_ref + d) * np.float32(k / (2.0 * np.pi))
    t = t - np.float32(k) * np.floor(t / np.float32(k))
    kb = np.minimum(t.astype(np.int64), k - 1)
    q = np.take_along_axis(budget.interp_bins, kb[..., None], axis=-1)[..., 0]
    return _INTERP_LUT[q].astype(np.float64)


# --------------------------------------------------------------------------------------------
# per frame (called identically by perframe.measure_frame and kernel.frame_maps)
# --------------------------------------------------------------------------------------------
@numba.njit(cache=True, nogil=True, error_model="numpy")
def _uncertainty_kernel(dphi, sumw, valid, a, b, terms, table_factor, bins, lut, phi_ref, out, rsum, nf):  # pragma: no cover
    """Branch-free rows (LLVM vectorises them); NaN where not valid or without weight. The
    interpolation error is that of the phase bin of ``phi_ref + dphi`` (``bins``, ``lut``). The
    noise variance is ``rsum / sumw^2`` (``rsum = sumw``: ``1 / sumw``, bit for bit), times ``nf``
    with the table's (``nf = 1``: the same bits)."""
    h, w = dphi.shape
    nb = bins.shape[2]
    kf = np.float32(nb)
    to_bin = np.float32(nb / (2.0 * np.pi))
    t4row = np.empty(w, np.float32)
    kbrow = np.empty(w, np.int32)
    tf = np.float32(1.0) + np.float32(table_factor)
    nan32 = np.float32(np.nan)
    zero = np.float32(0.0)
    one = np.float32(1.0)
    two = np.float32(2.0)
    for v in range(h):
        dv = dphi[v]
        sv = sumw[v]
        rv = rsum[v]
        okv = valid[v]
        av = a[v]
        bv = b[v]
        t0, t1, t2, t3 = terms[0, v], terms[1, v], terms[2, v], terms[3, v]
        bv_ = bins[v]
        pr = phi_ref[v]
        ov = out[v]
        for u in range(w):  # each pixel's bin (vectorised) ...
            ok = okv[u] & (sv[u] * (sv[u] / rv[u]) > zero)
            d = dv[u] if ok else zero
            t = (pr[u] + d) * to_bin
            t = t - kf * np.floor(t / kf)
            kbrow[u] = max(min(np.int32(t), np.int32(nb - 1)), np.int32(0))
        for u in range(w):  # ... its gather alone (scalar), so that the loops around it vectorise
            t4row[u] = lut[bv_[u, kbrow[u]]]
        for u in range(w):
            sw = sv[u] * (sv[u] / rv[u])  # the effective weight sum (sum w)^2 / sum(w r)
            ok = okv[u] & (sw > zero)
            d = dv[u] if ok else zero
            sw = sw if ok else one
            aa = av[u]
            den = aa + bv[u] * d
            inv2 = one / (den * den)
            g = abs(aa) * inv2
            ja = -d * inv2
            jb = ja * d
            var = g * g / sw * tf * nf + (g * t0[u]) ** 2 + (g * t4row[u]) ** 2
            var += ja * ja * t1[u] + two * ja * jb * t2[u] + jb * jb * t3[u]
            r = np.sqrt(max(var, zero))
            ov[u] = r if ok else nan32


def height_uncertainty(dphi: NDArray[np.float32], sumw: NDArray[np.float32], valid: NDArray[np.bool_],
                       a: NDArray[np.float32], b: NDArray[np.float32], budget: PixelBudget,
                       out: NDArray[np.float32] | None = None,
                       ratio_sum: NDArray[np.float32] | None = None) -> NDArray[np.float32]:
    """Combined standard uncertainty (mm) of each pixel's height; NaN where not ``valid``.

    Parameters
    ----------
    dphi : float32 (H, W)
        The (filtered) phase difference the height was computed from.
    sumw : float32 (H, W)
        Sum of the inverse-variance weights the phase filter averaged (``1 / sigma^2`` without
        the filter): the filtered phase's variance from frame noise is ``1 / sumw``.
    valid : bool (H, W)
        Pixels with a finite height.
    a, b : float32 (H, W)
        The height model.
    budget : PixelBudget
        From :func:`pixel_budget`.
    ratio_sum : float32 (H, W), optional
        The filter's ``sum w r`` (:func:`huefringe.phase.denoise_phase`'s ``ratio_sum``), when the
        pixels' noise variance is ``r`` times the one that weighted them: the filtered phase's
        variance is then ``ratio_sum / sumw^2``.
    """
    if out is None:
        out = np.empty(np.shape(dphi), np.float32)
    if budget.interp_bins is None:  # one bin: the table-wide figure for every phase
        bins = _encode_interp(budget.terms[4])[..., None]
        phi_ref = np.zeros(np.shape(dphi), np.float32)
    else:
        bins, phi_ref = budget.interp_bins, budget.phi_ref
    sw = np.ascontiguousarray(sumw, np.float32)
    _uncertainty_kernel(np.ascontiguousarray(dphi, np.float32), sw,
                        np.ascontiguousarray(valid, bool), np.ascontiguousarray(a, np.float32),
                        np.ascontiguousarray(b, np.float32), budget.terms, np.float32(budget.table_factor), bins,
                        _INTERP_LUT, phi_ref, out, sw if ratio_sum is None else np.ascontiguousarray(ratio_sum, np.float32),
                        np.float32(budget.noise_factor))
    return out


#: The edge floor acts where the 3 x 3 residual exceeds this many u: noise alone (6 degrees of
#: freedom) gets there with probability 6e-4, a mixed pixel next to a step of height H >> u does.
EDGE_SIGNIFICANCE = np.float32(2.0)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _edge_floor_kernel(height, valid, u):  # pragma: no cover - numba
    """In place: ``u = s`` where ``s > EDGE_SIGNIFICANCE u``, ``s`` the rms residual (``n - 3`` degrees of freedom) of the
    valid heights of the 3 x 3 window about their least-squares plane (at least 5 pixels). A pixel counts as valid
    where ``valid`` holds and its height is finite (both callers: the height is NaN exactly where not valid)."""
    h, w = height.shape
    if h < 3 or w < 3:
        return
    zero = np.float32(0.0)
    sixth = np.float32(1.0 / 6.0)
    ninth = np.float32(1.0 / 9.0)
    nan32 = np.float32(np.nan)
    ring = np.empty((3, w), np.float32)  # the window's three rows, NaN where not valid
    rrow = np.empty(w, np.float32)
    part = np.empty(w, np.int64)
    good = np.zeros(3, np.int64)  # valid pixels of each ring row
    for j in range(2):
        hj, mj, rj = height[j], valid[j], ring[j]
        g = 0
        for x in range(w):
            hv = hj[x] if mj[x] else nan32
            rj[x] = hv
            g += np.int32(hv == hv)
        good[j] = g
    for v in range(1, h - 1):
        h0, h1, h2 = ring[(v - 1) % 3], ring[v % 3], ring[(v + 1) % 3]
        hn, mn = height[v + 1], valid[v + 1]
        g = 0
        for x in range(w):
            hv = hn[x] if mn[x] else nan32
            h2[x] = hv
            g += np.int32(hv == hv)
        good[(v + 1) % 3] = g
        uv = u[v]
        # full windows (the common case): x, y in {-1, 0, 1}, sum x^2 = sum y^2 = 6, the plane's
        # residual sum of squares in closed form. Branch-free, so that LLVM vectorises the row; a
        # window with an invalid pixel gives NaN, which raises nothing and marks it for below.
        for x in range(1, w - 1):
            hc = h1[x]
            za = h0[x - 1] - hc
            zb = h0[x] - hc
            zc = h0[x + 1] - hc
            zd = h1[x - 1] - hc
            ze = h1[x + 1] - hc
            zf = h2[x - 1] - hc
            zg = h2[x] - hc
            zh = h2[x + 1] - hc
            sh = ((za + zb) + (zc + zd)) + ((ze + zf) + (zg + zh))
            sxh = (zc + ze + zh) - (za + zd + zf)
            syh = (zf + zg + zh) - (za + zb + zc)
            # the residuals themselves (not shh - sh^2 / 9 - ...: on a slope that cancels in float32)
            c = sh * ninth
            gx = sxh * sixth
            gy = syh * sixth
            gp = gx + gy
            gm = gx - gy
            ea = (za - c) + gp
            eb = (zb - c) + gy
            ec = (zc - c) - gm
            ed = (zd - c) + gx
            ee = (ze - c) - gx
            ef = (zf - c) + gm
            eg = (zg - c) - gy
            eh = (zh - c) - gp
            ss = (((ea * ea + eb * eb) + (ec * ec + ed * ed)) + ((ee * ee + ef * ef) + (eg * eg + eh * eh))) + c * c
            r = np.sqrt(ss * sixth)
            rrow[x] = r
            ux = uv[x]
            uv[x] = r if r > EDGE_SIGNIFICANCE * ux else ux  # NaN (not valid) stays NaN
        # windows with invalid pixels around a valid centre (rows with any): listed
        # (branch-free), then the general least squares
        if good[0] + good[1] + good[2] == 3 * w:
            continue
        n = 0
        for x in range(1, w - 1):
            part[n] = x
            n += (rrow[x] != rrow[x]) & (h1[x] == h1[x])
        for i in range(n):
            x = part[i]
            _edge_partial(h0, h1, h2, x, uv)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _edge_partial(h0, h1, h2, x, uv):  # pragma: no cover - numba
    """The general least-squares residual of one window with invalid (NaN) pixels; raises ``uv[x]``."""
    zero = np.float32(0.0)
    n = zero
    sx = zero
    sy = zero
    sxx = zero
    syy = zero
    sxy = zero
    sh = zero
    sxh = zero
    syh = zero
    hc = h1[x]
    for dv in range(-1, 2):
        row = h0 if dv == -1 else (h1 if dv == 0 else h2)
        for du in range(-1, 2):
            hv = row[x + du]
            m = hv == hv
            z = hv - hc if m else zero
            wgt = np.float32(1.0) if m else zero
            fx = np.float32(du) * wgt
            fy = np.float32(dv) * wgt
            n += wgt
            sx += fx
            sy += fy
            sxx += fx * du
            syy += fy * dv
            sxy += fx * dv
            sh += z
            sxh += fx * z
            syh += fy * z
    # normal equations of z = c + gx x + gy y, by Cramer's rule
    a11, a12, a13, a22, a23, a33 = n, sx, sy, sxx, sxy, syy
    c11 = a22 * a33 - a23 * a23
    c12 = a13 * a23 - a12 * a33
    c13 = a12 * a23 - a13 * a22
    det = a11 * c11 + a12 * c12 + a13 * c13
    if n < np.float32(5.0) or det <= np.float32(1e-3):
        return
    c22 = a11 * a33 - a13 * a13
    c23 = a12 * a13 - a11 * a23
    c33 = a11 * a22 - a12 * a12
    b0 = (c11 * sh + c12 * sxh + c13 * syh) / det
    b1 = (c12 * sh + c22 * sxh + c23 * syh) / det
    b2 = (c13 * sh + c23 * sxh + c33 * syh) / det
    ss = zero  # the residuals themselves (shh - b . s cancels in float32 on a slope)
    for dv in range(-1, 2):
        row = h0 if dv == -1 else (h1 if dv == 0 else h2)
        for du in range(-1, 2):
            hv = row[x + du]
            e = (hv - hc) - b0 - b1 * du - b2 * dv
            ss += e * e if hv == hv else zero
    s2 = ss / (n - np.float32(3.0))
    r = np.float32(np.sqrt(s2))
    uv[x] = r if r > EDGE_SIGNIFICANCE * uv[x] else uv[x]


def edge_floor(height: NDArray[np.float32], valid: NDArray[np.bool_], u: NDArray[np.float32]) -> NDArray[np.float32]:
    """Mixed pixels: raise ``u`` (in place) to the local scatter of the heights about their 3 x 3
    least-squares plane where that exceeds ``EDGE_SIGNIFICANCE`` (2) times ``u`` (noise alone
    rarely does: with unfiltered heights it would otherwise count the noise twice).

    At a step edge or a cast-shadow border a pixel sees both surfaces (lens blur), and its hue,
    phase and height lie between them: an error the noise and calibration terms do not hold. A
    smooth surface (plane or gentle slope) leaves the residual at its noise, below ``u``; a step
    of height ``H`` gives ``H / sqrt(12) = 0.29 H`` next to it. Called by the reference chain and
    the kernel alike on the float32 height map, which is NaN exactly where not ``valid`` (a pixel
    counts where ``valid`` holds and its height is finite). The border rows and columns are left
    as they are. The residuals are summed themselves, in float32: the closed form
    ``sum z^2 - (sum z)^2 / 9 - ...`` cancels on a slope (up to 4e-3 relative off the float64
    least squares on the tests' maps; now 2e-6).
    """
    _edge_floor_kernel(np.ascontiguousarray(height, np.float32), np.ascontiguousarray(valid, bool), u)
    return u


#: Lateral position uncertainty (px) of a height on a locally linear surface: a symmetric footprint
#: (camera blur, the phase filter's window) returns a plane's height exactly, so only its shift
#: moves the height there: the filter's weights follow the signal (noise) and the texture lean's
#: first-order remainder. Measured on the tuning cases (docs/uncertainty.md, "Lateral term"):
#: with :data:`LATERAL_STEP_PX` it puts the smooth reliefs' and the tooth's steep flanks at
#: |error| <= 2u for 0.96-0.97 (1.75 px alone, session 8: 0.98-0.99).
LATERAL_PX = 0.5
#: Lateral reach (px) of a footprint where the slope changes within it (a step left by the edge
#: mask, a shadow border, a sharp bend): the camera blur (sigma 0.6-0.9 px on the bench) plus the
#: phase filter's radius (2 px); there the mixed pixels' error (hue mixing of two surfaces,
#: nonlinear in the heights) follows the slope that the blur leaves. Times
#: ``|grad h~ - grad h~_coarse|`` (:func:`lateral_term`).
LATERAL_STEP_PX = 2.0
#: Gaussian scale (px) of the normalised average of the valid heights whose gradient is the slope.
LATERAL_SMOOTH_PX = 1.5
#: Gaussian scale (px) of the coarse slope: what a locally linear surface keeps over the footprint's
#: reach (a step's slope is spread over it, a smooth flank's is not).
LATERAL_COARSE_PX = 5.0


def _gaussian_kernel(smooth_px: float) -> NDArray[np.float64]:
    """``scipy.ndimage``'s Gaussian (truncate 4) with one extra tap each side (for the difference kernel)."""
    r = int(4.0 * smooth_px + 0.5)
    t = np.arange(-r - 1, r + 2, dtype=np.float64)
    g_ext = np.exp(-0.5 * (t / smooth_px) ** 2)
    g_ext /= g_ext[1:-1].sum()
    return g_ext


def _sep(img: NDArray[np.float32], kx: NDArray[np.floating], ky: NDArray[np.floating]) -> NDArray[np.float32]:
    """Separable correlation, edges replicated (``scipy.ndimage``'s ``mode="nearest"``); OpenCV: 4-8 x faster."""
    return cv2.sepFilter2D(img, cv2.CV_32F, np.asarray(kx, np.float32), np.asarray(ky, np.float32),
                           borderType=cv2.BORDER_REPLICATE)


def _smoothed_slope(h: NDArray[np.float32], ok: NDArray[np.bool_], smooth_px: float):
    """The gradient (mm/px, central differences) of the normalised Gaussian average of the valid
    heights, and that average's weight sum (NaN heights carry no weight)."""
    g = _gaussian_kernel(smooth_px)[1:-1]
    num = _sep(np.where(ok, h, np.float32(0.0)), g, g)
    den = _sep(ok.astype(np.float32), g, g)
    with np.errstate(invalid="ignore", divide="ignore"):
        hm = np.where(den > 1e-3, num / np.maximum(den, np.float32(1e-3)), np.float32(np.nan))
    gy, gx = np.gradient(hm)
    return np.nan_to_num(gx), np.nan_to_num(gy), den


def lateral_term(height: NDArray[np.floating], u: NDArray[np.floating] | None = None, *,
                 lateral_px: float = LATERAL_PX, smooth_px: float = LATERAL_SMOOTH_PX,
                 step_px: float = 0.0, coarse_px: float = LATERAL_COARSE_PX) -> NDArray[np.float32]:
    """The height error of a lateral position uncertainty (mm), per pixel::

        u_lat^2 = (lateral_px |g|)^2 + (step_px min(|g - g_coarse|, |g|))^2

    A pixel's height is a weighted mean over a footprint (camera blur, the phase filter's window,
    the mixed pixels beside a step or a reflectance edge that the first-order texture correction
    leaves). On a locally linear surface a symmetric footprint returns the height exactly; only
    its shift (``lateral_px``: the filter's noise weights, the texture lean's remainder) moves it,
    by ``dx |grad h|``. Where the slope changes within the footprint's reach (a step left after
    the edge mask, a shadow border) the mixed pixels' error follows the part of the slope that is
    not linear there: ``g - g_coarse``, the slope ``g`` (Gaussian ``smooth_px``) less the coarse
    one (``coarse_px``), which a smooth flank keeps and a step spreads, times ``step_px`` (the
    reach: blur plus filter radius). ``step_px = 0`` (the default) gives the first term alone.

    The slopes are those of the measured heights, normalised-Gaussian averaged over the valid
    pixels (NaN pixels carry no weight), by central differences in mm per px. With ``u`` (the
    per-pixel uncertainty without this term) the fine slope's own noise is removed in
    quadrature: the smoothed central difference is a linear filter ``K`` of the heights, so its
    variance from pixel errors of standard uncertainty ``u`` is ``sum K^2 u^2`` (taken
    independent: on unfiltered heights exact, on filtered ones it removes a little more than the
    noise holds); the step part never exceeds that noise-free slope (on a noisy flat top both
    are ~0). NaN where the height is NaN.
    """
    h = np.asarray(height, np.float32)
    ok = np.isfinite(h)
    gx, gy, den = _smoothed_slope(h, ok, smooth_px)
    slope2 = gx**2 + gy**2
    if u is not None:  # the noise of the slope itself: sum K^2 u^2 of the separable kernels
        g_ext = _gaussian_kernel(smooth_px)
        d2 = (0.5 * (g_ext[:-2] - g_ext[2:])) ** 2  # central difference of the smoothed map
        g2 = g_ext[1:-1] ** 2
        u2 = np.where(ok, np.nan_to_num(np.asarray(u, np.float32)) ** 2, np.float32(0.0))
        var = _sep(u2, d2, g2) + _sep(u2, g2, d2)
        with np.errstate(invalid="ignore", divide="ignore"):
            var = var / np.maximum(den, np.float32(1e-3)) ** 2
        slope2 = np.maximum(slope2 - var, np.float32(0.0))
    lat2 = np.float32(lateral_px) ** 2 * slope2
    if step_px > 0:
        cx, cy, _ = _smoothed_slope(h, ok, coarse_px)
        bend2 = np.minimum((gx - cx) ** 2 + (gy - cy) ** 2, slope2)
        lat2 = lat2 + np.float32(step_px) ** 2 * bend2
    return np.where(ok, np.sqrt(lat2), np.nan).astype(np.float32)


def add_lateral(height: NDArray[np.floating], u: NDArray[np.floating], **kwargs: float) -> NDArray[np.float32]:
    """``sqrt(u^2 + lateral_term(height, u, **kwargs)^2)`` (a new float32 map; NaN where either is NaN)."""
    lat = lateral_term(height, u, **kwargs).astype(np.float64)
    return np.sqrt(np.asarray(u, np.float64) ** 2 + lat**2).astype(np.float32)


def texture_term(height: NDArray[np.floating], moved: NDArray[np.floating]) -> NDArray[np.float32]:
    """The texture-edge correction's residual (mm) per pixel: ``|h(s + u_s) - h(s)|``.

    ``height`` is measured from the capture corrected with the blur ``s`` the session uses
    (:func:`huefringe.texture.correct`, ``B - s grad W . grad(B / W)``), ``moved`` from the
    same capture corrected with ``s + u_s`` (``u_s``: :func:`huefringe.texture.blur_uncertainty`),
    through the same chain. The correction is linear in ``s``, so their difference is the height
    error of a blur wrong by one standard uncertainty, to first order: largest exactly where
    ``|grad W . grad(B / W)|`` is (reflectance edges across the fringe), about 0 on a uniform
    reflectance. 0 where only ``moved`` is NaN, NaN where ``height`` is.
    """
    h = np.asarray(height, np.float32)
    d = np.abs(np.asarray(moved, np.float32) - h)
    return np.where(np.isfinite(h), np.nan_to_num(d, nan=0.0), np.nan).astype(np.float32)


@numba.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _texture_delta(m, p, out):  # pragma: no cover - compiled
    h, w = m.shape
    for v in numba.prange(h):
        for u in range(w):
            d = np.float64(m[v, u]) - np.float64(p[v, u])
            d = np.pi - (np.pi - d) % (2.0 * np.pi)
            out[v, u] = np.float32(d) if d - d == 0 else np.float32(0.0)


@numba.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _texture_term_phase(dphi, delta, height, a, b, out):  # pragma: no cover - compiled
    h, w = dphi.shape
    for v in numba.prange(h):
        for u in range(w):
            hv = height[v, u]
            if not hv - hv == 0:
                out[v, u] = np.float32(np.nan)
                continue
            d = np.float64(dphi[v, u])
            e = d + np.float64(delta[v, u])
            av = np.float64(a[v, u])
            bv = np.float64(b[v, u])
            t = abs(e / (av + bv * e) - d / (av + bv * d))
            out[v, u] = np.float32(t) if t - t == 0 else np.float32(0.0)


def texture_delta(moved_dphi: NDArray[np.floating], dphi: NDArray[np.floating]) -> NDArray[np.float32]:
    """Each pixel's unfiltered phase change (rad, float32) when the texture correction's blur moves
    by its uncertainty: ``wrap(moved_dphi - dphi)`` (float64, to [-pi, pi)), 0 where either is
    NaN. The filter carries it through with its own weights and windows (``denoise_weighted``'s
    ``carry``). Compiled, rows in parallel."""
    m = np.asarray(moved_dphi)
    out = np.empty(m.shape, np.float32)
    _texture_delta(m, np.asarray(dphi), out)
    return out


def texture_term_phase(dphi: NDArray[np.floating], delta: NDArray[np.floating], height: NDArray[np.floating],
                       a: NDArray[np.floating], b: NDArray[np.floating]) -> NDArray[np.float32]:
    """:func:`texture_term` to first order from one pass: ``|h(dphi + delta) - h(dphi)|`` (mm) with
    ``h = dphi / (a + b dphi)``, ``dphi`` the filtered phase the height came from and ``delta`` the
    filter's weighted mean of :func:`texture_delta` over each pixel's window (the moved capture's
    phase change filtered with the weights and windows of the capture's own). The correction is
    linear in the blur and the filter is, for fixed weights, linear in the phase, so this is the
    height change of a blur wrong by one standard uncertainty without a second filtered pass.
    NaN where ``height`` is NaN (float64 arithmetic; compiled, rows in parallel)."""
    d = np.asarray(dphi)
    out = np.empty(d.shape, np.float32)
    _texture_term_phase(d, np.asarray(delta), np.asarray(height), np.asarray(a), np.asarray(b), out)
    return out


def split_terms(u: NDArray[np.floating], height: NDArray[np.floating], a: NDArray[np.floating],
                b: NDArray[np.floating], budget: PixelBudget) -> dict[str, NDArray[np.float64]]:
    """The five terms (mm) of a combined uncertainty map, recovered from ``u`` and the height.

    ``dphi = a h / (1 - b h)`` inverts the model; the calibration terms are recomputed, and the
    noise term is what remains: ``u_noise^2 = (u^2 - u_interp^2 - u_ref^2 - u_model^2) /
    (1 + f_table)``. Keys: :data:`TERMS`.
    """
    h = np.asarray(height, np.float64)
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    t = budget.terms.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = a * h / (1.0 - b * h)
        den = a + b * d
        g = np.abs(a) / den**2
        ja = -d / den**2
        jb = ja * d
    out = {
        "interpolation": g * _interp_of(d, budget),
        "reference": g * t[0],
        "model": np.sqrt(np.maximum(ja * ja * t[1] + 2 * ja * jb * t[2] + jb * jb * t[3], 0.0)),
    }
    rest = np.asarray(u, np.float64) ** 2 - out["interpolation"] ** 2 - out["reference"] ** 2 - out["model"] ** 2
    noise = np.sqrt(np.maximum(rest, 0.0) / (1.0 + budget.table_factor))
    out["noise"] = noise
    out["table"] = noise * math.sqrt(budget.table_factor)
    return {k: out[k] for k in TERMS}


# --------------------------------------------------------------------------------------------
# step heights
# --------------------------------------------------------------------------------------------
def _neighbour_counts(valid: NDArray[np.bool_], radius: int) -> NDArray[np.float64]:
    """Valid pixels in each pixel's ``(2 r + 1)^2`` window: how many raw pixels its filtered value
    shares with its neighbours (1 without the filter)."""
    if radius <= 0:
        return np.ones(valid.shape)
    from scipy import ndimage

    n = 2 * radius + 1
    return np.rint(ndimage.uniform_filter(valid.astype(np.float64), n, mode="constant") * n * n)


@numba.njit(cache=True, nogil=True)
def _spread_kernel(v, u, r, c, h, w, out):  # pragma: no cover - numba
    """:func:`_spread` of ``k`` weight rows ``c`` (k, N) over the same squares: the four corners
    of each square into a 2-D difference array ``out`` (k, h + 1, w + 1), then its running sums
    down the rows and along them."""
    for i in range(v.size):
        v0 = max(v[i] - r[i], 0)
        v1 = min(v[i] + r[i] + 1, h)
        u0 = max(u[i] - r[i], 0)
        u1 = min(u[i] + r[i] + 1, w)
        area = np.float64((v1 - v0) * (u1 - u0))
        for k in range(c.shape[0]):
            val = c[k, i] / area
            out[k, v0, u0] += val
            out[k, v0, u1] -= val
            out[k, v1, u0] -= val
            out[k, v1, u1] += val
    for k in range(c.shape[0]):
        for y in range(1, h + 1):
            for x in range(w + 1):
                out[k, y, x] += out[k, y - 1, x]
        for y in range(h + 1):
            for x in range(1, w + 1):
                out[k, y, x] += out[k, y, x - 1]


def _spread(v: NDArray[np.integer], u: NDArray[np.integer], c: NDArray[np.floating], n: NDArray[np.floating],
            shape: tuple[int, ...]) -> NDArray[np.float64]:
    """Weights of the raw pixels in ``sum_i c_i f_i``, the ``f_i`` (at ``(v_i, u_i)``) each the mean of
    the ``n_i`` raw pixels of a square about it (side ``sqrt(n_i)``, rounded to odd, clipped to the
    image): every ``c_i`` spread evenly over its square (box sums by a 2-D difference array,
    compiled). ``c`` may also be ``(k, N)``: ``k`` weight rows over the same squares, giving
    ``(k, H, W)``."""
    h, w = shape[:2]
    r = np.maximum(np.rint((np.sqrt(np.maximum(n, 1.0)) - 1.0) / 2.0), 0).astype(np.int64)
    cc = np.asarray(c, np.float64)
    rows = np.ascontiguousarray(cc.reshape(-1, r.size))
    out = np.zeros((rows.shape[0], h + 1, w + 1))
    _spread_kernel(np.ascontiguousarray(v, np.int64), np.ascontiguousarray(u, np.int64), r, rows, h, w, out)
    res = out[:, :h, :w]
    return res[0] if cc.ndim == 1 else res


def _crop(boxes: Sequence[tuple[int, int, int, int]], halo: int, shape: tuple[int, ...]) -> tuple[slice, slice]:
    """The rows and columns of the boxes ``(u0, v0, u1, v1)``, grown by ``halo`` and clipped."""
    v0 = max(min(bx[1] for bx in boxes) - halo, 0)
    v1 = min(max(bx[3] for bx in boxes) + halo, shape[0])
    u0 = max(min(bx[0] for bx in boxes) - halo, 0)
    u1 = min(max(bx[2] for bx in boxes) + halo, shape[1])
    return slice(v0, v1), slice(u0, u1)


def _groups(boxes: Sequence[tuple[int, int, int, int]], halo: int, shape: tuple[int, ...]) -> list[tuple[slice, slice]]:
    """Crops (:func:`_crop`) of the boxes grown by ``halo``, merged until no two crops meet (a
    group's crop is the bounding box of its boxes, grown): a pixel's spread square never leaves
    its box's crop, so the spreads of the groups are independent."""
    groups = [[bx] for bx in boxes]
    merged = True
    while merged:
        merged = False
        for i in range(len(groups)):
            for j in range(i + 1, len(groups)):
                ri, rj = _crop(groups[i], halo, shape), _crop(groups[j], halo, shape)
                if ri[0].start < rj[0].stop and rj[0].start < ri[0].stop and ri[1].start < rj[1].stop \
                        and rj[1].start < ri[1].stop:
                    groups[i] += groups.pop(j)
                    merged = True
                    break
            if merged:
                break
    return [_crop(g, halo, shape) for g in groups]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _crop_budget(z, u, valid, ncount, a, b, terms, f_table, has_bins, bins, phi_ref, lut, r0, c0, wts, mask,
                 m_out, c_out):  # pragma: no cover - numba
    """:func:`split_terms` of each valid pixel of the crop at ``(r0, c0)`` (the shape of
    ``wts``), in one pass: ``m_out[t, k, l] += sum_j wts_k wts_l raw_t`` for the spread terms
    (noise, table, interpolation; ``raw = term^2 ncount``) and ``c_out[t] += term`` for the
    correlated ones (reference, model) over ``mask``; returns the pixels of ``mask`` counted.
    The same float64 operations as :func:`split_terms` (and :func:`_interp_of`'s float32 bin)."""
    kk = wts.shape[0]
    nbins = bins.shape[2]
    scale = np.float32(nbins / (2.0 * np.pi))
    fk = np.float32(nbins)
    big = np.float32(3.4028234663852886e38)
    root_f = np.sqrt(f_table)
    n_mask = 0
    raw = np.empty(3)
    for y in range(wts.shape[1]):
        v = r0 + y
        for x in range(wts.shape[2]):
            uu = c0 + x
            if not valid[v, uu]:
                continue
            h = z[v, uu]
            av = np.float64(a[v, uu])
            bv = np.float64(b[v, uu])
            d = av * h / (1.0 - bv * h)
            den = av + bv * d
            g = np.abs(av) / den**2
            ja = -d / den**2
            jb = ja * d
            if has_bins:
                d32 = np.float32(d)
                if d32 != d32:
                    d32 = np.float32(0.0)
                elif d32 > big:
                    d32 = big
                elif d32 < -big:
                    d32 = -big
                t = (phi_ref[v, uu] + d32) * scale
                t = t - fk * np.floor(t / fk)
                kb = min(np.int64(t), nbins - 1)
                e_interp = np.float64(lut[bins[v, uu, kb]])
            else:
                e_interp = np.float64(terms[4, v, uu])
            interp = g * e_interp
            ref = g * np.float64(terms[0, v, uu])
            t1 = np.float64(terms[1, v, uu])
            t2 = np.float64(terms[2, v, uu])
            t3 = np.float64(terms[3, v, uu])
            model = np.sqrt(max(ja * ja * t1 + 2 * ja * jb * t2 + jb * jb * t3, 0.0))
            uv = np.float64(u[v, uu])
            rest = uv**2 - interp**2 - ref**2 - model**2
            noise = np.sqrt(max(rest, 0.0) / (1.0 + f_table))
            table = noise * root_f
            n = ncount[v, uu]
            raw[0] = noise**2 * n
            raw[1] = table**2 * n
            raw[2] = interp**2 * n
            for k in range(kk):
                wk = wts[k, y, x]
                if wk == 0.0:
                    continue
                for l in range(kk):
                    wkl = wk * wts[l, y, x]
                    for q in range(3):
                        m_out[q, k, l] += wkl * raw[q]
            if mask[y, x]:
                c_out[0] += ref
                c_out[1] += model
                n_mask += 1
    return n_mask


#: the order of :func:`_crop_budget`'s outputs
_SPREAD_TERMS = ("noise", "table", "interpolation")
_CORR_TERMS = ("reference", "model")
assert {GROUPS[t] for t in _CORR_TERMS} == {"correlated"} and set(_SPREAD_TERMS) | set(_CORR_TERMS) == set(TERMS)
assert all(GROUPS[t] != "correlated" for t in _SPREAD_TERMS)


def _frame_step_terms(z: NDArray[np.float64], u: NDArray[np.floating], valid: NDArray[np.bool_],
                      ncount: NDArray[np.float64], base_boxes: Sequence[tuple[int, int, int, int]],
                      step_boxes: Sequence[tuple[int, int, int, int]], pitch_mm: float, a: NDArray[np.floating],
                      b: NDArray[np.floating], budget: PixelBudget,
                      xy: tuple[NDArray[np.floating], NDArray[np.floating]] | None = None) -> list[dict[str, float]]:
    """One frame's variance of each step's height, term by term (:func:`step_budget`).

    Only the pixels the step budget reaches are visited: the boxes grown by the largest
    support's half side (:func:`_groups`: a crop per top, one per group of base boxes). The
    raw-pixel weights of each top are spread on its crop and those of the base plane once per
    frame, as the three spreads of the plane's coefficients (``mean_T(plane) = xbar . coef``,
    linear in ``xbar``), so that each step's base variance is the quadratic form
    ``xbar^T M xbar`` of ``M_kl = sum_j A_k A_l raw_j``; the terms of each pixel
    (:func:`split_terms`) and these sums are taken in one compiled pass per crop
    (:func:`_crop_budget`).
    """
    shape = z.shape
    halo = int(np.rint((np.sqrt(float(np.max(ncount))) - 1.0) / 2.0)) + 1
    has_bins = budget.interp_bins is not None and budget.phi_ref is not None
    bins = budget.interp_bins if has_bins else np.zeros((1, 1, 1), np.uint8)
    phi_ref = np.ascontiguousarray(budget.phi_ref, np.float32) if has_bins else np.zeros((1, 1), np.float32)
    terms = np.ascontiguousarray(budget.terms, np.float32)
    a32, b32 = np.ascontiguousarray(a), np.ascontiguousarray(b)
    u_c = np.ascontiguousarray(u)

    def crop_sums(sl: tuple[slice, slice], wts: NDArray[np.float64], mask: NDArray[np.bool_]):
        m = np.zeros((3, wts.shape[0], wts.shape[0]))
        c = np.zeros(2)
        n = _crop_budget(z, u_c, valid, ncount, a32, b32, terms, float(budget.table_factor), has_bins, bins, phi_ref,
                         _INTERP_LUT, sl[0].start, sl[1].start, np.ascontiguousarray(wts), mask, m, c)
        return m, c, n

    bmask = np.zeros(shape, bool)
    for u0, v0, u1, v1 in base_boxes:
        bmask[v0:v1, u0:u1] = True
    bmask &= valid
    vb, ub = np.nonzero(bmask)
    if xy is None:  # telecentric: the plane's lever arms are u * pitch, v * pitch
        xb = np.column_stack([np.ones(vb.size), ub * pitch_mm, vb * pitch_mm])
    else:  # a lens model: each pixel's own X, Y (metrology.step_height fits the plane there too)
        xb = np.column_stack([np.ones(vb.size), xy[0][vb, ub], xy[1][vb, ub]])
    pinv = np.linalg.pinv(xb)  # (3, NB): plane coefficients from the base heights
    nb = ncount[vb, ub]
    # the base plane: the spreads of its three coefficients, once, on each group's crop
    quad = np.zeros((3, 3, 3))
    base_sum = np.zeros(2)
    base_n = 0
    for gsl in _groups(base_boxes, halo, shape):
        inside = (vb >= gsl[0].start) & (vb < gsl[0].stop) & (ub >= gsl[1].start) & (ub < gsl[1].stop)
        crop_shape = (gsl[0].stop - gsl[0].start, gsl[1].stop - gsl[1].start)
        coef = _spread(vb[inside] - gsl[0].start, ub[inside] - gsl[1].start, pinv[:, inside], nb[inside], crop_shape)
        m, c, n = crop_sums(gsl, coef, np.ascontiguousarray(bmask[gsl]))
        quad += m
        base_sum += c
        base_n += n
    base_mean = base_sum / max(base_n, 1)
    out = []
    for box in step_boxes:
        tsl = _crop([box], halo, shape)
        off = (tsl[0].start, tsl[1].start)
        tmask = np.zeros((tsl[0].stop - off[0], tsl[1].stop - off[1]), bool)
        tmask[box[1] - off[0] : box[3] - off[0], box[0] - off[1] : box[2] - off[1]] = True
        tmask &= valid[tsl]
        vt, ut = np.nonzero(tmask)
        nt = vt.size
        if xy is None:
            xbar = np.array([1.0, (ut + off[1]).mean() * pitch_mm, (vt + off[0]).mean() * pitch_mm])
        else:
            xbar = np.array([1.0, xy[0][vt + off[0], ut + off[1]].mean(), xy[1][vt + off[0], ut + off[1]].mean()])
        n_t = ncount[tsl][tmask]
        a_top = _spread(vt, ut, np.full(nt, 1.0 / nt), n_t, tmask.shape)
        m, c, n = crop_sums(tsl, a_top[None], tmask)
        top_mean = c / max(n, 1)
        row: dict[str, float] = {"n_eff": float(nt / n_t.mean())}
        plane_var = 0.0
        for q, term in enumerate(_SPREAD_TERMS):
            vtop = float(m[q, 0, 0])
            vbase = float(xbar @ quad[q] @ xbar)
            row[term] = vtop + vbase
            plane_var += vbase
        for q, term in enumerate(_CORR_TERMS):
            row[term] = float(top_mean[q] ** 2 + base_mean[q] ** 2)
        row["base_plane"] = plane_var
        out.append({k: row[k] for k in ("n_eff", *TERMS, "base_plane")})
    return out


def coating_term(tops: Sequence[NDArray[np.floating]]) -> float:
    """The coating-dependent systematic of a step's top (mm): the rms, over the top box, of the
    frame-mean heights' residual about their least-squares plane, less its frame-noise part.

    The per-pixel table is calibrated on the object's own hue bands, but the phase-error table and
    the planes' model on the grey plate (paper eqs. 6-9: each channel's reflectivity bends the
    hue, so the blurred fringe's hue error on a red or blue coating is not the plate's). What is
    left is a pattern fixed to the fringe phase (period = the fringe's) that the frame mean keeps:
    on a box spanning about one period its mean is not zero, and that mean is the step's error. Its
    size is that of the pattern: the top's non-flatness ``r`` about its plane, averaged over the F
    frames; the noise the mean still holds, ``mean_T var_f(r_f) / F`` (sample variance over the
    frames of each frame's residual), is removed in quadrature. One frame: the plane residual
    alone (noise included, conservative). ``tops``: the top box of each frame (NaN invalid).
    """
    stack = np.asarray([np.asarray(t, np.float64) for t in tops])
    if stack.size == 0 or stack.shape[1] < 2 or stack.shape[2] < 2:
        return 0.0
    vv, uu = np.mgrid[: stack.shape[1], : stack.shape[2]]
    res = []
    for z in stack:  # each frame about its own plane (a vibrating specimen tilts between frames)
        ok = np.isfinite(z)
        if ok.sum() < 6:
            continue
        x = np.column_stack([np.ones(ok.sum()), uu[ok], vv[ok]])
        coef = np.linalg.lstsq(x, z[ok], rcond=None)[0]
        r = np.full(z.shape, np.nan)
        r[ok] = z[ok] - x @ coef
        res.append(r)
    if not res:
        return 0.0
    r = np.asarray(res)
    nf = r.shape[0]
    both = np.all(np.isfinite(r), axis=0)
    if both.sum() < 6:
        return 0.0
    mean = r[:, both].mean(axis=0)
    total = float(np.mean((mean - mean.mean()) ** 2))
    noise = float(np.mean(np.var(r[:, both], axis=0, ddof=1))) / nf if nf > 1 else 0.0
    return math.sqrt(max(total - noise, 0.0))


def step_budget(
    heights: Sequence[NDArray[np.floating]],
    uncertainties: Sequence[NDArray[np.floating]],
    specimen: Mapping[str, Any],
    pitch_mm: float,
    a: NDArray[np.floating],
    b: NDArray[np.floating],
    budget: PixelBudget,
    *,
    edge_exclusion: float,
    denoise_radius: int,
    supports: Sequence[NDArray[np.floating]] | None = None,
    workers: int = 1,
    camera: Any = None,
    lateral_px: float = 0.0,
    lateral_step_px: float = 0.0,
) -> list[dict[str, Any]]:
    """Standard uncertainty of each step's mean height over the frames, term by term.

    A step height is ``mean_T(z) - mean_T(plane)``, the plane fitted over the base boxes B
    (:func:`huefringe.metrology.step_height`). Per frame and term:

    - independent and pixel terms: a filtered pixel ``i`` averages ``n_i`` raw pixels (its
      support: ``supports``, the filter's own count, which the sigma-adaptive window grows;
      without it the valid pixels of the fixed ``(2 denoise_radius + 1)^2`` window), taken as a
      square of side ``sqrt(n_i)`` about it, each raw pixel of variance ``u_j^2 n_j``. A linear
      combination ``sum_i c_i f_i`` (``c_i = 1/N`` on T; on B the plane's weights, which give
      ``mean_T(plane)``) is then ``sum_j a_j x_j`` with ``a_j`` the ``c_i / n_i`` of the squares
      that hold ``j`` (:func:`_spread`), of variance ``sum_j a_j^2 u_j^2 n_j``: well inside a
      large region ``sum_i c_i^2 u_i^2 n_i``, less where the squares reach past its border (a
      small box, a wide window). ``N / mean(n_i)`` is reported as the effective number of
      independent pixels;
    - correlated terms: fully correlated within T and within B, independent between them:
      ``mean_T(u)^2 + mean_B(u)^2``.

    Over F frames the independent part is divided by F, the others are not:
    ``u^2 = <u_ind^2> / F + <u_pixel^2> + <u_corr>^2 + u_coating^2`` (:func:`coating_term`: the
    top's systematic non-flatness, which a box about one fringe period wide does not average out). ``workers`` > 1 computes that many frames
    at once (threads; the sequences are indexed from them, so lazy ones must allow it).
    ``camera`` (a :class:`huefringe.camera.CameraModel` that is not plain): the base plane's lever
    arms are each pixel's X, Y at its height (``camera.xy``), as ``metrology.step_height`` fits it,
    instead of ``u * pitch``. ``lateral_px`` or ``lateral_step_px`` > 0: the maps carry the lateral term
    (:func:`add_lateral` with that ``dx`` and ``step_px``), which is taken out of each pixel's u before the split
    (on a top it is the slope of the coating's phase-fixed pattern, which :func:`coating_term`
    holds; left in, the split would count it as frame noise).
    """
    from huefringe import metrology

    if len(uncertainties) != len(heights):
        raise ValueError(f"{len(heights)} height maps but {len(uncertainties)} uncertainty maps")
    if supports is not None and len(supports) != len(heights):
        raise ValueError(f"{len(heights)} height maps but {len(supports)} support maps")
    base, steps, _ = metrology._specimen_parts(specimen)
    shape = np.shape(a)  # the model's: no map is read before the frames' own turn
    base_boxes = [metrology.check_box(bx, shape, f"base_roi[{i}]") for i, bx in enumerate(base)]
    step_boxes = [metrology.central_box(metrology.check_box(s["roi"], shape, str(s["name"])), edge_exclusion)
                  for s in steps]
    rows: dict[int, dict[str, list[float]]] = {k: {t: [] for t in (*TERMS, "base_plane", "n_eff")} for k in range(len(steps))}

    def frame(f: int) -> list[dict[str, float]]:
        z = np.asarray(heights[f], np.float64)  # taken here: lazy sequences read one frame per task
        u = np.asarray(uncertainties[f])
        if z.shape != shape or u.shape != shape:
            raise ValueError(f"frame {f}: height {z.shape} and uncertainty {u.shape} maps, the model {shape}")
        if lateral_px > 0 or lateral_step_px > 0:  # the lateral term out (computed with the combined u: a little less than was added)
            lat = lateral_term(z, u, lateral_px=lateral_px, step_px=lateral_step_px).astype(np.float64)
            u = np.sqrt(np.maximum(np.asarray(u, np.float64) ** 2 - lat**2, 0.0)).astype(np.float32)
        valid = np.isfinite(z) & np.isfinite(u)
        if supports is None:
            ncount = _neighbour_counts(valid, denoise_radius)
        else:
            ncount = np.maximum(np.asarray(supports[f], np.float64), 1.0)
            if ncount.shape != shape:
                raise ValueError(f"support map {f} has shape {ncount.shape}, the heights {shape}")
        tops = [z[bx[1]:bx[3], bx[0]:bx[2]].copy() for bx in step_boxes]  # for the coating term
        xy = None if camera is None or getattr(camera, "plain", True) else camera.xy(z)
        return _frame_step_terms(z, u, valid, ncount, base_boxes, step_boxes, pitch_mm, a, b, budget, xy), tops

    if workers > 1 and len(heights) > 1:  # the compiled passes and NumPy's array work release the GIL
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(int(workers)) as pool:
            per_frame = list(pool.map(frame, range(len(heights))))
    else:
        per_frame = [frame(f) for f in range(len(heights))]
    coating = [coating_term([tops[k] for _, tops in per_frame]) for k in range(len(steps))]
    per_frame = [terms for terms, _ in per_frame]
    for terms_of_frame in per_frame:
        for k, terms in enumerate(terms_of_frame):
            for key, val in terms.items():
                rows[k][key].append(val)
    out = []
    nf = len(heights)
    for k, s in enumerate(steps):
        r = rows[k]
        mean_var = {t: float(np.mean(r[t])) for t in TERMS}
        ind_frame = math.sqrt(mean_var["noise"])
        pix = math.sqrt(mean_var["table"] + mean_var["interpolation"])
        corr = math.sqrt(mean_var["reference"] + mean_var["model"])
        coat = coating[k]
        u = math.sqrt(ind_frame**2 / nf + pix**2 + corr**2 + coat**2)
        out.append({
            "name": str(s["name"]),
            "u_mm": u,
            "U_mm": 2.0 * u,
            "k": 2.0,
            "independent_per_frame_mm": ind_frame,
            "independent_mm": ind_frame / math.sqrt(nf),
            "pixel_calibration_mm": pix,
            "correlated_mm": corr,
            "coating_mm": coat,
            "base_plane_per_frame_mm": math.sqrt(float(np.mean(r["base_plane"]))),
            "effective_independent_pixels": float(np.mean(r["n_eff"])),
            "terms_mm": {t: math.sqrt(mean_var[t] / (nf if GROUPS[t] == "independent" else 1)) for t in TERMS},
            "frames": nf,
        })
    return out


def conformance(error_mm: float, tolerance_mm: float, expanded_mm: float) -> str:
    """ISO 14253-1 decision with the expanded uncertainty U: ``pass`` when
    ``|error| <= tolerance - U`` (conformance zone), ``fail`` when ``|error| > tolerance + U``
    (non-conformance zone), ``undecided`` between them."""
    e = abs(float(error_mm))
    if e <= tolerance_mm - expanded_mm:
        return "pass"
    if e > tolerance_mm + expanded_mm:
        return "fail"
    return "undecided"


# --------------------------------------------------------------------------------------------
# validation against ground truth
# --------------------------------------------------------------------------------------------
def reliability(errors: NDArray[np.floating], u: NDArray[np.floating], *, bins: int = 12) -> dict[str, Any]:
    """Coverage of ``|error| <= 2 u`` and the binned reliability curve (observed rms error, and the
    68.27th percentile of ``|error|`` — the robust one-sigma, equal to u for Gaussian errors —
    against predicted u, bins of equal count). NaN pixels (either) are left out."""
    e = np.asarray(errors, np.float64).ravel()
    s = np.asarray(u, np.float64).ravel()
    ok = np.isfinite(e) & np.isfinite(s) & (s > 0)
    e, s = e[ok], s[ok]
    if e.size == 0:
        return {"pixels": 0, "coverage_2u": None, "bins": []}
    edges = np.unique(np.quantile(s, np.linspace(0, 1, bins + 1)))
    idx = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, max(edges.size - 2, 0))
    rows = []
    for i in range(max(edges.size - 1, 1)):
        m = idx == i
        if m.sum() < 10:
            continue
        rows.append({"u_mm": float(np.sqrt(np.mean(s[m] ** 2))), "observed_rms_mm": float(np.sqrt(np.mean(e[m] ** 2))),
                     "observed_p68_mm": float(np.percentile(np.abs(e[m]), 68.27)),
                     "coverage_2u": float(np.mean(np.abs(e[m]) <= 2 * s[m])), "pixels": int(m.sum())})
    return {"pixels": int(e.size), "coverage_2u": float(np.mean(np.abs(e) <= 2 * s)),
            "median_u_mm": float(np.median(s)), "rms_error_mm": float(np.sqrt(np.mean(e**2))),
            "rms_u_mm": float(np.sqrt(np.mean(s**2))), "bins": rows}
