"""Study: could a compact per-pixel curve replace the kernel's full 256-entry hue tables?

Usage::

    ./run python benchmarks/study_compact_table.py [--size 192x124] [--bands 256] [--table PATH.npy]

The kernel's floor is one 64-byte table line per pixel, fetched from a per-pixel column of
``N`` uint16 hue counts (``kernel.prepare``). A compact representation of the same captured-hue
-> emitted-phase curve (the inverse of the column: linear between the knots
``(hue_i, 2 pi i / N)``) would only lift that floor if it were small enough to be read whole and
in sequence (about 16 bytes per pixel: four pixels per cache line), or shared between
neighbouring pixels. It must agree with the full table to 1e-4 rad and to move no
height by more than 0.5 um. This script measures, per valid pixel, the largest difference
between the full table's phase and each candidate, over every hue (for piecewise-linear curves
the largest difference lies on a knot of one of the two, so the knots of both are evaluated):

``uniform-M``   the inverse curve sampled at M hues uniformly spaced (a lookup without a
                search: index = hue * M / 2 pi), linear in between, phases kept in float32
                (``4 M`` bytes per pixel; uint16 phases would add up to 4.8e-5 rad);
``sextant-d``   per sextant ``[k pi / 3, (k + 1) pi / 3)`` of hue, a least-squares polynomial
                of degree d in hue (``24 (d + 1)`` bytes per pixel in float32);
``tile-mean``   each 32 x 32 tile's median column shared by all its pixels (no per-pixel data).

Heights: the difference in rad over the smallest ``a`` of the rig's plane calibration
(``h ~ dphi / a``; about 1 rad per mm for the bench rig of ``_kernel_case``), in um.

On the benchmark rig (the toy projector-camera model with gamma, crosstalk, coloured patches and
noise, whose table is built by ``huetable.build_table`` as the workflow builds it) and on a
table written by the workflow (``--table results/<id>/calib/table_object.npy``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

TWO_PI = 2.0 * np.pi


def pixel_curves(table: np.ndarray, start: np.ndarray, valid: np.ndarray, max_pixels: int, seed: int = 0
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(hue knots in rad, phase knots in rad, pixel index) of up to ``max_pixels`` valid pixels:
    each column rotated to start at its minimum, so that hue increases along it (one turn)."""
    n = table.shape[0]
    idx = np.flatnonzero(valid.ravel())
    rng = np.random.default_rng(seed)
    if idx.size > max_pixels:
        idx = np.sort(rng.choice(idx, max_pixels, replace=False))
    cols = table.reshape(n, -1)[:, idx].T.astype(np.float64)  # (P, N) counts, band order
    s0 = start.ravel()[idx].astype(np.int64)
    k = (s0[:, None] + np.arange(n)[None, :]) % n  # band of each sorted position
    hue = np.take_along_axis(cols, k, axis=1) * (TWO_PI / 65536.0)
    phase = k * (TWO_PI / n)  # emitted/code phase of the band (wraps once along the column)
    phase = np.where(np.arange(n)[None, :] >= (n - s0)[:, None], phase + TWO_PI, phase)  # unwrapped
    return hue, phase, idx


def full_phase(hue_k: np.ndarray, phase_k: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The full table's inverse (periodic, linear between knots) of one pixel at hues ``x``."""
    hx = np.concatenate([hue_k[-1:] - TWO_PI, hue_k, hue_k[:1] + TWO_PI])
    px = np.concatenate([phase_k[-1:] - TWO_PI, phase_k, phase_k[:1] + TWO_PI])
    return np.interp(np.mod(x - hue_k[0], TWO_PI) + hue_k[0], hx, px)


def uniform_errors(hue: np.ndarray, phase: np.ndarray, m: int) -> np.ndarray:
    """Max |uniform-M - full| per pixel (rad), on the knots of both curves."""
    grid = np.arange(m) * (TWO_PI / m)
    out = np.empty(hue.shape[0])
    for p in range(hue.shape[0]):
        g = np.float32(full_phase(hue[p], phase[p], grid)).astype(np.float64)
        g = np.unwrap(g)  # periodic curve: continue across 0
        gx = np.concatenate([grid, [TWO_PI]])
        gy = np.concatenate([g, [g[0] + TWO_PI]])
        xs = np.concatenate([np.mod(hue[p], TWO_PI), grid])
        compact = np.interp(xs, gx, gy)
        ref = full_phase(hue[p], phase[p], xs)
        d = np.mod(compact - ref + np.pi, TWO_PI) - np.pi
        out[p] = np.abs(d).max()
    return out


def sextant_errors(hue: np.ndarray, phase: np.ndarray, degree: int) -> np.ndarray:
    """Max |polynomial per sextant - full| per pixel (rad), on the full table's knots."""
    out = np.zeros(hue.shape[0])
    for p in range(hue.shape[0]):
        h = np.mod(hue[p], TWO_PI)
        ph = phase[p]
        sx = np.minimum((h / (np.pi / 3)).astype(int), 5)
        for s in range(6):
            sel = sx == s
            if sel.sum() <= degree + 1:
                continue
            x = h[sel] - (s + 0.5) * np.pi / 3
            y = ph[sel]
            y = np.unwrap(y)
            c = np.polynomial.polynomial.polyfit(x, y, degree)
            r = np.polynomial.polynomial.polyval(x, c) - y
            out[p] = max(out[p], float(np.abs(r).max()))
    return out


def tile_errors(table: np.ndarray, start: np.ndarray, valid: np.ndarray, idx: np.ndarray, hue: np.ndarray,
                phase: np.ndarray, tile: int = 32) -> np.ndarray:
    """Max |tile's median curve - full| per pixel (rad), on the pixel's knots."""
    h, w = valid.shape
    v, u = np.divmod(idx, w)
    tid = (v // tile) * (-(-w // tile)) + u // tile
    out = np.zeros(idx.size)
    for t in np.unique(tid):
        ps = np.flatnonzero(tid == t)
        grid = np.arange(1024) * (TWO_PI / 1024)
        curves = np.stack([np.unwrap(full_phase(hue[p], phase[p], grid)) for p in ps])
        curves -= (curves[:, :1] // TWO_PI) * TWO_PI
        med = np.median(curves, axis=0)
        for j, p in enumerate(ps):
            d = np.mod(curves[j] - med + np.pi, TWO_PI) - np.pi
            out[p] = np.abs(d).max()
    return out


def summarise(name: str, err: np.ndarray, a_min: float, nbytes: float | None) -> dict[str, Any]:
    row = {"name": name, "bytes_per_pixel": nbytes, "max_rad": float(err.max()),
           "p99_rad": float(np.quantile(err, 0.99)), "median_rad": float(np.median(err)),
           "within_1e-4_rad": float(np.mean(err <= 1e-4)), "max_height_um": float(1e3 * err.max() / a_min),
           "within_0.5um": float(np.mean(1e3 * err / a_min <= 0.5))}
    b = "-" if nbytes is None else f"{nbytes:.0f}"
    print(f"  {name:<12} {b:>6} B/px  max {row['max_rad']:.2e} rad  p99 {row['p99_rad']:.2e}  median "
          f"{row['median_rad']:.2e}  pixels within 1e-4 rad {100 * row['within_1e-4_rad']:5.1f} %  max height "
          f"{row['max_height_um']:.2f} um  within 0.5 um {100 * row['within_0.5um']:5.1f} %")
    return row


def study(table: np.ndarray, start: np.ndarray, valid: np.ndarray, a_min: float, pixels: int) -> list[dict[str, Any]]:
    n = table.shape[0]
    hue, phase, idx = pixel_curves(table, start, valid, pixels)
    print(f"  {idx.size} valid pixels sampled; full table {2 * n} B/px (kernel layout "
          f"{64 * -(-n // 29)} B/px), one 64-byte line read per pixel")
    rows = []
    for m in (128, 256, 512, 1024, 2048):
        rows.append(summarise(f"uniform-{m}", uniform_errors(hue, phase, m), a_min, 4.0 * m))
    for d in (3, 5, 9):
        rows.append(summarise(f"sextant-{d}", sextant_errors(hue, phase, d), a_min, 24.0 * (d + 1)))
    rows.append(summarise("tile-mean", tile_errors(table, start, valid, idx, hue, phase), a_min, None))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="192x124")
    ap.add_argument("--bands", type=int, default=256)
    ap.add_argument("--pixels", type=int, default=2000, help="valid pixels sampled per table")
    ap.add_argument("--table", type=Path, action="append", default=[], help="a workflow table (.npy) to study too")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    from _kernel_case import make_case

    w, h = (int(x) for x in a.size.lower().split("x"))
    rig = make_case(w, h, n_bands=a.bands, repeats=2)
    a_min = float(np.min(rig.cal.a))
    print(f"benchmark rig {w} x {h}, {a.bands} bands x 2 repeats (a >= {a_min:.3f} rad/mm):")
    doc: dict[str, Any] = {"rig": study(np.asarray(rig.table.table), rig.table.start, rig.table.valid, a_min,
                                        a.pixels)}
    for path in a.table:
        from huefringe.huetable import HueTable

        t = HueTable.load(path)
        print(f"{path} ({t.n_bands} bands, {t.shape[1]} x {t.shape[0]}; a taken as {a_min:.3f} rad/mm):")
        doc[str(path)] = study(np.asarray(t.table), np.asarray(t.start), np.asarray(t.valid, bool), a_min, a.pixels)
    if a.json:
        a.json.write_text(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
