"""The complementary Gray code against plain Gray codes on a defocused projector.

Usage: nice ./run python benchmarks/complementary_gray.py [--blur 3 4 5 6] [--repeats 5]

One axis of a 1024 px projector: a four-step phase block of period P = 16 px (origin at half a
period, as SLMaster's fringes) and one of three Gray codes, read without inverses and without
white and black frames against the mean of the phase frames (SLMaster's captures):

- ``plain``: 6 bits of P cells (SLMaster's code without its extra pattern; 10 frames);
- ``half``: 7 bits of P / 2 cells (as many frames as the complementary code; 11 frames);
- ``complementary``: 6 bits of P cells plus the half-period bit (11 frames).

The projector shows its images through a gamma-2.2 display and a Gaussian defocus of ``--blur``
projector pixels (so that the phase frames' mean, the bits' threshold, lies below the stripes'
half level and the thresholded stripes widen), 640 x 120 camera pixels sample them at a known
coordinate (ambient 5 %, albedo 0.8, 1 DN noise, 8 bits), and :func:`huefringe.codecs.decode_sequence`
decodes them with the default ``codecs`` thresholds. Printed per blur and code: the valid
fraction; pixels flagged ORDER (and how many lie within a quarter period of a cell edge); valid
pixels a period or more from the truth; the RMS error and RMS sigma of the others (projector px);
the largest |error| / sigma; the decode time per frame (median of ``--repeats``). The table is in
docs/capture.md ("Gray cells and the fringe period").
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from huefringe.codecs import DecodeOptions, GrayBlock, PhaseBlock, Reason, SequenceSpec, decode_sequence, equal_shifts, generate

P, W, H, N = 16.0, 1024, 64, 6


def spec(kind: str) -> SequenceSpec:
    gray = {"plain": GrayBlock("x", N, P, False), "half": GrayBlock("x", N + 1, P / 2, False),
            "complementary": GrayBlock("x", N, P, False, True)}[kind]
    shifts = tuple(float(v) for v in equal_shifts(4))
    return SequenceSpec((PhaseBlock("x", P, shifts, origin_px=P / 2), gray), W, H, projector_gamma=2.2)


def capture(sp: SequenceSpec, ux: np.ndarray, blur_px: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    mapx, mapy = ux.astype(np.float32), np.full(ux.shape, H / 2, np.float32)
    out = []
    for p in generate(sp).astype(np.float32) / 255.0:
        p = cv2.GaussianBlur(p**sp.projector_gamma, (0, 0), blur_px)
        s = cv2.remap(p, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        out.append(np.clip(np.rint(255.0 * (0.05 + 0.8 * s) + rng.normal(0.0, 1.0, ux.shape)), 0, 255).astype(np.uint8))
    return np.stack(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blur", type=float, nargs="+", default=[3.0, 4.0, 5.0, 6.0])
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    yy, xx = np.mgrid[0:120, 0:640].astype(np.float64)
    ux = 30.0 + xx * (W - 60.0) / 640.0 + 0.013 * yy
    edge = np.abs((ux + 0.5) / P - np.round((ux + 0.5) / P)) * P < P / 4
    opts = DecodeOptions.from_config()
    print(f"{ux.size} camera pixels, {edge.sum()} within P/4 of a cell edge")
    print("| blur (px) | code | frames | valid | ORDER (at edges) | valid, a period off | RMS error (px) | RMS sigma (px) | max abs(e)/sigma | decode (ms/frame) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for blur in a.blur:
        for kind in ("plain", "half", "complementary"):
            sp = spec(kind)
            cap = capture(sp, ux, blur, seed=3)
            ts = []
            for _ in range(a.repeats):
                t0 = time.perf_counter()
                d = decode_sequence(cap, sp, opts)["x"]
                ts.append(time.perf_counter() - t0)
            err = d.coord - ux
            wrong = d.valid & (np.abs(err) > P / 2)
            order = (d.reasons & Reason.ORDER) > 0
            ok = d.valid & ~wrong
            print(f"| {blur:g} | {kind} | {sp.n_frames} | {d.valid.mean():.4f} | {order.sum()} ({order[edge].sum()}) | "
                  f"{wrong.sum()} | {np.sqrt(np.mean(err[ok] ** 2)):.3f} | {np.sqrt(np.mean(d.sigma[ok] ** 2)):.3f} | "
                  f"{np.max(np.abs(err[ok]) / d.sigma[ok]):.2f} | {np.median(ts) * 1e3 / sp.n_frames:.2f} |")


if __name__ == "__main__":
    main()
