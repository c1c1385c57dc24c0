"""Bayer sessions re-demosaiced from their native photosite values (config ``camera.demosaic``,
session key ``camera.bayer``): the analytic fringe, the reader, three-chip sessions untouched, and
the bench's Bayer gauge blocks against ground truth (docs/accuracy-cameras.md)."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import tifffile
import yaml
from scipy.ndimage import gaussian_filter1d

import huefringe
from huefringe import bench, camera, metrology, patterns, pipeline, uncertainty
from huefringe.colour import hue
from huefringe.height import accuracy
from huefringe.session import SessionError, load_session, read_rgb_codes


def _fringe(period: float = 48.0, blur_px: float = 1.0) -> np.ndarray:
    """A 16-bit trapezoid fringe along u (constant along v), its corners blurred by ``blur_px``."""
    u = np.arange(192, dtype=np.float64)
    row = np.asarray(patterns.trapezoid_rgb((2 * np.pi * u / period) % (2 * np.pi)), np.float64)
    row = gaussian_filter1d(0.1 + 0.8 * row, blur_px, axis=0, mode="wrap")
    return np.rint(np.broadcast_to(row, (32, 192, 3)) * 65535).astype(np.uint16)


def _hue_error(out: np.ndarray, truth: np.ndarray) -> np.ndarray:
    d = hue(out.astype(np.float32) / 65535, "hexcone") - hue(truth.astype(np.float32) / 65535, "hexcone")
    return np.angle(np.exp(1j * d))[8:-8, 8:-8]


@pytest.mark.parametrize("pattern", camera.BAYER_PATTERNS)
def test_lanczos_demosaic_keeps_the_fringe_hue_where_opencv_errs(pattern: str) -> None:
    """The trapezoid (period 48 px, corners blurred over 1 px) through a mosaic: OpenCV's two-tap
    demosaics leave a hue error of rms 0.0094-0.0101 rad (max 0.027 rad, 0.21 px of fringe) at the
    corners; the lattice Lanczos resampling rms 0.0021 rad (max 0.0064)."""
    rgb = _fringe()
    raw = camera.mosaic(rgb, pattern)
    rms = {m: float(np.sqrt(np.mean(_hue_error(camera.demosaic(raw, pattern, m), rgb) ** 2)))
           for m in camera.DEMOSAIC_METHODS}
    print(pattern, rms)
    assert rms["lanczos"] < 0.003
    assert rms["edge_aware"] > 0.008 and rms["bilinear"] > 0.008
    assert np.abs(_hue_error(camera.demosaic(raw, pattern, "lanczos"), rgb)).max() < 0.008


@pytest.mark.parametrize("pattern", camera.BAYER_PATTERNS)
def test_lanczos_demosaic_keeps_native_values(pattern: str) -> None:
    rng = np.random.default_rng(3)
    raw = rng.integers(0, 65535, (24, 32), dtype=np.uint16)
    out = camera.lanczos_demosaic(raw, pattern)
    np.testing.assert_array_equal(camera.mosaic(out, pattern), raw)


def test_lanczos_demosaic_noise_stays_below_the_native_noise() -> None:
    """White photosite noise of variance 1: R and B keep 0.68 at every pixel on average (linear
    along the fringes, Lanczos across), G 0.68; Lanczos both ways would leave 0.83."""
    rng = np.random.default_rng(0)
    raw = (30000 + 1000 * rng.standard_normal((200, 200))).astype(np.uint16)
    out = camera.lanczos_demosaic(raw, "RGGB").astype(np.float64)[10:-10, 10:-10]
    var = [float(out[..., k].var()) / 1e6 for k in range(3)]
    print(var)
    assert all(0.62 < x < 0.72 for x in var)


def test_noise_correlation_of_independent_and_demosaiced_noise() -> None:
    """Independent pixel noise: factor about 1; the same photosite noise through the Lanczos
    re-demosaic: a 5 x 5 mean keeps several times the independent variance."""
    rng = np.random.default_rng(5)
    plain = [rng.standard_normal((120, 160)) for _ in range(4)]
    assert uncertainty.noise_correlation(plain)["factor"] == pytest.approx(1.0, abs=0.12)
    dem = []
    for _ in range(4):
        raw = np.rint(30000 + 2000 * rng.standard_normal((120, 160))).astype(np.uint16)
        dem.append(camera.lanczos_demosaic(raw, "RGGB")[..., 0].astype(np.float64))
    got = uncertainty.noise_correlation(dem)
    print(got)
    assert got["factor"] > 2.5 and got["images"] == 4 and got["box"] == 5
    assert uncertainty.noise_correlation([np.full((4, 4), np.nan)]) == {"factor": 1.0, "box": 5, "images": 0}


def test_noise_aware_filter_settings() -> None:
    class T:
        stats = {"noise_correlation": {"factor": 4.0}}

    class Plain:
        stats: dict = {}

    adaptive = {"enabled": True, "max_radius": 6, "target_sigma_rad": 0.006, "reject_sigma_rad": 0.03}
    assert pipeline.noise_aware_adaptive(adaptive, T()) == {**adaptive, "target_sigma_rad": 0.003, "reject_sigma_rad": 0.015}
    assert pipeline.noise_aware_adaptive(adaptive, Plain()) is adaptive
    T.stats = {"noise_correlation": {"factor": 0.8}}  # below 1: as given
    assert pipeline.noise_aware_adaptive(adaptive, T()) == adaptive


@pytest.mark.parametrize("driver", ["edge_aware", "bilinear"])
def test_resampling_takes_the_natives_back_from_a_driver_demosaic(driver: str) -> None:
    """Whatever OpenCV demosaic the driver ran, the re-demosaic sees the sensor's own values: the
    same image as demosaicing the raw mosaic with Lanczos (but near the 1-px ring OpenCV copies)."""
    rgb = _fringe()
    raw = camera.mosaic(rgb, "GRBG")
    stored = camera.demosaic(raw, "GRBG", driver)
    again = camera.BayerResampling("GRBG", "lanczos").apply(stored)
    assert again.dtype == stored.dtype and again.shape == stored.shape
    np.testing.assert_array_equal(again[10:-10, 10:-10], camera.lanczos_demosaic(raw, "GRBG")[10:-10, 10:-10])
    np.testing.assert_array_equal(again[0], stored[0])  # the outer ring is kept as stored


def test_three_chip_sessions_are_never_resampled() -> None:
    meta = {"camera": {"width": 320, "height": 240, "bit_depth": 16, "pixel_pitch_mm": 0.25}}
    for setting in camera.RESAMPLE_SETTINGS:
        assert camera.bayer_resampling(meta, setting) is None
        rec = camera.demosaic_record(meta, {"demosaic": setting})
        assert rec == {"bayer": None, "setting": setting, "applied": False}
    _, reader = camera.corrections({"lens_model": True, "demosaic": rec}, meta)
    assert reader.bayer is None and reader.registration is None
    assert camera.corrections(None, meta)[1].bayer is None
    bay = {"camera": {**meta["camera"], "bayer": "BGGR"}}
    assert camera.bayer_resampling(bay) == camera.BayerResampling("BGGR", "lanczos")
    assert camera.bayer_resampling(bay, "stored") is None
    assert camera.corrections(None, bay)[1].bayer == camera.BayerResampling("BGGR", "lanczos")
    with pytest.raises(ValueError, match="camera.demosaic"):
        camera.bayer_resampling(bay, "vng")


# ------------------------------------------------------------------ the bench's Bayer gauge blocks


def _gauge(preset: str, root: Path) -> Path:
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path(preset)))
    cfg["session"]["frames"] = 1
    return bench.write_session(bench.validate_bench_config(cfg), root / preset)


@pytest.fixture(scope="module")
def bayer_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _gauge("bayer_gauge", tmp_path_factory.mktemp("bayer"))


def _score(session: Path, config: dict) -> tuple[dict, huefringe.api.Measurement]:
    m = huefringe.measure(session, config)
    s = m.session
    acc = accuracy(m.height(0), tifffile.imread(s.ground_truth[0]))
    ev = metrology.evaluate_session(list(m.heights), s.specimen, s.pixel_pitch_mm,
                                    range_mm=max(s.planes_mm) - min(s.planes_mm), camera=m.camera)
    acc["worst_step_um"] = 1e3 * max(abs(st["error_mm"]) for st in ev["steps"])
    return acc, m


def test_bench_bayer_session_declares_its_pattern(bayer_session: Path) -> None:
    meta = yaml.safe_load((bayer_session / "session.yaml").read_text())
    assert meta["camera"]["bayer"] == "RGGB"
    assert load_session(bayer_session).meta["camera"]["bayer"] == "RGGB"


def _cover2u(m: huefringe.api.Measurement) -> float:
    e = m.height(0).astype(np.float64) - tifffile.imread(m.session.ground_truth[0])
    u = m.uncertainty[0].astype(np.float64)
    ok = np.isfinite(e) & np.isfinite(u)
    return float(np.mean(np.abs(e[ok]) <= 2 * u[ok]))


def test_bayer_gauge_blocks_resampled_against_ground_truth(bayer_session: Path) -> None:
    """bayer_gauge (RGGB, OpenCV edge-aware in the 'driver', 320 x 240, one frame): the stored RGB
    measures median 0.0180 mm, p95 0.117 mm, worst step 16.5 um, |error| <= 2u at 0.74 of the
    pixels; re-demosaiced with Lanczos and the noise correlation known to the filter and the
    uncertainty: 0.0136 mm, 0.0855 mm, 11.4 um, |error| <= 2u at 0.87 (coverage 0.898 / 0.896).
    With the white-edge texture blur, the phase filter's target 0.002 rad, its rings tested against
    the local plane, its fixed window against each pixel's own side, its weights from the smoothed
    own signal and u by zone: Lanczos 0.0077 / 0.0381 mm, 13.3 um, 2u 0.957; stored 0.0116 /
    0.0477 mm, 14.9 um, 2u 0.892 (coverage 0.884 / 0.895: the noise-aware step-edge test drops more
    of the re-demosaiced chain's pixels): the re-demosaiced chain's gain is in the pixels' errors
    and u; the worst step mean (one frame, U about 20 um) is as scattered on both chains, within U
    on each."""
    new, m = _score(bayer_session, {})
    old, m_old = _score(bayer_session, {"camera": {"demosaic": "stored"}})
    print("lanczos", new, _cover2u(m), "\nstored", old, _cover2u(m_old))
    assert m.camera_record["demosaic"] == {"bayer": "RGGB", "setting": "lanczos", "applied": True,
                                           "pattern": "RGGB", "method": "lanczos"}
    corr = m.tables["object"].stats["noise_correlation"]
    assert 2.0 < corr["factor"] < 5.0 and corr["images"] == 12
    assert "noise_correlation" not in m_old.tables["object"].stats  # stored: nothing known of the mosaic
    assert new["median_abs_mm"] < 0.011 < old["median_abs_mm"]
    assert new["p95_abs_mm"] < 0.058 and new["p95_abs_mm"] < old["p95_abs_mm"] - 0.005
    assert new["worst_step_um"] < 20.0 and old["worst_step_um"] < 20.0
    assert new["coverage"] > old["coverage"] - 0.015
    # with every term of u on both: 0.957 against 0.892; the noise correlation is what lifts the
    # re-demosaiced chain into 0.95 +- 0.03, the stored demosaic stays below it
    assert 0.92 < _cover2u(m) < 0.98 and _cover2u(m_old) < 0.92


def test_three_chip_gauge_blocks_unchanged_by_the_setting(tmp_path: Path) -> None:
    """plain_gauge has no camera.bayer: the heights are bit for bit the same with every setting."""
    session = _gauge("plain_gauge", tmp_path)
    assert "bayer" not in yaml.safe_load((session / "session.yaml").read_text())["camera"]
    a = huefringe.measure(session, {"camera": {"demosaic": "lanczos"}})
    b = huefringe.measure(session, {"camera": {"demosaic": "stored"}})
    assert a.camera_record["demosaic"]["applied"] is False
    assert "noise_correlation" not in a.tables["object"].stats
    np.testing.assert_array_equal(a.heights, b.heights)
    np.testing.assert_array_equal(a.uncertainty, b.uncertainty)
    acc = accuracy(a.height(0), tifffile.imread(a.session.ground_truth[0]))
    assert acc["median_abs_mm"] < 0.012  # the three-chip reference (0.0108 mm at 2 frames)


def test_session_with_an_unknown_pattern_or_an_odd_size_is_refused(bayer_session: Path, tmp_path: Path) -> None:
    from huefringe.session import _camera_problems

    meta = yaml.safe_load((bayer_session / "session.yaml").read_text())
    meta["camera"]["bayer"] = "RGBG"
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "session.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(SessionError, match="bayer"):
        load_session(tmp_path / "s")
    cam = {"width": 321, "height": 240, "bit_depth": 16, "pixel_pitch_mm": 0.25, "bayer": "RGGB"}
    (problem,) = _camera_problems(cam, tmp_path / "session.yaml")
    assert "camera/bayer" in str(problem) and "321 x 240" in str(problem)
    assert _camera_problems({**cam, "width": 320}, tmp_path / "session.yaml") == []


def test_reader_of_a_bayer_session_reads_resampled_codes(bayer_session: Path) -> None:
    s = load_session(bayer_session)
    reader = camera.corrections(None, s.meta)[1]
    stored = read_rgb_codes(s.frames[0])
    got = reader.codes(s.frames[0])
    assert got.dtype == np.uint16 and got.shape == stored.shape
    inner = (slice(1, -1), slice(1, -1))
    np.testing.assert_array_equal(camera.mosaic(got, "RGGB")[inner], camera.mosaic(stored, "RGGB")[inner])
    assert np.any(got != stored)
    np.testing.assert_array_equal(reader.rgb(s.frames[0]), got.astype(np.float32) * np.float32(1 / 65535))


def test_both_chains_read_the_same_resampled_captures(bayer_session: Path) -> None:
    """The fused kernel reads the re-demosaiced codes, the NumPy chain the same codes scaled:
    the heights agree bit for bit (the tables and the plane calibration are shared)."""
    fast = huefringe.measure(bayer_session, {"measurement": {"kernel": True}})
    ref = huefringe.measure(bayer_session, {"measurement": {"kernel": False}})
    assert fast.camera_record["demosaic"]["applied"]
    np.testing.assert_array_equal(fast.heights, ref.heights)
