"""Projector-camera rig targets on the bench: calibration and triangulation against truth, per rig.

Usage: ./run python benchmarks/rig_targets.py
Prints one row per (rig, poses, seed): focal-length errors (%), principal-point errors (px),
stereo RMS against OpenCV on the ideal corners, flat-board form deviation and plane RMS (mm),
sphere radius error (mm), step-height errors (%), and triangulation ms per frame.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from rig_helpers import COORD_SIGMA_PX, calibrated  # noqa: E402

from huefringe.bench.rig import PlaneScene, SphereScene, StepsScene  # noqa: E402
from huefringe.rig import triangulate  # noqa: E402
from huefringe.metrology import fit_plane_u, fit_sphere_u, form_deviation, step_height_u  # noqa: E402

CASES = [("tune", 8, 1), ("tune", 6, 2), ("holdout-wide", 6, 7), ("holdout-wide", 10, 3),
         ("holdout-narrow", 8, 11), ("holdout-narrow", 6, 5)]


def measure(rig, cal, scene, mode, seed):
    rng = np.random.default_rng(seed)
    xyz, ok, *extra = scene.cast(rig.rays)
    m = rig.coordinates(xyz, ok, rng, COORD_SIGMA_PX)
    t0 = time.perf_counter()
    t = triangulate(cal, m["u"], m["v"] if mode == "both" else None, sigma_u=m["sigma"],
                    sigma_v=m["sigma"] if mode == "both" else None, valid=m["valid"])
    return t, xyz, extra, (time.perf_counter() - t0) * 1e3


def main() -> None:
    print("rig poses seed | f err % cam/proj | pp err px cam/proj | RMS/ref | flat form mm / rms mm | sphere dR mm | steps err % | ms/frame u/both")
    for name, n, seed in CASES:
        rig, cal, rep, ref = calibrated(name, n, seed)
        tr = rig.calibration
        f = [max(abs(K[0, 0] / Kt[0, 0] - 1), abs(K[1, 1] / Kt[1, 1] - 1)) * 100
             for K, Kt in ((cal.camera_matrix, tr.camera_matrix), (cal.projector_matrix, tr.projector_matrix))]
        pp = [np.hypot(*(K[:2, 2] - Kt[:2, 2]))
              for K, Kt in ((cal.camera_matrix, tr.camera_matrix), (cal.projector_matrix, tr.projector_matrix))]
        t, _, _, ms_u = measure(rig, cal, PlaneScene(), "u", seed)
        pl = fit_plane_u(t.xyz[t.valid], t.sigma[t.valid])
        form = form_deviation(pl, t.xyz[t.valid])
        t, _, (sph,), ms_b = measure(rig, cal, SphereScene(), "both", seed)
        dr = fit_sphere_u(t.xyz[t.valid & sph], t.sigma[t.valid & sph])["radius_mm"] - SphereScene().radius
        sc = StepsScene()
        t, xyz, (lab,), _ = measure(rig, cal, sc, "u", seed)
        R, o = sc.frame()
        loc = (xyz - o) @ R
        steps = []
        for k, (x0, y0, x1, y1, h) in enumerate(sc.blocks, start=1):
            band = (lab == 0) & (loc[..., 1] > y0) & (loc[..., 1] < y1) & (
                ((loc[..., 0] > x0 - 13) & (loc[..., 0] < x0 - 3)) | ((loc[..., 0] > x1 + 3) & (loc[..., 0] < x1 + 13)))
            top = (lab == k) & (loc[..., 0] > x0 + 3) & (loc[..., 0] < x1 - 3)
            m = step_height_u(t.xyz[t.valid & band], t.sigma[t.valid & band], t.xyz[t.valid & top], t.sigma[t.valid & top])
            steps.append((m["height_mm"] / h - 1) * 100)
        print(f"{name} {n} {seed} | {f[0]:.3f}/{f[1]:.3f} | {pp[0]:.2f}/{pp[1]:.2f} | "
              f"{rep.rms_px['stereo'] / ref.rms_px['stereo']:.3f} | {form:.4f} / {pl.rms_mm:.4f} | {dr:+.4f} | "
              f"{' '.join(f'{s:+.3f}' for s in steps)} | {ms_u:.0f}/{ms_b:.0f}")


if __name__ == "__main__":
    main()
