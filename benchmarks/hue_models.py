"""Which hue model measures better? Runs the whole chain with both on the same bench sessions.

Usage: ./run python benchmarks/hue_models.py [--frames 3]

For each bench preset (demo: gauge blocks with the pre-distorted pattern; flat: the plain
trapezoid of paper Fig. 7), the tables, plane calibration and height maps are computed once with
the hexcone hue and once with the HSI hue (paper eqs. 1-2), and the height error against the
bench's ground truth is printed. The README quotes the figures.
"""

from __future__ import annotations

import argparse
import copy
import tempfile
from pathlib import Path

import numpy as np
import tifffile

from huefringe import bench, stages
from huefringe.height import accuracy
from huefringe.settings import load_config

REPO = Path(__file__).resolve().parents[1]


def run(model: str, session: Path, out: Path, cfg: dict) -> dict:
    p = stages.measure_session(session, out, {**cfg, "hue_model": model})
    s = p["session"]
    accs = [accuracy(tifffile.imread(h), tifffile.imread(s.ground_truth[i]))
            for i, h in zip(s.frame_ids, p["heights"], strict=True)]
    return {k: float(np.mean([a[k] for a in accs])) for k in ("median_abs_mm", "p95_abs_mm", "rms_mm", "coverage")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3)
    args = ap.parse_args()
    cfg = load_config(REPO / "config.yaml")
    print(f"{'preset':8} {'hue model':9} {'median |e| mm':>13} {'p95 |e| mm':>10} {'rms mm':>8} {'coverage':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        for preset in ("demo", "flat"):
            bcfg = copy.deepcopy(bench.load_bench_config(bench.preset_path(preset)))
            bcfg["session"]["frames"] = args.frames
            session = bench.write_session(bcfg, Path(tmp) / preset)
            for model in ("hexcone", "hsi"):
                r = run(model, session, Path(tmp) / f"{preset}-{model}", cfg)
                print(f"{preset:8} {model:9} {r['median_abs_mm']:13.4f} {r['p95_abs_mm']:10.4f} {r['rms_mm']:8.4f} {r['coverage']:8.3f}")


if __name__ == "__main__":
    main()
