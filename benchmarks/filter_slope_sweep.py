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
offset into the mean. Under a minute on one core.
"""

from __future__ import annotations

import argparse

import numpy as np

from huefringe.phase import adaptive_kwargs, denoise_phase
from huefringe.settings import defaults


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--sigma", type=float, default=0.03)
    a = ap.parse_args()
    m = defaults()["measurement"]
    radius = int(m["denoise_radius"])
    filters = {"fixed 5 x 5": {}, "defaults (sigma-adaptive)": adaptive_kwargs(m["denoise_adaptive"])}
    rng = np.random.default_rng(7)
    h, w = 60, 80
    vv, uu = np.mgrid[:h, :w].astype(np.float64)
    sig = np.full((h, w), a.sigma, np.float32)
    ok = np.ones((h, w), bool)
    inner = (slice(8, -8), slice(8, -8))
    print(f"sigma {a.sigma} rad, {a.draws} draws; spread / predicted (mean error rms / predicted)\n")
    print("| slope / sigma per px | direction | " + " | ".join(filters) + " |")
    print("| ---: | --- |" + " ---: |" * len(filters))
    for ratio in (0.25, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 12.0):
        for dname, ramp in (("row", uu), ("diagonal", (uu + vv) / np.sqrt(2.0))):
            truth = ratio * a.sigma * ramp
            cells = []
            for kw in filters.values():
                outs, sums = [], []
                for _ in range(a.draws):
                    sw = np.zeros((h, w), np.float32)
                    d = (truth + a.sigma * rng.standard_normal((h, w))).astype(np.float32)
                    outs.append(denoise_phase(d, sig, ok, radius=radius, weight_sum=sw, **kw))
                    sums.append(sw)
                o = np.asarray(outs, np.float64)[(slice(None), *inner)]
                sw = np.asarray(sums, np.float64)[(slice(None), *inner)]
                pred = np.sqrt(np.mean(1.0 / sw, axis=0))
                spread = o.std(axis=0, ddof=1)
                bias = o.mean(axis=0) - truth[inner]
                cells.append(f"{np.median(spread / pred):.2f} ({np.sqrt(np.mean(bias**2)) / np.median(pred):.2f})")
            print(f"| {ratio:g} | {dname} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
