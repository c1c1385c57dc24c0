"""The calibrated field of a rig calibration, and a flat board's form inside and outside it (bench truth)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from huefringe.bench.oneshot import BOARD, calibrated_rig_report
from huefringe.bench.rig import RIGS, PlaneScene, pose_set
from huefringe.rig import PoseObservation, calibrated_field, field_mask
from huefringe.rig.triangulation import triangulate

WIDE = (0.14, 0.11)


def _form_rms(p: np.ndarray) -> float:
    c = p.mean(axis=0)
    n = np.linalg.svd(p - c, full_matrices=False)[2][-1]
    return float(np.sqrt(np.mean(((p - c) @ n) ** 2)))


@pytest.fixture(scope="module")
def board_view():
    """Noise-free projector columns of a flat board filling the holdout-wide rig's view (13 px clear of its edges)."""
    rig = RIGS["holdout-wide"]
    sc = PlaneScene(point=(0.0, 0.0, 426.0), tilt_deg=(6.0, -5.0))
    xyz, seen = sc.cast(rig.rays)
    m = rig.coordinates(xyz, sc.lit(rig, xyz, seen), np.random.default_rng(0), 0.0)
    ok = cv2.erode(m["valid"].astype(np.uint8), np.ones((13, 13), np.uint8)).astype(bool)
    return m["u_true"], ok


def test_calibrated_field_is_the_union_of_the_poses_corner_hulls() -> None:
    rig = RIGS["holdout-wide"]
    w, h = rig.camera_size
    obj = BOARD.object_points().astype(np.float64)
    poses = [PoseObservation(f"p{i}", rig.to_camera(obj @ R.T + t), rig.to_camera(obj @ R.T + t))
             for i, (R, t) in enumerate(pose_set(rig, BOARD, 6, seed=7))]
    f = calibrated_field(poses, (w, h))
    mask = field_mask(f, (h, w))
    assert f["image_fraction"] == pytest.approx(mask.mean(), abs=1e-4)
    near = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)   # a hull's edge pixel
    for p in poses:                                   # every corner inside, and each pose's own hull alone
        c = np.round(p.camera).astype(int)
        assert near[c[:, 1], c[:, 0]].all()
        one = field_mask({"hulls_px": [f["hulls_px"][int(p.name[1:])]]}, (h, w))
        assert one.sum() <= mask.sum() and (one & ~mask).sum() == 0
    # boards near the middle of the image leave most of it to the extrapolated lens model
    assert 0.25 < f["image_fraction"] < 0.45
    assert not mask[:20, :20].any() and not mask[-20:, -20:].any()
    assert field_mask({}, (h, w)).sum() == 0


def test_flat_board_form_is_the_distortion_extrapolated_outside_the_calibrated_field(board_view) -> None:
    """Pose seed 5, 8 boards near the image's middle: a flat board's form is 54 um over the whole
    view and 2.6 um inside the poses' field; the same poses spread over the field (wider aims)
    bring the whole view within 0.02 mm. The coordinates are the true ones: every error is the
    calibration's."""
    u, ok = board_view
    rig = RIGS["holdout-wide"]
    h, w = ok.shape
    cal, _, report = calibrated_rig_report(n_poses=8, seed=5)
    field = field_mask(report.calibrated_field, (h, w))
    t = triangulate(cal, u=u, valid=ok, mode="u")
    v = t.valid & ok
    whole, inside = _form_rms(t.xyz[v]), _form_rms(t.xyz[v & field])
    assert whole > 0.03 and inside < 0.005, (whole, inside)
    assert report.calibrated_field["image_fraction"] < 0.4
    # the true calibration: flat to the float precision
    tt = triangulate(rig.calibration, u=u, valid=ok, mode="u")
    assert _form_rms(tt.xyz[tt.valid & ok]) < 1e-4
    cal_w, _, report_w = calibrated_rig_report(n_poses=8, seed=5, aim=WIDE)
    tw = triangulate(cal_w, u=u, valid=ok, mode="u")
    assert report_w.calibrated_field["image_fraction"] > report.calibrated_field["image_fraction"] + 0.05
    assert _form_rms(tw.xyz[tw.valid & ok]) < 0.02


def test_phase_filter_on_the_offset_from_the_reference() -> None:
    """The plane route's phase filter on a one-shot frame (its offset from the reference), weighted
    by the capture's noise read from the smoothed signal: with the rig's true calibration the
    gauge's median error along the ray falls from 28.5 to 7.4 um, the steps stay within 0.3 %, and
    sigma (the frame's own noise through the filter's weights, the reference's own and the table's
    interpolation term in the bin of the pixel's code phase, without the table's noise) holds the
    errors, on the safe side (0.954 unfiltered, 0.986 filtered of the pixels within 2 sigma)."""
    from huefringe.bench.oneshot import face_mask, gauge_scene, render_session
    from huefringe.metrology import step_height_u
    from huefringe.rig.oneshot import filter_against_reference, hue_table_from_frames, measure_oneshot, oneshot_reference
    from huefringe.settings import defaults

    m = defaults()["measurement"]
    cap = render_session(gauge_scene(), n_bands=48, repeats=2, seed=1)
    table = hue_table_from_frames(cap.white, cap.bands, cap.bands_block)
    cal = RIGS["holdout-wide"].calibration
    ref = oneshot_reference(cap.reference, cal, cap.block)
    out = {}
    for r in (0, int(m["denoise_radius"])):
        res = measure_oneshot(cap.frames[0], cap.white, table, cap.block, cal, ref, denoise_radius=r,
                              denoise_adaptive=m["denoise_adaptive"])
        ok = res.valid & np.isfinite(cap.truth_xyz).all(axis=-1)
        t = cap.truth_xyz[ok]
        e = np.abs(np.einsum("ij,ij->i", res.xyz[ok] - t, t / np.linalg.norm(t, axis=-1, keepdims=True)))
        out[r] = (res, ok, float(np.median(e)), float(np.mean(e <= 2 * res.sigma_ray[ok])))
    (r0, ok0, med0, cov0), (rf, okf, medf, covf) = out[0], out[int(m["denoise_radius"])]
    assert okf.sum() >= 0.999 * ok0.sum()                       # the adaptive filter rejects next to nothing
    assert medf < 0.35 * med0 and medf < 0.010, (med0, medf)
    assert abs(cov0 - 0.95) <= 0.03 and 0.95 <= covf <= 0.99, (cov0, covf)
    base = face_mask(cap, 0) & rf.valid
    for k, h0 in ((1, 3.0), (2, 1.0), (3, 4.0)):
        top = face_mask(cap, k) & rf.valid
        s = step_height_u(rf.xyz[base], rf.sigma[base], rf.xyz[top], rf.sigma[top])
        assert abs(s["height_mm"] - h0) <= 0.003 * h0, (k, s)
    ph = r0.phase
    assert filter_against_reference(ph, ref, cap.block, radius=0) is ph
