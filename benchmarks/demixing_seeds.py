"""Colour demixing over bench seeds: the paired step change of ``camera.colour_demixing`` auto vs false.

Usage: ./run python benchmarks/demixing_seeds.py [--seeds 1-20] [--camera diagonal|identity|bench]
       [--low-noise] [--session KEY=VALUE ...] [--keep DIR]

Default session: tests/test_rig_chain.py's coarse plain gauge (160 x 120 px at 0.5 mm, period 24 px,
16 bands x 2 repeats, 2 frames). Per seed both settings are measured (``huefringe.api.measure``) and
scored against the bench's ground truth; printed: each step's mean and seed-to-seed sd, the paired
change with its standard error, median / p95 / coverage, and the estimate's error against the bench
camera's crosstalk and its leave-out spread. ``--camera diagonal`` keeps the crosstalk's diagonal only
(the same camera without crosstalk), ``--low-noise`` sets a full well of 1e7 e- and 0.05 DN read
noise. About 1.5 s per seed and setting at 160 x 120 on 2 shared cores. docs/accuracy.md.
"""

from __future__ import annotations

import argparse
import copy
import tempfile
from pathlib import Path

import numpy as np
import tifffile
import yaml

from huefringe import bench
from huefringe.api import measure
from huefringe.metrology import evaluate_session
from huefringe.session import load_session

COARSE = {"width": 160, "height": 120, "pixel_pitch_mm": 0.5, "period_px": 24, "hue_bands": 16, "repeats": 2,
          "frames": 2, "id": "coarse"}


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1-20", help="first-last (default 1-20)")
    ap.add_argument("--camera", choices=("bench", "diagonal", "identity"), default="bench")
    ap.add_argument("--low-noise", action="store_true")
    ap.add_argument("--session", nargs="*", default=[], help="session overrides KEY=VALUE (YAML values)")
    ap.add_argument("--keep", type=Path, default=None, help="write the bench sessions here (reused when present)")
    args = ap.parse_args()
    where = args.keep or Path(tempfile.mkdtemp(prefix="demixing-seeds-"))
    base = copy.deepcopy(bench.load_bench_config(bench.preset_path("plain_gauge")))
    base["session"].update(COARSE)
    base["session"].update({k: yaml.safe_load(v) for k, v in (kv.split("=", 1) for kv in args.session)})
    cam = base["camera"]
    if args.camera == "diagonal":
        cam["crosstalk"] = np.diag(np.diag(cam["crosstalk"])).tolist()
    elif args.camera == "identity":
        cam["crosstalk"] = np.eye(3).tolist()
    if args.low_noise:
        cam.update(full_well_e=10_000_000, read_noise_dn=0.05)
    truth_m = np.asarray(cam["crosstalk"]) * np.asarray(cam["sensitivity"])[None, :]
    truth_m = truth_m / np.diag(truth_m)[None, :]
    rows: dict[str, list[dict]] = {"false": [], "auto": []}
    for seed in _seeds(args.seeds):
        cfg = copy.deepcopy(base)
        cfg["session"]["seed"] = seed
        folder = where / f"{args.camera}{'-low' if args.low_noise else ''}-{seed}"
        path = folder / cfg["session"]["id"]
        if not path.exists():
            bench.write_session(cfg, path)
        s = load_session(path)
        truth = np.stack([tifffile.imread(s.ground_truth[f]) for f in s.frame_ids])
        for setting, value in (("false", False), ("auto", "auto")):
            m = measure(s, {"camera": {"colour_demixing": value}})
            ok = np.isfinite(m.heights)
            err = np.abs(m.heights - truth)[ok]
            ev = evaluate_session(list(m.heights), s.specimen, s.pixel_pitch_mm, camera=m.camera,
                                  range_mm=max(s.planes_mm) - min(s.planes_mm))
            rec = m.camera_record["colour_demixing"]
            est = rec.get("estimate") or {}
            row = {"steps": {st["name"]: 1e3 * st["error_mm"] for st in ev["steps"]}, "median": float(np.median(err)),
                   "p95": float(np.percentile(err, 95)), "coverage": float(ok.mean()), "applied": rec["applied"],
                   "estimate_error": float(np.abs(np.asarray(est["matrix"]) - truth_m).max()) if est else None,
                   "spread": est.get("max_segment_spread")}
            rows[setting].append(row)
            print(f"seed {seed} demixing {setting}: " + " ".join(f"{k} {v:+.1f}" for k, v in row["steps"].items())
                  + f" um, median {row['median']:.4f} p95 {row['p95']:.4f} coverage {row['coverage']:.3f}", flush=True)
    n = len(rows["false"])
    print(f"\n{n} seeds, camera {args.camera}{', low noise' if args.low_noise else ''}; steps um: mean (sd)\n")
    print("| step | demixing false | demixing auto | paired change |\n| --- | ---: | ---: | ---: |")
    for name in rows["false"][0]["steps"]:
        off = np.array([r["steps"][name] for r in rows["false"]])
        on = np.array([r["steps"][name] for r in rows["auto"]])
        d = on - off
        se = d.std(ddof=1) / np.sqrt(n) if n > 1 else float("nan")
        sd = (lambda x: x.std(ddof=1) if n > 1 else float("nan"))
        print(f"| {name} | {off.mean():+.1f} ({sd(off):.1f}) | {on.mean():+.1f} ({sd(on):.1f}) | {d.mean():+.1f} +- {se:.1f} |")
    for key in ("median", "p95", "coverage"):
        print(f"{key}: false {np.mean([r[key] for r in rows['false']]):.4f}, auto {np.mean([r[key] for r in rows['auto']]):.4f}")
    errs = [r["estimate_error"] for r in rows["auto"] if r["estimate_error"] is not None]
    spreads = [r["spread"] for r in rows["auto"] if r["spread"] is not None]
    if errs:
        print(f"estimate error vs the bench crosstalk: max {max(errs):.1e}; leave-out spread max {max(spreads):.1e}; "
              f"applied on {sum(r['applied'] for r in rows['auto'])} of {n}")


if __name__ == "__main__":
    main()
