"""The rig route against truth, as the workflow runs it: bench structured-light sessions (a calibration
session of printed-board poses, the composite gauge with blocks and a ball, a flat board) ->
rig_calibrate -> rig_measure -> rig_metrology -> rig_accuracy (docs/rig.md, "Measured on the bench").

Usage: ./run python benchmarks/rig_session_route.py [--rigs tune,holdout-wide,holdout-narrow]
                                                    [--seeds 4,5,6] [--poses 8] [--work DIR]
                                                    [--sessions rig-gauge,rig-board[,rig-oneshot]]
Each (rig, pose seed) case writes its sessions with huefringe.bench (the presets rig-poses,
rig-gauge, rig-board with the rig, the pose seed and count replaced), calibrates and measures them
with huefringe.stages.calibrate_rig_session / measure_rig_session (the workflow's stages), and
prints one row per figure: error, U (k = 2), |error| <= U, and the per-pixel X, Y, Z coverage
|e_ray| <= 2 u_ray. About 25 s per case on one core. ``--sessions`` picks the measured presets;
``rig-oneshot`` (the one-shot colour session: its report and accuracy are of its first frame) adds
about 30 s per case.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from huefringe.bench import load_sl_bench_config, write_sl_session
from huefringe.settings import load_config
from huefringe.stages import calibrate_rig_session, measure_rig_session


def case(work: Path, rig: str, seed: int, poses: int, sessions: tuple[str, ...] = ("rig-gauge", "rig-board")) -> dict:
    root = work / f"{rig}-s{seed}"
    cfg = load_sl_bench_config("rig-poses")
    cfg.update(rig=rig)
    cfg["poses"].update(seed=seed, count=poses)
    write_sl_session(cfg, root / "rig-poses")
    for name in sessions:
        c = load_sl_bench_config(name)
        c.update(rig=rig, calibration_session="../rig-poses")
        write_sl_session(c, root / name)
    conf = load_config({"codecs": {"noise": {"read_dn": 1.0, "full_well_e": None}}})  # the bench rig's camera
    t0 = time.perf_counter()
    calib = calibrate_rig_session(root / "rig-poses", root / "results/rig-poses/calib/rig.yml", conf)["calibration"]
    t_cal = time.perf_counter() - t0
    out = {"rig": rig, "seed": seed, "poses": poses, "calibrate_s": t_cal, "figures": [], "pixels": {}}
    for name in sessions:
        t0 = time.perf_counter()
        files = measure_rig_session(root / name, root / "results" / name, conf, calibration=calib, surfaces=False)
        out[f"measure_{name}_s"] = time.perf_counter() - t0
        rep = json.loads(files["json"].read_text())
        for f in rep["steps"] + [e for v in rep["forms"].values() for e in v]:
            out["figures"].append({"session": name, "name": f["name"], "nominal": f["nominal_mm"], "value": f["mean_mm"],
                                   "error": f["error_mm"], "U": f["U_mm"], "u_cal": f["uncertainty_budget"]["calibration_mm"],
                                   "u_pts": f["uncertainty_budget"]["points_mm"]})
        out["pixels"][name] = json.loads(files["accuracy"].read_text())
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rigs", default="tune,holdout-wide,holdout-narrow")
    ap.add_argument("--seeds", default="4,5,6")
    ap.add_argument("--poses", type=int, default=8)
    ap.add_argument("--work")
    ap.add_argument("--sessions", default="rig-gauge,rig-board", help="the measured bench presets, comma separated")
    a = ap.parse_args()
    work = Path(a.work) if a.work else Path(tempfile.mkdtemp(prefix="rig-route-"))
    rows = []
    for rig in a.rigs.split(","):
        for seed in (int(s) for s in a.seeds.split(",")):
            r = case(work, rig, seed, a.poses, tuple(a.sessions.split(",")))
            rows.append(r)
            took = ", ".join(f"{k[len('measure_'):-2]} {v:.1f} s" for k, v in r.items() if k.startswith("measure_"))
            print(f"\n## {rig}, pose seed {seed}, {a.poses} poses (calibration {r['calibrate_s']:.1f} s, {took})")
            print("| session | figure | nominal mm | error mm | error % | U mm | u calibration mm | u points mm | |e| <= U |")
            print("|---|---|---|---|---|---|---|---|---|")
            for f in r["figures"]:
                pct = f"{100 * f['error'] / f['nominal']:+.3f}" if f["nominal"] else ""
                ucal = f["u_cal"] if isinstance(f["u_cal"], float) else float("nan")
                print(f"| {f['session']} | {f['name']} | {f['nominal']:g} | {f['error']:+.4f} | {pct} | {f['U']:.4f} | "
                      f"{ucal:.4f} | {f['u_pts']:.4f} | {'yes' if abs(f['error']) <= f['U'] else 'NO'} |")
            for name, p in r["pixels"].items():
                print(f"pixels {name}: {p['pixels']} valid with truth ({p['coverage_of_truth']:.1%} of the lit), "
                      f"{p['valid_without_truth']} valid without direct light; |e_ray| median {p['median_abs_error_mm']:.4f} "
                      f"p95 {p['p95_abs_error_mm']:.4f} mm, median u_ray {p['median_u_ray_mm']:.4f} mm, "
                      f"|e_ray| <= 2u {p['within_2u']:.3f}; decoding alone: |e| median {p['decoding']['median_abs_error_mm']:.4f} mm, "
                      f"median sigma {p['decoding']['median_sigma_mm']:.4f} mm, |e| <= 2 sigma {p['decoding']['within_2sigma']:.3f}")
    figs = [f for r in rows for f in r["figures"]]
    inside = sum(abs(f["error"]) <= f["U"] for f in figs)
    print(f"\nall cases: {inside} of {len(figs)} figures with |error| <= U (k = 2)")
    steps = [f for f in figs if f["name"].startswith("block-")]
    print("steps within 0.3 %:", sum(abs(f["error"]) <= 0.003 * f["nominal"] for f in steps), "of", len(steps))
    z = [f["error"] / (f["U"] / 2) for f in steps if f["U"] > 0]
    if z:
        print(f"steps' standardised errors e / u: RMS {float(np.sqrt(np.mean(np.square(z)))):.2f}, "
              f"|e / u| max {max(abs(v) for v in z):.2f} over {len(z)} (1 and about 2 if u holds the errors)")
    (work / "rig_session_route.json").write_text(json.dumps(rows, indent=1))
    print(f"raw: {work / 'rig_session_route.json'}")


if __name__ == "__main__":
    main()
