"""Shared bench setup of the rig tests: calibrate a bench rig from its board poses."""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from huefringe.bench.rig import RIGS, pose_set
from huefringe.rig import Board, PoseObservation, calibrate_rig, projector_corners

BOARD = Board(9, 7, 12.0)
CORNER_SIGMA_PX = 0.03      # corner detection noise per axis (findChessboardCornersSB on the bench board with 2 DN noise: 0.02-0.04 px RMS in 2-D)
COORD_SIGMA_PX = 0.05       # decoded projector coordinate noise (N-step, 8 bit)
HALF_WINDOW_PX = 10
MIN_PIXELS = 50


def observe(rig_name: str, n_poses: int, seed: int, corrupt: int | None = None):
    """Board poses of a bench rig: observations, and the reference (ideal projector corners)."""
    rig = RIGS[rig_name]
    rng = np.random.default_rng(seed + 100)
    obs, ideal = [], []
    for i, (R, t) in enumerate(pose_set(rig, BOARD, n_poses, seed=seed)):
        p = rig.board_pose(BOARD, R, t, rng, corner_sigma_px=CORNER_SIGMA_PX, coord_sigma_px=COORD_SIGMA_PX)
        if i == corrupt:            # a pose whose codes were decoded one fringe-order step off on part of the board
            p["u"][:, : p["u"].shape[1] // 2] += 4.0
        pc, _ = projector_corners(p["camera"], p["u"], p["v"], p["valid"], HALF_WINDOW_PX, MIN_PIXELS,
                                  sigma_u=p["sigma"], sigma_v=p["sigma"])
        obs.append(PoseObservation(f"pose{i:02d}", p["camera"], pc))
        # the ideal local homography: the exact projector pixel at the (noisy) detected camera corner
        d = np.column_stack([cv2.undistortPoints(p["camera"].reshape(-1, 1, 2), rig.calibration.camera_matrix,
                                                 rig.calibration.camera_distortion, None, None, None,
                                                 (3, 300, 1e-15)).reshape(-1, 2), np.ones(len(p["camera"]))])
        n = R[:, 2]
        xyz = d * ((n @ t) / (d @ n))[:, None]
        ideal.append(PoseObservation(f"pose{i:02d}", p["camera"], rig.to_projector(xyz)))
    return rig, obs, ideal


@lru_cache(maxsize=None)
def calibrated(rig_name: str, n_poses: int, seed: int, corrupt: int | None = None):
    rig, obs, ideal = observe(rig_name, n_poses, seed, corrupt)
    kw = dict(outlier_factor=3.0, fix_k3=True, min_poses=4)
    cal, rep = calibrate_rig(obs, BOARD, rig.camera_size, rig.projector_size, **kw)
    _, ref = calibrate_rig(ideal, BOARD, rig.camera_size, rig.projector_size, **kw)
    return rig, cal, rep, ref


SL_SEQUENCE = {"projector": {"width": 800, "height": 600}, "frames": "cap_*.png", "blocks": [
    {"phase": {"axis": "x", "period_px": 16, "steps": 4}}, {"gray": {"axis": "x", "cells": 50, "cell_px": 16}},
    {"phase": {"axis": "y", "period_px": 16, "steps": 4}}, {"gray": {"axis": "y", "cells": 38, "cell_px": 16}},
    "white", "black"]}
"""The rig tests' sequence: four-step phase and Gray code (with inverses) on both projector axes (34 frames)."""

SL_RIG = "holdout-wide"
SL_BASE = ((20, 20, 620, 130), (20, 360, 620, 460))
"""Camera-pixel boxes on the steps scene's base plane (above and below the blocks) on ``SL_RIG``."""
SL_TOPS = {2.0: (150, 175, 225, 315), 5.0: (290, 175, 360, 315), 10.0: (425, 180, 495, 315)}
"""Camera-pixel boxes on the top of each block of the steps scene (height mm -> box) on ``SL_RIG``."""


def write_rig_captures(root, sequence: dict | None = None, n_poses: int = 6, seed: int = 4) -> dict[str, object]:
    """Bench-rig captures as a lab writes them: ``root/poses/pose_NN/cap_NN.png`` (a printed
    9 x 7 board of 12 mm squares, the sequence only), ``root/board/`` (a flat board seen whole)
    and ``root/steps/`` (blocks of 2, 5 and 10 mm on a base plane), ``root/sequence.yaml``
    (``sequence``, default :data:`SL_SEQUENCE`)."""
    from pathlib import Path

    import yaml

    from huefringe.bench.rig import PlaneScene, StepsScene, write_captures, write_pose_folders
    from huefringe.codecs import load_sequence

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    (root / "sequence.yaml").write_text(yaml.safe_dump(sequence or SL_SEQUENCE, sort_keys=False))
    spec = load_sequence(root / "sequence.yaml")
    rig = RIGS[SL_RIG]
    write_pose_folders(rig, BOARD, spec, n_poses, seed, root / "poses", corner_image=False, printed=True)
    for name, scene, s in (("board", PlaneScene(point=(0.0, 0.0, 430.0)), 1), ("steps", StepsScene(), 2)):
        xyz, ok = scene.cast(rig.rays)[:2]
        m = rig.coordinates(xyz, ok, np.random.default_rng(s), 0.0)
        write_captures(rig, spec, root / name, m["u_true"], m["v_true"], m["valid"], np.random.default_rng(s + 10))
    return {"rig": rig, "spec": spec}
