"""Step heights' uncertainty: the budget of each step of a specimen over the frames
(:func:`step_budget`) and the ISO 14253-1 decision with the expanded uncertainty
(:func:`conformance`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from huefringe.uncertainty.calibration import GROUPS, PixelBudget, TERMS, _INTERP_LUT
from huefringe.uncertainty.frame import lateral_term

__all__ = ["coating_term", "conformance", "step_budget"]


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
