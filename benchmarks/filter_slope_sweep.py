"""Study: the phase filter's spread against its predicted ``1 / sqrt(sum w)`` over the phase's slope per pixel in units of its noise.

Usage: ./run python benchmarks/filter_slope_sweep.py [--draws 40] [--sigma 0.03] [--step]

Synthetic phase maps (80 x 60 px): a ramp of ``s`` rad per pixel along the rows (and the same
along the diagonal) plus Gaussian noise of one sigma, through ``phase.denoise_phase`` at the
workflow's defaults (radius 2, k = 3; the fixed 5 x 5 window alone, and with the sigma-adaptive
support), ``--draws`` noise draws. Per slope ``s / sigma``: the filtered phase's spread over the
draws against its predicted ``1 / sqrt(sum w)`` (median over the inner pixels), and the rms of the
draws' mean error against the same prediction. The variance ``1 / sum w`` holds for decisions
that do not depend on the noise; where a neighbour's expected difference from the pixel is near
the filter's k-sigma test, whether it is taken depends on the draw and a taken one carries its
offset into the mean. The last column is a sketch of the alternative, not the library's filter:
the 5 x 5 window's neighbours carried back along a plane fitted to the window by least squares
(unweighted, through the pixel) and tested by their residual, ``r^2 <= k^2 (2 sigma^2 +
var(plane))`` (NumPy, one sigma, no step handling); with it the median window's weight sum
(``sum w sigma^2``, the neighbours taken) is printed too. ``--step`` adds ramps with a step
inside the window (per column near it, the two sketches beside the library's filters: the plane
fitted to the whole window, and refitted to the neighbours its residual test keeps). The column
before the last prices the fixed window's own decisions (:func:`decision_sketch`, NumPy, the
library's decisions reproduced to 1e-5 rad): its spread over ``sqrt(1 / sum w + V)``, ``V`` a
delta-method variance of the decisions (its own draws). About a minute on one core (two with
``--step``).
"""

from __future__ import annotations

import argparse
import inspect
from collections.abc import Callable

import numpy as np

from huefringe.phase import adaptive_kwargs, denoise_phase
from huefringe.settings import defaults


def plane_sketch(d: np.ndarray, sigma: float, radius: int, k: float,
                 iterations: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The filtered phase and weight sum of the sketch: each neighbour of the window less the
    least-squares plane through the pixel (``g_u = sum o_u r / sum o_u^2``, the same along ``v``,
    over the window's neighbours inside the map), kept where its residual passes the k-sigma test.
    With ``iterations`` > 0 the plane is fitted to the neighbours the level test keeps
    (``r^2 <= 2 k^2 sigma^2``, the filter's own-side test) and refitted that many times to those
    its residual test keeps (a plane a step inside the window pulls less)."""
    h, w = d.shape
    offs = [(dv, du) for dv in range(-radius, radius + 1) for du in range(-radius, radius + 1)]
    pad = np.pad(d.astype(np.float64), radius, constant_values=np.nan)
    nb = np.stack([pad[radius + dv:radius + dv + h, radius + du:radius + du + w] for dv, du in offs])
    ou = np.array([du for _, du in offs], np.float64)[:, None, None]
    ov = np.array([dv for dv, _ in offs], np.float64)[:, None, None]
    diff = nb - d[None]
    ok = np.isfinite(diff)
    r0 = np.where(ok, diff, 0.0)
    fit = ok & (diff**2 <= 2.0 * k * k * sigma**2) if iterations > 0 else ok
    for _ in range(max(iterations, 1)):
        su, sv = (ou**2 * fit).sum(0), (ov**2 * fit).sum(0)
        su, sv = np.where(su > 0, su, np.inf), np.where(sv > 0, sv, np.inf)
        plane = (r0 * ou * fit).sum(0) / su * ou + (r0 * ov * fit).sum(0) / sv * ov
        var_plane = sigma**2 * (ou**2 / su + ov**2 / sv)
        res = diff - plane
        fit = ok & (res**2 <= k * k * (2.0 * sigma**2 + var_plane))
    wk = fit / sigma**2
    return d + (np.where(fit, res, 0.0) * wk).sum(0) / wk.sum(0), wk.sum(0)


def decision_sketch(d: np.ndarray, sigma: float, radius: int, k: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The library's fixed window (``denoise_phase`` without growth) in NumPy, with a delta-method
    variance of its accept decisions: each neighbour ``j`` is kept where ``e_j = diff_j - off``
    (``off``, ``add``: the pixel's own-side estimate and its variance, ``phase._own_side``) lies
    within ``+-a_j``, ``a_j^2 = k^2 (add + s_j^2)``; read as soft decisions ``p_j = Phi((a_j - e_j) /
    s_e) - Phi((-a_j - e_j) / s_e)`` (``s_e^2 = add + s_j^2``, at the observed ``e_j``), the mean's
    variance beyond ``1 / sum w`` is ``V = [sum_j p_j (1 - p_j) (w_j r_j)^2 + (sum_j w_j r_j p'_j)^2
    add + sum_j (w_j r_j p'_j)^2 s_j^2] / (sum w)^2`` (``r_j`` the neighbour's offset from the
    mean, ``p'_j`` the derivative of ``p_j`` in ``e_j``): a flip's own variance, the shared
    reference's, each neighbour's truncation. Returns the filtered phase, ``sum w`` and ``V``."""
    from scipy.stats import norm

    from huefringe.phase._passes import _own_side

    h, w = d.shape
    s2 = np.full((h, w), sigma**2, np.float32)
    inv = (1.0 / s2).astype(np.float32)
    off, add = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    _own_side(d.astype(np.float32), s2, inv, radius, np.float32(k * k), off, add)
    off, add = off.astype(np.float64), add.astype(np.float64)
    dp = np.pad(d.astype(np.float64), radius, constant_values=np.nan)
    items, wsum, acc = [], np.zeros((h, w)), np.zeros((h, w))
    for dv in range(-radius, radius + 1):
        for du in range(-radius, radius + 1):
            dj = dp[radius + dv:radius + dv + h, radius + du:radius + du + w]
            inside = np.isfinite(dj)
            diff = np.where(inside, dj - d, 0.0)
            wj = np.where(inside, 1.0 / sigma**2, 0.0)
            if dv == 0 and du == 0:  # the pixel itself, always
                keep, p, dpde = np.ones((h, w), bool), np.ones((h, w)), np.zeros((h, w))
            else:
                e = diff - off
                se = np.sqrt(add + sigma**2)
                a = k * se
                keep = inside & (e * e <= a * a)
                p = np.where(inside, norm.cdf((a - e) / se) - norm.cdf((-a - e) / se), 0.0)
                dpde = np.where(inside, (norm.pdf((-a - e) / se) - norm.pdf((a - e) / se)) / se, 0.0)
            wsum += np.where(keep, wj, 0.0)
            acc += np.where(keep, wj * diff, 0.0)
            items.append((diff, wj, p, dpde))
    mean = acc / wsum
    flip, shared, trunc = np.zeros((h, w)), np.zeros((h, w)), np.zeros((h, w))
    for diff, wj, p, dpde in items:
        r = diff - mean
        flip += p * (1.0 - p) * (wj * r) ** 2
        shared += wj * r * dpde
        trunc += (wj * r * dpde) ** 2 * sigma**2
    return d + mean, wsum, (flip + shared**2 * add + trunc) / wsum**2


def step_table(draws: int, sigma: float, radius: int, k: float, filters: dict) -> None:
    """``--step``: a ramp with a step at column 40 (80 x 40 px), per column near it the filtered
    spread over its prediction and the draws' mean error in sigma, for the library's filters and
    the two sketches."""
    rng = np.random.default_rng(3)
    h, w = 40, 80
    uu = np.mgrid[:h, :w][1].astype(np.float64)
    sig = np.full((h, w), sigma, np.float32)
    ok = np.ones((h, w), bool)
    cols = (36, 37, 38, 39, 40, 41, 42, 43, 60)
    runs = {**{n: (lambda d, kw=kw: _library(d, sig, ok, radius, kw)) for n, kw in filters.items()},
            "local plane (sketch)": lambda d: plane_sketch(d, sigma, radius, k),
            "local plane, refitted (sketch)": lambda d: plane_sketch(d, sigma, radius, k, iterations=3)}
    for slope, step in ((0.0, 20.0), (3.0, 20.0), (0.5, 6.0)):
        truth = slope * sigma * uu + np.where(uu >= 40, step * sigma, 0.0)
        print(f"\nslope {slope:g} sigma per px, a step of {step:g} sigma at column 40: spread / predicted "
              "(mean error in sigma)\n")
        print("| filter | " + " | ".join(f"column {c}" for c in cols) + " |")
        print("| --- |" + " ---: |" * len(cols))
        for name, run in runs.items():
            o, sw = _draws(run, truth, sigma, draws, rng)
            o, sw = o[:, 8:-8], sw[:, 8:-8]
            pred = np.sqrt(np.mean(1.0 / sw, axis=0))
            ratio = o.std(axis=0, ddof=1) / pred
            bias = (o.mean(axis=0) - truth[8:-8]) / sigma
            print(f"| {name} | " + " | ".join(f"{np.median(ratio[:, c]):.2f} ({np.median(bias[:, c]):+.2f})"
                                             for c in cols) + " |", flush=True)


def _decision_cell(truth: np.ndarray, sigma: float, draws: int, radius: int, k: float, rng: np.random.Generator,
                   inner: tuple) -> str:
    """The fixed window's spread over ``sqrt(1 / sum w + V)`` (:func:`decision_sketch`, its own draws)."""
    outs, var = [], []
    for _ in range(draws):
        d = (truth + sigma * rng.standard_normal(truth.shape)).astype(np.float32)
        o, sw, v = decision_sketch(d, sigma, radius, k)
        if not outs:  # the library's decisions, reproduced
            lib = denoise_phase(d, np.full(d.shape, sigma, np.float32), np.ones(d.shape, bool), radius=radius, k=k)
            assert np.nanmax(np.abs(lib - o)) < 1e-5, np.nanmax(np.abs(lib - o))
        outs.append(o[inner])
        var.append(1.0 / sw[inner] + v[inner])
    spread = np.asarray(outs).std(axis=0, ddof=1)
    return f"{np.median(spread / np.sqrt(np.mean(np.asarray(var), axis=0))):.2f}"


def _library(d: np.ndarray, sig: np.ndarray, ok: np.ndarray, radius: int, kw: dict) -> tuple[np.ndarray, np.ndarray]:
    """The library's filter with its weight sum."""
    sw = np.zeros(d.shape, np.float32)
    return denoise_phase(d, sig, ok, radius=radius, weight_sum=sw, **kw), sw


def _draws(run: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], truth: np.ndarray, sigma: float, draws: int,
           rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``run`` on ``draws`` noisy copies of ``truth`` (Gaussian, ``sigma``): the filtered phases and
    weight sums, stacked (float64)."""
    outs, sums = [], []
    for _ in range(draws):
        o1, sw = run((truth + sigma * rng.standard_normal(truth.shape)).astype(np.float32))
        outs.append(o1)
        sums.append(sw)
    return np.asarray(outs, np.float64), np.asarray(sums, np.float64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--sigma", type=float, default=0.03)
    ap.add_argument("--step", action="store_true", help="also a ramp with a step: per column near it")
    a = ap.parse_args()
    m = defaults()["measurement"]
    radius = int(m["denoise_radius"])
    k = float(inspect.signature(denoise_phase).parameters["k"].default)  # the library's test
    filters = {"fixed 5 x 5": {}, "defaults (sigma-adaptive)": adaptive_kwargs(m["denoise_adaptive"])}
    rng = np.random.default_rng(7)
    h, w = 60, 80
    vv, uu = np.mgrid[:h, :w].astype(np.float64)
    sig = np.full((h, w), a.sigma, np.float32)
    ok = np.ones((h, w), bool)
    inner = (slice(8, -8), slice(8, -8))
    runs = {**{n: (lambda d, kw=kw: _library(d, sig, ok, radius, kw)) for n, kw in filters.items()},
            "sketch": lambda d: plane_sketch(d, a.sigma, radius, k)}
    rng_dec = np.random.default_rng(8)  # the decision term's own draws (the other columns' stay as they were)
    print(f"sigma {a.sigma} rad, {a.draws} draws; spread / predicted (mean error rms / predicted)\n")
    print("| slope / sigma per px | direction | " + " | ".join(filters) + " | fixed 5 x 5 with its decision term "
          "(sketch) | local plane (sketch) |")
    print("| ---: | --- |" + " ---: |" * (len(filters) + 2))
    for ratio in (0.25, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 12.0):
        for dname, ramp in (("row", uu), ("diagonal", (uu + vv) / np.sqrt(2.0))):
            truth = ratio * a.sigma * ramp
            cells = []
            for name, run in runs.items():
                o, sw = _draws(run, truth, a.sigma, a.draws, rng)
                o, sw = o[(slice(None), *inner)], sw[(slice(None), *inner)]
                pred = np.sqrt(np.mean(1.0 / sw, axis=0))
                spread = o.std(axis=0, ddof=1)
                bias = o.mean(axis=0) - truth[inner]
                cell = f"{np.median(spread / pred):.2f} ({np.sqrt(np.mean(bias**2)) / np.median(pred):.2f})"
                if name == "sketch":
                    cell += f", {np.median(np.mean(sw, axis=0)) * a.sigma**2:.0f} taken"
                    cells.append(_decision_cell(truth, a.sigma, a.draws, radius, k, rng_dec, inner))
                cells.append(cell)
            print(f"| {ratio:g} | {dname} | " + " | ".join(cells) + " |", flush=True)
    if a.step:
        step_table(a.draws, a.sigma, radius, k, filters)


if __name__ == "__main__":
    main()
