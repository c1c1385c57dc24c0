"""The camera block of session.yaml (pinhole / telecentric with distortion) and X, Y from it:
analytic cases against OpenCV's own projection."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from huefringe.camera import CameraModel
from huefringe.session import SessionError, read_meta
from session_factory import make_session

K = [[800.0, 0.0, 321.3], [0.0, 801.0, 238.7], [0.0, 0.0, 1.0]]
DIST = [-0.12, 0.05, 4e-4, -3e-4, 0.0]
POSE = {"rvec": [0.03, -0.02, 0.01], "tvec": [-64.0, -48.0, 300.0]}  # plate 300 mm away, slightly tilted


def pinhole_meta(dist=DIST, **extra):
    cam = {"width": 640, "height": 480, "bit_depth": 8, "pixel_pitch_mm": 0.2, "model": "pinhole",
           "matrix": K, "distortion": dist, "plate_pose": POSE}
    cam.update(extra)
    return {"camera": cam}


def project(points_board: np.ndarray, dist=DIST) -> np.ndarray:
    uv, _ = cv2.projectPoints(points_board.reshape(-1, 1, 3), np.array(POSE["rvec"]), np.array(POSE["tvec"]),
                              np.array(K), np.array(dist))
    return uv.reshape(-1, 2)


@pytest.mark.parametrize("h", [0.0, 5.0, -2.5, 17.0])
def test_pinhole_xy_inverts_opencvs_projection(h: float) -> None:
    """A point at height h at plate (X, Y) is board point (X, Y, -h): projected by OpenCV with
    distortion, xy_at gives it back to 1e-6 mm."""
    model = CameraModel.from_meta(pinhole_meta())
    rng = np.random.default_rng(1)
    xy = np.column_stack([rng.uniform(-60, 185, 400), rng.uniform(-45, 140, 400)])
    uv = project(np.column_stack([xy, np.full(len(xy), -h)]))
    inside = (uv[:, 0] > -0.5) & (uv[:, 0] < 639.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < 479.5)
    assert inside.sum() > 200
    x, y = model.xy_at(uv[inside, 0], uv[inside, 1], h)
    assert np.max(np.abs(x - xy[inside, 0])) < 1e-6
    assert np.max(np.abs(y - xy[inside, 1])) < 1e-6


def test_pinhole_xy_map_each_pixel_at_its_own_height() -> None:
    """xy(height map) = xy_at of each pixel at its own height; a flat plane at 5 mm projects back
    onto every pixel centre (1e-6 px), NaN heights give NaN."""
    model = CameraModel.from_meta(pinhole_meta())
    rng = np.random.default_rng(2)
    height = rng.uniform(0, 20, (480, 640))
    height[10:20, 30:40] = np.nan
    x, y = model.xy(height)
    v, u = np.mgrid[0:480, 0:640]
    x2, y2 = model.xy_at(u, v, height)
    np.testing.assert_array_equal(x, x2)
    np.testing.assert_array_equal(y, y2)
    assert np.isnan(x[15, 35]) and np.isnan(y[15, 35])
    flat = np.full((480, 640), 5.0)
    x, y = model.xy(flat)
    uv = project(np.column_stack([x.ravel(), y.ravel(), -flat.ravel()]))
    assert np.max(np.abs(uv[:, 0] - u.ravel())) < 1e-6
    assert np.max(np.abs(uv[:, 1] - v.ravel())) < 1e-6


def test_telecentric_is_u_times_pitch_exactly() -> None:
    model = CameraModel.from_meta({"camera": {"width": 64, "height": 48, "bit_depth": 8, "pixel_pitch_mm": 0.2}})
    assert model.plain
    h = np.zeros((48, 64), np.float32)
    x, y = model.xy(h)
    v, u = np.mgrid[0:48, 0:64]
    np.testing.assert_array_equal(x, u * 0.2)
    np.testing.assert_array_equal(y, v * 0.2)
    # the lens ignored on request: camera.lens_model false
    off = CameraModel.from_meta(pinhole_meta(), lens_model=False)
    assert off.plain and off.pitch_mm == 0.2


def test_telecentric_distortion_in_plate_millimetres() -> None:
    """Telecentric with distortion and no matrix: the coefficients act on plate millimetres about
    the image centre, X = u' pitch with (u', v') the undistorted pixel."""
    pitch, d = 0.2, [1e-4, 0.0, 0.0, 0.0]
    model = CameraModel.from_meta({"camera": {"width": 65, "height": 49, "bit_depth": 8, "pixel_pitch_mm": pitch,
                                              "distortion": d}})
    assert not model.plain
    # a true plate point 4 mm right of the centre is imaged at r (1 + k1 r^2) mm
    r_true = 4.0
    r_img = r_true * (1 + 1e-4 * r_true**2)
    x, y = model.xy_at(32 + r_img / pitch, 24.0, 7.0)  # heights do not move a telecentric camera's X
    assert abs(x - (32 * pitch + r_true)) < 1e-9 and abs(y - 24 * pitch) < 1e-9
    zero = CameraModel.from_meta({"camera": {"width": 65, "height": 49, "bit_depth": 8, "pixel_pitch_mm": pitch,
                                             "distortion": [0.0, 0.0, 0.0, 0.0, 0.0]}})
    assert zero.plain


def test_heights_need_no_resampling_mobius() -> None:
    """Pinhole camera (with distortion) and pinhole projector: along one camera ray the projector
    column is a Moebius function of h, so h = dphi / (a + b dphi) holds exactly per pixel with a, b
    from two planes (the model huefringe fits), at any third height."""
    model = CameraModel.from_meta(pinhole_meta())
    kp = np.array([[1000.0, 0, 400], [0, 1000.0, 300], [0, 0, 1]])
    rp, tp = np.array([0.02, -0.35, 0.01]), np.array([-160.0, -50.0, 330.0])  # projector 20 deg off axis
    period = 24.0

    def phase(u, v, h):
        x, y = model.xy_at(u, v, h)
        pts = np.column_stack([x, y, np.full(x.size, -h)])
        up, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), rp, tp, kp, None)
        return 2 * np.pi * up.reshape(-1, 2)[:, 0] / period

    rng = np.random.default_rng(3)
    u, v = rng.uniform(0, 639, 300), rng.uniform(0, 479, 300)
    p0 = phase(u, v, 0.0)
    d1, d2 = phase(u, v, 4.0) - p0, phase(u, v, 8.0) - p0
    # a + b dphi_i = dphi_i / h_i, two planes -> a, b per pixel
    b = (d1 / 4.0 - d2 / 8.0) / (d1 - d2)
    a = d1 / 4.0 - b * d1
    for h in (-3.0, 2.0, 13.0, 25.0):
        d = phase(u, v, h) - p0
        assert np.max(np.abs(d / (a + b * d) - h)) < 1e-9 * max(1.0, abs(h))
    assert np.max(np.abs(b)) > 1e-4  # not trivially linear: the perspective term is there


# --------------------------------------------------------------------------- session checks


def _with_camera(tmp_path: Path, **cam) -> Path:
    root = make_session(tmp_path / "s")
    meta = yaml.safe_load((root / "session.yaml").read_text())
    meta["camera"].update(cam)
    (root / "session.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return root


def test_plain_session_still_reads(tmp_path: Path) -> None:
    meta = read_meta(make_session(tmp_path / "s"))
    assert CameraModel.from_meta(meta).plain


def test_pinhole_block_reads(tmp_path: Path) -> None:
    cam = pinhole_meta()["camera"]
    root = _with_camera(tmp_path, **{k: cam[k] for k in ("model", "matrix", "distortion", "plate_pose")})
    model = CameraModel.from_meta(read_meta(root))
    assert model.kind == "pinhole" and model.centre == (321.3, 238.7)


@pytest.mark.parametrize("cam, words", [
    ({"model": "pinhole", "plate_pose": POSE}, ["camera/matrix", "missing", "pinhole"]),
    ({"model": "pinhole", "matrix": K}, ["camera/plate_pose", "missing"]),
    ({"distortion": [0.1, 0.0, 0.0]}, ["camera/distortion", "4, 5, 8, 12 or 14", "got 3"]),
    ({"distortion": [0.1, 0.0, 0.0, 0.0, 0.0, 0.0]}, ["camera/distortion", "got 6"]),
    ({"matrix": [[800.0, 0.0, 300.0], [0.0, 800.0, 200.0], [0.0, 0.1, 1.0]]}, ["camera/matrix", "[0, 0, 1]"]),
    ({"matrix": [[800.0, 0.0, 300.0], [0.0, 800.0, 200.0]]}, ["camera/matrix"]),
    ({"matrix": [[800.0, 0.0, float("nan")], [0.0, 800.0, 200.0], [0.0, 0.0, 1.0]]}, ["camera/matrix", "not finite"]),
    ({"distortion": [0.1, float("inf"), 0.0, 0.0]}, ["camera/distortion", "not finite"]),
    ({"model": "fisheye"}, ["camera/model"]),
    ({"plate_pose": POSE}, ["camera/plate_pose", "only a pinhole"]),
    ({"model": "pinhole", "matrix": K, "plate_pose": {"rvec": [0, 0, 0]}}, ["camera/plate_pose", "tvec"]),
])
def test_bad_camera_block_is_refused_naming_the_key(tmp_path: Path, cam: dict, words: list[str]) -> None:
    root = _with_camera(tmp_path, **cam)
    with pytest.raises(SessionError) as err:
        read_meta(root)
    text = str(err.value)
    assert "session.yaml" in text
    for w in words:
        assert w in text, text


def test_xy_ground_truth_is_read_checked_and_scored(tmp_path: Path) -> None:
    """ground_truth/xy/frame_NNNN.tiff (float32 (H, W, 2)) is part of the session, a wrong shape
    is refused naming the file, and xy_accuracy scores all pixels and the corners."""
    import tifffile

    from huefringe.height import xy_accuracy
    from huefringe.session import load_session

    root = make_session(tmp_path / "s")  # 32 x 24
    gt = root / "ground_truth" / "xy"
    gt.mkdir(parents=True)
    v, u = np.mgrid[0:24, 0:32].astype(np.float32)
    truth = np.stack([u * 0.2, v * 0.2], -1).astype(np.float32)
    truth[0, 0] = np.nan
    tifffile.imwrite(gt / "frame_0000.tiff", truth)
    s = load_session(root)
    assert set(s.ground_truth_xy) == {0} and gt / "frame_0000.tiff" in s.input_files()
    x, y = CameraModel.from_meta(s.meta).xy(np.zeros((24, 32), np.float32))
    x[23, 31] += 0.03  # a corner pixel off by 30 um
    a = xy_accuracy(x, y, truth)
    assert a["pixels"] == 24 * 32 - 1 and abs(a["max_mm"] - 0.03) < 1e-6 and abs(a["corner_max_mm"] - 0.03) < 1e-6
    assert 0 < a["corner_pixels"] < 40
    tifffile.imwrite(gt / "frame_0001.tiff", truth[..., 0])
    with pytest.raises(SessionError) as err:
        load_session(root)
    assert "frame_0001.tiff" in str(err.value) and "x 2" in str(err.value)
