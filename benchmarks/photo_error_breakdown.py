"""Where a photo relief's height error comes from: systematic (shared by the frames) against noise,
by white level and by the reflectance's relative gradient |grad W| / W.

Usage: ./run python benchmarks/photo_error_breakdown.py KEEP [--cases NAME ...] [--variants NAME ...]

``KEEP`` is an ``accuracy_matrix.py --keep`` folder (its cases' sessions and per-variant height
maps). With two or more frames of the same static relief (vibration only moves it by microns),
each pixel's error ``e_f`` splits into the frames' mean (the part every frame shares: texture
residual, table and model error, plus what is left of the noise, ``1/sqrt(F)`` of it) and the
frame-to-frame difference (noise only): ``noise_rms = std over frames``, and the frame-to-frame
correlation of the errors is the systematic share of their variance. Rows: all valid pixels,
then bins of the object white's level (fraction of its 99th percentile, channel mean) and of
``|grad W| / W`` (Gaussian derivative, sigma 1 px). Printed as Markdown tables.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

from huefringe.session import load_session, read_rgb

import accuracy_matrix as am


def _frames(keep: Path, case: str, variant: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    slug = am._slug(case)
    s = load_session(keep / slug / "session")
    out = keep / slug / "".join(c if c.isalnum() else "-" for c in variant)
    e = np.stack([tifffile.imread(out / f"frame_{n:04d}.tiff").astype(np.float64)
                  - tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids])
    truth = tifffile.imread(s.ground_truth[s.frame_ids[0]]).astype(np.float64)
    white = np.asarray(read_rgb(s.object_white), np.float64).mean(axis=-1)
    return e, truth, white, np.isfinite(truth)


def _row(label: str, e: np.ndarray, m: np.ndarray, lit: int) -> str:
    ok = m & np.all(np.isfinite(e), axis=0)
    if ok.sum() < 20:
        return f"| {label} | {int(ok.sum())} | - | - | - | - | - | - | - |"
    ee = e[:, ok]
    mean = ee.mean(axis=0)
    noise = ee.std(axis=0, ddof=1)  # per-pixel frame-to-frame sd
    a = np.abs(ee).ravel()
    r = np.corrcoef(ee[0] - ee[0].mean(), ee[1] - ee[1].mean())[0, 1] if ee.shape[0] > 1 else np.nan
    return (f"| {label} | {int(ok.sum())} ({ok.sum() / max(lit, 1):.3f}) | {np.median(a):.4f} | {np.percentile(a, 95):.4f} "
            f"| {np.median(np.abs(mean)):.4f} | {np.percentile(np.abs(mean), 95):.4f} "
            f"| {np.sqrt(np.mean(noise ** 2)):.4f} | {np.sqrt(np.mean(mean ** 2)):.4f} | {r:.2f} |")


def breakdown(keep: Path, case: str, variant: str) -> list[str]:
    e, truth, white, lit_m = _frames(keep, case, variant)
    lit_m &= white > 0
    lit = int(lit_m.sum())
    w = white / np.percentile(white[lit_m], 99)
    g = np.hypot(ndimage.gaussian_filter(white, 1.0, order=(0, 1)), ndimage.gaussian_filter(white, 1.0, order=(1, 0)))
    rel = g / np.maximum(white, 1e-6)
    lines = [f"**{case}, {variant}** ({e.shape[0]} frames; {lit} lit pixels)", "",
             "| pixels | valid (of lit) | median abs | p95 abs | median abs frame mean | p95 abs frame mean "
             "| noise rms (frame sd) | frame-mean rms | frame-frame corr |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
             _row("all", e, lit_m, lit)]
    for lo, hi in ((0.0, 0.12), (0.12, 0.25), (0.25, 0.5), (0.5, 0.75), (0.75, 10.0)):
        lines.append(_row(f"W {lo:.2f}-{hi:.2f}", e, lit_m & (w >= lo) & (w < hi), lit))
    for lo, hi in ((0.0, 0.05), (0.05, 0.1), (0.1, 0.2), (0.2, 0.4), (0.4, 100.0)):
        lines.append(_row(f"grad W / W {lo:.2f}-{hi:.2f}", e, lit_m & (rel >= lo) & (rel < hi), lit))
    # the p95 tail: which of its pixels are systematic (both frames beyond the threshold, same sign)
    ok = lit_m & np.all(np.isfinite(e), axis=0)
    a = np.abs(e[:, ok])
    thr = np.percentile(a.ravel(), 95)
    tail = (a > thr).any(axis=0)
    both = (a > thr).all(axis=0) & (np.sign(e[0, ok]) == np.sign(e[1, ok]))
    lines += ["", f"p95 tail (|e| > {thr:.4f} mm in a frame): {int(tail.sum())} pixels, {both.sum() / max(tail.sum(), 1):.2f} "
              f"of them beyond it in both frames with one sign; their median |grad W|/W {np.median(rel[ok][tail]):.3f} "
              f"(all valid {np.median(rel[ok]):.3f}), median W {np.median(w[ok][tail]):.3f} (all {np.median(w[ok]):.3f})", ""]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("keep", type=Path)
    ap.add_argument("--cases", nargs="*", default=["tex astronaut p56 72x1", "tex chelsea p56 72x1"])
    ap.add_argument("--variants", nargs="*", default=["all on"])
    args = ap.parse_args()
    for c in args.cases:
        for v in args.variants:
            print("\n".join(breakdown(args.keep, c, v)))


if __name__ == "__main__":
    main()
