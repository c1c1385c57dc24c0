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
        pc, _ = projector_corners(p["camera"], p["u"], p["v"], p["valid"], HALF_WINDOW_PX, MIN_PIXELS)
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
