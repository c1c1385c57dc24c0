"""Method vs three-step baseline on the demo scene, with and without the membrane's vibration.

Usage: ./run python benchmarks/demo_vibration.py [--frames 10] [--amplitudes 0 0.03 0.1]

Prints, per vibration amplitude, the per-pixel height error against ground truth and the step
heights (mean and standard deviation over frames) of both methods.
"""

from __future__ import annotations

import argparse
import copy
import tempfile
from pathlib import Path

import numpy as np
import tifffile

from huefringe import bench, metrology, stages
from huefringe.height import accuracy
from huefringe.settings import load_config

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--amplitudes", type=float, nargs="+", default=[0.0, 0.03, 0.1])
    args = ap.parse_args()
    cfg = load_config(REPO / "config.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        for amp in args.amplitudes:
            b = copy.deepcopy(bench.load_bench_config(bench.preset_path("demo")))
            b["session"]["frames"] = args.frames
            b["vibration"]["amplitude_mm"] = amp
            root = Path(tmp) / f"a{amp:g}"
            session = bench.write_session(b, root / "session")
            p = stages.measure_session(session, root / "out", cfg, baseline=True)
            s = p["session"]
            n = s.frame_ids
            print(f"\nvibration amplitude {amp:g} mm at {b['vibration']['frequency_hz']:g} Hz, {len(n)} frames")
            for name, paths in (("trapezoidal-hsi", p["heights"]), ("three-step", p["baseline"])):
                maps = [tifffile.imread(x) for x in paths]
                acc = [accuracy(h, tifffile.imread(s.ground_truth[i])) for h, i in zip(maps, n, strict=True)]
                med = np.mean([a["median_abs_mm"] for a in acc])
                p95 = np.mean([a["p95_abs_mm"] for a in acc])
                steps = metrology.evaluate_session(maps, s.specimen, s.pixel_pitch_mm, range_mm=6.0)["steps"]
                st = "  ".join(f"{x['name']} {x['mean_mm']:.4f}+-{x['std_mm']:.4f}" for x in steps)
                print(f"  {name:16} median|e| {med:.4f} mm  p95|e| {p95:.4f} mm  steps: {st}")


if __name__ == "__main__":
    main()
