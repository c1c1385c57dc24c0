"""The compiled passes of the edge-preserving phase filter: per-pixel weights, the fixed window, the adaptive window's growth, the window sums."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from numba import njit, prange

from huefringe import _threads  # noqa: F401  (numba's threading layer, before any parallel launch)


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
def _denoise_row(dj, di, sj2, off, add, inv, k2, acc, wsum):  # pragma: no cover - compiled
    """One window offset for one row: ``acc += w diff``, ``wsum += w`` where the neighbour agrees
    with the pixel's own-side estimate (:func:`_own_side`), ``(diff - off)^2 <= k2 (s_j^2 + add)``.

    Branch-free and on 1-D float32 rows, so that LLVM vectorises it (SIMD over ``u``).
    """
    two_pi = np.float32(2.0 * np.pi)
    inv_two_pi = np.float32(1.0 / (2.0 * np.pi))
    pi = np.float32(np.pi)
    zero = np.float32(0.0)
    for u in range(dj.size):
        diff = dj[u] - di[u]
        diff = diff - two_pi * np.floor((diff + pi) * inv_two_pi)  # to [-pi, pi)
        e = diff - off[u]
        keep = e * e <= k2 * (add[u] + sj2[u])
        wj = inv[u] if keep else zero
        acc[u] += wj * diff
        wsum[u] += wj


@njit(cache=True, nogil=True, error_model="numpy")
def _own_row(dj, di, sj2, si2, inv, k2, acc, wsum):  # pragma: no cover - compiled
    """One window offset of the own-side estimate (:func:`_own_side`) for one row: the neighbour
    counts where ``diff^2 <= 2 k2 min(s_i^2, s_j^2)``, i.e. where the less noisy of the two places
    it (a noisy pixel does not take a precise neighbour its own noise cannot tell apart)."""
    two_pi = np.float32(2.0 * np.pi)
    inv_two_pi = np.float32(1.0 / (2.0 * np.pi))
    pi = np.float32(np.pi)
    zero = np.float32(0.0)
    two = np.float32(2.0)
    for u in range(dj.size):
        diff = dj[u] - di[u]
        diff = diff - two_pi * np.floor((diff + pi) * inv_two_pi)  # to [-pi, pi)
        keep = diff * diff <= two * k2 * min(si2[u], sj2[u])
        wj = inv[u] if keep else zero
        acc[u] += wj * diff
        wsum[u] += wj


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def _own_side(d, s2, inv, radius, k2, off, add):  # pragma: no cover - compiled
    """Each valid pixel's estimate of its own side of any step, the weighted mean of the window's
    neighbours that :func:`_own_row` keeps (itself always): ``off`` receives its offset from the
    pixel (rad), ``add`` its variance ``1 / sum w``; 0 and 0 where not valid."""
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
                _own_row(d[vv, u0 + du : u1 + du], d[v, u0:u1], s2[vv, u0 + du : u1 + du], s2[v, u0:u1],
                         inv[vv, u0 + du : u1 + du], k2, acc[u0:u1], wsum[u0:u1])
        for u in range(w):
            ok = inv[v, u] > 0
            off[v, u] = acc[u] / wsum[u] if ok else np.float32(0.0)
            add[v, u] = np.float32(1.0) / wsum[u] if ok else np.float32(0.0)


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def _denoise_kernel(d, s2, inv, off, add, radius, k2, out, wout):  # pragma: no cover - compiled
    """Row by row, window offset by window offset (``dv`` then ``du``, the same order for every
    pixel); ``inv = 0`` marks invalid pixels, which then add nothing. ``wout``: each pixel's sum
    of accepted weights (its filtered variance is ``1 / wout``; 0 where not valid). ``off`` and
    ``add``: each pixel's own-side estimate and its variance (:func:`_own_side`), which the
    neighbours are tested against (:func:`_denoise_row`); the pixel itself always counts. Rows in
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
                if dv == 0 and du == 0:  # the pixel itself, always
                    _own_row(d[v], d[v], s2[v], s2[v], inv[v], k2, acc, wsum)
                    continue
                _denoise_row(d[vv, u0 + du : u1 + du], d[v, u0:u1], s2[vv, u0 + du : u1 + du], off[v, u0:u1],
                             add[v, u0:u1], inv[vv, u0 + du : u1 + du], k2, acc[u0:u1], wsum[u0:u1])
        for u in range(w):
            out[v, u] = d[v, u] + acc[u] / wsum[u] if inv[v, u] > 0 else np.float32(np.nan)
            wout[v, u] = wsum[u] if inv[v, u] > 0 else np.float32(0.0)


@njit(cache=True, nogil=True, error_model="numpy")
def _denoise_row_carry(dj, di, sj2, off, add, inv, cj, k2, acc, wsum, cacc):  # pragma: no cover - compiled
    """:func:`_denoise_row` (the same operations on ``acc`` and ``wsum``) and ``cacc += w c`` over
    the same accepted neighbours."""
    two_pi = np.float32(2.0 * np.pi)
    inv_two_pi = np.float32(1.0 / (2.0 * np.pi))
    pi = np.float32(np.pi)
    zero = np.float32(0.0)
    for u in range(dj.size):
        diff = dj[u] - di[u]
        diff = diff - two_pi * np.floor((diff + pi) * inv_two_pi)  # to [-pi, pi)
        e = diff - off[u]
        keep = e * e <= k2 * (add[u] + sj2[u])
        wj = inv[u] if keep else zero
        acc[u] += wj * diff
        wsum[u] += wj
        cacc[u] += wj * cj[u]


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def _denoise_kernel_carry(d, s2, inv, off, add, c, radius, k2, out, wout, cout):  # pragma: no cover - compiled
    """:func:`_denoise_kernel` (the same bits in ``out`` and ``wout``) and ``cout``, each pixel's
    weighted mean of ``c`` over the neighbours it accepted, ``sum w c / sum w`` (0 where not valid):
    the filtered change of a phase change ``c`` small enough not to move the accept decisions."""
    h, w = d.shape
    for v in prange(h):
        acc = np.zeros(w, np.float32)
        wsum = np.zeros(w, np.float32)
        cacc = np.zeros(w, np.float32)
        for dv in range(-radius, radius + 1):
            vv = v + dv
            if vv < 0 or vv >= h:
                continue
            for du in range(-radius, radius + 1):
                u0 = max(0, -du)
                u1 = min(w, w - du)
                if dv == 0 and du == 0:  # the pixel itself, always
                    _own_row(d[v], d[v], s2[v], s2[v], inv[v], k2, acc, wsum)
                    for u in range(w):
                        cacc[u] += inv[v, u] * c[v, u]
                    continue
                _denoise_row_carry(d[vv, u0 + du : u1 + du], d[v, u0:u1], s2[vv, u0 + du : u1 + du], off[v, u0:u1],
                                   add[v, u0:u1], inv[vv, u0 + du : u1 + du], c[vv, u0 + du : u1 + du], k2,
                                   acc[u0:u1], wsum[u0:u1], cacc[u0:u1])
        for u in range(w):
            out[v, u] = d[v, u] + acc[u] / wsum[u] if inv[v, u] > 0 else np.float32(np.nan)
            wout[v, u] = wsum[u] if inv[v, u] > 0 else np.float32(0.0)
            cout[v, u] = cacc[u] / wsum[u] if inv[v, u] > 0 else np.float32(0.0)


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
    (clipped to the image), scaled by ``wsum / sum w``. The tables' rows are built in order
    (``S[v + 1] = S[v] + the running sums of row v``) into a ring of the ``2 max(rad) + 2`` rows the
    boxes of the current row reach, not whole tables: the same additions, without touching tens
    of fresh megabytes a frame."""
    h, w = inv.shape
    big = 0
    for v in range(h):
        for u in range(w):
            big = max(big, np.int64(rad[v, u]))
    nb = 2 * big + 2
    sw = np.zeros((nb, w + 1))
    sr = np.zeros((nb, w + 1))
    sn = np.zeros((nb, w + 1))
    built = 0  # the table rows 0 .. built are in the ring (row i in slot i % nb); row 0 is zeros
    for v in range(h):
        top = min(v + big + 1, h)
        while built < top:
            i = built + 1  # table row i from row i - 1 and image row i - 1
            prev = (i - 1) % nb
            cur = i % nb
            aw = 0.0
            ar = 0.0
            an = 0.0
            sw[cur, 0] = 0.0
            sr[cur, 0] = 0.0
            sn[cur, 0] = 0.0
            for u in range(w):
                iv = np.float64(inv[i - 1, u])
                aw += iv
                ar += iv * r2[i - 1, u]
                an += 1.0 if iv > 0 else 0.0
                sw[cur, u + 1] = sw[prev, u + 1] + aw
                sr[cur, u + 1] = sr[prev, u + 1] + ar
                sn[cur, u + 1] = sn[prev, u + 1] + an
            built = i
        for u in range(w):
            r = np.int64(rad[v, u])
            if r <= radius or inv[v, u] <= 0:
                continue
            v0 = max(v - r, 0) % nb
            v1 = min(v + r + 1, h) % nb
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


#: the layers of the adaptive pass's summed-area tables (a pixel's weight ``w``, phase ``d``, table coordinates ``x, y``)
_T_W, _T_D, _T_DD, _T_N, _T_X, _T_Y, _T_XD, _T_YD, _T_XX, _T_YY, _T_XY, _T_C = range(12)


@njit(cache=True, nogil=True, error_model="numpy")
def _table_row(d, inv, c, carry, tab, prev, cur, row, y, xc):  # pragma: no cover - compiled
    """One row of the summed-area tables (float64, ``tab[slot, u, layer]``, ``(W + 1)`` columns):
    slot ``cur`` = slot ``prev`` plus the running sums along image row ``row`` of ``w``, ``w d``,
    ``w d^2``, the valid pixels, ``w x``, ``w y``, ``w x d``, ``w y d``, ``w x^2``, ``w y^2``,
    ``w x y`` (and ``w c`` with ``carry``), ``x = u - xc`` and ``y`` the row's table coordinates
    (small integers, so that the sums keep their precision: :func:`_plane_box`)."""
    h, w = d.shape
    nt = tab.shape[2]
    for k in range(nt):
        tab[cur, 0, k] = 0.0
    aw = 0.0
    ad = 0.0
    add = 0.0
    an = 0.0
    ax = 0.0
    ay = 0.0
    axd = 0.0
    ayd = 0.0
    axx = 0.0
    ayy = 0.0
    axy = 0.0
    ac = 0.0
    for u in range(w):
        iv = np.float64(inv[row, u])
        if iv > 0:
            x = np.float64(d[row, u])
            xu = np.float64(u) - xc
            wx = iv * xu
            wy = iv * y
            aw += iv
            ad += iv * x
            add += iv * x * x
            an += 1.0
            ax += wx
            ay += wy
            axd += wx * x
            ayd += wy * x
            axx += wx * xu
            ayy += wy * y
            axy += wx * y
            if carry:
                ac += iv * np.float64(c[row, u])
        tab[cur, u + 1, 0] = tab[prev, u + 1, 0] + aw
        tab[cur, u + 1, 1] = tab[prev, u + 1, 1] + ad
        tab[cur, u + 1, 2] = tab[prev, u + 1, 2] + add
        tab[cur, u + 1, 3] = tab[prev, u + 1, 3] + an
        tab[cur, u + 1, 4] = tab[prev, u + 1, 4] + ax
        tab[cur, u + 1, 5] = tab[prev, u + 1, 5] + ay
        tab[cur, u + 1, 6] = tab[prev, u + 1, 6] + axd
        tab[cur, u + 1, 7] = tab[prev, u + 1, 7] + ayd
        tab[cur, u + 1, 8] = tab[prev, u + 1, 8] + axx
        tab[cur, u + 1, 9] = tab[prev, u + 1, 9] + ayy
        tab[cur, u + 1, 10] = tab[prev, u + 1, 10] + axy
        if carry:
            tab[cur, u + 1, 11] = tab[prev, u + 1, 11] + ac


@njit(cache=True, nogil=True, error_model="numpy")
def _plane_tables(d, inv, c, carry, xc):  # pragma: no cover - compiled
    """Whole summed-area tables ``(H + 1, W + 1, layers)`` of :func:`_table_row` (row ``i`` the
    sums over image rows ``0 .. i - 1``, ``y`` the image row): what the adaptive pass builds a
    ring of rows at a time, for tests and studies."""
    h, w = d.shape
    tab = np.zeros((h + 1, w + 1, 12 if carry else 11))
    for i in range(1, h + 1):
        _table_row(d, inv, c, carry, tab, i - 1, i, i - 1, np.float64(i - 1), xc)
    return tab


@njit(cache=True, inline="always")
def _box(tab, r0, r1, u0, u1, k):  # pragma: no cover - compiled
    """Layer ``k`` of a summed-area table summed over a box (table rows ``r0``, ``r1``, columns ``u0``, ``u1``)."""
    return tab[r1, u1, k] - tab[r0, u1, k] - tab[r1, u0, k] + tab[r0, u0, k]


@njit(cache=True, inline="always", error_model="numpy")
def _plane_box(tab, r0, r1, u0, u1, xp, yp, gu, gv, vgu, vgv):  # pragma: no cover - compiled
    """A box's statistics about the plane of slope ``(gu, gv)`` (rad/px) through the pixel at table
    coordinates ``(xp, yp)``, O(1) from the summed-area tables ``tab`` (:func:`_table_row`; the
    box's top and bottom table rows in slots ``r0``, ``r1``, its columns ``u0 .. u1``): its weight ``W = sum w``, valid pixels ``n``, plane-corrected
    mean ``sum w (d - g.o) / W`` (``o`` a pixel's offset from the pixel), its weighted scatter about
    that mean ``sum w (d - g.o - mean)^2`` and the part of that scatter's expectation the slope's
    own variances ``vgu, vgv`` add, ``vgu sum w (o_x - mean o_x)^2 + vgv sum w (o_y - mean o_y)^2``.
    The moments are centred on the pixel algebraically (``sum w o_x = sum w x - xp W``, ...) in
    float64."""
    bw = _box(tab, r0, r1, u0, u1, 0)
    sd = _box(tab, r0, r1, u0, u1, 1)
    sdd = _box(tab, r0, r1, u0, u1, 2)
    bn = _box(tab, r0, r1, u0, u1, 3)
    sx = _box(tab, r0, r1, u0, u1, 4)
    sy = _box(tab, r0, r1, u0, u1, 5)
    sxd = _box(tab, r0, r1, u0, u1, 6)
    syd = _box(tab, r0, r1, u0, u1, 7)
    sxx = _box(tab, r0, r1, u0, u1, 8)
    syy = _box(tab, r0, r1, u0, u1, 9)
    sxy = _box(tab, r0, r1, u0, u1, 10)
    ox = sx - xp * bw
    oy = sy - yp * bw
    oxd = sxd - xp * sd
    oyd = syd - yp * sd
    oxx = sxx - 2.0 * xp * sx + xp * xp * bw
    oyy = syy - 2.0 * yp * sy + yp * yp * bw
    oxy = sxy - xp * sy - yp * sx + xp * yp * bw
    se = sd - gu * ox - gv * oy
    see = sdd - 2.0 * (gu * oxd + gv * oyd) + gu * gu * oxx + 2.0 * gu * gv * oxy + gv * gv * oyy
    mean = se / bw
    chi = see - se * mean
    extra = vgu * (oxx - ox * ox / bw) + vgv * (oyy - oy * oy / bw)
    return bw, bn, mean, chi, extra


#: The squared disagreement (in sigma^2 of its difference) of the plane's two sides from which a
#: dropped plane counts as a step (5 sigma): there the grown window's bias is the lateral term's
#: step part's, not :func:`_window_bias2`'s.
_STEP_KINK2 = np.float32(25.0)


@njit(cache=True, inline="always", error_model="numpy")
def _wrap_pi(x):  # pragma: no cover - compiled
    """A float32 phase difference wrapped to [-pi, pi), as the passes' inner loops write it inline."""
    two_pi = np.float32(2.0 * np.pi)
    return x - two_pi * np.floor((x + np.float32(np.pi)) * np.float32(1.0 / (2.0 * np.pi)))


@njit(cache=True, inline="always", error_model="numpy")
def _plane_slope_of(fa, fb, fc, wa, wb, wc, base, kink2):  # pragma: no cover - compiled
    """:func:`_plane_slope` from the three estimates and their weights (the sides inside the
    image): its definition, branch-free (SIMD over a row in :func:`_row_planes`)."""
    zero = np.float32(0.0)
    ok = (wa > 0) & (wc > 0)
    va = np.float32(1.0) / wa
    vb = np.float32(1.0) / wb
    vc = np.float32(1.0) / wc
    fwd = _wrap_pi(fc - fb) / base
    bwd = _wrap_pi(fb - fa) / base
    dd = fwd - bwd
    s = va + np.float32(4.0) * vb + vc
    x = dd * dd * base * base
    kinked = x > kink2 * s
    step = x > _STEP_KINK2 * s
    g = np.float32(0.5) * (fwd + bwd)
    vg = (va + vc) / (np.float32(4.0) * base * base)
    keep = ok & ~kinked & (g * g > np.float32(4.0) * vg)
    return (g if keep else zero), (vg if keep else zero), ok & kinked & step


@njit(cache=True, inline="always", error_model="numpy")
def _second_difference_of(fa, fb, fc, wa, wb, wc, base):  # pragma: no cover - compiled
    """:func:`_second_difference` from the three estimates and their weights (the sides inside
    the image): its definition, branch-free."""
    zero = np.float32(0.0)
    ok = (wa > 0) & (wc > 0)
    fwd = _wrap_pi(fc - fb)
    bwd = _wrap_pi(fb - fa)
    b4 = base * base * base * base
    hh = (fwd - bwd) / (base * base)
    var = (np.float32(1.0) / wa + np.float32(4.0) / wb + np.float32(1.0) / wc) / b4
    return (hh if ok else zero), (var if ok else zero)


@njit(cache=True, inline="always", error_model="numpy")
def _curvature_of(h1, v1, h2, v2):  # pragma: no cover - compiled
    """:func:`_curvature_probe`'s choice between its two second differences ``(h1, v1)`` over
    ``max_radius`` and ``(h2, v2)`` over twice that (a variance of 0: not available), branch-free."""
    zero = np.float32(0.0)
    agree = (h2 - h1) * (h2 - h1) <= np.float32(9.0) * (v1 + v2)
    far = v2 > 0
    near = v1 > 0
    hh = (h2 if agree else zero) if far else h1
    vv = (v2 if agree else zero) if far else v1
    return (hh if near else zero), (vv if near else zero)


@njit(cache=True, inline="always", error_model="numpy")
def _cross_difference_of(fpp, fpm, fmp, fmm, wpp, wpm, wmp, wmm, base):  # pragma: no cover - compiled
    """:func:`_cross_difference` from the four diagonal estimates and their weights (inside the
    image): its definition, branch-free."""
    zero = np.float32(0.0)
    ok = (wpp > 0) & (wpm > 0) & (wmp > 0) & (wmm > 0)
    x = _wrap_pi(fpp - fpm)
    y = _wrap_pi(fmp - fmm)
    b2 = np.float32(4.0) * base * base
    one = np.float32(1.0)
    return ((x - y) / b2 if ok else zero), ((one / wpp + one / wpm + one / wmp + one / wmm) / (b2 * b2) if ok else zero)


@njit(cache=True, inline="always", error_model="numpy")
def _plane_slope(fl, wl, a, b, c, base, kink2):  # pragma: no cover - compiled
    """The local phase slope (rad/px) through a pixel along one axis, and its variance, from the
    first-pass estimates ``fl`` (the map flattened, C order) at flat indices ``a`` (``-base`` px), ``b`` (the pixel) and ``c``
    (``+base`` px), their variances ``1 / wl``: the central difference ``(first_c - first_a) /
    (2 base)``, variance ``(1 / wfirst_a + 1 / wfirst_c) / (4 base^2)``, where the two one-sided
    differences agree within ``sqrt(kink2)`` standard deviations of their difference (the
    filter's ``plane_kink_sigma``, 3 by default) and the slope exceeds 2 of
    its own; else 0 (a step, an edge or a kink between the sides, a slope lost in the noise, a side
    outside the image or not valid: the pixel's level). Differences wrapped to [-pi, pi). The third
    value is True where the plane was dropped for sides that disagree by 5 sigma or more (a step
    between them: the grown window's bias is then the lateral term's step part's, not
    :func:`_window_bias2`'s)."""
    if a < 0 or c < 0:
        return np.float32(0.0), np.float32(0.0), False
    return _plane_slope_of(fl[a], fl[b], fl[c], wl[a], wl[b], wl[c], base, kink2)


@njit(cache=True, inline="always", error_model="numpy")
def _second_difference(fl, wl, a, b, c, base):  # pragma: no cover - compiled
    """The phase's second derivative (rad/px^2) at a pixel along one direction from the first-pass
    estimates ``fl`` at flat indices ``a``, ``b`` (the pixel) and ``c``, ``base`` px apart:
    ``(wrap(first_c - first_b) - wrap(first_b - first_a)) / base^2``, and its variance
    ``(1 / wfirst_a + 4 / wfirst_b + 1 / wfirst_c) / base^4``; ``(0, 0)`` where a side is outside
    the image or not valid."""
    if a < 0 or c < 0:
        return np.float32(0.0), np.float32(0.0)
    return _second_difference_of(fl[a], fl[b], fl[c], wl[a], wl[b], wl[c], base)


@njit(cache=True, inline="always", error_model="numpy")
def _cross_difference(fl, wl, pp, pm, mp, mm, base):  # pragma: no cover - compiled
    """The phase's mixed second derivative (rad/px^2) at a pixel from the first-pass estimates at the
    flat indices of its four diagonal neighbours ``base`` px away (``pp`` = (+u, +v), ``pm`` = (+u,
    -v), ...): ``(wrap(f_pp - f_pm) - wrap(f_mp - f_mm)) / (4 base^2)``, and its variance; ``(0, 0)``
    where one is outside the image or not valid."""
    if pp < 0 or pm < 0 or mp < 0 or mm < 0:
        return np.float32(0.0), np.float32(0.0)
    return _cross_difference_of(fl[pp], fl[pm], fl[mp], fl[mm], wl[pp], wl[pm], wl[mp], wl[mm], base)


@njit(cache=True, inline="always", error_model="numpy")
def _curvature_probe(fl, wl, i0, x, n, mr, stride):  # pragma: no cover - compiled
    """The surface's second derivative along one axis at flat index ``i0`` (coordinate ``x`` of
    ``n`` along the axis, ``stride`` its flat stride, ``mr`` = ``max_radius``): the second
    difference over ``2 max_radius`` px either side, where it agrees with the one over ``max_radius``
    px within 3 standard deviations of their difference (else a step or an edge lies between the
    two probes: 0), over ``max_radius`` px where the far probes are outside the image; its
    variance."""
    step = mr * stride
    b1 = np.float32(mr)
    h1, v1 = _second_difference(fl, wl, i0 - step if x >= mr else -1, i0, i0 + step if x + mr < n else -1, b1)
    h2, v2 = _second_difference(fl, wl, i0 - 2 * step if x >= 2 * mr else -1, i0,
                                i0 + 2 * step if x + 2 * mr < n else -1, np.float32(2 * mr))
    return _curvature_of(h1, v1, h2, v2)


@njit(cache=True, inline="always", error_model="numpy")
def _cross_probe(fl, wl, i0, u, v, w, h, mr):  # pragma: no cover - compiled
    """The surface's mixed second derivative at flat index ``i0`` (pixel ``u, v``) from its diagonal
    neighbours ``2 max_radius`` px away where they are inside the image, else ``max_radius``
    (:func:`_cross_difference`); ``(0, 0)`` near the border."""
    zero = np.float32(0.0)
    for b in (2 * mr, mr):
        if u >= b and u + b < w and v >= b and v + b < h:
            return _cross_difference(fl, wl, i0 + b * w + b, i0 - b * w + b, i0 + b * w - b, i0 - b * w - b,
                                     np.float32(b))
    return zero, zero


@njit(cache=True, inline="always", error_model="numpy")
def _shrunk(x, v):  # pragma: no cover - compiled
    """An estimate ``x`` of variance ``v`` shrunk towards 0 by its own noise, ``x max(1 - v / x^2,
    0)`` (James-Stein's positive part): a curvature lost in the noise adds nothing, a clear one
    nearly all of itself."""
    x = np.float64(x)
    x2 = x * x
    r = x * (1.0 - np.float64(v) / x2)
    return r if x2 > v else 0.0  # branch-free (SIMD in _row_planes)


@njit(cache=True, inline="always", error_model="numpy")
def _slope_unknown(fl, wl, i0, x, n, bu, stride):  # pragma: no cover - compiled
    """Whether nothing says the surface is flat along one axis at flat index ``i0`` (coordinate
    ``x`` of ``n`` along the axis, ``stride`` its flat stride) where the local plane lacks a probe
    (:func:`_plane_slope`'s estimates ``bu`` px either side, one of them outside the image or not
    valid): both probes missing, or the one there differs from the pixel's first-pass estimate
    by a significant slope, ``g^2 > 4 var(g)`` (the plane's own significance test, one-sided: ``g``
    the wrapped difference over ``bu``, ``var(g) = (1 / w_probe + 1 / w_pixel) / bu^2``). False
    where both probes are there (the plane's own tests decide)."""
    step = bu * stride
    a = i0 - step if x >= bu else -1
    c = i0 + step if x + bu < n else -1
    oka = a >= 0 and wl[a] > 0
    okc = c >= 0 and wl[c] > 0
    if oka and okc:
        return False
    if not oka and not okc:
        return True
    j = c if okc else a
    two_pi = 2.0 * np.pi
    d = np.float64(fl[j]) - np.float64(fl[i0])
    d = d - two_pi * np.floor((d + np.pi) / two_pi)
    g = d / bu
    vg = (1.0 / np.float64(wl[j]) + 1.0 / np.float64(wl[i0])) / (bu * bu)
    return g * g > 4.0 * vg


@njit(cache=True, inline="always", error_model="numpy")
def _window_bias2(m, sw, sr, hu2, huv, hv2, unknown=False):  # pragma: no cover - compiled
    """The squared bias (rad^2) of a grown window's weighted mean at its pixel: the accepted
    neighbours' values ``r`` (less the plane, if any) modelled as ``r0 + d . o + q(o)``, ``q(o) =
    o^T H o / 2`` with ``H`` the surface's curvature (second derivatives of the first-pass map,
    :func:`_curvature_probe`, :func:`_cross_probe`, each shrunk by its own noise, :func:`_shrunk`)
    and ``d`` fitted by weighted least squares to ``r - q``; the mean is the model averaged over
    the window, so it errs from the pixel's ``r0`` by ``d . c + mean(q)`` (``c`` the weights'
    centroid): a lopsided window on a slope the plane does not follow (next to a shadow, where the
    plane was dropped) by the first part, every grown window on a curved surface by the second,
    symmetric or not. Returned as ``(d . c + mean(q))^2 - var(d . c)`` (the fitted slope's noise,
    inverse-variance weights, removed: a slope the noise could make adds nothing on average; 0 if
    negative or the offsets are degenerate). With ``unknown`` (the plane lacked a probe and
    nothing says the surface is flat there, :func:`_slope_unknown`) there is no such null: the
    estimate's posterior mean square under a flat prior, ``(d . c + mean(q))^2 + var(d . c)``. ``m``: the
    sums ``w du, w dv, w du^2, w dv^2, w du dv, w (r - q) du, w (r - q) dv``; ``sw = sum w``,
    ``sr = sum w r``; ``hu2, huv, hv2``: ``H_uu / 2``, ``H_uv``, ``H_vv / 2`` (rad / px^2)."""
    cu = m[0] / sw
    cv = m[1] / sw
    suu = m[2] / sw
    svv = m[3] / sw
    suv = m[4] / sw
    muu = suu - cu * cu
    mvv = svv - cv * cv
    muv = suv - cu * cv
    qb = hu2 * suu + huv * suv + hv2 * svv  # mean(q)
    rb = sr / sw - qb
    ru = m[5] / sw - rb * cu
    rv = m[6] / sw - rb * cv
    det = muu * mvv - muv * muv
    if not det > 1e-6:
        return np.float32(0.0)
    gu = (mvv * ru - muv * rv) / det
    gv = (muu * rv - muv * ru) / det
    b = gu * cu + gv * cv + qb
    vb = (cu * cu * mvv - 2.0 * cu * cv * muv + cv * cv * muu) / (det * sw)
    if unknown:
        return np.float32(b * b + vb)
    return np.float32(max(b * b - vb, 0.0))


@njit(cache=True, nogil=True, error_model="numpy")
def _row_planes(fl, wl, v, w, mr, kink2, bias, gu, vgu, ku, gv, vgv, kv, phc):  # pragma: no cover - compiled
    """Row ``v``'s local planes (:func:`_plane_slope` along u and v: ``gu, vgu, ku``, ``gv, vgv,
    kv``) and, with ``bias``, the curvature terms (:func:`_curvature_probe`, :func:`_cross_probe`,
    :func:`_shrunk`: ``phc``) of the pixels ``u`` in ``[2 mr, w - 2 mr)`` of a row ``2 mr`` px
    or more inside the image, where every probe lies inside it: the per-pixel functions'
    branch-free definitions (:func:`_plane_slope_of`, :func:`_second_difference_of`,
    :func:`_curvature_of`, :func:`_cross_difference_of`) on a whole row (SIMD; unsigned indices,
    so no negative-index wrap-around); the same bits."""
    bf = np.float32(mr)
    b2f = np.float32(2 * mr)
    m1 = np.uint64(mr)
    m2 = np.uint64(2 * mr)
    s1 = np.uint64(mr * w)
    s2 = np.uint64(2 * mr * w)
    i = np.uint64(v * w)
    for k in range(w - 4 * mr):
        u = np.uint64(2 * mr) + np.uint64(k)
        c = i + u
        fb = fl[c]
        wb = wl[c]
        gu[u], vgu[u], ku[u] = _plane_slope_of(fl[c - m1], fb, fl[c + m1], wl[c - m1], wb, wl[c + m1], bf, kink2)
        gv[u], vgv[u], kv[u] = _plane_slope_of(fl[c - s1], fb, fl[c + s1], wl[c - s1], wb, wl[c + s1], bf, kink2)
    if not bias:
        return
    p0, p1, p2 = phc[0], phc[1], phc[2]
    for k in range(w - 4 * mr):
        u = np.uint64(2 * mr) + np.uint64(k)
        c = i + u
        fb = fl[c]
        wb = wl[c]
        h1, v1 = _second_difference_of(fl[c - m1], fb, fl[c + m1], wl[c - m1], wb, wl[c + m1], bf)
        h2, v2 = _second_difference_of(fl[c - m2], fb, fl[c + m2], wl[c - m2], wb, wl[c + m2], b2f)
        huu, vuu = _curvature_of(h1, v1, h2, v2)
        h1, v1 = _second_difference_of(fl[c - s1], fb, fl[c + s1], wl[c - s1], wb, wl[c + s1], bf)
        h2, v2 = _second_difference_of(fl[c - s2], fb, fl[c + s2], wl[c - s2], wb, wl[c + s2], b2f)
        hvv, vvv = _curvature_of(h1, v1, h2, v2)
        pp = c + s2 + m2
        pm = c - s2 + m2
        mp = c + s2 - m2
        mm = c - s2 - m2
        huv, vuv = _cross_difference_of(fl[pp], fl[pm], fl[mp], fl[mm], wl[pp], wl[pm], wl[mp], wl[mm], b2f)
        p0[u] = np.float32(0.5 * _shrunk(huu, vuu))
        p1[u] = np.float32(_shrunk(huv, vuv))
        p2[u] = np.float32(0.5 * _shrunk(hvv, vvv))


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def _adaptive_pass(d, s2, inv, first, wfirst, radius, max_radius, k2, target_w, reject_w, out, wout,  # pragma: no cover
                   rad, full, chi_z, s2min, carry, c, cfirst, cout, boxed, kink2, b2o, posterior):
    """Second pass of :func:`denoise_weighted` for the pixels whose first-pass variance
    ``1 / wfirst`` exceeds ``1 / target_w``: the window grows ring by ring (Chebyshev radius
    ``radius + 1 .. max_radius``) until the accepted weights reach ``target_w``. Neighbours are
    tested against the local plane through the pixel's first-pass estimate ``m``: ``o_j`` the
    neighbour's offset, ``g`` the local phase slope from the first-pass map (:func:`_plane_slope`,
    estimates ``max_radius`` px either side; 0 where it is not significant or the sides disagree
    by more than ``sqrt(kink2)`` sigma)
    and ``p_j = g . o_j`` the plane's rise to the neighbour, it is accepted when
    ``p_j^2 <= k2 (s_j^2 + 1 / wfirst)`` (the ring follows the ramp's iso-phase band as far as the
    level test would reach on average, but decided by the smooth plane, not by the noisy values)
    and ``(d_j - m - p_j)^2 <= k2 (s_j^2 + 1 / wfirst + var(p_j))`` (a step, an outlier); its
    phase enters the mean as ``d_j - p_j``, the value the plane carries back to the pixel. A noisy
    pixel is judged by its better estimate, so a step stays a step. On a ramp whose pixels carry
    different sigma (a textured surface) a test against the level alone lets the accepted set move
    with the first-pass estimate's noise, and a mean of the raw values follows the texture's
    weights along the slope (a variance ``1 / sum w`` does not hold, and an error shared by the
    frames); the plane removes both to first order. Where ``g = 0`` the test and the mean are the
    level's, bit for bit. Pixels whose weights stay below ``reject_w`` become NaN (no filter can
    save them). ``wout`` receives each pixel's final sum of accepted weights (0 where not
    valid). Float32, fixed visiting order: the result depends only on the inputs. With ``full``,
    ``rad`` receives each pixel's final window half side (``radius`` where the first pass stands),
    for :func:`window_sums`.

    The pixels of a row that need the pass go through it together, one window offset at a time
    across all of them (SIMD over the pixels), each leaving the list once its weights reach the
    target; each pixel still adds its neighbours in the same order (ring, then row ``dv``, then
    ``du``), so the sums are those of a pixel-by-pixel loop, bit for bit.

    With ``chi_z > 0`` a pixel first tries whole boxes (half side ``radius .. max_radius``, clipped
    to the image) in O(1) each, about the same local plane: from summed-area tables of ``w``,
    ``w d``, ``w d^2``, the valid pixels and their moments in ``x``, ``y`` (:func:`_table_row`,
    built a ring of ``2 max_radius + 2`` rows at a time per block of rows, ``x`` centred on the
    image, ``y`` counted from the block's first table row), the box's plane-corrected weighted mean
    ``sum w (d_j - p_j) / sum w`` and its scatter about it (:func:`_plane_box`). A box is taken,
    with every valid pixel of it and its weight sum, when (1) the plane's largest rise across it
    stays within the ring pass's band for every pixel, ``max p_j^2 <= k2 (s2min + 1 / wfirst)``
    with ``s2min`` the smallest ``s_j^2`` within ``max_radius`` of the pixel (so that the ring pass
    would not leave any pixel out for being off the iso-phase band), (2) its scatter about
    the plane is within ``chi_z`` standard deviations of its ``n - 1`` expectation (plus the slope
    variances' share): a box across a step, an outlier, a kink or the wrap at +-pi fails it by far,
    and (3) its mean agrees with the pixel's first-pass estimate within ``k`` combined sigma; at
    the first box that reaches ``target_w`` (or the last) it stops. A box that fails any test sends
    the pixel through the ring pass above. Where the ring pass would accept every pixel of the box,
    both give the same mean and weight sum to float rounding. ``boxed`` (when of the phase's shape)
    receives 1 where a box was taken, else the test that sent the pixel to the rings: 2 the band,
    3 the scatter, 4 the mean (0: no box tried). Rows run in parallel (``prange``, blocks of 32 rows):
    each pixel's result depends only on the inputs, not on the threads.

    With ``carry``, ``cout`` receives each pixel's weighted mean of ``c`` over the neighbours its
    final window accepted, ``sum w c / sum w``: ``cfirst`` (the first pass's, from
    :func:`_denoise_kernel_carry`) where the first pass stands, the ring pass's own sums where it
    grew, the box's (a layer ``w c`` of the tables) where a box was taken. The phase,
    ``wout`` and ``rad`` are the same bits with or without it.

    With ``b2o`` of the phase's shape, it receives each grown pixel's squared bias
    (:func:`_window_bias2`, rad^2) from the moments of the neighbours its rings accepted, their
    values less the surface's curvature at the pixel (from the first-pass map), summed
    in a loop of their own after each window offset (in the pass's inner loops they cost the
    carried path its vectorisation); NaN where the first pass stands, where a box was taken and where
    the plane was dropped at a kink of 5 sigma or more (a step: the lateral term's step part holds
    that window's mixing; counted twice, the gauge blocks' edge zones are over-covered). Where the
    plane lacked a probe along an axis and nothing says the surface is flat there (both probes
    missing, or the one valid probe's one-sided slope significant: :func:`_slope_unknown`) the
    term is the estimate's posterior mean square, ``b^2 + var(b)``, not ``b^2 - var(b)``: no
    plane test stood for a slope the noise alone could make (with ``posterior``; without it
    ``b^2 - var(b)`` there too).
    The phase and the other outputs are the same bits with or without it."""
    h, w = d.shape
    boxes = chi_z > 0
    mark = boxed.shape[0] == h and boxed.shape[1] == w
    big = max_radius
    nring = 2 * big + 2 if boxes else 1
    ntab = 12 if carry else 11
    block = 32
    xc = np.float64(w // 2)
    fl = first.ravel()  # the first-pass map and its weights flattened, for the local planes
    wl = wfirst.ravel()
    for blk in prange((h + block - 1) // block):
        vb0 = blk * block
        t0 = max(vb0 - big, 0)  # table row i: the sums over image rows t0 .. t0 + i - 1
        tab = np.empty((nring, w + 1 if boxes else 1, ntab))  # a ring of table rows (only its built rows are read)
        tab[0] = 0.0
        built = 0
        for v in range(vb0, min(vb0 + block, h)):
            _adaptive_row(d, s2, inv, first, wfirst, radius, max_radius, k2, target_w, reject_w, out, wout, rad,
                          full, chi_z, s2min, carry, c, cfirst, cout, boxed, mark, boxes, v, tab, nring, t0,
                          built, xc, fl, wl, kink2, b2o, posterior)
            if boxes:
                built = min(v + big + 1, h) - t0


@njit(cache=True, nogil=True, error_model="numpy")
def _adaptive_row(d, s2, inv, first, wfirst, radius, max_radius, k2, target_w, reject_w, out, wout,  # pragma: no cover
                  rad, full, chi_z, s2min, carry, c, cfirst, cout, boxed, mark, boxes, v, tab, nring, t0, built, xc,
                  fl, wl, kink2, b2o, posterior):
    """One row of :func:`_adaptive_pass` (its tables' ring built up to the rows the row's boxes reach)."""
    h, w = d.shape
    nan = np.float32(np.nan)
    two_pi = np.float32(2.0 * np.pi)
    inv_two_pi = np.float32(1.0 / (2.0 * np.pi))
    pi = np.float32(np.pi)
    zero = np.float32(0.0)
    if boxes:
        top = min(v + max_radius + 1, h) - t0
        while built < top:
            i = built + 1
            _table_row(d, inv, c, carry, tab, (i - 1) % nring, i % nring, t0 + i - 1, np.float64(i - 1), xc)
            built = i
    pu = np.empty(w, np.int64)  # the row's pixels that need the pass, and their running state
    pm = np.empty(w, np.float32)
    psf = np.empty(w, np.float32)
    pgu = np.empty(w, np.float32)  # the local plane: phase slope along u and v (rad/px), variances
    pgv = np.empty(w, np.float32)
    pvu = np.empty(w, np.float32)
    pvv = np.empty(w, np.float32)
    pdc = np.empty(w, np.float32)
    pacc = np.empty(w, np.float32)
    pw = np.empty(w, np.float32)
    xg = np.empty(w, np.float32)  # scratch: the gathered neighbours
    ig = np.empty(w, np.float32)
    sg = np.empty(w, np.float32)
    cg = np.empty(w, np.float32)  # the gathered carried values (``carry``)
    pcc = np.empty(w, np.float32)
    bias = b2o.shape[0] == h and b2o.shape[1] == w  # the grown window's own slope times its centroid
    mom = np.empty((7, w), np.float32)  # sum w du, w dv, w du^2, w dv^2, w du dv, w r' du, w r' dv
    phc = np.empty((3, w), np.float32)  # the surface's curvature from the first-pass map (H_uu / 2, H_uv, H_vv / 2)
    wk = np.empty(w, np.float32)  # scratch: each pixel's accepted weight and residual at this offset
    rk = np.empty(w, np.float32)
    pk = np.empty(w, np.bool_)  # the plane dropped at a kink (a step): its window's bias is the lateral term's
    pun = np.empty(w, np.bool_)  # the plane lacked a probe where nothing says the surface is flat (_slope_unknown)
    mr = max_radius
    # the row's planes and curvatures in one branch-free pass where every probe is inside the image
    # and enough of the row grows to pay for it; the other pixels call the per-pixel functions
    lo, hi = 2 * mr, w - 2 * mr
    rowwise = 2 * mr <= v < h - 2 * mr and lo < hi and max_radius > radius
    if rowwise:
        ngrow = 0
        for u in range(w):
            ngrow += (inv[v, u] > 0) & (wfirst[v, u] < target_w)
        rowwise = 4 * ngrow >= w
    if rowwise:
        rpl = np.empty((4, w), np.float32)  # gu, vgu, gv, vgv
        rkk = np.empty((2, w), np.bool_)  # ku, kv
        rph = np.empty((3, w), np.float32)
        _row_planes(fl, wl, v, w, mr, kink2, bias, rpl[0], rpl[1], rkk[0], rpl[2], rpl[3], rkk[1], rph)
    n = 0
    if full:
        for u in range(w):
            rad[v, u] = radius
    if carry:
        for u in range(w):
            cout[v, u] = cfirst[v, u]
    if bias:
        for u in range(w):
            b2o[v, u] = nan
    for u in range(w):
        out[v, u] = first[v, u]
        wout[v, u] = wfirst[v, u]
        if mark:
            boxed[v, u] = 0.0
        if inv[v, u] <= 0:
            continue
        ws = wfirst[v, u]
        if ws >= target_w or max_radius <= radius:
            out[v, u] = first[v, u] if ws >= reject_w else nan
            continue
        bu = max_radius  # the plane from first-pass estimates as far out as the largest ring
        inner = rowwise and lo <= u < hi
        if inner:
            gu, vgu, ku, gv, vgv, kv = rpl[0, u], rpl[1, u], rkk[0, u], rpl[2, u], rpl[3, u], rkk[1, u]
        else:
            gu, vgu, ku = _plane_slope(fl, wl, v * w + u - bu if u >= bu else -1, v * w + u,
                                       v * w + u + bu if u + bu < w else -1, np.float32(bu), kink2)
            gv, vgv, kv = _plane_slope(fl, wl, (v - bu) * w + u if v >= bu else -1, v * w + u,
                                       (v + bu) * w + u if v + bu < h else -1, np.float32(bu), kink2)
        if boxes:
            m = np.float64(first[v, u])
            sf = 1.0 / np.float64(ws)
            dc = d[v, u]
            gu8 = np.float64(gu)
            gv8 = np.float64(gv)
            xp = np.float64(u) - xc
            yp = np.float64(v - t0)
            # the smallest box whose weight reaches the target (or the largest): where the ring
            # pass accepts every pixel, the ring at which it stops
            r = radius
            while True:
                v0 = max(v - r, 0)
                v1 = min(v + r + 1, h)
                u0 = max(u - r, 0)
                u1 = min(u + r + 1, w)
                r0 = (v0 - t0) % nring
                r1 = (v1 - t0) % nring
                if r == max_radius or _box(tab, r0, r1, u0, u1, 0) >= target_w:
                    break
                r += 1
            # the plane's largest rise across the box, against the ring pass's band
            ax0 = gu8 * (u0 - u)
            ax1 = gu8 * (u1 - 1 - u)
            ay0 = gv8 * (v0 - v)
            ay1 = gv8 * (v1 - 1 - v)
            rise = max(max(ax0, ax1) + max(ay0, ay1), -(min(ax0, ax1) + min(ay0, ay1)))
            done = False
            if rise * rise > k2 * (sf + np.float64(s2min[v, u])):
                if mark:
                    boxed[v, u] = 2.0  # the ring pass takes a band of the box only: it decides
            else:
                bw, bn, mean, chi, extra = _plane_box(tab, r0, r1, u0, u1, xp, yp,
                                                      gu8, gv8, np.float64(vgu), np.float64(vgv))
                dof = bn - 1.0
                dm = mean - m
                dm = dm - 2.0 * np.pi * np.floor((dm + np.pi) / (2.0 * np.pi))
                scattered = chi > dof + extra + chi_z * np.sqrt(2.0 * max(dof, 1.0))
                if scattered or dm * dm > k2 * (sf + 1.0 / bw):
                    if mark:
                        boxed[v, u] = 3.0 if scattered else 4.0  # not one plane: the ring pass decides
                else:
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
                        if carry:
                            cout[v, u] = np.float32(_box(tab, r0, r1, u0, u1, 11) / bw)
                        if mark:
                            boxed[v, u] = 1.0
                    out[v, u] = val if wb >= reject_w else nan
                    wout[v, u] = wb
                    done = True
            if done:
                continue
        pu[n] = u
        pk[n] = ku or kv
        pun[n] = False
        if bias and posterior:
            pun[n] = _slope_unknown(fl, wl, v * w + u, u, w, bu, 1) or _slope_unknown(fl, wl, v * w + u, v, h, bu, w)
        if bias and inner:
            phc[0, n] = rph[0, u]
            phc[1, n] = rph[1, u]
            phc[2, n] = rph[2, u]
        elif bias:
            huu, vuu = _curvature_probe(fl, wl, v * w + u, u, w, bu, 1)
            hvv, vvv = _curvature_probe(fl, wl, v * w + u, v, h, bu, w)
            huv, vuv = _cross_probe(fl, wl, v * w + u, u, v, w, h, bu)
            phc[0, n] = np.float32(0.5 * _shrunk(huu, vuu))
            phc[1, n] = np.float32(_shrunk(huv, vuv))
            phc[2, n] = np.float32(0.5 * _shrunk(hvv, vvv))
        pgu[n] = gu
        pvu[n] = vgu
        pgv[n] = gv
        pvv[n] = vgv
        n += 1
    if n == 0:
        return
    for q in range(n):
        u = pu[q]
        pm[q] = first[v, u]
        psf[q] = np.float32(1.0) / wfirst[v, u]
        pdc[q] = d[v, u]
        pacc[q] = 0.0
        pw[q] = 0.0
        pcc[q] = 0.0
        if bias:
            for k in range(7):
                mom[k, q] = 0.0
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
                # is not vectorised on gathered loads), 0 inverse variance outside the image;
                # branch-free (SIMD over the pixels); a neighbour not taken adds +0 to sums
                # that start at +0 and so are never -0: bit for bit as skipping it. The
                # carried map in loops of its own (the same operations on the rest)
                fdu = np.float32(du)
                fdv = np.float32(dv)
                du2 = fdu * fdu
                dv2 = fdv * fdv
                if carry:
                    for q in range(n):
                        uu = pu[q] + du
                        inb = (uu >= 0) & (uu < w)
                        uc = min(max(uu, 0), w - 1)
                        xg[q] = d[vv, uc]
                        ig[q] = inv[vv, uc] if inb else zero
                        sg[q] = s2[vv, uc]
                        cg[q] = c[vv, uc]
                    for q in range(n):
                        x = xg[q]
                        iv = ig[q]
                        pl = pgu[q] * fdu + pgv[q] * fdv
                        dm = x - pm[q] - pl
                        dm = dm - two_pi * np.floor((dm + pi) * inv_two_pi)
                        lim = k2 * (sg[q] + psf[q])
                        keep = (iv > 0) & (pl * pl <= lim) & (dm * dm <= lim + k2 * (pvu[q] * du2 + pvv[q] * dv2))
                        diff = x - pdc[q]
                        diff = diff - two_pi * np.floor((diff + pi) * inv_two_pi)
                        pacc[q] += iv * (diff - pl) if keep else zero
                        pw[q] += iv if keep else zero
                        wk[q] = iv if keep else zero
                        rk[q] = diff - pl
                        pcc[q] += iv * cg[q] if keep else zero
                else:
                    for q in range(n):
                        uu = pu[q] + du
                        inb = (uu >= 0) & (uu < w)
                        uc = min(max(uu, 0), w - 1)
                        xg[q] = d[vv, uc]
                        ig[q] = inv[vv, uc] if inb else zero
                        sg[q] = s2[vv, uc]
                    for q in range(n):
                        x = xg[q]
                        iv = ig[q]
                        pl = pgu[q] * fdu + pgv[q] * fdv
                        dm = x - pm[q] - pl
                        dm = dm - two_pi * np.floor((dm + pi) * inv_two_pi)
                        lim = k2 * (sg[q] + psf[q])
                        keep = (iv > 0) & (pl * pl <= lim) & (dm * dm <= lim + k2 * (pvu[q] * du2 + pvv[q] * dv2))
                        diff = x - pdc[q]
                        diff = diff - two_pi * np.floor((diff + pi) * inv_two_pi)
                        pacc[q] += iv * (diff - pl) if keep else zero
                        pw[q] += iv if keep else zero
                        wk[q] = iv if keep else zero
                        rk[q] = diff - pl
                if bias:  # the moments of the grown window's accepted neighbours (their own loop: SIMD)
                    m0, m1, m2, m3, m4, m5, m6 = mom[0], mom[1], mom[2], mom[3], mom[4], mom[5], mom[6]
                    h0, h1, h2 = phc[0], phc[1], phc[2]
                    duv = fdu * fdv
                    for q in range(n):  # the value less the curvature (a loop of its own: SIMD)
                        rk[q] -= h0[q] * du2 + h1[q] * duv + h2[q] * dv2
                    for q in range(n):
                        wq = wk[q]
                        rq = wq * rk[q]
                        m0[q] += wq * fdu
                        m1[q] += wq * fdv
                        m2[q] += wq * du2
                        m3[q] += wq * dv2
                        m4[q] += wq * duv
                        m5[q] += rq * fdu
                        m6[q] += rq * fdv
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
                        if carry:
                            cout[v, u] = pcc[q] / wsum
                        if bias and not pk[q]:
                            b2o[v, u] = _window_bias2(mom[:, q], np.float64(wsum), np.float64(pacc[q]),
                                                      np.float64(phc[0, q]), np.float64(phc[1, q]),
                                                      np.float64(phc[2, q]), pun[q])
                    out[v, u] = val if wsum >= reject_w else nan
                    wout[v, u] = wsum
                    continue
                if keep_n < q:  # (before the first pixel that stopped, each state is already in place)
                    pu[keep_n] = pu[q]
                    pm[keep_n] = pm[q]
                    psf[keep_n] = psf[q]
                    pvv[keep_n] = pvv[q]
                    pvu[keep_n] = pvu[q]
                    pgv[keep_n] = pgv[q]
                    pgu[keep_n] = pgu[q]
                    pdc[keep_n] = pdc[q]
                    pacc[keep_n] = pacc[q]
                    pw[keep_n] = pw[q]
                    pcc[keep_n] = pcc[q]
                    pk[keep_n] = pk[q]
                    pun[keep_n] = pun[q]
                    if bias:
                        for k in range(7):
                            mom[k, keep_n] = mom[k, q]
                        for k in range(3):
                            phc[k, keep_n] = phc[k, q]
                keep_n += 1
            n = keep_n
            if n == 0:
                break
