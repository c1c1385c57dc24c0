"""Benchmark: build a per-pixel hue table from 256 bands x 3 repeats at 768 x 494 (PNG on disk).

Usage::

    ./run python benchmarks/bench_calibration.py [--width 768 --height 494 --bands 256 --repeats 3]
                                                 [--dir DIR] [--keep]

Writes a synthetic session's ``hue/`` folder (8-bit PNG, a simple projector-camera forward model
with gamma, crosstalk and coloured patches) to a temporary folder, then measures, each in a fresh
subprocess so that peak memory is that of the measured step alone:

``read``   reading every PNG with ``huefringe.session.read_rgb`` (the I/O floor),
``build``  ``huefringe.huetable.build_table`` on the same files,
``lookup`` ``HueTable.to_phase`` on one frame (numba and NumPy reference).

It prints wall times, peak RSS (``ru_maxrss``) and the tracemalloc peak, and the ratios
build/read and peak/table size, so that the figures are comparable across machines.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np


def _forward(h: int, w: int, seed: int = 0):
    """A small rig: reflectance patches, per-channel gamma, crosstalk, 8-bit camera."""
    rng = np.random.default_rng(seed)
    refl = np.full((h, w, 3), 0.85)
    refl[h // 4 : h // 2, w // 8 : w // 3] = (0.85, 0.2, 0.12)  # red patch
    refl[h // 4 : h // 2, w // 2 : 3 * w // 4] = (0.15, 0.6, 0.2)  # green patch
    refl[2 * h // 3 :, : w // 3] = 0.1  # dark
    refl[2 * h // 3 :, w // 3 : w // 3 + 40] = 0.003  # black (masked)
    gamma = np.array([1.8, 2.2, 2.6])
    mix = np.array([[0.85, 0.12, 0.03], [0.10, 0.80, 0.10], [0.03, 0.12, 0.85]])

    def capture(emitted: np.ndarray) -> np.ndarray:
        e = np.round(np.asarray(emitted, dtype=np.float64) * 255) / 255
        o = refl * (e**gamma + 0.02)
        c = 0.9 * (o @ mix.T + 0.01) + rng.normal(0, 0.002, o.shape)
        return np.clip(np.round(c * 255), 0, 255).astype(np.uint8)

    return capture


def write_session(d: Path, w: int, h: int, n: int, reps: int) -> None:
    from huefringe.io import write_png_rgb
    from huefringe.patterns import band_rgb, trapezoid_rgb

    cap = _forward(h, w)
    (d / "hue").mkdir(parents=True, exist_ok=True)
    write_png_rgb(d / "white.png", cap(np.ones(3)))
    for i in range(n):
        for r in range(reps):
            write_png_rgb(d / "hue" / f"band_{i:03d}_r{r}.png", cap(band_rgb(i, n)))
    x = np.arange(w)
    write_png_rgb(d / "frame.png", cap(trapezoid_rgb(2 * np.pi * x / 37.3)[None]))


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def step(kind: str, d: Path, n: int, reps: int, prefetch: int = 0) -> dict:
    """One measured step, run in its own process; returns a JSON-able dict."""
    from huefringe import huetable as cal
    from huefringe import colour
    from huefringe.session import read_rgb

    paths = cal.hue_band_paths(d / "hue", n, reps)
    white = read_rgb(d / "white.png")
    out: dict = {"kind": kind, "prefetch": prefetch, "rss_before_mb": _peak_rss_mb()}
    if kind == "read":
        tracemalloc.start()
        t = time.perf_counter()
        for band in paths:
            for p in band:
                read_rgb(p)
        out["seconds"] = time.perf_counter() - t
        out["tracemalloc_peak_mb"] = tracemalloc.get_traced_memory()[1] / 1e6
        tracemalloc.stop()
        out["peak_rss_mb"] = _peak_rss_mb()
        return out
    # warm the numba cache outside the measurement (compilation is a one-off per install)
    tiny = np.random.default_rng(0).random((2, 2, 3)).astype(np.float32)
    cal.build_table([[0]] * 6, np.ones((2, 2, 3), np.float32), read=lambda _p: tiny, smooth_window=1)
    tracemalloc.start()
    t = time.perf_counter()
    tab = cal.build_table(paths, white, prefetch=prefetch)
    out["seconds"] = time.perf_counter() - t
    out["tracemalloc_peak_mb"] = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    out["peak_rss_mb"] = _peak_rss_mb()
    out["table_mb"] = tab.table.nbytes / 1e6
    out["maps_mb"] = (tab.nbytes - tab.table.nbytes) / 1e6
    out["valid_fraction"] = tab.stats["valid_fraction"]
    out["masked_by_reason"] = tab.stats["masked_by_reason"]
    frame = read_rgb(d / "frame.png")
    hue = colour.hue(colour.white_balance(frame, white, tab.stats["params"]["floor"]), tab.model)
    tab.to_phase(hue)  # warm
    t = time.perf_counter()
    a = tab.to_phase(hue)
    out["lookup_numba_s"] = time.perf_counter() - t
    t = time.perf_counter()
    b = tab.to_phase(hue, method="numpy")
    out["lookup_numpy_s"] = time.perf_counter() - t
    dd = np.abs(np.angle(np.exp(1j * (a.astype(np.float64) - b))))
    out["lookup_max_diff_rad"] = float(np.nanmax(dd))
    with tempfile.TemporaryDirectory() as td:
        t = time.perf_counter()
        tab.save(Path(td) / "table")
        out["save_s"] = time.perf_counter() - t
        t = time.perf_counter()
        cal.HueTable.load(Path(td) / "table")
        out["load_mmap_s"] = time.perf_counter() - t
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=768)
    ap.add_argument("--height", type=int, default=494)
    ap.add_argument("--bands", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--dir", type=Path, default=None, help="reuse/keep the synthetic session here")
    ap.add_argument("--keep", action="store_true")
    ap.add_argument("--step", choices=["read", "build"], default=None, help=argparse.SUPPRESS)
    ap.add_argument("--prefetch", type=int, default=0, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.step:
        print(json.dumps(step(a.step, a.dir, a.bands, a.repeats, a.prefetch)))
        return 0

    tmp = None
    d = a.dir
    if d is None:
        tmp = tempfile.TemporaryDirectory(prefix="hf-bench-calib-")
        d = Path(tmp.name)
    if not (d / "hue" / f"band_{a.bands - 1:03d}_r{a.repeats - 1}.png").exists():
        t = time.perf_counter()
        write_session(d, a.width, a.height, a.bands, a.repeats)
        print(f"wrote {a.bands} x {a.repeats} PNGs {a.width}x{a.height} in {time.perf_counter() - t:.1f} s to {d}")
    res = {}
    for key, kind, pf in (("read", "read", 0), ("build", "build", 0), ("build_prefetch", "build", 1)):
        cmd = [sys.executable, __file__, "--step", kind, "--dir", str(d), "--bands", str(a.bands),
               "--repeats", str(a.repeats), "--prefetch", str(pf)]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=os.environ.copy())
        res[key] = json.loads(out.stdout.strip().splitlines()[-1])
    r, b, bp = res["read"], res["build"], res["build_prefetch"]
    tab_mb = b["table_mb"]
    n_img = a.bands * a.repeats
    all_images_mb = n_img * a.width * a.height * 3 * 4 / 1e6
    print(f"images: {n_img} x {a.width}x{a.height}; table (uint16 N*H*W*2): {tab_mb:.1f} MB, "
          f"per-pixel maps {b['maps_mb']:.1f} MB; all images as float32 would be {all_images_mb:.0f} MB")
    print(f"read only   : {r['seconds']:7.2f} s   peak RSS {r['peak_rss_mb']:7.1f} MB")
    print(f"build_table : {b['seconds']:7.2f} s   peak RSS {b['peak_rss_mb']:7.1f} MB   "
          f"tracemalloc peak {b['tracemalloc_peak_mb']:.1f} MB")
    print(f"build (prefetch=1, reading in background threads): {bp['seconds']:7.2f} s   "
          f"peak RSS {bp['peak_rss_mb']:7.1f} MB   tracemalloc peak {bp['tracemalloc_peak_mb']:.1f} MB")
    print(f"ratios      : build/read time {b['seconds'] / r['seconds']:.2f}; "
          f"tracemalloc peak / table {b['tracemalloc_peak_mb'] / tab_mb:.2f}; "
          f"peak RSS / table {b['peak_rss_mb'] / tab_mb:.2f}; per image {1e3 * b['seconds'] / n_img:.1f} ms")
    print(f"to_phase    : numba {1e3 * b['lookup_numba_s']:.1f} ms, numpy reference {1e3 * b['lookup_numpy_s']:.1f} ms "
          f"(x{b['lookup_numpy_s'] / b['lookup_numba_s']:.0f}); max diff {b['lookup_max_diff_rad']:.1e} rad")
    print(f"save        : {b['save_s']:.2f} s; valid {100 * b['valid_fraction']:.1f} %, masked {b['masked_by_reason']}")
    ok = b["seconds"] < 30 and b["peak_rss_mb"] < 2048 and bp["seconds"] < 30 and bp["peak_rss_mb"] < 2048
    print(f"target (< 30 s, < 2 GB): {'met' if ok else 'MISSED'}")
    if tmp is not None and not a.keep:
        tmp.cleanup()
    elif tmp is not None:
        print(f"kept {d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
