"""Milliseconds per frame of the rig route's stages beside the I/O floor of the same run.

Usage: ./run python benchmarks/bench_rig_stages.py [--rounds 3] [--work DIR]

The bench's rig-poses and rig-gauge sessions (640 x 480 camera, 38 captures of N = 4 phase and
Gray code on both axes) are written once; then, per round, on one core: reading the 38 captures
(the I/O floor: OpenCV's PNG decoding), decoding them (`huefringe.codecs.decode_sequence`),
triangulating (`huefringe.rig.triangulate`, ray-ray with propagated sigma), the same frame's
column alone against the projector's planes of constant column (the one-shot route's
triangulation, ``mode="u"`` with ``sigma_u``), the calibration's
per-pixel term (8 leave-one-pose-out triangulations), the height over the base plane and its grid,
and the features' figures with their calibration term (`huefringe.rig.metrology`). Speed is
reported as wall and CPU (process) milliseconds and as ratios to the I/O floor of the same run; no
test asserts it.
"""

from __future__ import annotations

import os

for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core, BLAS included (before NumPy loads it)

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from huefringe.bench import load_sl_bench_config, write_sl_session  # noqa: E402
from huefringe.rig.measure import (  # noqa: E402
    calibrate_sl_session,
    calibration_spread,
    decode_frame,
    height_over_plane,
    plane_grid,
    triangulate_frame,
)
from huefringe.rig.metrology import base_plane, feature_values  # noqa: E402
from huefringe.rig.triangulation import triangulate  # noqa: E402
from huefringe.session import load_sl_session  # noqa: E402
from huefringe.settings import load_config  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--work")
    a = ap.parse_args()
    cv2.setNumThreads(1)
    import numba

    numba.set_num_threads(1)
    work = Path(a.work) if a.work else Path(tempfile.mkdtemp(prefix="rig-stages-"))
    for name in ("rig-poses", "rig-gauge"):
        if not (work / name / "session.yaml").exists():
            write_sl_session(load_sl_bench_config(name), work / name)
    cfg = load_config({"codecs": {"noise": {"read_dn": 1.0, "full_well_e": None}}})
    s = load_sl_session(work / "rig-gauge")
    t0 = time.perf_counter()
    run = calibrate_sl_session(load_sl_session(work / "rig-poses"), cfg)
    t_cal = time.perf_counter() - t0
    times: dict[str, list[float]] = {}
    cpu: dict[str, list[float]] = {}

    def clock(key: str, fn, *args, **kw):
        t, c = time.perf_counter(), time.process_time()
        out = fn(*args, **kw)
        times.setdefault(key, []).append(1000 * (time.perf_counter() - t))
        cpu.setdefault(key, []).append(1000 * (time.process_time() - c))
        return out

    for _ in range(a.rounds):
        images = clock("read 38 captures (I/O floor)", s.read_captures)
        d = clock("decode", decode_frame, images, s.spec, cfg)
        f = clock("triangulate", triangulate_frame, d, run.calibration, cfg, where="bench", spec=s.spec)
        clock("triangulate u alone (one-shot's ray-plane)", triangulate, run.calibration, d["u"],
              sigma_u=d["sigma_u"], valid=d["valid_u"] & np.isfinite(d["u"]), mode="u")
        clock("calibration term (8 triangulations)", calibration_spread, f, list(run.jackknife))
        plane = clock("base plane", base_plane, f, s.features)
        h, u = clock("height over plane", height_over_plane, f, plane.centroid, plane.normal)
        clock("height grid", plane_grid, f, h, u, plane.centroid, plane.normal)
        clock("features' figures", feature_values, f.xyz, f.sigma, s.features)
    floor = float(np.median(times["read 38 captures (I/O floor)"]))
    print(f"rig route, {s.width} x {s.height}, {len(s.captures)} captures, one core, median of {a.rounds} rounds "
          f"(calibration from 8 poses with 8 leave-one-out fits: {t_cal:.1f} s)")
    print("| stage | ms per frame | CPU ms per frame | x I/O floor |")
    print("|---|---|---|---|")
    total = total_cpu = 0.0
    for k, v in times.items():
        ms, cms = float(np.median(v)), float(np.median(cpu[k]))
        if not k.startswith("read"):
            total, total_cpu = total + ms, total_cpu + cms
        print(f"| {k} | {ms:.1f} | {cms:.1f} | {ms / floor:.2f} |")
    print(f"| compute (all but reading) | {total:.1f} | {total_cpu:.1f} | {total / floor:.2f} |")


if __name__ == "__main__":
    main()
