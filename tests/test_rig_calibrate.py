"""Projector-camera calibration against the bench's truth (tuning rig and hold-out rigs)."""

from __future__ import annotations

import numpy as np
import pytest
from rig_helpers import BOARD, calibrated, observe
from scipy.spatial import cKDTree

from huefringe.bench.rig import RIGS, pose_set
from huefringe.rig import calibrate_rig, detect_corners, projector_corners
from huefringe.rig.calibrate import refine_corners_fronto_parallel

CASES = [("tune", 8, 1), ("holdout-wide", 6, 7), ("holdout-wide", 10, 3), ("holdout-narrow", 8, 11), ("holdout-narrow", 6, 5)]


@pytest.mark.parametrize(("rig_name", "n_poses", "seed"), CASES)
def test_intrinsics_within_targets(rig_name, n_poses, seed):
    rig, cal, rep, _ = calibrated(rig_name, n_poses, seed)
    truth = rig.calibration
    for K, Kt in ((cal.camera_matrix, truth.camera_matrix), (cal.projector_matrix, truth.projector_matrix)):
        assert abs(K[0, 0] / Kt[0, 0] - 1) < 0.003
        assert abs(K[1, 1] / Kt[1, 1] - 1) < 0.003
        assert np.hypot(K[0, 2] - Kt[0, 2], K[1, 2] - Kt[1, 2]) < 2.0
    assert np.linalg.norm(cal.T - truth.T) / np.linalg.norm(truth.T) < 0.003
    assert rep.rejected == []


@pytest.mark.parametrize(("rig_name", "n_poses", "seed"), CASES)
def test_reprojection_rms_against_ideal_corners(rig_name, n_poses, seed):
    _, _, rep, ref = calibrated(rig_name, n_poses, seed)
    assert rep.rms_px["stereo"] <= 1.2 * ref.rms_px["stereo"]
    assert rep.rms_px["projector"] <= 1.2 * ref.rms_px["projector"]


def test_pose_that_does_not_fit_is_named_and_left_out():
    rig, cal, rep, _ = calibrated("holdout-wide", 8, 3, corrupt=5)
    assert rep.rejected == ["pose05"]
    assert [p["used"] for p in rep.poses].count(False) == 1
    truth = rig.calibration
    assert abs(cal.projector_matrix[0, 0] / truth.projector_matrix[0, 0] - 1) < 0.003


def test_refuses_poses_missing_corners_naming_them():
    rig, obs, _ = observe("tune", 6, 1)
    obs[2].camera = obs[2].camera[:-3]
    with pytest.raises(ValueError, match="pose02: 60 camera"):
        calibrate_rig(obs, BOARD, rig.camera_size, rig.projector_size, outlier_factor=3.0, fix_k3=True, min_poses=4)
    with pytest.raises(ValueError, match="at least 8"):
        calibrate_rig(obs[:1] + obs[3:], BOARD, rig.camera_size, rig.projector_size, outlier_factor=3.0,
                      fix_k3=True, min_poses=8)


def test_corner_detection_on_the_rendered_board():
    rig = RIGS["tune"]
    rng = np.random.default_rng(4)
    R, t = pose_set(rig, BOARD, 1, seed=9)[0]
    p = rig.board_pose(BOARD, R, t, rng, corner_sigma_px=0.0, coord_sigma_px=0.05, image=True)
    img = np.clip(p["image"] + rng.normal(0, 2, p["image"].shape), 0, 255).astype(np.uint8)
    c = detect_corners(img, BOARD)
    assert c is not None and len(c) == len(p["camera_true"])
    err = c[cKDTree(c).query(p["camera_true"])[1]] - p["camera_true"]
    assert np.sqrt(np.mean(np.sum(err**2, axis=1))) < 0.1
    assert detect_corners(np.full_like(img, 128), BOARD) is None


def _homography_maps(h=120, w=160):
    H = np.array([[1.1, 0.05, 100.0], [0.02, 0.95, 50.0], [1e-4, -5e-5, 1.0]])
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    P = np.stack([xx, yy, np.ones_like(xx)], -1) @ H.T
    return H, xx, P[..., 0] / P[..., 2], P[..., 1] / P[..., 2]


def _apply(H, c):
    q = np.column_stack([c, np.ones(len(c))]) @ H.T
    return q[:, :2] / q[:, 2:]


def test_local_homography_exact_and_invalid_pixels_left_out():
    H, xx, U, V = _homography_maps()
    rng = np.random.default_rng(3)
    c = np.column_stack([rng.uniform(2, 158, 40), rng.uniform(2, 118, 40)])     # windows clipped at the borders too
    valid = rng.random(U.shape) > 0.3
    Ub = np.where(valid, U, U + 50.0)                                             # garbage where not valid
    sig = np.where(rng.random(U.shape) > 0.1, 0.05, np.nan)                       # no sigma: left out as well
    Ub = np.where(np.isfinite(sig), Ub, Ub - 70.0)
    p, ok = projector_corners(c, Ub, V, valid, 10, 50, sigma_u=sig, sigma_v=sig)
    assert ok.all()
    assert np.abs(p - _apply(H, c)).max() < 1e-8
    p, ok = projector_corners([[80.0, 60.0]], U, V, np.zeros_like(valid), 10, 50)
    assert not ok.any() and np.isnan(p).all()


def test_weighted_local_homography_beats_unweighted_when_half_the_window_is_noisy():
    H, xx, U, V = _homography_maps()
    rng = np.random.default_rng(5)
    sig = np.where(xx < 80, 0.02, 0.3)                # the window's right half decodes with 15 x the noise
    Un, Vn = U + rng.normal(0, 1, U.shape) * sig, V + rng.normal(0, 1, U.shape) * sig
    c = np.column_stack([80.0 + rng.uniform(-0.5, 0.5, 60), rng.uniform(15, 105, 60)])
    valid = np.ones(U.shape, dtype=bool)
    t = _apply(H, c)
    pw, ok_w = projector_corners(c, Un, Vn, valid, 10, 50, sigma_u=sig, sigma_v=sig)
    pu, ok_u = projector_corners(c, Un, Vn, valid, 10, 50)
    assert ok_w.all() and ok_u.all()
    ew, eu = (np.sqrt(np.mean(np.sum((p - t) ** 2, axis=1))) for p in (pw, pu))
    # inverse-variance weights: about the error of the quiet half alone (0.02 px over ~220 pixels,
    # a 6-parameter-ish fit extrapolated to the window's edge); equal weights: the noisy half's
    assert ew < 0.01, ew
    assert ew < 0.4 * eu, (ew, eu)
    # equal sigmas weigh alike: the same fit as no sigma
    p1, _ = projector_corners(c, Un, Vn, valid, 10, 50, sigma_u=np.full(U.shape, 0.1), sigma_v=np.full(U.shape, 0.1))
    assert np.abs(p1 - pu).max() < 1e-9


def test_fronto_parallel_refinement_removes_the_detector_bias_on_tilted_boards():
    # the detector's corners on tilted boards carry a bias shared by each pose's corners (a shift
    # and a scale of the grid); found again in the board's fronto-parallel view, with the rig's
    # model, they lie on the true corners
    rig = RIGS["holdout-wide"]
    rng = np.random.default_rng(5)
    cal = rig.calibration
    before, after = [], []
    for R, t in pose_set(rig, BOARD, 8, seed=4):
        p = rig.board_pose(BOARD, R, t, rng, corner_sigma_px=0.0, coord_sigma_px=0.05, image=True)
        img = np.clip(p["image"] + rng.normal(0, 1, p["image"].shape), 0, 255).astype(np.uint8)
        c = detect_corners(img, BOARD)
        truth = p["camera_true"][cKDTree(p["camera_true"]).query(c)[1]]
        r = refine_corners_fronto_parallel(img, c, BOARD, cal.camera_matrix, cal.camera_distortion)
        assert r is not None and r.shape == c.shape
        before.append((c - truth).mean(axis=0))
        after.append((r - truth).mean(axis=0))
        assert np.sqrt(np.mean(np.sum((r - truth) ** 2, axis=1))) < 0.03
    # each pose's own shift of its grid (about the poses' common one, which a board pose absorbs)
    spread = [np.sqrt(np.mean(np.sum((np.array(m) - np.mean(m, axis=0)) ** 2, axis=1))) for m in (before, after)]
    print(spread)
    assert spread[1] < 0.5 * spread[0]


def test_fronto_parallel_refinement_refuses_a_wrong_board():
    rig = RIGS["tune"]
    R, t = pose_set(rig, BOARD, 1, seed=9)[0]
    p = rig.board_pose(BOARD, R, t, np.random.default_rng(1), corner_sigma_px=0.0, coord_sigma_px=0.05, image=True)
    c = detect_corners(p["image"], BOARD)
    cal = rig.calibration
    assert refine_corners_fronto_parallel(np.full_like(p["image"], 128), c, BOARD, cal.camera_matrix,
                                          cal.camera_distortion) is None


@pytest.mark.slow
def test_refined_corners_remove_the_shared_depth_bias_of_a_printed_board_session(tmp_path):
    # the demo's calibration session (holdout-wide rig, pose seed 4): the detector's corners put
    # every point ~0.2 mm too far along its ray (camera focal length +0.6 px, every pose agreeing);
    # refined in fronto-parallel views the calibration lands on the truth
    from huefringe.bench import load_sl_bench_config, write_sl_session
    from huefringe.rig.measure import calibrate_sl_session
    from huefringe.rig.triangulation import camera_rays, triangulate
    from huefringe.session import load_sl_session
    from huefringe.settings import load_config

    cfg = load_sl_bench_config("rig-poses")
    write_sl_session(cfg, tmp_path / "rig-poses")
    s = load_sl_session(tmp_path / "rig-poses")
    rig = RIGS[cfg["rig"]]
    yy, xx = np.mgrid[20:460:20, 20:620:20]
    pix = np.column_stack([xx.ravel(), yy.ravel()]).astype(float)
    d = camera_rays(rig.calibration, pix)
    X = d * (430.0 / d[:, 2:3])
    uv = rig.to_projector(X)
    ray = X / np.linalg.norm(X, axis=1, keepdims=True)
    bias = {}
    for rounds in (0, 1):
        conf = load_config({"codecs": {"noise": {"read_dn": 1.0, "full_well_e": None}},
                            "rig": {"corner_refinement_rounds": rounds}})
        run = calibrate_sl_session(s, conf)
        t = triangulate(run.calibration, uv[:, 0], uv[:, 1], pixels=pix, mode="both")
        bias[rounds] = float(np.nanmean(np.einsum("ij,ij->i", t.xyz - X, ray)))
        if rounds:
            assert run.report.corner_refinement["not_refined"] == []
            assert abs(run.calibration.camera_matrix[0, 0] - rig.camera_f) < 0.2
    assert bias[0] > 0.15
    assert abs(bias[1]) < 0.04
