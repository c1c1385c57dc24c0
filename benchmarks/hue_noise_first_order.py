"""How far the first-order propagation of channel noise through the hexcone hue holds.

Usage: ./run python benchmarks/hue_noise_first_order.py [--colours 400] [--draws 4000]

``perframe.frame_hue_noise`` propagates each channel's variance through the hue's first
derivatives. Random colours (channels uniform in 0.05-1, chroma at least 0.02) with Gaussian
channel noise (sigma uniform in 0.002-0.08, the same in the three channels): the hue's spread
over the draws against the first-order figure, ``(pi / 3) sigma sqrt(C^2 + (mid - min)^2 +
(max - mid)^2) / C^2``, binned by the first-order figure. This sets
``perframe.OWN_TRUSTED_RAD``, below which the own figure is trusted under the table's pooled one
(docs/uncertainty.md, "The noise ratio"). Seed 1; a few seconds.
"""

from __future__ import annotations

import argparse

import numpy as np

from huefringe.colour import hue


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--colours", type=int, default=400)
    ap.add_argument("--draws", type=int, default=4000)
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    res = []
    for _ in range(args.colours):
        rgb = rng.uniform(0.05, 1.0, 3)
        c = rgb.max() - rgb.min()
        if c < 0.02:
            continue
        s = rng.uniform(0.002, 0.08)
        x = rgb[None, :] + s * rng.standard_normal((args.draws, 3))
        h = hue(x[None].astype(np.float32), "hexcone", min_saturation=0.0)[0].astype(np.float64)
        h0 = float(hue(rgb[None, None].astype(np.float32), "hexcone", min_saturation=0.0)[0, 0])
        d = np.angle(np.exp(1j * (h - h0)))
        d = d[np.isfinite(d)]
        mx, mn = rgb.max(), rgb.min()
        mid = rgb.sum() - mx - mn
        first = np.pi / 3 * s * np.sqrt(c**2 + (mid - mn) ** 2 + (mx - mid) ** 2) / c**2
        res.append((first, float(np.std(d))))
    r = np.array(res)
    print("| first-order hue noise (rad) | colours | spread / first-order: median | min | max |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for lo, hi in [(0, .01), (.01, .02), (.02, .03), (.03, .05), (.05, .08), (.08, .12), (.12, .2), (.2, .4), (.4, 1)]:
        m = (r[:, 0] >= lo) & (r[:, 0] < hi)
        if m.any():
            q = r[m, 1] / r[m, 0]
            print(f"| {lo:.2f}-{hi:.2f} | {int(m.sum())} | {np.median(q):.3f} | {q.min():.3f} | {q.max():.3f} |")


if __name__ == "__main__":
    main()
