"""The error a photo relief's frames share: the phase filter's weighted centroid on the slope.

Usage: ./run python benchmarks/filter_centroid.py [--frames 4] [--keep DIR]

A tuning scene (no hold-out): the astronaut photo relief (bench preset ``photo_sensor``) seen by
the coffee hold-out's sensor class (8 e- read noise, 5,000 e- full well), 48 px period, 72 hue bands
x 1 repeat, 320 x 240, 16 bit, seed 71, ``--frames`` frames; measured by the workflow's stages at
config.yaml's defaults. Each pixel's error ``e_f`` splits into the frames' mean (what they share,
plus the noise over ``sqrt(F)``) and the frame-to-frame part. The phase filter's first pass is an
inverse-variance mean over the 5 x 5 window, with weights ``w = 1 / sigma^2`` from the hue table's
per-pixel noise over the table's slope at the frame's hue (``perframe.phase_sigma``): on a slope
it returns the heights at the weights' centroid. Its prediction from the bench's truth ``T``,
``sum w_j (T_j - T_i) / sum w_j`` over the window's valid pixels, is compared with the frames' mean
error (correlation, least-squares slope, what is left), and the 2u coverage of the written u
(which holds the term ``|g . c|``, ``uncertainty.lateral_term``, where the first pass's window
stands, and the grown windows' own bias where they grew) against the same u with the fixed
window's term taken out of every pixel (on the grown ones that takes out more than it added).
Pixels 3 px or more inside the valid region of every frame.
"""

from __future__ import annotations

import argparse
import copy
import glob
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe import bench, colour, uncertainty  # noqa: E402
from huefringe.huetable import HueTable  # noqa: E402
from huefringe.perframe import phase_sigma  # noqa: E402
from huefringe.session import load_session, read_rgb  # noqa: E402

RADIUS = 2  # measurement.denoise_radius (config.yaml)


def scene(frames: int) -> dict:
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("photo_sensor")))
    cfg["session"].update({"period_px": 48, "seed": 71, "frames": frames})
    cfg["camera"].update({"read_noise_e": 8, "full_well_e": 5000})
    cfg["scene"]["image"] = "astronaut"
    return bench.validate_bench_config(cfg)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--keep", type=Path, default=None, help="keep the session and results here; reuse them")
    args = ap.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        where = (args.keep or Path(tmp)) / f"astronaut-8e-5ke-p48-72x1-{args.frames}f"
        session, tables = am._case_dirs(where, scene(args.frames))
        out = where / "all-on"
        if not sorted(out.glob("frame_*[0-9].u.tiff")):
            am.measure(session, tables, out, am._config({}))
        s = load_session(session)
        ids = s.frame_ids
        e = np.stack([tifffile.imread(out / f"frame_{n:04d}.tiff").astype(np.float64)
                      - tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in ids])
        u = np.stack([tifffile.imread(out / f"frame_{n:04d}.u.tiff").astype(np.float64) for n in ids])
        table = HueTable.load(glob.glob(str(tables / "*" / "table_object.json"))[0])
        gains = colour.white_gains(np.asarray(read_rgb(s.object_white), np.float32))
        k = np.ones((2 * RADIUS + 1, 2 * RADIUS + 1))
        preds, us_without = [], []
        for f, n in enumerate(ids):
            rgb = np.asarray(read_rgb(s.frames[n]), np.float32)
            _, slope = table.to_phase_and_slope(colour.balanced_hue(rgb, gains, table.model))
            sig = phase_sigma(table, slope)
            truth = tifffile.imread(s.ground_truth[n]).astype(np.float64)
            ok = np.isfinite(e[f]) & np.isfinite(sig) & np.isfinite(truth)
            w = np.where(ok, 1.0 / sig**2, 0.0)
            sw = ndimage.correlate(w, k, mode="constant")
            preds.append(ndimage.correlate(w * np.where(ok, truth, 0.0), k, mode="constant")
                         / np.maximum(sw, 1e-30) - truth)
            term = uncertainty.lateral_term((e[f] + truth).astype(np.float32), u[f].astype(np.float32), lateral_px=0.0,
                                            weight=w.astype(np.float32), filter_radius=RADIUS).astype(np.float64)
            us_without.append(np.sqrt(np.maximum(u[f] ** 2 - term**2, 0.0)))
    pred = np.mean(preds, axis=0)
    inner = ndimage.binary_erosion(np.all(np.isfinite(e) & np.isfinite(u), axis=0), iterations=3) & np.isfinite(pred)
    ee, m, p = e[:, inner], e[:, inner].mean(axis=0), pred[inner]
    f_ = len(ids)
    noise2 = float(np.mean(ee.var(axis=0, ddof=1)))
    shared = np.sqrt(max(float(np.mean(m**2)) - noise2 / f_, 0.0))
    fit = np.polyfit(p, m, 1)
    left = np.sqrt(max(float(np.mean((m - p) ** 2)) - noise2 / f_, 0.0))
    ok_all = np.isfinite(e) & np.isfinite(u)
    uw = np.stack(us_without)
    print(f"astronaut, 8 e- / 5,000 e-, p48, 72 x 1, {f_} frames (tuning scene); {int(inner.sum())} pixels "
          f"3 px inside the valid region ({time.perf_counter() - t0:.0f} s)")
    print("| quantity | mm |\n| --- | ---: |")
    print(f"| rms e | {np.sqrt(np.mean(ee**2)):.4f} |")
    print(f"| shared (frames' mean, its noise part removed) | {shared:.4f} |")
    print(f"| frame-to-frame (noise) | {np.sqrt(noise2):.4f} |")
    print(f"| filter centroid's prediction from the truth, rms | {np.sqrt(np.mean(p**2)):.4f} |")
    print(f"| shared less the prediction (its noise part removed) | {left:.4f} |")
    print(f"\ncorrelation of the frames' mean error with the prediction {np.corrcoef(m, p)[0, 1]:.3f}, "
          f"least-squares slope {fit[0]:.2f}; median |frames' mean| {np.median(np.abs(m)):.4f} mm, "
          f"less the prediction {np.median(np.abs(m - p)):.4f} mm")
    print(f"2u coverage, every valid pixel of every frame: {np.mean(np.abs(e[ok_all]) <= 2 * u[ok_all]):.3f} with the "
          f"centroid term (the written u), {np.mean(np.abs(e[ok_all]) <= 2 * uw[ok_all]):.3f} with the fixed "
          "window's term taken out of every pixel")


if __name__ == "__main__":
    main()
