"""The per-frame height uncertainty, called identically by :func:`huefringe.perframe.measure_frame`
and :func:`huefringe.kernel.frame_maps`: the root sum of squares of the terms, the edge floor,
the lateral and texture terms, and the split into terms.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from huefringe import _threads  # noqa: F401  (numba's threading layer, before any parallel launch)
from huefringe.uncertainty.calibration import PixelBudget, TERMS, _INTERP_LUT, _encode_interp

__all__ = ["add_lateral", "edge_floor", "filter_centroid", "height_uncertainty", "lateral_term", "split_terms",
           "texture_delta", "texture_term", "texture_term_phase"]


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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _uncertainty_kernel(dphi, sumw, valid, a, b, terms, table_factor, bins, lut, phi_ref, out, rsum, nf,
                        bias2):  # pragma: no cover
    """Branch-free rows (LLVM vectorises them); NaN where not valid or without weight. The
    interpolation error is that of the phase bin of ``phi_ref + dphi`` (``bins``, ``lut``). The
    noise variance is ``rsum / sumw^2`` (``rsum = sumw``: ``1 / sumw``, bit for bit), times ``nf``
    with the table's (``nf = 1``: the same bits). ``bias2`` (of the phase's shape; else not used)
    adds a phase variance per pixel where finite."""
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
    has_b = bias2.shape[0] == h and bias2.shape[1] == w
    for v in range(h):
        dv = dphi[v]
        sv = sumw[v]
        rv = rsum[v]
        b2v = bias2[v] if has_b else bias2[0]
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
            if has_b:
                bb = b2v[u]
                var += g * g * (bb if bb == bb else zero)
            r = np.sqrt(max(var, zero))
            ov[u] = r if ok else nan32


def height_uncertainty(dphi: NDArray[np.float32], sumw: NDArray[np.float32], valid: NDArray[np.bool_],
                       a: NDArray[np.float32], b: NDArray[np.float32], budget: PixelBudget,
                       out: NDArray[np.float32] | None = None,
                       ratio_sum: NDArray[np.float32] | None = None,
                       bias2: NDArray[np.float32] | None = None) -> NDArray[np.float32]:
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
    bias2 : float32 (H, W), optional
        A phase variance (rad^2) added per pixel where finite: the sigma-adaptive filter's own
        bias where it grew the window (:func:`huefringe.phase.denoise_phase`'s ``bias2``), a term
        the frames share. :func:`split_terms` counts it with the noise.
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
                        np.float32(budget.noise_factor),
                        np.ascontiguousarray(bias2, np.float32) if bias2 is not None else np.zeros((1, 1), np.float32))
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
    as they are. The residuals are summed themselves, in float32, within 2e-6 relative of the float64 least
    squares on the tests' maps; the closed form ``sum z^2 - (sum z)^2 / 9 - ...`` would cancel on a
    slope (up to 4e-3 relative off).
    """
    _edge_floor_kernel(np.ascontiguousarray(height, np.float32), np.ascontiguousarray(valid, bool), u)
    return u


#: Lateral position uncertainty (px) of a height on a locally linear surface: a symmetric footprint
#: (camera blur, the phase filter's window) returns a plane's height exactly, so only its shift
#: moves the height there: the filter's weights follow the signal (noise) and the texture lean's
#: first-order remainder. Measured on the tuning cases (docs/uncertainty.md, "Lateral term"):
#: with :data:`LATERAL_STEP_PX` it puts the smooth reliefs' and the tooth's steep flanks at
#: |error| <= 2u for 0.96-0.97.
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


def _smoothed_sums(x0: NDArray[np.float32], okf: NDArray[np.float32],
                   smooth_px: float) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The Gaussian sums of the valid heights (``x0``: the heights, 0 where not valid) and of the
    valid pixels (``okf``: 1 or 0): the numerator and weight sum of their normalised average."""
    g = _gaussian_kernel(smooth_px)[1:-1]
    return _sep(x0, g, g), _sep(okf, g, g)


_F32_MAX = np.float32(np.finfo(np.float32).max)


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _finite_or_big(g):  # pragma: no cover - compiled
    """``np.nan_to_num`` of one float32: NaN 0, +-inf the largest float32."""
    big = _F32_MAX
    return np.float32(0.0) if g != g else (big if g > big else (-big if g < -big else g))


@numba.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _lateral_inputs(h, u, has_u, x0, okf, u2):  # pragma: no cover - compiled
    """The lateral term's filter inputs: ``x0`` the heights, 0 where not finite, ``okf`` the finite
    ones as 1.0, and (``has_u``) ``u2`` their squared uncertainty (NumPy's ``nan_to_num``: NaN 0,
    +-inf the largest float32), 0 where the height is not finite."""
    rows, cols = h.shape
    zero = np.float32(0.0)
    one = np.float32(1.0)
    for v in numba.prange(rows):
        for x in range(cols):
            z = h[v, x]
            ok = z - z == 0
            x0[v, x] = z if ok else zero
            okf[v, x] = one if ok else zero
            if has_u:
                q = _finite_or_big(u[v, x])
                u2[v, x] = q * q if ok else zero


@numba.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _normalised(num, den, hm):  # pragma: no cover - compiled
    """``hm = den > 1e-3 ? num / max(den, 1e-3) : NaN`` (float32): the normalised average (``hm``
    may be ``num``)."""
    rows, cols = num.shape
    lo = np.float32(1e-3)
    nan = np.float32(np.nan)
    for v in numba.prange(rows):
        for x in range(cols):
            d = den[v, x]
            hm[v, x] = num[v, x] / max(d, lo) if d > lo else nan


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _lateral_pixel(z, gx, gy, cx, cy, va, vb, den, uu, has_u, step, c_lat, c_step, add,
                   centroid, ox, oy):  # pragma: no cover
    """One pixel of :func:`_lateral_kernel` from its (``nan_to_num``-ed) fine and coarse slopes and
    (with ``centroid``) the filter's centroid offset ``ox, oy``."""
    zero = np.float32(0.0)
    raw2 = gx * gx + gy * gy
    s2 = raw2
    if has_u:
        m = max(den, np.float32(1e-3))
        t = s2 - (va + vb) / (m * m)
        s2 = t if (t > zero or t != t) else zero
    lat2 = c_lat * s2
    if centroid:  # (g . c)^2 on the share of the slope that is not its noise
        sh = gx * ox + gy * oy
        sh = sh * sh
        share = s2 / raw2 if raw2 > zero else zero
        lat2 = lat2 + sh * share
    if step:
        ex = gx - cx
        ey = gy - cy
        b = ex * ex + ey * ey
        b = b if (b <= s2 or b != b) else s2
        lat2 = lat2 + c_step * b
    lat = np.sqrt(lat2)
    if add:
        u64 = np.float64(uu)
        l64 = np.float64(lat)
        lat = np.float32(np.sqrt(u64 * u64 + l64 * l64))
    return lat if z - z == 0 else np.float32(np.nan)


@numba.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _lateral_kernel(h, hm, hmc, va, vb, den, has_u, step, c_lat, c_step, u, add, centroid, ox, oy,
                    out):  # pragma: no cover
    """:func:`lateral_term` per pixel from the normalised averages ``hm`` (fine) and ``hmc``
    (coarse, with ``step``), the slope noise's two separable sums ``va + vb`` over ``max(den,
    1e-3)^2`` (with ``has_u``), ``c_lat = lateral_px^2``, ``c_step = step_px^2``: float32, in
    NumPy's order of operations (``np.gradient``'s central differences over 2, one-sided at the
    borders, through ``nan_to_num``; NaN-propagating ``maximum`` / ``minimum``). With ``add``,
    ``out`` is ``float32(sqrt(float64(u)^2 + float64(term)^2))`` (:func:`add_lateral`), else the
    term; NaN where the height is not finite. The inner columns in a branch-free loop (SIMD)."""
    rows, cols = h.shape
    two = np.float32(2.0)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    for v in numba.prange(rows):
        vm = max(v - 1, 0)
        vp = min(v + 1, rows - 1)
        ydiv = two if 0 < v < rows - 1 else one
        for x in (0, cols - 1):  # the border columns: one-sided differences along u
            xm = max(x - 1, 0)
            xp = min(x + 1, cols - 1)
            gx = _finite_or_big(hm[v, xp] - hm[v, xm])
            gy = _finite_or_big((hm[vp, x] - hm[vm, x]) / ydiv)
            cx = cy = zero
            if step:
                cx = _finite_or_big(hmc[v, xp] - hmc[v, xm])
                cy = _finite_or_big((hmc[vp, x] - hmc[vm, x]) / ydiv)
            out[v, x] = _lateral_pixel(h[v, x], gx, gy, cx, cy, va[v, x] if has_u else zero,
                                       vb[v, x] if has_u else zero, den[v, x], u[v, x] if add else zero, has_u, step,
                                       c_lat, c_step, add, centroid, ox[v, x] if centroid else zero,
                                       oy[v, x] if centroid else zero)
        hr = hm[v]
        hu = hm[vp]
        hd = hm[vm]
        cr = hmc[v] if step else hmc[0]
        cu = hmc[vp] if step else hmc[0]
        cd = hmc[vm] if step else hmc[0]
        for x in range(1, cols - 1):
            gx = _finite_or_big((hr[x + 1] - hr[x - 1]) / two)
            gy = _finite_or_big((hu[x] - hd[x]) / ydiv)
            cx = cy = zero
            if step:
                cx = _finite_or_big((cr[x + 1] - cr[x - 1]) / two)
                cy = _finite_or_big((cu[x] - cd[x]) / ydiv)
            out[v, x] = _lateral_pixel(h[v, x], gx, gy, cx, cy, va[v, x] if has_u else zero,
                                       vb[v, x] if has_u else zero, den[v, x], u[v, x] if add else zero, has_u, step,
                                       c_lat, c_step, add, centroid, ox[v, x] if centroid else zero,
                                       oy[v, x] if centroid else zero)


def _lateral(height: NDArray[np.floating], u: NDArray[np.floating] | None, lateral_px: float, smooth_px: float,
             step_px: float, coarse_px: float, add: bool, weight: NDArray[np.floating] | None = None,
             filter_radius: int = 0, grown: NDArray[np.floating] | None = None) -> NDArray[np.float32]:
    """:func:`lateral_term` (``add`` False) or :func:`add_lateral` (``add`` True): the filter inputs
    and the normalised averages in compiled passes, the Gaussian sums by OpenCV, the rest per
    pixel in one compiled pass."""
    h = np.ascontiguousarray(height, np.float32)
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValueError(f"the lateral term needs a 2-D height map of at least 2 x 2 pixels, got {h.shape}")
    has_u = u is not None
    uf = np.ascontiguousarray(u, np.float32) if has_u else np.empty((1, 1), np.float32)
    if has_u and uf.shape != h.shape:
        raise ValueError(f"uncertainty map {uf.shape} differs from the height map {h.shape}")
    x0, okf = np.empty_like(h), np.empty_like(h)
    u2 = np.empty_like(h) if has_u else np.empty((1, 1), np.float32)
    _lateral_inputs(h, uf, has_u, x0, okf, u2)
    hm, den = _smoothed_sums(x0, okf, smooth_px)
    _normalised(hm, den, hm)  # in place
    va = vb = np.empty((1, 1), np.float32)
    if has_u:  # the noise of the slope itself: sum K^2 u^2 of the separable kernels
        g_ext = _gaussian_kernel(smooth_px)
        d2 = (0.5 * (g_ext[:-2] - g_ext[2:])) ** 2  # central difference of the smoothed map
        g2 = g_ext[1:-1] ** 2
        va, vb = _sep(u2, d2, g2), _sep(u2, g2, d2)
    step = step_px > 0
    hmc = np.empty((1, 1), np.float32)
    if step:
        hmc, denc = _smoothed_sums(x0, okf, coarse_px)
        _normalised(hmc, denc, hmc)
    out = np.empty_like(h)
    # the sum with u in float64 from u as given (a float64 map is not rounded to float32 first)
    ua = uf if not add or np.asarray(u).dtype == np.float32 else np.ascontiguousarray(u, np.float64)
    centroid = weight is not None and filter_radius > 0
    if centroid:
        ox, oy = filter_centroid(weight, int(filter_radius))
        if ox.shape != h.shape:
            raise ValueError(f"filter weights {ox.shape} differ from the height map {h.shape}")
        if grown is not None:  # the grown windows carry their own bias (the filter's bias2), not this one
            g2 = np.asarray(grown)
            if g2.shape != h.shape:
                raise ValueError(f"grown-window map {g2.shape} differs from the height map {h.shape}")
            own = np.isfinite(g2)
            ox = np.where(own, np.float32(0.0), ox)
            oy = np.where(own, np.float32(0.0), oy)
    else:
        ox = oy = np.empty((1, 1), np.float32)
    _lateral_kernel(h, hm, hmc, va, vb, den, has_u, step, np.float32(lateral_px) ** 2, np.float32(step_px) ** 2,
                    ua, add, centroid, ox, oy, out)
    return out


def filter_centroid(weight: NDArray[np.floating], radius: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The offset (px; x along a row, y down a column) of the weighted centroid of each pixel's
    ``(2 radius + 1)^2`` window from the pixel: ``sum w_j (x_j - x_i) / sum w_j`` over the pixels
    of positive weight (the phase filter's inverse-variance weights ``1 / sigma^2``; outside the
    image none). 0 where the window holds no weight. Three separable box sums (OpenCV)."""
    w = np.where(np.isfinite(weight) & (weight > 0), np.asarray(weight, np.float32), np.float32(0.0))
    if radius <= 0:
        z = np.zeros(w.shape, np.float32)
        return z, z
    ones = np.ones(2 * radius + 1, np.float32)
    ramp = np.arange(-radius, radius + 1, dtype=np.float32)
    def box(kx: NDArray[np.float32], ky: NDArray[np.float32]) -> NDArray[np.float32]:
        return cv2.sepFilter2D(w, cv2.CV_32F, kx, ky, borderType=cv2.BORDER_CONSTANT)
    sw = box(ones, ones)
    inv = np.divide(np.float32(1.0), sw, out=np.zeros_like(sw), where=sw > 0)
    ox, oy = box(ramp, ones), box(ones, ramp)
    ox *= inv
    oy *= inv
    return ox, oy


def lateral_term(height: NDArray[np.floating], u: NDArray[np.floating] | None = None, *,
                 lateral_px: float = LATERAL_PX, smooth_px: float = LATERAL_SMOOTH_PX,
                 step_px: float = 0.0, coarse_px: float = LATERAL_COARSE_PX,
                 weight: NDArray[np.floating] | None = None, filter_radius: int = 0,
                 grown: NDArray[np.floating] | None = None) -> NDArray[np.float32]:
    """The height error of a lateral position uncertainty (mm), per pixel::

        u_lat^2 = (lateral_px |g|)^2 + (step_px min(|g - g_coarse|, |g|))^2 + (g . c)^2

    ``c`` (with ``weight`` and ``filter_radius`` > 0) is the offset of the phase filter's weighted
    centroid from the pixel (:func:`filter_centroid`): the filter's inverse-variance mean over its
    window is the heights' value at that centroid, so on a slope ``g`` it is off by ``g . c``.
    The weights follow the texture (a dark pixel is noisier) and the table's slope along the fringe,
    so ``c`` is fixed from frame to frame and the error is shared by the frames; its sign is known
    but the slope is the measured one, so it is carried here, not corrected (docs/uncertainty.md,
    "The filter's centroid"). ``grown`` (the filter's ``bias2`` map, finite where the sigma-adaptive
    pass grew the window and reports its bias) leaves those pixels out of it: their window is not
    the fixed one, and the height uncertainty holds their own bias.

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
    are ~0). NaN where the height is NaN. Compiled passes around OpenCV's separable filters,
    float32 in the order of operations the NumPy form has (tests compare them bit for bit).
    """
    return _lateral(height, u, lateral_px, smooth_px, step_px, coarse_px, add=False, weight=weight,
                    filter_radius=filter_radius, grown=grown)


def add_lateral(height: NDArray[np.floating], u: NDArray[np.floating], **kwargs: Any) -> NDArray[np.float32]:
    """``sqrt(u^2 + lateral_term(height, u, **kwargs)^2)`` (a new float32 map; NaN where either is NaN),
    the sum in float64, in the same compiled pass as the term."""
    o: dict[str, Any] = {"lateral_px": LATERAL_PX, "smooth_px": LATERAL_SMOOTH_PX, "step_px": 0.0,
                         "coarse_px": LATERAL_COARSE_PX, "weight": None, "filter_radius": 0, "grown": None}
    unknown = set(kwargs) - o.keys()
    if unknown:
        raise TypeError(f"add_lateral got unexpected keyword arguments {sorted(unknown)}")
    o.update(kwargs)
    return _lateral(height, u, float(o["lateral_px"]), float(o["smooth_px"]), float(o["step_px"]),
                    float(o["coarse_px"]), add=True, weight=o["weight"], filter_radius=int(o["filter_radius"] or 0),
                    grown=o["grown"])


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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _texture_delta_row(m, p, out):  # pragma: no cover - compiled
    """One row of :func:`_texture_delta` (1-D ``m``, ``p``, ``out``): ``d = m - p`` (float64),
    ``pi - (pi - d) % (2 pi)`` (Python's ``%``), as float32; 0 where not finite. The row's pixels
    whose ``a = pi - d`` lies in ``(-2 pi, 4 pi)`` (every pixel of two phases in ``[-pi, pi]``)
    take ``a``, ``a - 2 pi`` or ``a + 2 pi`` in a branch-free loop (SIMD): the ``%``'s bits
    (``fmod`` is exact there and so is ``a - 2 pi``, Sterbenz's lemma), and a value that is not
    finite gives 0 either way; a row holding a finite ``a`` outside (phases outside
    ``[-pi, pi]``) goes through the ``%`` itself, whose call in the loop would keep it from
    vectorising. Also called row by row by the fused kernel (``kernel._frame_kernel``'s
    ``out_delta``)."""
    w = m.size
    b = 2.0 * np.pi
    outside = False
    for u in range(w):
        d = np.float64(m[u]) - np.float64(p[u])
        a = np.pi - d
        outside |= (a - a == 0) & ((a <= -b) | (a >= b + b))  # (not finite: 0 either way)
        r = a if (a >= 0.0) & (a < b) else (a - b if a >= b else a + b)
        d = np.pi - r
        out[u] = np.float32(d) if d - d == 0 else np.float32(0.0)
    if outside:
        for u in range(w):
            d = np.float64(m[u]) - np.float64(p[u])
            d = np.pi - (np.pi - d) % b
            out[u] = np.float32(d) if d - d == 0 else np.float32(0.0)


@numba.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _texture_delta(m, p, out):  # pragma: no cover - compiled
    """:func:`_texture_delta_row` on every row, rows in parallel."""
    for v in numba.prange(m.shape[0]):
        _texture_delta_row(m[v], p[v], out[v])


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
