"""Lateral chromatic aberration: estimated from a session's reference planes, undone by resampling
R and B of every capture (both per-frame chains read the same registered codes); and X, Y from a
lens model in the cloud and the metrology."""

from __future__ import annotations

import copy
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench_helpers import CONFIG, bench_config, write
from ca_helpers import aberrated_copy, magnify_channels
from huefringe import api, camera, cloud, metrology
from huefringe.camera import CameraModel, CaptureReader, ChannelRegistration
from huefringe.io import read_tiff
from huefringe.session import load_session, read_rgb, read_rgb_codes
from huefringe.pipeline import session_camera_record


def _camera(registration: object) -> dict:
    """The configuration's camera block with ``chromatic_registration`` set, colour demixing off
    (the registration on the camera channels alone)."""
    return {**CONFIG["camera"], "chromatic_registration": registration, "colour_demixing": False}



@pytest.fixture(scope="module")
def gauge(tmp_path_factory) -> Path:
    """The demo's gauge blocks (pre-distorted pattern) at 320 x 240, 2 frames, few bands."""
    cfg = bench_config("demo", width=320, height=240, frames=2, hue_bands=32, repeats=2)
    return write(cfg, tmp_path_factory.mktemp("ca"))


@pytest.fixture(scope="module")
def aberrated(gauge: Path, tmp_path_factory) -> tuple[Path, float, float]:
    target = tmp_path_factory.mktemp("ca_ab") / "gauge-ca"
    sr, sb = aberrated_copy(gauge, target, 0.5, -0.4)
    return target, sr, sb


def _cfg(mode, kernel=True):
    c = copy.deepcopy(CONFIG)
    c["camera"] = {"lens_model": True, "chromatic_registration": mode}
    c["measurement"]["kernel"] = kernel
    return c


def _median_error(m) -> tuple[float, float]:
    errs = [m.heights[i] - read_tiff(m.session.ground_truth[n]) for i, n in enumerate(m.frames)]
    e = np.concatenate([x[np.isfinite(x)] for x in errs])
    return float(np.median(np.abs(e))), float(np.mean(m.valid))


def test_estimate_recovers_a_known_magnification(gauge: Path, aberrated) -> None:
    """R +0.5 px and B -0.4 px at the corners, estimated back within 0.05 px there; the plain
    session reads below the auto threshold (registration not applied)."""
    target, sr, sb = aberrated
    rec = session_camera_record(load_session(target), _camera("auto"), CONFIG["calibration"])
    est = rec["chromatic_registration"]["estimate"]
    r = est["corner_radius_px"]
    assert abs(est["scale"]["R"] - sr) * r < 0.05
    assert abs(est["scale"]["B"] - sb) * r < 0.05
    assert rec["chromatic_registration"]["applied"]
    plain = session_camera_record(load_session(gauge), _camera("auto"), CONFIG["calibration"])
    reg = plain["chromatic_registration"]
    assert max(reg["estimate"]["corner_displacement_px"].values()) < 0.5 * camera.CA_AUTO_THRESHOLD_PX
    assert not reg["applied"]
    off = session_camera_record(load_session(gauge), _camera(False), CONFIG["calibration"])
    assert "estimate" not in off["chromatic_registration"] and not off["chromatic_registration"]["applied"]


def test_registration_undoes_the_magnification_on_codes() -> None:
    """A smooth colour image magnified and registered back matches itself within a code (8 bit)
    away from the border, and the registration keeps the sensor dtype."""
    v, u = np.mgrid[0:240, 0:320].astype(np.float64)
    img = np.stack([120 + 100 * np.sin(2 * np.pi * (u + k * 13) / 40.0) for k in range(3)], -1)
    img = np.rint(img).astype(np.uint8)
    c = (159.5, 119.5)
    sr, sb = 0.5 / np.hypot(*c), -0.4 / np.hypot(*c)
    ab = magnify_channels(img, sr, sb, c)
    back = ChannelRegistration(c, sr, sb).apply(ab)
    assert back.dtype == np.uint8
    inner = (slice(8, -8), slice(8, -8))
    before = np.abs(ab[inner].astype(int) - img[inner]).max()
    after = np.abs(back[inner].astype(int) - img[inner]).max()
    assert before >= 4 and after <= 1


def test_registration_lowers_the_height_error(gauge: Path, aberrated) -> None:
    """On the aberrated gauge blocks the registered measurement is close to the clean one and
    far better than the unregistered one (median |error| vs the bench's ground truth)."""
    target, _, _ = aberrated
    clean, cov_clean = _median_error(api.measure(gauge, _cfg(False)))
    off, _ = _median_error(api.measure(target, _cfg(False)))
    m_on = api.measure(target, _cfg("auto"))
    on, cov_on = _median_error(m_on)
    assert m_on.camera_record["chromatic_registration"]["applied"] and m_on.camera.plain
    np.testing.assert_array_equal(m_on.xy(0)[0][np.isfinite(m_on.height(0))],
                                  (np.arange(320) * m_on.session.pixel_pitch_mm)[None, :].repeat(240, 0)[np.isfinite(m_on.height(0))])
    assert off > 2.5 * clean  # the aberration matters
    assert on < 0.5 * off
    assert on < 1.2 * clean
    assert cov_on > cov_clean - 0.01  # not by dropping pixels


def test_both_chains_read_the_same_registered_codes(aberrated) -> None:
    """With registration the fused kernel and the NumPy reference chain stay bit-identical."""
    target, _, _ = aberrated
    fast = api.measure(target, _cfg(True, kernel=True), frames=[0])
    ref = api.measure(target, _cfg(True, kernel=False), frames=[0])
    np.testing.assert_array_equal(fast.heights, ref.heights)


def test_reader_without_registration_is_the_session_reader(gauge: Path) -> None:
    s = load_session(gauge)
    reader = CaptureReader()
    p = s.frames[0]
    assert np.array_equal(reader.rgb(p), read_rgb(p)) and reader.rgb(p).dtype == np.float32
    assert np.array_equal(reader.codes(p), read_rgb_codes(p))
    reg = CaptureReader(ChannelRegistration((159.5, 119.5), 0.0, 0.0))
    np.testing.assert_array_equal(reg.codes(p), read_rgb_codes(p))  # zero scale: identity maps


# --------------------------------------------------------------------------- X, Y consumers

K = np.array([[700.0, 0.0, 161.0], [0.0, 700.0, 118.0], [0.0, 0.0, 1.0]])
PIN = {"camera": {"width": 320, "height": 240, "bit_depth": 8, "pixel_pitch_mm": 0.43, "model": "pinhole",
                  "matrix": K.tolist(), "distortion": [-0.15, 0.08, 0.0, 0.0, 0.0],
                  "plate_pose": {"rvec": [0.02, 0.01, 0.0], "tvec": [-68.0, -51.0, 300.0]}}}


def _seen_plane(model: CameraModel, c: np.ndarray, step: tuple[tuple[slice, slice], float] | None = None):
    """The height map a pinhole camera sees of ``z = c0 + c1 X + c2 Y`` (fixed point per pixel)."""
    v, u = np.mgrid[0:240, 0:320].astype(np.float64)
    h = np.zeros((240, 320))
    add = np.zeros_like(h)
    if step is not None:
        add[step[0]] = step[1]
    for _ in range(30):
        x, y = model.xy_at(u, v, h)
        h = c[0] + c[1] * x + c[2] * y + add
    return h


def test_metrology_fits_the_plane_in_the_lens_models_x_y() -> None:
    """A tilted plate seen by a pinhole camera: fit_plane with the model's X, Y recovers its
    coefficients to 1e-9 and a 2 mm step to 1e-9 mm; with u * pitch it does not."""
    model = CameraModel.from_meta(PIN)
    c = np.array([0.7, 0.004, -0.003])
    top = (slice(90, 150), slice(130, 200))
    h = _seen_plane(model, c, (top, 2.0))
    base = [[0, 0, 320, 60], [0, 180, 320, 240]]
    xy = model.xy(h)
    plane, rms = metrology.fit_plane(h, base, 0.43, xy=xy)
    np.testing.assert_allclose(plane, c, atol=1e-9)
    assert rms < 1e-9
    box = [130, 90, 200, 150]
    assert abs(metrology.step_height(h, plane, box, 0.43, edge_exclusion=0.2, xy=xy) - 2.0) < 1e-9
    plane_flat, _ = metrology.fit_plane(h, base, 0.43)
    assert np.max(np.abs(plane_flat - c)) > 1e-4
    spec = {"kind": "step_heights", "base_roi": base, "steps": [{"name": "top", "nominal_mm": 2.0, "roi": box}],
            "tolerance_mm": 0.01}
    res = metrology.evaluate_session([h.astype(np.float32)], spec, 0.43, range_mm=5.0, camera=model)
    assert abs(res["steps"][0]["mean_mm"] - 2.0) < 1e-5  # float32 heights


def test_cloud_points_carry_the_lens_models_x_y(tmp_path: Path) -> None:
    """write_height_cloud with xy gives the bytes of write_points on the model's points."""
    model = CameraModel.from_meta(PIN)
    h = _seen_plane(model, np.array([1.0, 0.002, 0.001])).astype(np.float32)
    h[5:9, 10:30] = np.nan
    xy = model.xy(h)
    pts, pix = cloud.height_to_points(h, 0.43, xy)
    np.testing.assert_array_equal(pts[:, 0], xy[0].ravel()[pix])
    cloud.write_points(tmp_path / "ref.ply", pts)
    n = cloud.write_height_cloud(tmp_path / "ours.ply", h, 0.43, xy=xy)
    assert n == pix.size
    assert (tmp_path / "ours.ply").read_bytes() == (tmp_path / "ref.ply").read_bytes()
    # projected back through OpenCV, every point lands on its own pixel centre
    uv, _ = cv2.projectPoints(np.column_stack([pts[:, :2], -pts[:, 2]]).reshape(-1, 1, 3),
                              np.array([0.02, 0.01, 0.0]), np.array([-68.0, -51.0, 300.0]), K,
                              np.array([-0.15, 0.08, 0.0, 0.0, 0.0]))
    vv, uu = np.divmod(pix, 320)
    assert np.max(np.abs(uv.reshape(-1, 2) - np.column_stack([uu, vv]))) < 1e-5


def test_mesh_vertices_move_to_the_lens_models_x_y() -> None:
    """place_vertices (last, after sigma and cleaning) puts every grid vertex at model.xy of its pixel."""
    from huefringe import mesh as meshing

    model = CameraModel.from_meta(PIN)
    h = _seen_plane(model, np.array([1.0, 0.002, 0.001])).astype(np.float32)
    h[100:110, 40:60] = np.nan
    m = meshing.height_to_mesh(h, 0.43, jump_mm=1.0)
    v, u = meshing.vertex_pixels(m)
    sigma = np.random.default_rng(0).random(h.shape).astype(np.float32)
    meshing.attach_sigma(m, sigma)
    meshing.place_vertices(m, model.xy_at)
    x, y = model.xy(h)
    np.testing.assert_allclose(m.vertices[:, 0], x[v, u], atol=1e-9)
    np.testing.assert_allclose(m.vertices[:, 1], y[v, u], atol=1e-9)
    np.testing.assert_array_equal(m.vertices[:, 2], h[v, u])
    np.testing.assert_array_equal(m.vertex_attributes["sigma_mm"], sigma[v, u])
    assert m.metadata["xy"] == "lens model"


def test_auto_does_not_register_from_a_strip_too_narrow_for_the_period(tmp_path: Path) -> None:
    """On a 200 x 150 px flat board without aberration the fit reads only the central ~20 columns
    (1.5 periods left out at each side) and extrapolates 3-4 px of "aberration" to the corners;
    auto must not act on it (it took p95 from 0.04 to 0.55 mm), ``true`` still does. A field
    narrower than three periods is not estimable at all, and auto leaves it alone."""
    cfg = bench_config("flat", width=200, height=150, hue_bands=48, frames=1, id="small")
    s = load_session(write(cfg, tmp_path))
    rec = session_camera_record(s, _camera("auto"), CONFIG["calibration"])["chromatic_registration"]
    assert max(rec["estimate"]["corner_displacement_px"].values()) > 10 * camera.CA_AUTO_THRESHOLD_PX  # the misread
    assert rec["reach"] < camera.CA_AUTO_MIN_REACH
    assert not rec["applied"] and "field's half-width" in rec["not_applied_because"]
    assert session_camera_record(s, _camera(True), CONFIG["calibration"])["chromatic_registration"]["applied"]
    narrow = load_session(write(bench_config("dental", width=160, height=120, hue_bands=16, frames=1, id="narrow"),
                                tmp_path / "narrow"))
    rec = session_camera_record(narrow, _camera("auto"), CONFIG["calibration"])["chromatic_registration"]
    assert not rec["estimate"]["estimable"] and rec["estimate"]["scale"] == {"R": 0.0, "B": 0.0}
    assert not rec["applied"]


# --------------------------------------------------------------------------- a bench lens with crosstalk

def _bench_lens_config(ca: list[float] | None) -> dict:
    """The plain gauge blocks (10 % crosstalk) at 320 x 240, 48 bands x 1, 2 frames, 2 x 2 sub-samples."""
    cfg = bench_config("plain_gauge", hue_bands=48, repeats=1, frames=2, id="ca" if ca else "clean")
    cfg["camera"]["supersample"] = 2
    if ca:
        cfg["camera"]["lateral_ca_px"] = ca
    return cfg


@pytest.fixture(scope="module")
def bench_lens(tmp_path_factory) -> tuple[Path, Path, dict]:
    """A bench lens with lateral CA of +0.5 / -0.5 px (R / B) at the corners, and the same camera without."""
    root = tmp_path_factory.mktemp("ca_lens")
    cfg = _bench_lens_config([0.5, -0.5])
    return write(cfg, root), write(_bench_lens_config(None), root), cfg


def test_mixing_and_magnification_match_the_bench_lens(bench_lens) -> None:
    """The camera's response to the projector primaries (from the hue bands) is the bench's crosstalk
    within 0.002, and the primaries' magnification at the corners is the bench's within 0.01 px; the
    camera channels themselves (no bands: the estimate before the mixing) read it 0.04 px too large."""
    ca, clean, cfg = bench_lens
    s = load_session(ca)
    rec = session_camera_record(s, _camera("auto"), CONFIG["calibration"])["chromatic_registration"]
    est = rec["estimate"]
    xt = np.asarray(cfg["camera"]["crosstalk"], np.float64)
    assert est["mixing"]["estimable"]
    np.testing.assert_allclose(est["mixing"]["matrix"], xt / np.diag(xt)[None, :], atol=0.002)
    r = est["corner_radius_px"]
    truth = {"R": 1 / (1 - 0.5 / r) - 1, "B": 1 / (1 + 0.5 / r) - 1}  # bench: R sees G at c + (p - c)(1 - a / r)
    for c in "RB":
        assert abs(est["scale"][c] - truth[c]) * r < 0.01
    assert rec["applied"]
    white = read_rgb(s.reference_white)
    planes = [read_rgb(p) for p in s.planes.values()]
    old = camera.estimate_lateral_ca(planes, white, s.period_px, est["centre"])
    for c in "RB":
        assert abs(old["scale"][c] - truth[c]) * r > 0.03  # crosstalk biases the camera channels' phases
    # a camera without CA stays untouched by auto (its estimate, unmixed, reads a few thousandths of a px)
    plain = session_camera_record(load_session(clean), _camera("auto"), CONFIG["calibration"])
    assert max(plain["chromatic_registration"]["estimate"]["corner_displacement_px"].values()) < 0.02
    assert not plain["chromatic_registration"]["applied"]


def test_registration_of_a_bench_lens_comes_back_to_the_clean_camera(bench_lens) -> None:
    """Median |height error| against the bench's truth (frame 0): registered within 10 % of the same
    camera without CA (measured 0.0136 against 0.0141 mm; the camera channels registered instead,
    before the mixing: 0.0197 mm with Lanczos, 0.0176 with the spline), at least 3 x
    better than not registering (0.0497 mm); coverage not bought."""
    ca, clean, _ = bench_lens
    base, cov_base = _median_error(api.measure(clean, _cfg(False), frames=[0]))
    off, _ = _median_error(api.measure(ca, _cfg(False), frames=[0]))
    m = api.measure(ca, _cfg("auto"), frames=[0])
    on, cov_on = _median_error(m)
    assert m.camera_record["chromatic_registration"]["applied"]
    assert off > 3 * on
    assert on < 1.1 * base
    assert cov_on > cov_base - 0.01


_MIX = np.array([[1.0, 0.12, 0.02], [0.09, 1.0, 0.09], [0.02, 0.13, 1.0]])  # column k: the camera's response to primary k


def test_mixing_band_pairs_vary_one_primary_each() -> None:
    """Each pair of bands differs in its varying primary only, in the direction given, two
    segments per primary from 12 bands on; fewer bands leave primaries out (not estimable)."""
    from huefringe.patterns import band_rgb

    for n in (12, 32, 96, 256):
        pairs = camera.mixing_band_pairs(n)
        assert sorted(k for k, *_ in pairs) == [0, 0, 1, 1, 2, 2]
        for k, first, last, sign in pairs:
            d = band_rgb(last, n) - band_rgb(first, n)
            assert sign * d[k] > 0.49 and np.all(np.abs(np.delete(d, k)) < 1e-12)
    assert {k for k, *_ in camera.mixing_band_pairs(8)} != {0, 1, 2}
    assert not camera.estimate_channel_mixing({}, 8)["estimable"]


def test_channel_mixing_from_bands_whatever_the_gamma_and_colour() -> None:
    """Bands of a plate with per-pixel, per-primary reflectance, an irradiance falloff, projector
    gamma 1.9-2.4, a black level and ambient light give the mixing matrix to 1e-9; clipped pixels
    are left out; a mixing with a 0.6 off-diagonal is refused."""
    from huefringe.patterns import band_rgb

    rng = np.random.default_rng(0)
    refl = rng.uniform(0.3, 0.7, (60, 80, 3))
    irr = np.linspace(0.6, 1.0, 80)[None, :, None]
    gamma = np.array([2.2, 1.9, 2.4])

    def bands(mix: np.ndarray, n: int) -> dict[int, np.ndarray]:
        out = {}
        for _, first, last, _ in camera.mixing_band_pairs(n):
            for i in (first, last):
                out[i] = np.clip((refl * irr * (0.02 + 0.98 * band_rgb(i, n) ** gamma)) @ mix.T * 0.8 + 0.01, 0, 1)
        return out

    for n in (12, 96, 256):
        est = camera.estimate_channel_mixing(bands(_MIX, n), n)
        assert est["estimable"]
        np.testing.assert_allclose(est["matrix"], _MIX, atol=1e-9)
    b = bands(_MIX, 96)
    b[0][:10] = 1.0  # clipped rows: left out
    np.testing.assert_allclose(camera.estimate_channel_mixing(b, 96)["matrix"], _MIX, atol=1e-9)
    bad = _MIX.copy()
    bad[0, 1] = 0.6
    refused = camera.estimate_channel_mixing(bands(bad, 96), 96)
    assert not refused["estimable"] and "off-diagonal" in refused["why"] and refused["matrix"] == np.eye(3).tolist()


def test_registration_in_the_primaries_undoes_a_lens_with_crosstalk() -> None:
    """Fringes of three primaries, R and B magnified by the lens (+0.5 / -0.5 px at the corners),
    then mixed by the camera (``_MIX``) and stored as 16-bit codes: registered with the mixing they
    come back within 1 code of the unaberrated capture; registering the camera channels instead
    leaves 165 codes (1087 unregistered)."""
    v, u = np.mgrid[0:240, 0:320].astype(np.float64)
    c = (159.5, 119.5)
    sc = {0: 0.5 / np.hypot(*c), 1: 0.0, 2: -0.5 / np.hypot(*c)}

    def capture(aberrated: bool) -> np.ndarray:
        uu = [c[0] + (u - c[0]) / (1 + (sc[k] if aberrated else 0.0)) for k in range(3)]
        p = np.stack([0.45 + 0.4 * np.sin(2 * np.pi * (uu[k] - k * 40 / 3) / 40.0) for k in range(3)], -1)
        return np.rint(np.clip(p @ _MIX.T * 0.7, 0, 1) * 65535).astype(np.uint16)

    clean, obs = capture(False), capture(True)
    inner = (slice(8, -8), slice(8, -8))
    err = {}
    for name, mix in (("primaries", tuple(map(tuple, _MIX))), ("channels", None)):
        back = ChannelRegistration(c, sc[0], sc[2], mix).apply(obs)
        assert back.dtype == np.uint16
        err[name] = np.abs(back[inner].astype(int) - clean[inner]).max()
    assert np.abs(obs[inner].astype(int) - clean[inner]).max() > 1000
    assert err["primaries"] <= 1 and err["channels"] > 100
