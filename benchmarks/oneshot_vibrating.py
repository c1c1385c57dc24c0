"""The vibrating gauge blocks captured one-shot by the calibrated bench rig: steps per frame, U, per-pixel errors.

Usage: ./run python benchmarks/oneshot_vibrating.py [--work DIR] [--preset rig-oneshot-vibrating]

Writes the bench sessions rig-poses and the preset (default rig-oneshot-vibrating: the paper's
Fig. 9 gauge blocks on a tilted base, vibrating 0.03 mm at 29 Hz along the base's normal while its
five one-shot frames are captured at 60 frames/s) into DIR (kept and reused when present),
measures the preset's session as the workflow does (huefringe.stages.measure_rig_session: the rig
calibrated from rig-poses, every one-shot frame, the report of all of them) and prints:

* each step per frame, its mean, standard deviation, error against the nominal and U (k = 2)
  with its two terms, and whether the truth lies inside U; the ISO 14253-1 decision;
* each frame's displacement and, against the truth of the scene where that frame saw it
  (huefringe.bench.rig_session.displaced_config at the frame's mean displacement), the share of
  the lit pixels measured, the median and 95th percentile of |e| along the camera ray and the
  share of pixels with |e| <= 2u (u: the point's noise with the calibration's jackknife term,
  xyz/frame_NNNN_u.tiff);
* the time of the measurement (calibration, every frame, report).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import tifffile

from huefringe.bench import load_sl_bench_config, write_sl_session
from huefringe.bench.rig_session import displaced_config, scene_truth, vibration_displacements
from huefringe.settings import load_config
from huefringe.stages._run import measure_rig_session

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/huefringe-oneshot-vibrating")
    ap.add_argument("--preset", default="rig-oneshot-vibrating")
    args = ap.parse_args()
    work = Path(args.work)
    t0 = time.perf_counter()
    for name in ("rig-poses", args.preset):
        if not (work / name / "session.yaml").is_file():
            write_sl_session(load_sl_bench_config(name), work / name)
    t1 = time.perf_counter()
    out = work / "results"
    res = measure_rig_session(work / args.preset, out, load_config(REPO / "config.yaml"), surfaces=False)
    t2 = time.perf_counter()
    print(f"sessions written in {t1 - t0:.1f} s; calibrated and measured (every frame, the report) in {t2 - t1:.1f} s")
    doc = json.loads(Path(res["json"]).read_text())
    print(f"frames {doc['frames']}; ISO 14253-1: {doc['conformity']['decision']} ({doc['conformity']['reason']})")
    for s in doc["steps"]:
        b, e = s["uncertainty_budget"], s["error_mm"]
        print(f"{s['name']}: per frame {', '.join(f'{v:.4f}' for v in s['per_frame_mm'])} mm; mean {s['mean_mm']:.4f} mm, "
              f"std {1000 * s['std_mm']:.2f} um; error {1000 * e:+.1f} um ({s['error_pct']:+.3f} %), U {1000 * s['U_mm']:.1f} um "
              f"(points {1000 * b['points_mm']:.2f} um, calibration {1000 * b['calibration_mm']:.2f} um); "
              f"truth inside U: {abs(e) <= s['U_mm']}")
    for kind, entries in doc["forms"].items():
        for f in entries:
            print(f"  {kind} {f['name']}: {1000 * f['mean_mm']:.1f} um (std {1000 * (f['std_mm'] or 0):.1f} um), "
                  f"U {1000 * f['U_mm']:.1f} um, {f['conformance']}")
    cfg = load_sl_bench_config(args.preset)
    disp = vibration_displacements(cfg).mean(axis=1)
    for k in range(doc["frames"]):
        truth = scene_truth(displaced_config(cfg, float(disp[k])))["xyz"]
        xyz = tifffile.imread(out / f"xyz/frame_{k:04d}.tiff").astype(np.float64)
        u = tifffile.imread(out / f"xyz/frame_{k:04d}_u.tiff")
        lit = np.isfinite(truth).all(-1)
        both = np.isfinite(xyz).all(-1) & lit
        ray = truth[both] / np.linalg.norm(truth[both], axis=-1, keepdims=True)
        err = np.abs(np.einsum("ij,ij->i", xyz[both] - truth[both], ray))
        print(f"frame {k}: displacement {1000 * disp[k]:+.1f} um; measured {both.sum() / lit.sum():.3f} of the lit pixels, "
              f"none unlit: {not (np.isfinite(xyz).all(-1) & ~lit).any()}; |e| median {1000 * np.median(err):.1f} um, "
              f"95th percentile {1000 * np.percentile(err, 95):.1f} um; |e| <= 2u on {np.mean(err <= 2 * u[both][:, 3]):.3f}")


if __name__ == "__main__":
    main()
