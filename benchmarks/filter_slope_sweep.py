"""Study: the phase filter's spread against its predicted ``1 / sqrt(sum w)`` over the phase's slope per pixel in units of its noise.

Usage: ./run python benchmarks/filter_slope_sweep.py [--draws 40] [--sigma 0.03]

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
(``sum w sigma^2``, the neighbours taken) is printed too. About a minute on one core.
"""

from __future__ import annotations

import argparse
import inspect

import numpy as np

from huefringe.phase import adaptive_kwargs, denoise_phase
from huefringe.settings import defaults


def plane_sketch(d: np.ndarray, sigma: float, radius: int, k: float) -> tuple[np.ndarray, np.ndarray]:
    """The filtered phase and weight sum of the sketch: each neighbour of the window less the
    least-squares plane through the pixel (``g_u = sum o_u r / sum o_u^2``, the same along ``v``,
    over the window's neighbours inside the map), kept where its residual passes the k-sigma test."""
    h, w = d.shape
    offs = [(dv, du) for dv in range(-radius, radius + 1) for du in range(-radius, radius + 1)]
    pad = np.pad(d.astype(np.float64), radius, constant_values=np.nan)
    nb = np.stack([pad[radius + dv:radius + dv + h, radius + du:radius + du + w] for dv, du in offs])
    ou = np.array([du for _, du in offs], np.float64)[:, None, None]
    ov = np.array([dv for dv, _ in offs], np.float64)[:, None, None]
    diff = nb - d[None]
    ok = np.isfinite(diff)
    r0 = np.where(ok, diff, 0.0)
    su, sv = (ou**2 * ok).sum(0), (ov**2 * ok).sum(0)
    plane = (r0 * ou).sum(0) / su * ou + (r0 * ov).sum(0) / sv * ov
    var_plane = sigma**2 * (ou**2 / su + ov**2 / sv)
    res = diff - plane
    keep = ok & (res**2 <= k * k * (2.0 * sigma**2 + var_plane))
    wk = keep / sigma**2
    return d + (np.where(keep, res, 0.0) * wk).sum(0) / wk.sum(0), wk.sum(0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--sigma", type=float, default=0.03)
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
    print(f"sigma {a.sigma} rad, {a.draws} draws; spread / predicted (mean error rms / predicted)\n")
    print("| slope / sigma per px | direction | " + " | ".join(filters) + " | local plane (sketch) |")
    print("| ---: | --- |" + " ---: |" * (len(filters) + 1))
    for ratio in (0.25, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 12.0):
        for dname, ramp in (("row", uu), ("diagonal", (uu + vv) / np.sqrt(2.0))):
            truth = ratio * a.sigma * ramp
            cells = []
            for name in (*filters, "sketch"):
                outs, sums = [], []
                for _ in range(a.draws):
                    d = (truth + a.sigma * rng.standard_normal((h, w))).astype(np.float32)
                    if name == "sketch":
                        o1, sw = plane_sketch(d, a.sigma, radius, k)
                    else:
                        sw = np.zeros((h, w), np.float32)
                        o1 = denoise_phase(d, sig, ok, radius=radius, weight_sum=sw, **filters[name])
                    outs.append(o1)
                    sums.append(sw)
                o = np.asarray(outs, np.float64)[(slice(None), *inner)]
                sw = np.asarray(sums, np.float64)[(slice(None), *inner)]
                pred = np.sqrt(np.mean(1.0 / sw, axis=0))
                spread = o.std(axis=0, ddof=1)
                bias = o.mean(axis=0) - truth[inner]
                cell = f"{np.median(spread / pred):.2f} ({np.sqrt(np.mean(bias**2)) / np.median(pred):.2f})"
                if name == "sketch":
                    cell += f", {np.median(np.mean(sw, axis=0)) * a.sigma**2:.0f} taken"
                cells.append(cell)
            print(f"| {ratio:g} | {dname} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
