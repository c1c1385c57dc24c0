"""Phase-error lookup table: the decoded phase's systematic error as a function of the phase.

Why
---
The per-pixel hue tables are built from *uniform* hue bands, so they see projector gamma,
surface colour, crosstalk and ambient light, but not what projector defocus and camera lens
blur do to the trapezoid's ramps (paper eq. 3) once gamma has curved them: blurring a curved
ramp shifts it, differently on either side of each corner of the trapezoid. The decoded code
phase then carries an error ``e(phi)`` with period about 2 pi / 3 (it jumps where the brightest
channel changes). White balance removes each channel's reflectivity (a per-pixel scale), and
blur and gamma act per channel, so after white balance and the per-pixel table that error is, to
first order, a function of the decoded phase alone, the same for every surface colour
(crosstalk and ambient light break this mildly).

How (the classic relative: Zhang and Yau's phase-error lookup table)
--------------------------------------------------------------------
The calibration planes at known heights show every pixel the trapezoid at several phases, and
a plane's true phase is smooth (linear in X under the pinhole model, plus smooth lens
distortion). Each plane's decoded phase is unwrapped and fitted with a low-order 2-D polynomial
(:func:`huefringe.height.fit_poly2d`); the residuals of all planes, binned by the decoded phase
(median per bin, periodic smoothing), give ``e(phi)``. The fit absorbs a little of the error,
so the planes are corrected with the table and fitted again (``iterations``), the table
accumulating the binned residuals. Nothing but the session's planes is used (never ground
truth). Frames and planes alike are then corrected as ``phi_c = phi - e(phi)``, by linear
interpolation between bin centres (:func:`correct`; the fused kernel calls the same compiled
:func:`correct_one`, so both give the same bits).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from huefringe.height import fit_poly2d, unwrap_smooth
from huefringe.io import atomic_path, write_figure_png, write_json

TWO_PI = 2.0 * np.pi


@njit(cache=True, inline="always", error_model="numpy")
def _table_value(phi, error):  # pragma: no cover - compiled
    """``e(phi)`` for one float64 phase in [0, 2 pi): linear between the bin centres
    ``(i + 1/2) 2 pi / n`` of ``error`` (periodic); :func:`table_at` is its NumPy form."""
    n = error.size
    x = phi * (n / (2.0 * np.pi)) - 0.5
    i0 = int(np.floor(x))
    f = x - i0
    return (1.0 - f) * error[i0 % n] + f * error[(i0 + 1) % n]


@njit(cache=True, inline="always", error_model="numpy")
def correct_one(phi, error):  # pragma: no cover - compiled
    """``phi - e(phi)`` for one float32 phase in [0, 2 pi), wrapped to [0, 2 pi), float32.

    ``e`` is linear between the bin centres ``(i + 1/2) 2 pi / n`` of ``error`` (periodic).
    A non-finite ``phi`` is returned unchanged."""
    if not (phi - phi == 0):
        return phi
    two_pi = 2.0 * np.pi
    c = np.float64(phi) - _table_value(np.float64(phi), error)
    c = c + two_pi if c < 0.0 else (c - two_pi if c >= two_pi else c)
    r = np.float32(c)
    return np.float32(0.0) if r >= np.float32(two_pi) else r


@njit(cache=True, nogil=True)
def _correct(phi, error, out):  # pragma: no cover - compiled
    flat_in = phi.ravel()
    flat_out = out.ravel()
    for i in range(flat_in.size):
        flat_out[i] = correct_one(flat_in[i], error)


def correct(phase: NDArray[np.floating], error: NDArray[np.float64] | None) -> NDArray[np.float32]:
    """Corrected code phase ``phi - e(phi)`` (float32, [0, 2 pi), NaN stays NaN).

    Parameters
    ----------
    phase : ndarray
        Decoded code phase in [0, 2 pi), NaN where undefined; cast to float32 first (the
        chain's phases are float32).
    error : ndarray of float64, (n,), or None
        The table ``e`` at the bin centres (:attr:`PhaseErrorLUT.error`); None returns the
        phase unchanged (as float32).
    """
    p = np.ascontiguousarray(phase, dtype=np.float32)
    if error is None:
        return p
    e = np.ascontiguousarray(error, dtype=np.float64)
    if e.ndim != 1 or e.size < 3:
        raise ValueError(f"the phase-error table must be 1-D with at least 3 bins, got shape {e.shape}")
    out = np.empty_like(p)
    _correct(p, e, out)
    return out


@dataclass
class PhaseErrorLUT:
    """The phase-error table and what was measured while estimating it."""

    error: NDArray[np.float64]
    """``e(phi)`` (rad) at the bin centres ``(i + 1/2) 2 pi / n``."""
    before: NDArray[np.float64]
    """Binned median residual of the planes against their smooth fits, before correction."""
    after: NDArray[np.float64]
    """The same after correction (what the table leaves)."""
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def centres(self) -> NDArray[np.float64]:
        n = self.error.size
        return (np.arange(n) + 0.5) * TWO_PI / n

    def save(self, npz: str) -> None:
        """``error``, ``before``, ``after`` and ``centres`` to an ``.npz`` (atomically)."""
        with atomic_path(npz) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, error=self.error, before=self.before, after=self.after, centres=self.centres)


#: Box (px) over which the fringe frequency's square is averaged, and the range of its ratio to
#: the reference plane's taken as a slope (:func:`frequency_ratio`; beyond it a step's blurred
#: pixels, left uncorrected).
FREQUENCY_BOX_PX = 9
FREQUENCY_RATIO_RANGE = (0.6, 1.6)


def reference_gradient(phi_ref: NDArray[np.floating]) -> NDArray[np.float64]:
    """The reference phase's change per pixel, ``(2, H, W)`` (along columns, along rows): central
    wrapped differences of its float32 values (as the chain holds it), one-sided at the border; 0
    where not finite."""
    p = np.asarray(phi_ref, np.float32).astype(np.float64)
    out = np.zeros((2, *p.shape))
    for k, axis in enumerate((1, 0)):
        if p.shape[axis] < 2:
            continue
        d = np.mod(np.diff(p, axis=axis) + np.pi, TWO_PI) - np.pi
        g = np.moveaxis(out[k], axis, 0)
        dd = np.moveaxis(d, axis, 0)
        g[1:-1] = 0.5 * (dd[1:] + dd[:-1])
        g[0], g[-1] = dd[0], dd[-1]
    return np.nan_to_num(out)


def frequency_inputs(cal: Any) -> NDArray[np.float64]:
    """What :func:`correct_frequency` needs of a plane calibration, once per session: ``(3, H, W)``,
    the reference phase's change per pixel (:func:`reference_gradient`, along columns and rows) and
    its square, the fringe frequency the phase-error table's correction is taken to hold (the
    reference plane's: docs/design.md, "Phase-error table")."""
    g = reference_gradient(np.asarray(cal.phi_ref, np.float32))
    return np.ascontiguousarray(np.stack([g[0], g[1], g[0] ** 2 + g[1] ** 2]))


@njit(cache=True, nogil=True, inline="always")
def _smaller_step(fwd, bwd, has_f, has_b):  # pragma: no cover - compiled
    """Of a pixel's forward and backward differences the one of smaller magnitude (the one there
    is where only one is; 0 where none)."""
    if has_f and has_b:
        return fwd if abs(fwd) < abs(bwd) else bwd
    if has_f:
        return fwd
    if has_b:
        return bwd
    return 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _slope_row(d, ok, grad, lo, hi, half, v, su, sv, sc, taken, scratch):  # pragma: no cover - compiled
    """Row ``v`` of :func:`_frequency_kernel`: each pixel's slope where its own ratio is a slope's
    (``taken``), then their running sums along the row over the box (``su``, ``sv``) and the count
    (``sc``); ``scratch`` (3, W) holds the pixels' values while their sums are formed in place."""
    h, w = d.shape
    for u in range(w):
        su[u] = 0.0
        sv[u] = 0.0
        sc[u] = 0.0
        taken[u] = False
        if not ok[v, u]:
            continue
        x = np.float64(d[v, u])
        hf = u + 1 < w and ok[v, u + 1]
        hb = u > 0 and ok[v, u - 1]
        du = _smaller_step(np.float64(d[v, u + 1]) - x if hf else 0.0,
                           x - np.float64(d[v, u - 1]) if hb else 0.0, hf, hb)
        hf = v + 1 < h and ok[v + 1, u]
        hb = v > 0 and ok[v - 1, u]
        dv = _smaller_step(np.float64(d[v + 1, u]) - x if hf else 0.0,
                           x - np.float64(d[v - 1, u]) if hb else 0.0, hf, hb)
        g02 = grad[2, v, u]
        if g02 > 0.0:
            gu, gv = grad[0, v, u] + du, grad[1, v, u] + dv
            q = (gu * gu + gv * gv) / g02
            if lo <= q <= hi:
                su[u] = du
                sv[u] = dv
                sc[u] = 1.0
                taken[u] = True
    a = 0.0  # the running sums along the row, in place (the pixels' values read from the scratch)
    b = 0.0
    c = 0.0
    for u in range(min(half, w)):
        a += su[u]
        b += sv[u]
        c += sc[u]
    ru, rv, rc = scratch[0], scratch[1], scratch[2]
    ru[:] = su
    rv[:] = sv
    rc[:] = sc
    for u in range(w):
        if u + half < w:
            a += ru[u + half]
            b += rv[u + half]
            c += rc[u + half]
        if u - half - 1 >= 0:
            a -= ru[u - half - 1]
            b -= rv[u - half - 1]
            c -= rc[u - half - 1]
        su[u] = a
        sv[u] = b
        sc[u] = c


@njit(cache=True, nogil=True, error_model="numpy")
def _frequency_kernel(d, ok, grad, phi_ref, error, box, lo, hi, ratio, out):  # pragma: no cover - compiled
    """:func:`frequency_ratio` into ``ratio`` (float64, when of the phase's shape) and, with
    ``error`` non-empty, :func:`correct_frequency` into ``out`` (float32). Row by row: each pixel's
    slope and whether its ratio is a slope's, their running sums along the row over the box
    (:func:`_slope_row`, a ring of the ``box + 1`` rows the column sums need), then those running
    down the columns."""
    h, w = d.shape
    half = box // 2
    nr = box + 1
    want_ratio = ratio.shape[0] == h and ratio.shape[1] == w
    su = np.zeros((nr, w))  # the ring: per row, the box's sums along the row of the slopes taken, their count
    sv = np.zeros((nr, w))
    sc = np.zeros((nr, w))
    taken = np.zeros((nr, w), np.bool_)  # the pixel's own ratio is a slope's
    scratch = np.empty((3, w))
    n = error.size
    two_pi = 2.0 * np.pi
    au = np.zeros(w)  # the box's sums: running along the columns
    av = np.zeros(w)
    cnt = np.zeros(w)
    built = 0  # the rows whose slopes have entered the column sums
    for v in range(h):
        while built < min(v + half + 1, h):  # the box's rows down to v + half, in order
            r = built % nr
            _slope_row(d, ok, grad, lo, hi, half, built, su[r], sv[r], sc[r], taken[r], scratch)
            for u in range(w):
                au[u] += su[r, u]
                av[u] += sv[r, u]
                cnt[u] += sc[r, u]
            built += 1
        if v - half - 1 >= 0:
            r = (v - half - 1) % nr
            for u in range(w):
                au[u] -= su[r, u]
                av[u] -= sv[r, u]
                cnt[u] -= sc[r, u]
        tv = taken[v % nr]
        for u in range(w):
            q = 1.0
            if tv[u]:  # the box's mean slope, squared: its noise averaged before it is squared
                gu = grad[0, v, u] + au[u] / cnt[u]
                gv = grad[1, v, u] + av[u] / cnt[u]
                q = (gu * gu + gv * gv) / grad[2, v, u]
            if want_ratio:
                ratio[v, u] = q
            if n > 0:
                if q != 1.0:
                    x = np.float64(d[v, u])
                    e = _table_value((np.float64(phi_ref[v, u]) + x) % two_pi, error)
                    out[v, u] = np.float32(x - (q - 1.0) * e)
                else:
                    out[v, u] = d[v, u]


def _frequency(d32: NDArray[np.float32], ok: NDArray[np.bool_], grad: NDArray[np.float64], phi_ref: Any,
               error: NDArray[np.float64], box: int, limits: tuple[float, float]) -> tuple[NDArray[np.float64],
                                                                                         NDArray[np.float32]]:
    ratio = np.empty(d32.shape if not error.size else (0, 0))  # the ratio map only where it is asked for
    out = np.empty(d32.shape if error.size else (0, 0), np.float32)
    pr = np.ascontiguousarray(phi_ref, np.float32) if error.size else np.zeros((1, 1), np.float32)
    _frequency_kernel(d32, ok, np.ascontiguousarray(grad, np.float64), pr, error, int(box), float(limits[0]),
                      float(limits[1]), ratio, out)
    return ratio, out


def frequency_ratio(dphi: NDArray[np.floating], valid: NDArray[np.bool_], inputs: NDArray[np.float64], *,
                    box: int = FREQUENCY_BOX_PX,
                    limits: tuple[float, float] = FREQUENCY_RATIO_RANGE) -> NDArray[np.float64]:
    """The local fringe frequency squared over the reference plane's, per pixel.

    The code phase is ``phi_ref + dphi``; its gradient is the reference's (``inputs[:2]``,
    :func:`frequency_inputs`) plus the phase difference's, each component the smaller of the
    forward and backward differences between valid pixels (a step on one side leaves it alone). A
    pixel whose own ``|g|^2 / g_t^2`` (``g_t^2 = inputs[2]``, the reference's) lies outside
    ``limits`` is not on a slope (the blurred pixels of a step, whose differences on both sides
    cross it) and keeps 1; the others take ``|g_ref + s|^2 / g_t^2`` with ``s`` the mean slope of
    the phase difference over the pixels of their ``box`` x ``box`` window that are on one (the
    noise averaged before it is squared, where it would raise the ratio by its variance). 1 also
    where invalid or where ``g_t^2`` is 0. Compiled; float64 from the float32 phase difference.
    """
    d32 = np.ascontiguousarray(dphi, np.float32)
    ok = np.ascontiguousarray(np.asarray(valid, bool) & np.isfinite(d32))
    return _frequency(d32, ok, inputs, None, np.zeros(0), box, limits)[0]


def correct_frequency(dphi: NDArray[np.floating], valid: NDArray[np.bool_], phi_ref: NDArray[np.floating],
                      error: NDArray[np.float64] | None, inputs: NDArray[np.float64]) -> NDArray[np.float32]:
    """The phase difference with the phase-error table's correction scaled to the local fringe frequency.

    The table (:func:`correct`) takes out ``e(phi)``, as it holds at the reference plane's fringe
    frequency ``g_t``. Blur's phase error grows with the square of the fringe frequency in the
    image (the blur spans more phase), so where a slope changes the frequency to ``g`` the error is
    ``(g / g_t)^2 e(phi)``; this takes out the rest, ``((g / g_t)^2 - 1) e(phi)``
    (:func:`frequency_ratio` for ``(g / g_t)^2``, ``inputs`` from :func:`frequency_inputs`; ``phi =
    phi_ref + dphi``, ``phi_ref``'s float32 values as the chain holds them; ``e`` linear between
    bin centres as :func:`table_at`). Returns float32 (the chain's phase difference), ``dphi``
    unchanged where the ratio is 1 (invalid, outside the slopes' range) or without a table.
    """
    d32 = np.ascontiguousarray(dphi, np.float32)
    if error is None:
        return np.array(d32, copy=True)
    ok = np.ascontiguousarray(np.asarray(valid, bool) & np.isfinite(d32))
    e = np.ascontiguousarray(error, np.float64)
    if e.ndim != 1 or e.size < 3:
        raise ValueError(f"the phase-error table must be 1-D with at least 3 bins, got shape {e.shape}")
    return _frequency(d32, ok, inputs, phi_ref, e, FREQUENCY_BOX_PX, FREQUENCY_RATIO_RANGE)[1]


def _circular_smooth(values: NDArray[np.float64], sigma_bins: float) -> NDArray[np.float64]:
    if sigma_bins <= 0:
        return values
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(values, sigma_bins, mode="wrap")


def _fill_periodic(values: NDArray[np.float64]) -> NDArray[np.float64]:
    """Empty (NaN) bins linearly interpolated from their neighbours, periodically."""
    ok = np.isfinite(values)
    if ok.all() or not ok.any():
        return np.where(ok, values, 0.0)
    n = values.size
    idx = np.arange(n)
    xs = idx[ok]
    return np.interp(idx, np.concatenate([xs - n, xs, xs + n]), np.tile(values[ok], 3))


def binned_median(phase: NDArray[np.floating], residual: NDArray[np.floating], bins: int,
                  min_count: int = 10) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Median of ``residual`` in ``bins`` equal bins of ``phase`` over [0, 2 pi); NaN where a bin
    holds fewer than ``min_count`` samples. Returns the medians and the counts."""
    p = np.asarray(phase, np.float64).ravel()
    r = np.asarray(residual, np.float64).ravel()
    k = np.clip((np.mod(p, TWO_PI) * (bins / TWO_PI)).astype(np.int64), 0, bins - 1)
    order = np.argsort(k, kind="stable")
    ks, rs = k[order], r[order]
    counts = np.bincount(ks, minlength=bins)
    edges = np.concatenate([[0], np.cumsum(counts)])
    med = np.full(bins, np.nan)
    for i in range(bins):
        if counts[i] >= min_count:
            med[i] = np.median(rs[edges[i] : edges[i + 1]])
    return med, counts


def unwrap_planes(plane_phases: dict[float, NDArray[np.floating]], plane_valid: dict[float, NDArray[np.bool_]],
                  degree: int = 3, step: int = 2) -> dict[float, NDArray[np.float64]]:
    """Each plane's decoded phase unwrapped, NaN where invalid.

    A plane's phase is smooth: :func:`huefringe.height.unwrap_smooth` (rows, then a robust 2-D
    polynomial of degree ``degree`` and the wrapped difference to it). Done
    once: a correction ``e(phi)`` (small, continuous, periodic) changes the unwrapped phase by
    ``-e(phi)`` and never its 2 pi offsets, so :func:`plane_residuals` reuses these maps."""
    out = {}
    for z in sorted(plane_phases):
        phi = np.asarray(plane_phases[z], np.float64)
        out[z] = unwrap_smooth(phi, np.asarray(plane_valid[z], bool) & np.isfinite(phi), degree, step=step)
    return out


def table_at(phase: NDArray[np.floating], error: NDArray[np.float64]) -> NDArray[np.float64]:
    """``e(phi)``: the table linear between its bin centres (periodic), float64: the NumPy form of
    :func:`_table_value` (what :func:`correct_one` subtracts)."""
    n = error.size
    x = np.asarray(phase, np.float64) * (n / TWO_PI) - 0.5
    i0 = np.floor(x)
    f = x - i0
    i0 = np.nan_to_num(i0).astype(np.int64)
    return (1.0 - f) * error[i0 % n] + f * error[(i0 + 1) % n]


def plane_residuals(plane_phases: dict[float, NDArray[np.floating]], plane_valid: dict[float, NDArray[np.bool_]],
                    degree: int = 3, step: int = 2, *, error: NDArray[np.float64] | None = None,
                    unwrapped: dict[float, NDArray[np.float64]] | None = None,
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Decoded phase and the residual of the corrected phase against the plane's smooth 2-D fit.

    Each plane's phase is unwrapped (``unwrapped``, from :func:`unwrap_planes`, or here),
    corrected by ``error`` (``un - e(phi)``; none: uncorrected) and fitted with a robust 2-D
    polynomial of total degree ``degree`` (:func:`huefringe.height.fit_poly2d`, sampled every
    ``step`` pixels). Returns the decoded (uncorrected, wrapped) phases, the table's argument,
    and the residuals (rad) of the valid pixels, concatenated over the planes."""
    un_all = unwrapped if unwrapped is not None else unwrap_planes(plane_phases, plane_valid, degree, step)
    phis, res = [], []
    for z in sorted(plane_phases):
        phi = np.asarray(plane_phases[z], np.float64)
        valid = np.asarray(plane_valid[z], bool) & np.isfinite(phi)
        un = un_all[z] if error is None else un_all[z] - table_at(phi, error)
        fit = fit_poly2d(un, valid, degree, step=step)
        r = un - fit
        keep = valid & np.isfinite(r)
        r = r[keep]
        mad = 1.4826 * np.median(np.abs(r - np.median(r))) if r.size else 0.0
        inlier = np.abs(r) < max(8.0 * mad, 1e-6)  # unwrapping slips and shadow edges are not the error
        phis.append(phi[keep][inlier])
        res.append(r[inlier])
    return np.concatenate(phis), np.concatenate(res)


def estimate(plane_phases: dict[float, NDArray[np.floating]], plane_valid: dict[float, NDArray[np.bool_]], *,
             degree: int = 3, bins: int = 512, iterations: int = 3, smooth_bins: float = 1.5,
             min_count: int = 10, fit_step: int = 2,
             unwrapped: dict[float, NDArray[np.float64]] | None = None) -> PhaseErrorLUT:
    """Estimate the phase-error table ``e(phi)`` from the calibration planes (no ground truth).

    Parameters
    ----------
    plane_phases, plane_valid : dict
        Decoded code phase [0, 2 pi) and valid mask of each calibration plane, keyed by height
        (as :func:`huefringe.height.calibrate_planes` takes them).
    degree : int
        Degree of each plane's smooth 2-D fit (the plane calibration's ``plane_smooth_degree``).
    bins : int
        Bins over [0, 2 pi) (512: 0.012 rad each).
    iterations : int
        Fit, bin, correct rounds; each adds the binned residual left by the previous one.
    smooth_bins : float
        Standard deviation (bins) of the periodic Gaussian applied to each round's binned medians.
    fit_step : int
        Sampling step (pixels) of each plane's smooth fit.
    unwrapped : dict, optional
        The planes' unwrapped phases (:func:`unwrap_planes`), when the caller has them.

    Returns
    -------
    PhaseErrorLUT
        With ``stats``: rms of the binned error before/after, peak-to-peak of ``e``, the rms of
        the plane residuals before/after, the number of samples.
    """
    if bins < 8:
        raise ValueError(f"bins must be >= 8, got {bins}")
    error = np.zeros(bins)
    phases = {z: np.asarray(p, np.float32) for z, p in plane_phases.items()}
    if unwrapped is None:  # once: the corrections never change the 2 pi offsets
        unwrapped = unwrap_planes(phases, plane_valid, degree, fit_step)
    before = None
    history = []
    for _ in range(max(int(iterations), 1)):
        # residuals of the corrected planes, binned by the *decoded* phase (the table's argument)
        phi_d, r = plane_residuals(phases, plane_valid, degree, fit_step, error=error, unwrapped=unwrapped)
        med, counts = binned_median(phi_d, r, bins, min_count)
        if before is None:
            before = _fill_periodic(med)
            rms_before = float(np.sqrt(np.mean(r**2)))
        step = _circular_smooth(_fill_periodic(med), smooth_bins)
        history.append(float(np.sqrt(np.mean(step**2))))
        error = error + step
    phi_d, r = plane_residuals(phases, plane_valid, degree, fit_step, error=error, unwrapped=unwrapped)
    after, counts = binned_median(phi_d, r, bins, min_count)
    after = _fill_periodic(after)
    assert before is not None
    stats = {
        "bins": bins,
        "iterations": int(iterations),
        "degree": degree,
        "smooth_bins": smooth_bins,
        "samples": int(r.size),
        "planes": len(plane_phases),
        "binned_rms_before_rad": float(np.sqrt(np.mean(before**2))),
        "binned_rms_after_rad": float(np.sqrt(np.mean(after**2))),
        "error_peak_to_peak_rad": float(np.ptp(error)),
        "residual_rms_before_rad": rms_before,
        "residual_rms_after_rad": float(np.sqrt(np.mean(r**2))),
        "round_step_rms_rad": history,
    }
    return PhaseErrorLUT(error, before, after, stats)


def qa_figure(lut: PhaseErrorLUT, path: str, *, title: str = "") -> None:
    """Error against decoded phase on the planes, before and after the correction, and the table."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = lut.centres
    fig, ax = plt.subplots(figsize=(9.5, 4), dpi=110)
    ax.plot(c, 1e3 * lut.before, lw=1.0, color="tab:red", label=f"before (rms {1e3 * lut.stats['binned_rms_before_rad']:.1f} mrad)")
    ax.plot(c, 1e3 * lut.after, lw=1.0, color="tab:green", label=f"after (rms {1e3 * lut.stats['binned_rms_after_rad']:.1f} mrad)")
    ax.plot(c, 1e3 * lut.error, lw=0.8, ls="--", color="k", label="table e(phi)")
    for k in range(1, 6):
        ax.axvline(k * np.pi / 3, color="0.85", lw=0.6, zorder=0)
    ax.set_xlim(0, TWO_PI)
    ax.set_xlabel("decoded code phase (rad)")
    ax.set_ylabel("plane residual, median per bin (mrad)")
    ax.set_title(title or "phase-dependent error on the calibration planes")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)  # off the data
    fig.tight_layout()
    write_figure_png(fig, path)
    plt.close(fig)


def holdout_check(plane_phases: dict[float, NDArray[np.floating]], plane_valid: dict[float, NDArray[np.bool_]], *,
                  degree: int = 3, **kw: Any) -> dict[str, Any]:
    """Leave-one-plane-out test of the table: does it lower the error of a plane it did not see?

    For each plane, a table is learned from the other planes (:func:`estimate`, same settings but
    one round, which holds most of the table: later rounds add about a tenth, and fits sampled
    every 4 pixels) and the held-out plane's residual against its smooth fit is measured without and with it.
    Needs at least two planes (else ``{"planes": n}`` only). Returns the mean per-pixel residual
    rms and binned (systematic) rms of the held-out planes before/after, and ``helps``: the
    per-pixel rms after is below the rms before (the decision of ``enabled: auto``).
    """
    zs = sorted(plane_phases)
    if len(zs) < 2:
        return {"planes": len(zs)}
    rms_b, rms_a, bin_b, bin_a = [], [], [], []
    bins = int(kw["bins"])
    unwrapped = unwrap_planes(plane_phases, plane_valid, degree, 4)
    for z in zs:
        train = {k: plane_phases[k] for k in zs if k != z}
        lut = estimate(train, {k: plane_valid[k] for k in train}, degree=degree, **{**kw, "iterations": 1, "fit_step": 4},
                       unwrapped={k: unwrapped[k] for k in train})
        for err, rms, binned in ((None, rms_b, bin_b), (lut.error, rms_a, bin_a)):
            phi_d, r = plane_residuals({z: plane_phases[z]}, {z: plane_valid[z]}, degree, 4, error=err,
                                       unwrapped={z: unwrapped[z]})
            med, _ = binned_median(phi_d, r, bins)
            rms.append(float(np.sqrt(np.mean(r**2))))
            binned.append(float(np.sqrt(np.nanmean(med**2))))
    out = {"planes": len(zs),
           "holdout_residual_rms_before_rad": float(np.mean(rms_b)),
           "holdout_residual_rms_after_rad": float(np.mean(rms_a)),
           "holdout_binned_rms_before_rad": float(np.mean(bin_b)),
           "holdout_binned_rms_after_rad": float(np.mean(bin_a))}
    out["helps"] = bool(out["holdout_residual_rms_after_rad"] < out["holdout_residual_rms_before_rad"])
    return out


def from_calibration(plane_phases: dict[float, NDArray[np.floating]], plane_valid: dict[float, NDArray[np.bool_]],
                     calibration: dict[str, Any] | Any, *, phase_error: str | None = None,
                     figure: str | None = None, summary: str | None = None) -> PhaseErrorLUT | None:
    """The plane calibration's phase-error table as configured (``calibration.phase_error``).

    The table is always estimated and recorded (``phase_error`` .npz, ``summary`` .json,
    ``figure`` .png, each when given), so a run with the correction off still shows the error it
    leaves; it is returned (to be applied) when ``enabled`` is true, or, with ``enabled: auto``
    (the default), when the leave-one-plane-out test (:func:`holdout_check`) shows that a table
    learned from the other planes lowers a plane's residual. The decision and its figures are in
    the summary (``applied``, ``holdout``).
    """
    opts = calibration["phase_error"]
    degree = int(calibration["plane_smooth_degree"] or 3)  # null (raw plane pixels): the table still fits degree 3
    kw = {"bins": int(opts["bins"]), "iterations": int(opts["iterations"]), "smooth_bins": float(opts["smooth_bins"])}
    lut = estimate(plane_phases, plane_valid, degree=degree, **kw)
    mode = opts["enabled"]
    if mode not in (True, False, "auto"):
        raise ValueError(f"calibration.phase_error.enabled must be true, false or auto, got {mode!r}")
    check = holdout_check(plane_phases, plane_valid, degree=degree, **kw) if mode == "auto" else {}
    applied = bool(check.get("helps", True)) if mode == "auto" else bool(mode)
    lut.stats.update({"enabled": mode, "applied": applied, "holdout": check})
    if phase_error:
        lut.save(phase_error)
    if summary:
        write_json(summary, lut.stats)
    if figure:
        state = "applied" if applied else f"NOT applied (calibration.phase_error.enabled: {mode})"
        qa_figure(lut, figure, title=f"phase-dependent error on the calibration planes; table {state}")
    return lut if applied else None
