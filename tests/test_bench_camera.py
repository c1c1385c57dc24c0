"""The bench's cameras: single-chip Bayer sensor, lateral chromatic aberration, OpenCV
radial distortion and the pinhole (entocentric) camera, checked against analytic geometry and
OpenCV's own forward model."""

from __future__ import annotations

import copy

import cv2
import numpy as np
import pytest
import tifffile
import yaml

from huefringe import bench
from huefringe.bench.lens import Lens
from huefringe.bench.radiometry import Pattern, Rig, camera_response
from huefringe.phase import three_step_phase


def _cfg(preset: str = "flat", camera: dict | None = None, **session: object) -> dict:
    cfg = copy.deepcopy(bench.load_bench_config(preset))
    cfg["session"].update({"width": 96, "height": 72, "frames": 1, **session})
    cfg["camera"].update(camera or {})
    return bench.validate_bench_config(cfg)


def _ideal_optics(cfg: dict) -> dict:
    """No blur, no noise, no pixelation, a 16-bit DMD and camera: only the geometry is left."""
    cfg = copy.deepcopy(cfg)
    cfg["session"]["bit_depth"] = 16
    cfg["camera"].update({"lens_blur_sigma_px": 0.0, "full_well_e": None, "read_noise_dn": 0.0,
                          "crosstalk": np.eye(3).tolist(), "sensitivity": 1.0})
    cfg["projector"].update({"dmd_bits": 16, "pixel_mm": None, "defocus_sigma_px": 0.0})
    cfg["phase_shift"].update({"gamma_error": 0.0, "gamma_estimate": None})
    cfg["light"].update({"ambient": 0.0, "stray": 0.0})
    return bench.validate_bench_config(cfg)


# ------------------------------------------------------------------ pinhole geometry
def test_pinhole_flat_board_sees_the_projective_point() -> None:
    """A flat board at height h seen by the pinhole camera: the ground-truth X, Y of every pixel is
    the central projection X = Xc + (u - cx) pitch (Zc - h) / Zc (and Y alike), its height h."""
    zc, h = 300.0, 2.0
    cfg = _cfg(camera={"model": "pinhole", "working_distance_mm": zc})
    cfg["scene"]["height_mm"] = h
    b = bench.Bench(cfg)
    gt_h, xy = b.view_truth(None)
    pitch = cfg["session"]["pixel_pitch_mm"]
    w, hh = cfg["session"]["width"], cfg["session"]["height"]
    cx, cy = (w - 1) / 2, (hh - 1) / 2
    v, u = np.mgrid[0:hh, 0:w].astype(np.float64)
    x_expect = cx * pitch + (u - cx) * pitch * (zc - h) / zc
    y_expect = cy * pitch + (v - cy) * pitch * (zc - h) / zc
    assert np.max(np.abs(xy[..., 0] - x_expect)) < 1e-4
    assert np.max(np.abs(xy[..., 1] - y_expect)) < 1e-4
    np.testing.assert_allclose(gt_h, h, atol=1e-5)
    # the raised board is magnified: its corner pixel sees 2/300 of the half field less far out
    assert xy[0, 0, 0] == pytest.approx(cx * pitch * h / zc, abs=1e-4)


def test_pinhole_session_block_reprojects_the_ground_truth_onto_the_pixels() -> None:
    """session.yaml's camera block holds the true lens: cv2.projectPoints of every pixel's true
    board point (X, Y, -h) with its matrix, distortion and plate_pose lands on the pixel centre
    (gauge blocks: rays meeting block tops, walls and the base; distortion included)."""
    cfg = _cfg("plain_gauge", camera={"model": "pinhole", "working_distance_mm": 300.0,
                                      "distortion": [-0.25, 0.1, 1e-4, -2e-4, 0.0], "supersample": 1},
               width=320, height=240)
    b = bench.Bench(cfg)
    doc = bench.session_document(cfg, b)
    cam = doc["camera"]
    assert cam["model"] == "pinhole"
    k = np.asarray(cam["matrix"])
    assert k[0, 0] == pytest.approx(300.0 / cfg["session"]["pixel_pitch_mm"])
    gt_h, xy = b.view_truth(None)
    assert np.isfinite(gt_h).all() and float(np.nanmax(gt_h)) > 4.0  # the 4 mm block is seen
    pts = np.stack([xy[..., 0], xy[..., 1], -gt_h], axis=-1).reshape(-1, 3).astype(np.float64)
    img, _ = cv2.projectPoints(pts, np.asarray(cam["plate_pose"]["rvec"], float),
                               np.asarray(cam["plate_pose"]["tvec"], float), k, np.asarray(cam["distortion"]))
    v, u = np.mgrid[0:240, 0:320]
    err = np.hypot(img[:, 0, 0] - u.ravel(), img[:, 0, 1] - v.ravel())
    # float32 ground truth: 1e-5 mm is 5e-5 px at 0.25 mm pitch
    assert float(err.max()) < 1e-3
    # without distortion on the reference plane the origin is pixel (0, 0): X = u pitch
    lens = Lens("pinhole", 320, 240, 0.25, 300.0)
    x, y = lens.plate_xy(np.array([0.0, 319.0]), np.array([0.0, 239.0]), 0.0)
    np.testing.assert_allclose(x, [0.0, 319 * 0.25], atol=1e-12)
    np.testing.assert_allclose(y, [0.0, 239 * 0.25], atol=1e-12)


# ------------------------------------------------------------------ distortion
@pytest.mark.parametrize("kind,dist", [("pinhole", [-0.3, 0.12, 2e-4, -1e-4, 0.01]),
                                       ("telecentric", [4e-6, -1e-10, 1e-5, -1e-5, 0.0])])
def test_distortion_is_opencvs_and_undistort_points_removes_it(kind: str, dist: list[float]) -> None:
    """The bench applies OpenCV's distortion model: the undistorted position the bench gives each
    pixel projects back onto that pixel through cv2.projectPoints (1e-6 px), and cv2.undistortPoints
    (default criteria, as a lab would call it) of the pixel returns it within 1e-3 px."""
    lens = Lens(kind, 320, 240, 0.25, 300.0 if kind == "pinhole" else None, np.asarray(dist))
    v, u = np.mgrid[0:240:7, 0:320:7].astype(np.float64)
    ui, vi = lens.ideal_pixels(u, v)
    shift = np.hypot(ui - u, vi - v)
    assert float(shift.max()) > 1.0  # a real distortion: more than a pixel at the corners
    ud, vd = lens.distorted_pixels(ui, vi)
    assert float(np.max(np.hypot(ud - u, vd - v))) < 1e-6
    k = lens.matrix
    pts = np.stack([u.ravel(), v.ravel()], axis=-1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(pts, k, np.asarray(dist), P=k).reshape(-1, 2)
    assert float(np.max(np.hypot(und[:, 0] - ui.ravel(), und[:, 1] - vi.ravel()))) < 1e-3


def test_telecentric_distortion_ground_truth_and_session_block() -> None:
    """Telecentric with distortion: pixel (u, v) sees X = u' pitch, Y = v' pitch of its undistorted
    position u' (cv2.undistortPoints with the written matrix, fx = 1 / pitch)."""
    dist = [4e-6, 0.0, 0.0, 0.0, 0.0]
    cfg = _cfg(camera={"distortion": dist}, width=160, height=120)
    b = bench.Bench(cfg)
    cam = bench.session_document(cfg, b)["camera"]
    pitch = cfg["session"]["pixel_pitch_mm"]
    assert cam["model"] == "telecentric" and cam["distortion"] == dist
    np.testing.assert_allclose(np.asarray(cam["matrix"]), [[1 / pitch, 0, 79.5], [0, 1 / pitch, 59.5], [0, 0, 1]])
    _, xy = b.view_truth(None)
    v, u = np.mgrid[0:120, 0:160].astype(np.float64)
    k = np.asarray(cam["matrix"])
    und = cv2.undistortPoints(np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2), k, np.asarray(dist), P=k,
                              criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)).reshape(-1, 2)
    assert float(np.max(np.abs(xy[..., 0].ravel() - und[:, 0] * pitch))) < 1e-4
    assert float(np.max(np.abs(xy[..., 1].ravel() - und[:, 1] * pitch))) < 1e-4
    # positive k1 (pincushion): the corner pixel sees a point nearer the centre
    # (k1 r^3 = 4e-6 x 19.9^3 = 0.032 mm radially at the corner of this 32 x 24 mm field)
    assert float(np.hypot(xy[0, 0, 0], xy[0, 0, 1])) == pytest.approx(4e-6 * np.hypot(79.5, 59.5) ** 3 * pitch ** 3, rel=0.01)


# ------------------------------------------------------------------ chromatic aberration
@pytest.mark.parametrize("ca", [(0.5, -0.3), (-0.2, 0.6)])
def test_lateral_ca_at_the_corners_equals_the_configured_value(ca: tuple[float, float]) -> None:
    """The R and B images lie the configured distance further out than G at the image corners:
    measured from the fringe phase of the three phase-shift captures of the reference plate, per
    channel (the displacement along the fringes' direction, scaled to the radius), within 0.01 px."""
    cfg = _ideal_optics(_cfg(camera={"lateral_ca_px": list(ca)}, width=160, height=120, period_px=24))
    b = bench.Bench(cfg)
    caps = [b.capture(Pattern.phase_shift(s), plane_z=0.0).astype(np.float64) for s in range(3)]
    phi = [three_step_phase(*(c[..., k] for c in caps))[0].astype(np.float64) for k in range(3)]
    k_px = 2 * np.pi / cfg["session"]["period_px"]
    cx, cy = 79.5, 59.5
    r_c = np.hypot(cx, cy)
    for v, u in ((0, 0), (0, 159), (119, 0), (119, 159)):
        for ch, want in ((0, ca[0]), (2, ca[1])):
            # channel(p) = G(p - d): phi_ch(p) = phi_G(p) - k d_x
            dphi = np.angle(np.exp(1j * (phi[1][v, u] - phi[ch][v, u])))
            d_x = dphi / k_px
            radial = d_x * r_c / (u - cx)
            assert radial == pytest.approx(want, abs=0.01), (v, u, ch)
    # and the lens mapping itself: the corner sample of R sees what G sees ca_R further in
    lens = Lens("telecentric", 160, 120, 0.2, lateral_ca_px=ca)
    ur, vr = lens.ideal_pixels(np.array(0.0), np.array(0.0), 0)
    assert float(np.hypot(ur - 0.0, vr - 0.0)) == pytest.approx(abs(ca[0]), abs=1e-12)


# ------------------------------------------------------------------ Bayer
@pytest.mark.parametrize("pattern", ["RGGB", "GBRG"])
@pytest.mark.parametrize("method", ["edge_aware", "bilinear"])
def test_bayer_uniform_colour_passes_mosaic_and_demosaic_unchanged(pattern: str, method: str) -> None:
    """A uniform colour reaches the session unchanged through the colour filter array, the
    per-photosite quantisation and the camera's demosaic (three-chip and Bayer agree exactly)."""
    cfg = _cfg(camera={"sensor": {"kind": "bayer", "pattern": pattern, "demosaic": method}}, bit_depth=16)
    rig_b = Rig.from_config(cfg)
    rig_3 = Rig.from_config(_cfg(bit_depth=16))
    assert rig_b.cfa_pattern == pattern and rig_3.cfa_pattern is None
    rad = np.broadcast_to(np.float32([0.61, 0.42, 0.27]), (72, 96, 3)).copy()
    out_b = camera_response(rad, rig_b, None)
    out_3 = camera_response(rad, rig_3, None)
    assert out_b.dtype == np.uint16 and out_b.shape == (72, 96, 3)
    np.testing.assert_array_equal(out_b, out_3)
    assert len(np.unique(out_b.reshape(-1, 3), axis=0)) == 1


def test_bayer_noise_is_per_photosite_and_the_plate_survives_demosaic() -> None:
    """Noise is drawn once per photosite (one value, not three, per pixel), and the smooth white
    plate demosaics to the three-chip image within 2 DN of 65535 (noiseless)."""
    bay = _cfg(camera={"sensor": {"kind": "bayer"}}, bit_depth=16)
    three = _cfg(bit_depth=16)
    a = bench.Bench(bay).uniform_capturer(plane_z=0.0)(Pattern.white(), None).astype(np.int64)
    c = bench.Bench(three).uniform_capturer(plane_z=0.0)(Pattern.white(), None).astype(np.int64)
    assert int(np.abs(a - c)[2:-2, 2:-2].max()) <= 2
    rig = Rig.from_config(bay)

    class Count:
        n = 0

        def standard_normal(self, shape: tuple[int, ...], dtype: type) -> np.ndarray:
            Count.n += int(np.prod(shape))
            return np.zeros(shape, dtype)

    camera_response(np.full((72, 96, 3), 0.5, np.float32), rig, Count())  # type: ignore[arg-type]
    assert Count.n == 72 * 96


def test_bayer_config_errors_name_the_key() -> None:
    with pytest.raises(bench.BenchConfigError, match="camera.sensor.*even"):
        _cfg(camera={"sensor": {"kind": "bayer"}}, width=95)
    with pytest.raises(bench.BenchConfigError, match="working_distance_mm"):
        _cfg(camera={"model": "pinhole"})
    with pytest.raises(bench.BenchConfigError, match="only meaningful"):
        _cfg(camera={"working_distance_mm": 300.0})
    with pytest.raises(bench.BenchConfigError, match="4, 5, 8, 12 or 14"):
        _cfg(camera={"distortion": [0.1, 0.0, 0.0]})


# ------------------------------------------------------------------ sessions
def test_pinhole_session_writes_xy_truth_and_the_lens_block(tmp_path) -> None:
    """A pinhole bench session: session.yaml's camera block (model, matrix, distortion, plate_pose),
    ground_truth/xy/frame_NNNN.tiff float32 (H, W, 2) beside the heights; the unchanged presets
    write neither."""
    cfg = _cfg("plain_gauge", camera={"model": "pinhole", "working_distance_mm": 300.0, "distortion": [-0.2, 0.1, 0, 0, 0]},
               width=320, height=240, hue_bands=8, repeats=1)
    out = bench.write_session(cfg, tmp_path / "pin")
    meta = yaml.safe_load((out / "session.yaml").read_text())
    assert set(meta["camera"]) == {"width", "height", "bit_depth", "pixel_pitch_mm", "model", "matrix",
                                   "distortion", "plate_pose"}
    assert meta["camera"]["plate_pose"]["tvec"] == [-39.875, -29.875, 300.0]
    assert "pinhole lens at 300 mm" in meta["provenance"]["instrument"]
    xy = tifffile.imread(out / "ground_truth/xy/frame_0000.tiff")
    gt = tifffile.imread(out / "ground_truth/frames/frame_0000.tiff")
    assert xy.shape == (240, 320, 2) and xy.dtype == np.float32 and gt.shape == (240, 320)
    # the step ROIs sit on the block tops as the image shows them
    for step in meta["specimen"]["steps"]:
        u0, v0, u1, v1 = step["roi"]
        top = gt[v0:v1, u0:u1]
        assert float(top.max() - top.min()) < 0.07, step  # the top plus the vibration, no edge
    plain = _cfg(hue_bands=8, repeats=1)
    out2 = bench.write_session(plain, tmp_path / "plain")
    assert not (out2 / "ground_truth/xy").exists()
    assert set(yaml.safe_load((out2 / "session.yaml").read_text())["camera"]) == {
        "width", "height", "bit_depth", "pixel_pitch_mm"}
