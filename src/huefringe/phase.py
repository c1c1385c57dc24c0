"""Wrapped phase, phase differences, unwrapping and three-step phase shifting.

Two ways to unwrap the object's phase are offered:

``reference``
    The phase difference to the reference plane, wrapped to (-pi, pi], *is* the answer when the
    object stays within the unambiguous depth (``|dphi|`` < pi everywhere). No spatial unwrapping,
    so isolated regions and steps are measured independently and exactly.
``spatial``
    Quality-guided spatial unwrapping of the wrapped difference with scikit-image's
    :func:`~skimage.restoration.unwrap_phase`, for objects deeper than the unambiguous range but
    continuous. Each connected region gets the 2 pi offset that puts its lowest percentile inside
    (-pi, pi] (the object stands on the plate); regions other than the largest are flagged as isolated because that choice is an
    assumption.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from numba import njit, prange

from huefringe.patterns import TWO_PI, phase_shift_steps

UnwrapMode = Literal["reference", "spatial"]


def wrap(x: NDArray[np.floating]) -> NDArray[np.floating]:
    """Wrap angles to (-pi, pi]."""
    return np.pi - np.mod(np.pi - x, TWO_PI)


def three_step_phase(
    i0: NDArray[np.floating], i1: NDArray[np.floating], i2: NDArray[np.floating]
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Phase of three phase-shifted captures ``I_s = A + B cos(phi + delta_s)``.

    The steps are the capture-session format's ``delta_s = 2 pi (s - 1) / 3``. Since
    ``sum_s I_s cos(delta_s) = 1.5 B cos(phi)`` and ``sum_s I_s sin(delta_s) = -1.5 B sin(phi)``,
    ``phi = atan2(-sum I_s sin(delta_s), sum I_s cos(delta_s))``.

    Returns
    -------
    phi : ndarray
        Phase in [0, 2 pi).
    modulation : ndarray
        ``B / A`` (fringe contrast, 0..1); low values mark pixels without a usable fringe.
    """
    d = phase_shift_steps()
    stack = (np.asarray(i0, np.float64), np.asarray(i1, np.float64), np.asarray(i2, np.float64))
    c = sum(im * np.cos(ds) for im, ds in zip(stack, d, strict=True))
    s = sum(im * np.sin(ds) for im, ds in zip(stack, d, strict=True))
    phi = np.mod(np.arctan2(-s, c), TWO_PI)
    mean = (stack[0] + stack[1] + stack[2]) / 3.0
    amp = np.hypot(c, s) / 1.5
    with np.errstate(divide="ignore", invalid="ignore"):
        mod = np.where(mean > 0, amp / mean, 0.0)
    return phi.astype(np.float32), mod.astype(np.float32)


@dataclass
class Unwrapped:
    """Result of unwrapping a phase-difference map."""

    dphi: NDArray[np.float32]
    """Unwrapped phase difference (NaN where invalid)."""
    flags: dict[str, NDArray[np.bool_]] = field(default_factory=dict)
    """Pixel flags: ``isolated`` (region whose 2 pi offset is assumed), ``near_wrap`` (``|dphi|``
    close to pi), ``wrap_edge`` (neighbours differ by more than pi before wrapping: the surface
    crosses the unambiguous range)."""


@njit(cache=True, nogil=True)
def _wrap_flags(d, valid, near_wrap, edge, near):  # pragma: no cover - compiled
    """``edge``: both pixels of every valid 4-neighbour pair whose phases differ by more than pi;
    ``near``: valid pixels with ``|d| > near_wrap``. Differences in float64."""
    h, w = d.shape
    for v in range(h):
        for u in range(w):
            if not valid[v, u]:
                continue
            x = np.float64(d[v, u])
            near[v, u] = abs(x) > near_wrap
            if u + 1 < w and valid[v, u + 1] and abs(np.float64(d[v, u + 1]) - x) > np.pi:
                edge[v, u] = True
                edge[v, u + 1] = True
            if v + 1 < h and valid[v + 1, u] and abs(np.float64(d[v + 1, u]) - x) > np.pi:
                edge[v, u] = True
                edge[v + 1, u] = True


def unwrap(dphi_wrapped: NDArray[np.floating], valid: NDArray[np.bool_], mode: UnwrapMode = "reference",
           *, near_wrap: float = 0.9 * np.pi, min_region_px: int = 1,
           anchor_percentile: float = 1.0) -> Unwrapped:
    """Unwrap a wrapped phase difference to the reference plane.

    Parameters
    ----------
    dphi_wrapped : ndarray
        ``wrap(phi_object - phi_reference)`` in (-pi, pi].
    valid : ndarray of bool
        Pixels with a usable phase.
    mode : {"reference", "spatial"}
        See the module docstring.
    near_wrap : float
        Pixels with ``|dphi| > near_wrap`` (reference mode) are flagged ``near_wrap``.
    anchor_percentile : float
        Spatial mode: each region's 2 pi offset puts this percentile of its values inside
        (-pi, pi] (objects stand on the plate, so their lowest part is near the reference plane).
    """
    d = np.asarray(dphi_wrapped)
    if d.dtype not in (np.float32, np.float64):
        d = d.astype(np.float64)
    valid = np.asarray(valid, bool) & np.isfinite(d)
    flags: dict[str, NDArray[np.bool_]] = {}
    edge = np.zeros(d.shape, bool)
    near = np.zeros(d.shape, bool)
    _wrap_flags(d, valid, float(near_wrap), edge, near)
    flags["wrap_edge"] = edge
    if mode == "reference":
        out = np.where(valid, d, np.nan)
        flags["near_wrap"] = near
        flags["isolated"] = np.zeros(d.shape, bool)
    elif mode == "spatial":
        d = d.astype(np.float64)
        out = np.full(d.shape, np.nan)
        from scipy import ndimage  # here, not at the top: the per-frame jobs never need it
        from skimage.restoration import unwrap_phase

        labels, n = ndimage.label(valid)
        isolated = np.zeros(d.shape, bool)
        if n:
            sizes = ndimage.sum_labels(valid, labels, index=np.arange(1, n + 1))
            largest = int(np.argmax(sizes)) + 1
            masked = np.ma.masked_array(d, mask=~valid)
            uw = np.asarray(unwrap_phase(masked, rng=0).filled(np.nan), np.float64)
            for lab in range(1, n + 1):
                region = labels == lab
                if sizes[lab - 1] < min_region_px:
                    continue
                low = np.percentile(uw[region], anchor_percentile)
                k = np.floor((low + np.pi) / TWO_PI)
                out[region] = uw[region] - k * TWO_PI
                if lab != largest:
                    isolated |= region
        flags["isolated"] = isolated
        flags["near_wrap"] = np.zeros(d.shape, bool)
    else:
        raise ValueError(f"unknown unwrapping mode {mode!r} (reference or spatial)")
    return Unwrapped(out.astype(np.float32), flags)


def unwrap_rows(phi: NDArray[np.floating], valid: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Spatially unwrap a fringe phase map with many periods (e.g. a calibration plane).

    Uses scikit-image's quality-guided unwrapper on the valid pixels and returns NaN elsewhere.
    The absolute 2 pi offset is arbitrary; callers compare planes through differences.
    """
    from skimage.restoration import unwrap_phase

    masked = np.ma.masked_array(np.asarray(phi, np.float64), mask=~np.asarray(valid, bool))
    return np.asarray(unwrap_phase(masked, rng=0).filled(np.nan), np.float64)


@njit(cache=True, inline="always", error_model="numpy")
def denoise_weight(d, sg, valid):  # pragma: no cover - compiled
    """One pixel's filter inputs ``(dz, s2, inv)`` from its phase ``d``, sigma ``sg`` and validity
    (compiled, for :func:`_denoise_weights` and the fused kernel alike):
    ``ok = valid & finite(d) & finite(sg) & sg > 0``; ``dz = ok ? d : 0``,
    ``s2 = float32(clip(ok ? sg : 1, 1e-9, 1e9)) ** 2``, ``inv = ok ? 1 / s2 : 0``."""
    ok = valid & (d - d == 0) & (sg - sg == 0) & (sg > 0)
    sc = np.float32(min(max(np.float64(sg), 1e-9), 1e9)) if ok else np.float32(1.0)
    q = sc * sc
    return (np.float32(d) if ok else np.float32(0.0)), q, (np.float32(1.0) / q if ok else np.float32(0.0))


@njit(cache=True, nogil=True)
def _denoise_weights(d, sigma, valid, dz, s2, inv):  # pragma: no cover - compiled
    """:func:`denoise_weight` of every pixel."""
    h, w = d.shape
    for v in range(h):
        for u in range(w):
            dz[v, u], s2[v, u], inv[v, u] = denoise_weight(d[v, u], sigma[v, u], valid[v, u])


@njit(cache=True, nogil=True, error_model="numpy")
def _denoise_row(dj, di, sj2, si2, inv, k2, acc, wsum):  # pragma: no cover - compiled
    """One window offset for one row: ``acc += w diff``, ``wsum += w`` where the neighbour agrees.

    Branch-free and on 1-D float32 rows, so that LLVM vectorises it (SIMD over ``u``).
    """
    two_pi = np.float32(2.0 * np.pi)
    inv_two_pi = np.float32(1.0 / (2.0 * np.pi))
    pi = np.float32(np.pi)
    zero = np.float32(0.0)
    for u in range(dj.size):
        diff = dj[u] - di[u]
        diff = diff - two_pi * np.floor((diff + pi) * inv_two_pi)  # to [-pi, pi)
        keep = diff * diff <= k2 * (si2[u] + sj2[u])
        wj = inv[u] if keep else zero
        acc[u] += wj * diff
        wsum[u] += wj


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def _denoise_kernel(d, s2, inv, radius, k2, out, wout):  # pragma: no cover - compiled
    """Row by row, window offset by window offset (``dv`` then ``du``, the same order for every
    pixel); ``inv = 0`` marks invalid pixels, which then add nothing. ``wout``: each pixel's sum
    of accepted weights (its filtered variance is ``1 / wout``; 0 where not valid). Rows in
    parallel (``prange``)."""
    h, w = d.shape
    for v in prange(h):
        acc = np.zeros(w, np.float32)
        wsum = np.zeros(w, np.float32)
        for dv in range(-radius, radius + 1):
            vv = v + dv
            if vv < 0 or vv >= h:
                continue
            for du in range(-radius, radius + 1):
                u0 = max(0, -du)
                u1 = min(w, w - du)
                _denoise_row(d[vv, u0 + du : u1 + du], d[v, u0:u1], s2[vv, u0 + du : u1 + du], s2[v, u0:u1],
                             inv[vv, u0 + du : u1 + du], k2, acc[u0:u1], wsum[u0:u1])
        for u in range(w):
            out[v, u] = d[v, u] + acc[u] / wsum[u] if inv[v, u] > 0 else np.float32(np.nan)
            wout[v, u] = wsum[u] if inv[v, u] > 0 else np.float32(0.0)


@njit(cache=True, nogil=True, error_model="numpy")
def _window_sums(inv, r2, radius, wsum, rsum, cnt):  # pragma: no cover - compiled
    """:func:`window_sums` for one half side ``radius``: running box sums of ``w``, ``w r2`` and the
    valid pixels (float64 column sums slid down the rows, then along each row), scaled by
    ``wsum / sum w``."""
    h, w = inv.shape
    cw = np.zeros(w, np.float64)
    cr = np.zeros(w, np.float64)
    cn = np.zeros(w, np.float64)
    for v in range(min(radius, h)):  # rows 0 .. radius - 1 of the first window
        for u in range(w):
            iv = np.float64(inv[v, u])
            cw[u] += iv
            cr[u] += iv * r2[v, u]
            cn[u] += 1.0 if iv > 0 else 0.0
    for v in range(h):
        add = v + radius
        if add < h:
            for u in range(w):
                iv = np.float64(inv[add, u])
                cw[u] += iv
                cr[u] += iv * r2[add, u]
                cn[u] += 1.0 if iv > 0 else 0.0
        sub = v - radius - 1
        if sub >= 0:
            for u in range(w):
                iv = np.float64(inv[sub, u])
                cw[u] -= iv
                cr[u] -= iv * r2[sub, u]
                cn[u] -= 1.0 if iv > 0 else 0.0
        bw = 0.0
        br = 0.0
        bn = 0.0
        for u in range(min(radius, w)):
            bw += cw[u]
            br += cr[u]
            bn += cn[u]
        for u in range(w):
            if u + radius < w:
                bw += cw[u + radius]
                br += cr[u + radius]
                bn += cn[u + radius]
            if u - radius - 1 >= 0:
                bw -= cw[u - radius - 1]
                br -= cr[u - radius - 1]
                bn -= cn[u - radius - 1]
            ok = (inv[v, u] > 0) & (bw > 0)
            sc = np.float64(wsum[v, u]) / bw if ok else 0.0
            rsum[v, u] = np.float32(sc * br)
            cnt[v, u] = np.float32(sc * bn)


@njit(cache=True, nogil=True, error_model="numpy")
def _box_sums(inv, r2, rad, radius, wsum, rsum, cnt):  # pragma: no cover - compiled
    """:func:`window_sums` where the window grew past ``radius`` (``rad > radius``): summed-area
    tables (float64) of ``w``, ``w r2`` and the valid pixels, then the box of half side ``rad``
    (clipped to the image), scaled by ``wsum / sum w``."""
    h, w = inv.shape
    sw = np.zeros((h + 1, w + 1))
    sr = np.zeros((h + 1, w + 1))
    sn = np.zeros((h + 1, w + 1))
    for v in range(h):
        aw = 0.0
        ar = 0.0
        an = 0.0
        for u in range(w):
            iv = np.float64(inv[v, u])
            aw += iv
            ar += iv * r2[v, u]
            an += 1.0 if iv > 0 else 0.0
            sw[v + 1, u + 1] = sw[v, u + 1] + aw
            sr[v + 1, u + 1] = sr[v, u + 1] + ar
            sn[v + 1, u + 1] = sn[v, u + 1] + an
    for v in range(h):
        for u in range(w):
            r = np.int64(rad[v, u])
            if r <= radius or inv[v, u] <= 0:
                continue
            v0 = max(v - r, 0)
            v1 = min(v + r + 1, h)
            u0 = max(u - r, 0)
            u1 = min(u + r + 1, w)
            bw = sw[v1, u1] - sw[v0, u1] - sw[v1, u0] + sw[v0, u0]
            br = sr[v1, u1] - sr[v0, u1] - sr[v1, u0] + sr[v0, u0]
            bn = sn[v1, u1] - sn[v0, u1] - sn[v1, u0] + sn[v0, u0]
            sc = np.float64(wsum[v, u]) / bw if bw > 0 else 0.0
            rsum[v, u] = np.float32(sc * br)
            cnt[v, u] = np.float32(sc * bn)


def window_sums(inv: NDArray[np.float32], r2: NDArray[np.float32], rad: NDArray[np.floating] | int,
                wsum: NDArray[np.float32]) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """``sum w r2`` and the support of each pixel's filter window from its accepted weights
    ``wsum`` and box sums over the whole window (half side ``rad``, per pixel or one for all):
    ``wsum`` times the window's weighted mean of ``r2``, ``sum(w r2) / sum(w)``, and ``wsum``
    over the window's mean weight, ``n / sum(w)`` (the number of equal-weight pixels that would
    give ``wsum``). Exact (to float rounding) where the window took every valid neighbour, which
    is almost everywhere (the step budgets' central boxes included); where it rejected some
    (steps, outliers) the means are those of the whole window. Running box sums at the common
    half side, summed-area tables for the windows that grew: on a 640 x 480 bench frame they cut
    the uncertainty's cost from x1.47 to x1.31 of the adaptive kernel against summing them beside
    the weights (tests compare them with that exact accumulation)."""
    rsum = np.empty(inv.shape, np.float32)
    cnt = np.empty(inv.shape, np.float32)
    if np.ndim(rad) == 0:
        _window_sums(inv, r2, int(rad), wsum, rsum, cnt)
        return rsum, cnt
    rmap = np.ascontiguousarray(rad, np.float32)
    base = int(rmap.min()) if rmap.size else 0
    _window_sums(inv, r2, base, wsum, rsum, cnt)  # every pixel at the smallest half side (running sums) ...
    if rmap.size and rmap.max() > base:
        _box_sums(inv, r2, rmap, base, wsum, rsum, cnt)  # ... the grown windows again, from summed-area tables
    return rsum, cnt


@njit(cache=True, nogil=True, parallel=True)
def _level_tables(d, inv, sw, sc, ss, sn):  # pragma: no cover - compiled
    """Summed-area tables (float64, ``(H + 1, W + 1)``) of the weights ``w = inv``, ``w d``,
    ``w d^2`` and the valid pixels: rows summed in parallel, then the columns in parallel."""
    h, w = d.shape
    for v in prange(h):
        aw = 0.0
        ac = 0.0
        a_s = 0.0
        an = 0.0
        sw[v + 1, 0] = 0.0
        sc[v + 1, 0] = 0.0
        ss[v + 1, 0] = 0.0
        sn[v + 1, 0] = 0.0
        for u in range(w):
            iv = np.float64(inv[v, u])
            if iv > 0:
                x = np.float64(d[v, u])
                aw += iv
                ac += iv * x
                a_s += iv * x * x
                an += 1.0
            sw[v + 1, u + 1] = aw
            sc[v + 1, u + 1] = ac
            ss[v + 1, u + 1] = a_s
            sn[v + 1, u + 1] = an
    for u in prange(w + 1):
        sw[0, u] = 0.0
        sc[0, u] = 0.0
        ss[0, u] = 0.0
        sn[0, u] = 0.0
    for b in prange((w + 1 + 63) // 64):  # column blocks of 64 (contiguous loads down the rows)
        u0 = b * 64
        u1 = min(u0 + 64, w + 1)
        for v in range(1, h + 1):
            for u in range(u0, u1):
                sw[v, u] += sw[v - 1, u]
                sc[v, u] += sc[v - 1, u]
                ss[v, u] += ss[v - 1, u]
                sn[v, u] += sn[v - 1, u]


@njit(cache=True, inline="always")
def _box(t, v0, v1, u0, u1):  # pragma: no cover - compiled
    return t[v1, u1] - t[v0, u1] - t[v1, u0] + t[v0, u0]


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def _adaptive_pass(d, s2, inv, first, wfirst, radius, max_radius, k2, target_w, reject_w, out, wout,  # pragma: no cover
                   rad, full, sw, sc, ss, sn, chi_z):
    """Second pass of :func:`denoise_weighted` for the pixels whose first-pass variance
    ``1 / wfirst`` exceeds ``1 / target_w``: the window grows ring by ring (Chebyshev radius
    ``radius + 1 .. max_radius``) until the accepted weights reach ``target_w``. Neighbours are
    accepted when they agree with the pixel's first-pass estimate within ``k`` combined sigma
    (``diff^2 <= k2 (s_j^2 + 1 / wfirst)``): a noisy pixel is judged by its better estimate, so
    a step stays a step. Pixels whose weights stay below ``reject_w`` become NaN (no filter can
    save them). ``wout`` receives each pixel's final sum of accepted weights (0 where not
    valid). Float32, fixed visiting order: the result depends only on the inputs. With ``full``,
    ``rad`` receives each pixel's final window half side (``radius`` where the first pass stands),
    for :func:`window_sums`.

    The pixels of a row that need the pass go through it together, one window offset at a time
    across all of them (SIMD over the pixels), each leaving the list once its weights reach the
    target; each pixel still adds its neighbours in the same order (ring, then row ``dv``, then
    ``du``), so the sums are those of a pixel-by-pixel loop, bit for bit.

    With ``chi_z > 0`` a pixel first tries whole boxes (half side ``radius .. max_radius``) in
    O(1) each from the summed-area tables of :func:`_level_tables`: the box's weighted mean
    ``sum w d / sum w`` is taken, with every valid pixel of the box and its weight sum, when the
    box is consistent with one level (its weighted scatter ``sum w d^2 - (sum w d)^2 / sum w =
    sum w (d - mean)^2`` within ``chi_z`` standard deviations of its ``n - 1`` expectation: a box
    across the wrap at +-pi fails it by far) and its mean agrees with the pixel's first-pass
    estimate within ``k`` combined sigma; at the first box that reaches ``target_w`` (or the
    last) it stops. A box that fails either test (a step, an outlier, a slope steep for
    the noise) sends the pixel through the ring pass above. Rows run in parallel (``prange``):
    each pixel's result depends only on the inputs, not on the threads."""
    h, w = d.shape
    nan = np.float32(np.nan)
    two_pi = np.float32(2.0 * np.pi)
    inv_two_pi = np.float32(1.0 / (2.0 * np.pi))
    pi = np.float32(np.pi)
    zero = np.float32(0.0)
    boxes = chi_z > 0
    for v in prange(h):
        pu = np.empty(w, np.int64)  # the row's pixels that need the pass, and their running state
        pm = np.empty(w, np.float32)
        psf = np.empty(w, np.float32)
        pdc = np.empty(w, np.float32)
        pacc = np.empty(w, np.float32)
        pw = np.empty(w, np.float32)
        xg = np.empty(w, np.float32)  # scratch: the gathered neighbours
        ig = np.empty(w, np.float32)
        sg = np.empty(w, np.float32)
        n = 0
        if full:
            for u in range(w):
                rad[v, u] = radius
        for u in range(w):
            out[v, u] = first[v, u]
            wout[v, u] = wfirst[v, u]
            if inv[v, u] <= 0:
                continue
            ws = wfirst[v, u]
            if ws >= target_w or max_radius <= radius:
                out[v, u] = first[v, u] if ws >= reject_w else nan
                continue
            if boxes:
                m = np.float64(first[v, u])
                sf = 1.0 / np.float64(ws)
                dc = d[v, u]
                done = False
                for r in range(radius, max_radius + 1):
                    v0 = max(v - r, 0)
                    v1 = min(v + r + 1, h)
                    u0 = max(u - r, 0)
                    u1 = min(u + r + 1, w)
                    bw = _box(sw, v0, v1, u0, u1)
                    bc = _box(sc, v0, v1, u0, u1)
                    bs = _box(ss, v0, v1, u0, u1)
                    bn = _box(sn, v0, v1, u0, u1)
                    dof = bn - 1.0
                    mean = bc / bw
                    chi = bs - bc * mean
                    dm = mean - m
                    dm = dm - 2.0 * np.pi * np.floor((dm + np.pi) / (2.0 * np.pi))
                    if chi > dof + chi_z * np.sqrt(2.0 * max(dof, 1.0)) or dm * dm > k2 * (sf + 1.0 / bw):
                        break  # not one level: the ring pass decides
                    if bw >= target_w or r == max_radius:
                        wb = np.float32(bw)
                        if wb < ws:  # (as the ring pass) never less support than the first pass
                            wb = ws
                            val = first[v, u]
                        else:
                            dd = np.float32(mean) - dc
                            dd = dd - two_pi * np.floor((dd + pi) * inv_two_pi)
                            val = dc + dd
                            if full:
                                rad[v, u] = r
                        out[v, u] = val if wb >= reject_w else nan
                        wout[v, u] = wb
                        done = True
                        break
                if done:
                    continue
            pu[n] = u
            n += 1
        if n == 0:
            continue
        for q in range(n):
            u = pu[q]
            pm[q] = first[v, u]
            psf[q] = np.float32(1.0) / wfirst[v, u]
            pdc[q] = d[v, u]
            pacc[q] = 0.0
            pw[q] = 0.0
        for r in range(0, max_radius + 1):
            for dv in range(-r, r + 1):
                vv = v + dv
                if vv < 0 or vv >= h:
                    continue
                edge_row = dv == -r or dv == r
                step = 1 if edge_row else 2 * r
                du = -r
                while du <= r:
                    # the neighbours gathered into contiguous scratch rows (the arithmetic below
                    # is not vectorised on gathered loads), 0 inverse variance outside the image
                    for q in range(n):
                        uu = pu[q] + du
                        inb = (uu >= 0) & (uu < w)
                        uc = min(max(uu, 0), w - 1)
                        xg[q] = d[vv, uc]
                        ig[q] = inv[vv, uc] if inb else zero
                        sg[q] = s2[vv, uc]
                    # branch-free (SIMD over the pixels); a neighbour not taken adds +0 to
                    # sums that start at +0 and so are never -0: bit for bit as skipping it
                    for q in range(n):
                        x = xg[q]
                        iv = ig[q]
                        dm = x - pm[q]
                        dm = dm - two_pi * np.floor((dm + pi) * inv_two_pi)
                        keep = (iv > 0) & (dm * dm <= k2 * (sg[q] + psf[q]))
                        diff = x - pdc[q]
                        diff = diff - two_pi * np.floor((diff + pi) * inv_two_pi)
                        pacc[q] += iv * diff if keep else zero
                        pw[q] += iv if keep else zero
                    du += step if step > 0 else 1
            if r >= radius or r == max_radius:
                # a pixel stops once its weights reach the target (or at the last ring): its
                # result is written and it leaves the list
                last = r == max_radius
                keep_n = 0
                for q in range(n):
                    if last or pw[q] >= target_w:
                        u = pu[q]
                        ws = wfirst[v, u]
                        wsum = pw[q]
                        if wsum < ws:  # the grown window found less support than the first pass
                            wsum = ws
                            val = pm[q]
                        else:
                            val = pdc[q] + pacc[q] / wsum
                            if full:
                                rad[v, u] = r
                        out[v, u] = val if wsum >= reject_w else nan
                        wout[v, u] = wsum
                        continue
                    pu[keep_n] = pu[q]
                    pm[keep_n] = pm[q]
                    psf[keep_n] = psf[q]
                    pdc[keep_n] = pdc[q]
                    pacc[keep_n] = pacc[q]
                    pw[keep_n] = pw[q]
                    keep_n += 1
                n = keep_n
                if n == 0:
                    break


def denoise_phase(dphi: NDArray[np.floating], sigma: NDArray[np.floating], valid: NDArray[np.bool_],
                  *, radius: int = 2, k: float = 3.0, max_radius: int = 0, target_sigma: float = 0.0,
                  reject_sigma: float = 0.0, weight_sum: NDArray[np.float32] | None = None,
                  ratio: NDArray[np.float32] | None = None, ratio_sum: NDArray[np.float32] | None = None,
                  support: NDArray[np.float32] | None = None, box_chi_z: float = 0.0,
                  carry: NDArray[np.float32] | None = None,
                  carry_mean: NDArray[np.float32] | None = None) -> NDArray[np.float32]:
    """Edge-preserving, uncertainty-weighted local mean of a phase map.

    Each valid pixel becomes the inverse-variance weighted mean of the valid pixels in its
    ``(2 radius + 1)^2`` window whose phase agrees with it within ``k`` combined standard
    deviations (a bilateral filter whose range term is the known per-pixel uncertainty).
    Differences are taken modulo 2 pi, so wrapped maps are fine. Steps taller than ``k`` sigma
    (a 1 mm step is tens of sigma) are not blurred; flat regions gain up to
    ``2 radius + 1`` in precision. Pixels where the hue hardly changes with the code phase
    (projector gamma flattens the trapezoid's ramps near 0, 2 pi/3 and 4 pi/3) carry large
    ``sigma`` and are pulled toward their better-determined neighbours.

    Parameters
    ----------
    dphi : ndarray
        Phase (difference) map in radians; NaN where invalid.
    sigma : ndarray
        Per-pixel standard deviation of ``dphi`` in radians (finite, > 0 where valid).
    valid : ndarray of bool
    max_radius, target_sigma : int, float
        Sigma-adaptive support: a pixel whose filtered sigma (``1 / sqrt`` of its accepted
        inverse variances) is above ``target_sigma`` gets a window grown ring by ring up to
        ``max_radius``, its neighbours tested against its first-pass estimate (so a step is
        never crossed); 0 = fixed window.
    reject_sigma : float
        Pixels whose filtered sigma stays above this become NaN (invalid); 0 = never.
    box_chi_z : float
        > 0: the adaptive support grows by whole boxes, O(1) per pixel and radius from
        summed-area tables of the weighted phase and its square, wherever the box is consistent with one level
        within this many standard deviations of its chi-square (:func:`_adaptive_pass`); the
        pixels where it is not (steps, outliers) grow ring by ring. 0 = rings everywhere.
    carry, carry_mean : float32 ndarray, optional
        ``carry_mean`` receives each pixel's weighted mean of ``carry`` (finite everywhere) over
        its final window, ``sum(w carry) / sum(w)`` (:func:`window_sums`): another map filtered
        with this phase's weights, e.g. a small change of the phase to first order.
    weight_sum : float32 ndarray, optional
        Receives each pixel's sum of the weights ``1 / sigma^2`` of the neighbours it averaged
        (0 where not valid): the filtered phase's variance from independent pixel noise is
        exactly ``1 / weight_sum`` (:mod:`huefringe.uncertainty`).
    ratio, ratio_sum : float32 ndarray, optional
        When the pixels' actual noise variance is ``ratio`` times the ``sigma^2`` that weights
        them (e.g. the frame's own-signal noise against the pooled one), ``ratio_sum`` receives
        each pixel's ``sum w ratio``: the filtered phase's variance is then
        ``ratio_sum / weight_sum^2`` (``sum w^2 sigma_true^2 / (sum w)^2``).
    support : float32 ndarray, optional
        Receives the number of pixels each pixel averaged (itself included; 0 where not valid),
        counted in equal-weight pixels over its final window (:func:`window_sums`): the window's
        accepted neighbours where none was rejected, and the adaptive pass may grow it far
        beyond ``(2 radius + 1)^2``.

    Returns
    -------
    ndarray, float32
        The filtered phase, NaN where not valid. Computed in float32 (vectorised; about 5 ms
        for 640 x 480 at radius 2 on one core).
    """
    d = np.asarray(dphi)
    s = np.asarray(sigma)
    valid = np.asarray(valid, bool)
    if not d.shape == s.shape == valid.shape or d.ndim != 2:
        raise ValueError(f"dphi {d.shape}, sigma {s.shape} and valid {valid.shape} must be the same 2-D shape")
    if d.dtype not in (np.float32, np.float64):
        d = d.astype(np.float64)
    if s.dtype not in (np.float32, np.float64):
        s = s.astype(np.float64)
    # float32 throughout (SIMD); sigma clipped so that its square and inverse stay finite
    dz, s2, inv = (np.empty(d.shape, np.float32) for _ in range(3))
    _denoise_weights(d, s, valid, dz, s2, inv)
    return denoise_weighted(dz, s2, inv, radius=radius, k=k, max_radius=max_radius, target_sigma=target_sigma,
                            reject_sigma=reject_sigma, weight_sum=weight_sum, ratio=ratio, ratio_sum=ratio_sum,
                            support=support, box_chi_z=box_chi_z, carry=carry, carry_mean=carry_mean)


def denoise_weight_sums(dphi: NDArray[np.floating], sigma: NDArray[np.floating],
                        valid: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Each pixel's own weight ``1 / sigma^2`` as :func:`denoise_phase` computes it (0 where
    not valid): the weight sum of an unfiltered phase (radius 0)."""
    d = np.asarray(dphi)
    d = d if d.dtype in (np.float32, np.float64) else d.astype(np.float64)
    s = np.asarray(sigma)
    s = s if s.dtype in (np.float32, np.float64) else s.astype(np.float64)
    dz, s2, inv = (np.empty(d.shape, np.float32) for _ in range(3))
    _denoise_weights(d, s, np.asarray(valid, bool), dz, s2, inv)
    return inv


def denoise_weighted(dz: NDArray[np.float32], s2: NDArray[np.float32], inv: NDArray[np.float32], *,
                     radius: int = 2, k: float = 3.0, max_radius: int = 0, target_sigma: float = 0.0,
                     reject_sigma: float = 0.0, weight_sum: NDArray[np.float32] | None = None,
                     ratio: NDArray[np.float32] | None = None, ratio_sum: NDArray[np.float32] | None = None,
                     support: NDArray[np.float32] | None = None, box_chi_z: float = 0.0,
                     carry: NDArray[np.float32] | None = None,
                     carry_mean: NDArray[np.float32] | None = None) -> NDArray[np.float32]:
    """:func:`denoise_phase` on its prepared float32 inputs (for callers that compute them on
    the fly, like the fused kernel): ``ok = valid & finite(dphi) & finite(sigma) & sigma > 0``,
    ``dz = ok ? dphi : 0``, ``s2 = float32(clip(ok ? sigma : 1, 1e-9, 1e9)) ** 2`` and
    ``inv = ok ? 1 / s2 : 0``. Returns the filtered phase, NaN where ``inv == 0``;
    ``weight_sum``, ``ratio_sum`` and ``support`` (float32, C-contiguous, optional) receive the
    sums of the weights used, of the weights times ``ratio`` and the number of pixels averaged
    (:func:`denoise_phase`). The phase and ``weight_sum`` do not depend on whether the other
    two are asked for.
    """
    arrays = [np.ascontiguousarray(x, dtype=np.float32) for x in (dz, s2, inv)]
    if not arrays[0].shape == arrays[1].shape == arrays[2].shape or arrays[0].ndim != 2:
        raise ValueError("dz, s2 and inv must be 2-D arrays of the same shape")
    out = np.empty(arrays[0].shape, np.float32)
    for name, x in (("weight_sum", weight_sum), ("ratio_sum", ratio_sum), ("support", support)):
        if x is not None and (x.shape != out.shape or x.dtype != np.float32 or not x.flags.c_contiguous):
            raise ValueError(f"{name} must be a C-contiguous float32 array of the phase's shape")
    if (carry is None) != (carry_mean is None):
        raise ValueError("carry and carry_mean go together")
    if carry_mean is not None and (carry_mean.shape != out.shape or carry_mean.dtype != np.float32
                                   or not carry_mean.flags.c_contiguous):
        raise ValueError("carry_mean must be a C-contiguous float32 array of the phase's shape")
    full = ratio_sum is not None or support is not None or carry is not None
    if ratio_sum is not None and ratio is None:
        raise ValueError("ratio_sum needs ratio")
    r2 = (np.ascontiguousarray(ratio, np.float32) if ratio is not None else np.ones(out.shape, np.float32)) \
        if full else np.empty((1, 1), np.float32)
    if r2.shape != out.shape and full:
        raise ValueError(f"ratio has shape {r2.shape}, the phase {out.shape}")
    wsum = np.empty(out.shape, np.float32)
    k2 = np.float32(float(k) ** 2)
    _denoise_kernel(*arrays, int(radius), k2, out, wsum)
    if (max_radius > radius and target_sigma > 0) or reject_sigma > 0:
        final = np.empty_like(out)
        wfinal = weight_sum if weight_sum is not None else np.empty_like(wsum)
        target_w = np.float32(1.0 / target_sigma**2) if target_sigma > 0 else np.float32(0.0)
        reject_w = np.float32(1.0 / reject_sigma**2) if reject_sigma > 0 else np.float32(0.0)
        rad = np.empty(out.shape if full else (1, 1), np.float32)
        grows = max_radius > radius and target_sigma > 0 and box_chi_z > 0
        tables = [np.empty((h + 1, w + 1) if grows else (1, 1)) for h, w in [arrays[0].shape] for _ in range(4)]
        if grows:
            _level_tables(arrays[0], arrays[2], *tables)
        _adaptive_pass(*arrays, out, wsum, int(radius), int(max(max_radius, radius)), k2, target_w, reject_w, final,
                       wfinal, rad, full, *tables, float(box_chi_z) if grows else 0.0)
        out, wsum = final, wfinal
    else:
        rad = np.float32(radius)
        if weight_sum is not None:
            weight_sum[...] = wsum
    if full:
        rsum, cnt = window_sums(arrays[2], r2, rad, wsum)
        for dst, src in ((ratio_sum, rsum), (support, cnt)):
            if dst is not None:
                dst[...] = src
        if carry is not None:
            c = np.ascontiguousarray(carry, np.float32)
            if c.shape != out.shape:
                raise ValueError(f"carry has shape {c.shape}, the phase {out.shape}")
            carry_mean[...] = window_sums(arrays[2], c, rad, np.ones(out.shape, np.float32))[0]
    return out


#: ``measurement.denoise_adaptive`` defaults (sigmas in rad of phase)
ADAPTIVE_DEFAULTS = {"enabled": True, "max_radius": 6, "target_sigma_rad": 0.002, "reject_sigma_rad": 0.03,
                     "box_chi_z": 0.0}


def adaptive_kwargs(opts: dict | None) -> dict:
    """:func:`denoise_phase` / :func:`denoise_weighted` keywords of a ``measurement.denoise_adaptive``
    block (``enabled``, ``max_radius``, ``target_sigma_rad``, ``reject_sigma_rad``, ``box_chi_z``); ``{}`` when
    absent or disabled (the fixed window)."""
    if opts is None or opts is False:
        return {}
    o = {**ADAPTIVE_DEFAULTS, **(dict(opts) if opts is not True else {})}
    if not o["enabled"]:
        return {}
    return {"max_radius": int(o["max_radius"]), "target_sigma": float(o["target_sigma_rad"]),
            "reject_sigma": float(o["reject_sigma_rad"]), "box_chi_z": float(o["box_chi_z"])}
