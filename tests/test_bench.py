"""Tests of the virtual bench (huefringe.bench): geometry, radiometry, scenes, session writer."""

from __future__ import annotations

import copy
import hashlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tifffile
import yaml

import huefringe.bench as hb
from huefringe import patterns
from huefringe.bench import Bench, BenchConfigError, Pattern

TWO_PI = 2.0 * np.pi


# ------------------------------------------------------------------------------ helpers
def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Deep merge ``over`` into a copy of ``base``."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else copy.deepcopy(v)
    return out


def ideal(**over: Any) -> dict[str, Any]:
    """A small ideal rig (every bench default is ideal: gamma 1, no noise, blur, crosstalk, ambient)."""
    raw = {
        "session": {
            "id": "test",
            "width": 160,
            "height": 60,
            "bit_depth": 16,
            "pixel_pitch_mm": 0.2,
            "period_px": 40,
            "hue_bands": 6,
            "repeats": 1,
            "planes_mm": [0.0, 2.5],
            "frames": 2,
        },
        "projector": {"height_mm": 300.0, "x_mm": -130.0},
        "scene": {"kind": "flat", "height_mm": 0.0, "reflectance": 0.8},
    }
    if "scene" in over:  # a scene replaces the default one (its keys depend on its kind)
        raw["scene"] = over.pop("scene")
    return hb.validate_bench_config(merge(raw, over))


def hexcone_hue(img: np.ndarray) -> np.ndarray:
    """Hexcone hue in [0, 2 pi) of an RGB image (any dtype)."""
    rgb = img.astype(np.float64)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    mx, mn = rgb.max(axis=-1), rgb.min(axis=-1)
    c = np.where(mx > mn, mx - mn, 1.0)
    h = np.where(mx == r, np.mod((g - b) / c, 6.0), np.where(mx == g, (b - r) / c + 2.0, (r - g) / c + 4.0))
    return h * (np.pi / 3.0)


def wrap(a: np.ndarray) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return np.mod(a + np.pi, TWO_PI) - np.pi


def sha256_tree(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()
    }


# ------------------------------------------------------------------------------ geometry
def test_code_phase_is_the_triangulation_formula() -> None:
    x = np.linspace(-20.0, 120.0, 57)[:, None]
    h = np.linspace(0.0, 8.0, 33)[None, :]
    kw = {"projector_x_mm": -130.0, "projector_height_mm": 300.0, "period_mm": 12.0}
    dphi = hb.code_phase(x, h, **kw, x_origin_mm=3.0) - hb.code_phase(x, 0.0, **kw, x_origin_mm=3.0)
    expected = TWO_PI / 12.0 * (x + 130.0) * h / (300.0 - h)
    np.testing.assert_allclose(dphi, expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(hb.analytic_phase_difference(x, h, **kw), expected, rtol=1e-12, atol=1e-12)
    # the reference plane carries the linear code 2 pi (X - X_origin) / P
    np.testing.assert_allclose(hb.code_phase(x, 0.0, **kw, x_origin_mm=3.0), TWO_PI * (x - 3.0) / 12.0, atol=1e-12)


@pytest.mark.parametrize("xp", [-130.0, 190.0])
def test_captured_plane_phase_matches_triangulation(xp: float) -> None:
    """Hue of the trapezoid on the plate lifted to z, minus on z = 0: the analytic dphi."""
    cfg = ideal(projector={"x_mm": xp})
    bench = Bench(cfg)
    z = 2.5
    hue0 = hexcone_hue(bench.capture(Pattern.trapezoid(), plane_z=0.0))
    huez = hexcone_hue(bench.capture(Pattern.trapezoid(), plane_z=z))
    x = np.arange(cfg["session"]["width"]) * cfg["session"]["pixel_pitch_mm"]
    period_mm = cfg["session"]["period_px"] * cfg["session"]["pixel_pitch_mm"]
    expected = hb.analytic_phase_difference(x, z, projector_x_mm=xp, projector_height_mm=300.0, period_mm=period_mm)
    measured = wrap(huez - hue0)
    assert np.abs(expected).max() > 1.0  # a real test: phase moves by more than a radian
    # 8-bit DMD codes limit the hue to ~ (pi/3) * 0.5/255 = 2e-3 rad per capture
    assert np.abs(wrap(measured - expected[None, :])).max() < 5e-3
    code0 = hb.code_phase(x, 0.0, projector_x_mm=xp, projector_height_mm=300.0, period_mm=period_mm)
    assert np.abs(wrap(hue0 - code0[None, :])).max() < 3e-3


def _linearity_residual(img: np.ndarray, row: int) -> tuple[float, float]:
    u = np.arange(img.shape[1])
    hue = np.unwrap(hexcone_hue(img[row]))
    slope, icpt = np.polyfit(u, hue, 1)
    return float(slope), float(np.abs(hue - (slope * u + icpt)).max())


def test_hue_of_trapezoid_frame_is_linear_in_x_on_ideal_rig() -> None:
    cfg = ideal()
    img = Bench(cfg).capture(Pattern.trapezoid(), t=0.0)
    for row in (0, 30, 59):
        slope, resid = _linearity_residual(img, row)
        assert slope == pytest.approx(TWO_PI / cfg["session"]["period_px"], rel=1e-4)
        assert resid < 3e-3


def test_coloured_surface_bends_the_hue_until_white_normalised() -> None:
    cfg = ideal(scene={"kind": "flat", "height_mm": 0.0, "reflectance": [0.3, 0.7, 0.5]})
    bench = Bench(cfg)
    img = bench.capture(Pattern.trapezoid()).astype(np.float64)
    assert _linearity_residual(img, 30)[1] > 0.05
    balanced = img / bench.capture(Pattern.white()).astype(np.float64)
    assert _linearity_residual(balanced, 30)[1] < 3e-3


def test_hue_is_not_linear_with_projector_gamma() -> None:
    """The control: the same check fails once the projector has a gamma (paper Fig. 7c)."""
    cfg = ideal(projector={"gamma": [2.2, 2.0, 2.4]})
    img = Bench(cfg).capture(Pattern.trapezoid())
    assert _linearity_residual(img, 30)[1] > 0.05


# ------------------------------------------------------------------------------ radiometry
@pytest.mark.parametrize("power", [1.0, 0.01])
def test_noise_std_matches_shot_plus_read_noise(power: float) -> None:
    full_well, read_dn = 12000.0, 40.0  # read noise in 16-bit DN
    cfg = ideal(
        session={"width": 64, "height": 48},
        projector={"power": power},
        camera={"full_well_e": full_well, "read_noise_dn": read_dn, "sensitivity": [0.9, 1.0, 0.8]},
        surface={"lambertian": False, "plate_reflectance": 0.7},
        scene={"kind": "flat", "height_mm": 1.0, "reflectance": 0.7},
    )
    bench = Bench(cfg)
    caps = np.stack([bench.capture(Pattern.white(), rng=np.random.default_rng(i)) for i in range(12)]).astype(np.float64)
    mean = caps.mean(axis=(0, 1, 2))
    std = np.sqrt(caps.var(axis=0, ddof=1).mean(axis=(0, 1)))
    max_dn = 65535.0
    signal = power * 0.7 * np.array([0.9, 1.0, 0.8])  # fraction of full scale
    expected = np.sqrt(signal / full_well + (read_dn / max_dn) ** 2) * max_dn
    np.testing.assert_allclose(mean, signal * max_dn, rtol=2e-3)
    np.testing.assert_allclose(std, expected, rtol=0.10)
    noiseless = bench.capture(Pattern.white(), rng=None)
    assert np.ptp(noiseless.reshape(-1, 3), axis=0).max() == 0


def test_crosstalk_and_stray_light_follow_eq8() -> None:
    m = [[0.8, 0.15, 0.05], [0.1, 0.8, 0.1], [0.0, 0.2, 0.8]]
    cfg = ideal(
        camera={"crosstalk": m, "sensitivity": [1.0, 0.9, 0.8]},
        light={"ambient": [0.05, 0.0, 0.1], "stray": [0.02, 0.03, 0.0]},
        surface={"lambertian": False},
        scene={"kind": "flat", "height_mm": 0.0, "reflectance": [0.5, 0.6, 0.7]},
    )
    img = Bench(cfg).capture(Pattern.hue_band(1, 6)).astype(np.float64) / 65535.0
    proj = np.round(patterns.band_rgb(1, 6) * 255) / 255  # gamma 1
    r = np.array([0.5, 0.6, 0.7])
    expected = np.asarray(m) @ (np.array([1.0, 0.9, 0.8]) * (r * (proj + [0.05, 0.0, 0.1]) + [0.02, 0.03, 0.0]))
    np.testing.assert_allclose(img[10, 10], expected, atol=2e-5)


def test_phase_shift_precompensation_and_gamma_error() -> None:
    def three_step_error(gamma_error: float) -> float:
        cfg = ideal(projector={"gamma": 2.2}, phase_shift={"enabled": True, "gamma_error": gamma_error})
        bench = Bench(cfg)
        i = [bench.capture(Pattern.phase_shift(s), t=0.0)[..., 1].astype(np.float64) for s in range(3)]
        # I_s = A + B cos(phi + 2 pi (s-1)/3)  =>  phi = atan2(sqrt(3)(I0 - I2), 2 I1 - I0 - I2)
        phi = np.arctan2(np.sqrt(3.0) * (i[0] - i[2]), 2.0 * i[1] - i[0] - i[2])
        x = np.arange(cfg["session"]["width"]) * 0.2
        code = hb.code_phase(x, 0.0, projector_x_mm=-130.0, projector_height_mm=300.0, period_mm=8.0)
        return float(np.abs(wrap(phi - code[None, :])).max())

    assert three_step_error(0.0) < 0.02  # well compensated: only 8-bit quantisation left
    assert three_step_error(0.25) > 0.05  # a wrong gamma estimate distorts the sinusoid


# ------------------------------------------------------------------------------ shadows
@pytest.mark.parametrize("xp", [-130.0, 200.0])
def test_shadows_fall_away_from_the_projector(xp: float) -> None:
    block = {"name": "tall", "nominal_mm": 4.0, "reflectance": 0.8, "rect_mm": [13.9, 3.9, 18.1, 8.1]}
    cfg = ideal(
        session={"width": 160, "height": 60},
        projector={"x_mm": xp},
        light={"ambient": 0.05},
        scene={"kind": "gauge_blocks", "blocks": [block], "base_thickness_mm": 0.0, "base_reflectance": 0.8},
    )
    bench = Bench(cfg)
    white = bench.capture(Pattern.white()).astype(np.float64)[..., 1] / 65535.0
    row = white[30]
    u_left, u_right = 70, 90  # block covers u = 70 .. 90 (X = 14 .. 18 mm)
    x_edge = (u_left - 0.5) * 0.2 if xp > 50 else (u_right + 0.5) * 0.2
    expected_len_px = 4.0 * abs(x_edge - xp) / (300.0 - 4.0) / 0.2
    ambient_only = 0.8 * 0.05
    dark = np.flatnonzero(np.abs(row - ambient_only) < 1e-4)
    assert dark.size > 0
    if xp < 0:  # projector at -x: shadow on the +x side of the block
        assert dark.min() == u_right + 1
        assert row[u_left - 5 : u_left].min() > 0.5
    else:
        assert dark.max() == u_left - 1
        assert row[u_right + 1 : u_right + 6].min() > 0.5
    # point-sampled heights: the block's last sample sits up to one sample inside its edge
    assert expected_len_px - 1.5 <= dark.size <= expected_len_px + 0.5


def test_cast_shadow_mask_length() -> None:
    xs = np.arange(400) * 0.1
    h = np.zeros((3, 400))
    h[:, 200:] = 5.0  # a cliff at X = 20 facing -x
    sh = hb.cast_shadow_mask(h, xs, projector_x_mm=200.0, projector_height_mm=300.0)  # projector at +x
    n = int(sh[1].sum())
    assert sh[:, 200:].sum() == 0
    assert abs(n - 5.0 * (200.0 - 20.0) / 295.0 / 0.1) <= 1.0
    assert not hb.cast_shadow_mask(h, xs, projector_x_mm=-100.0, projector_height_mm=300.0).any()


# ------------------------------------------------------------------------------ sessions
def gauge_session(**over: Any) -> dict[str, Any]:
    raw = {
        "session": {
            "id": "gauge-test",
            "width": 120,
            "height": 80,
            "bit_depth": 8,
            "period_px": 30,
            "hue_bands": 6,
            "repeats": 2,
            "planes_mm": [0.0, 3.0],
            "frames": 3,
            "seed": 5,
        },
        "projector": {"height_mm": 300.0, "x_mm": 160.0, "gamma": [2.2, 2.0, 2.4], "pixel_mm": 0.1, "defocus_sigma_px": 0.8},
        "camera": {"full_well_e": 15000, "read_noise_dn": 0.6, "lens_blur_sigma_px": 0.6, "supersample": 2,
                   "exposure_ms": 3.0, "motion_blur_subframes": 2},
        "light": {"ambient": 0.02, "stray": 0.01},
        "vibration": {"amplitude_mm": 0.03, "frequency_hz": 29.0, "phase_rad": 0.4},
        "phase_shift": {"enabled": True, "gamma_error": 0.08},
        "scene": {"kind": "gauge_blocks", "blocks": "fig9", "base_margin_mm": 1.0, "reflectance_variation": 0.03},
        "specimen": {"margin_px": 2},
    }
    return merge(raw, over)


@pytest.mark.parametrize("fmt", ["png", "tiff"])
def test_same_yaml_writes_same_bytes(tmp_path: Path, fmt: str) -> None:
    cfg_file = tmp_path / "bench.yaml"
    cfg_file.write_text(yaml.safe_dump(gauge_session(session={"image_format": fmt})), encoding="utf-8")
    a = hb.write_session(hb.load_bench_config(cfg_file), tmp_path / "a", workers=2)
    b = hb.write_session(hb.load_bench_config(cfg_file), tmp_path / "b", workers=1)
    ha, hb_ = sha256_tree(a), sha256_tree(b)
    assert ha == hb_
    ext = "png" if fmt == "png" else "tiff"
    expected = {
        "session.yaml",
        f"reference/white.{ext}",
        f"object/white.{ext}",
        f"reference/planes/z_0.000.{ext}",
        f"reference/planes/z_3.000.{ext}",
        f"object/hue/band_005_r1.{ext}",
        f"reference/hue/band_000_r0.{ext}",
        f"object/frames/frame_0002.{ext}",
        f"object/phase_shift/frame_0002_s2.{ext}",
        "ground_truth/frames/frame_0000.tiff",
    }
    assert expected <= set(ha)
    assert sum(k.startswith("object/hue/") for k in ha) == 12
    assert sum(k.startswith("object/phase_shift/") for k in ha) == 9
    # a different seed changes the noisy images
    other = hb.write_session(gauge_session(session={"image_format": fmt, "seed": 6}), tmp_path / "c")
    assert sha256_tree(other)[f"object/white.{ext}"] != ha[f"object/white.{ext}"]
    assert not list(tmp_path.glob(".*partial*"))


def test_ground_truth_is_nominal_plus_base_plus_vibration(tmp_path: Path) -> None:
    cfg = hb.validate_bench_config(gauge_session(session={"hue_bands": 6, "repeats": 1}, phase_shift={"enabled": False}))
    out = hb.write_session(cfg, tmp_path / "s")
    doc = yaml.safe_load((out / "session.yaml").read_text())
    assert doc["format"] == "capture-session/1"
    assert list(doc) == ["format", "id", "camera", "pattern", "planes_mm", "specimen", "provenance"]
    assert doc["provenance"]["simulated"] is True and "captured_at" not in doc["provenance"]
    assert doc["provenance"]["instrument"].startswith("huefringe virtual bench")
    from huefringe.session import load_session

    assert load_session(out).provenance == doc["provenance"]  # the reader accepts what the bench writes
    spec = doc["specimen"]
    assert [(s["name"], s["nominal_mm"]) for s in spec["steps"]] == [("green", 3.0), ("blue", 1.0), ("red", 4.0)]
    base = 0.5
    for n in range(3):
        gt = tifffile.imread(out / f"ground_truth/frames/frame_{n:04d}.tiff")
        assert gt.dtype == np.float32 and gt.shape == (80, 120)
        dz = 0.03 * np.sin(TWO_PI * 29.0 * n / 60.0 + 0.4)
        for step in spec["steps"]:
            u0, v0, u1, v1 = step["roi"]
            np.testing.assert_allclose(gt[v0:v1, u0:u1], base + step["nominal_mm"] + dz, atol=1e-6)
        for u0, v0, u1, v1 in spec["base_roi"]:
            np.testing.assert_allclose(gt[v0:v1, u0:u1], base + dz, atol=1e-6)
        assert gt[0, 0] == 0.0  # bare plate outside the base does not vibrate
    assert len({float(tifffile.imread(out / f"ground_truth/frames/frame_{n:04d}.tiff")[40, 60]) for n in range(3)}) == 3


def test_lateral_vibration_moves_the_object_not_the_plate() -> None:
    cfg = hb.validate_bench_config(
        gauge_session(vibration={"amplitude_mm": 0.0, "frequency_hz": 15.0, "lateral_amplitude_mm": 0.4})
    )
    bench = Bench(cfg)
    rest = bench.ground_truth(None)
    moved = bench.ground_truth(bench.frame_time(1))  # 15 Hz at 60 fps: a quarter period, dx = +0.4 mm
    assert bench.motion(bench.frame_time(1))[0] == pytest.approx(0.4)
    inner = (slice(10, 70), slice(10, 110))  # inside the base: pure 2-pixel shift
    np.testing.assert_array_equal(moved[inner], rest[inner[0], 8:108])
    assert moved[0, 0] == rest[0, 0] == 0.0


@pytest.mark.parametrize(("fmt", "depth"), [("png", 8), ("tiff", 16)])
def test_written_session_passes_the_session_validator(tmp_path: Path, fmt: str, depth: int) -> None:
    from huefringe.session import load_session

    cfg = gauge_session(session={"frames": 2, "repeats": 1, "image_format": fmt, "bit_depth": depth})
    out = hb.write_session(cfg, tmp_path / "s")
    s = load_session(out, deep=True)
    assert s.id == "gauge-test" and len(s.frames) == 2 and len(s.phase_shift) == 2 and len(s.ground_truth) == 2
    assert s.bit_depth == depth


def test_base_roi_avoids_shadows_and_blocks() -> None:
    cfg = hb.validate_bench_config(gauge_session())
    bench = Bench(cfg)
    spec = hb.session_document(cfg, bench)["specimen"]
    light = bench.lighting(bench.object_surface(None))
    shadow = bench.grid.downsample(light.shadow.astype(np.float32)) > 0
    gt = bench.ground_truth(None)
    assert shadow.any()
    for u0, v0, u1, v1 in spec["base_roi"]:
        assert not shadow[v0:v1, u0:u1].any()
        np.testing.assert_allclose(gt[v0:v1, u0:u1], 0.5)
    for s in spec["steps"]:
        u0, v0, u1, v1 = s["roi"]
        assert not shadow[v0:v1, u0:u1].any()


def test_period_sweep_ids_and_periods(tmp_path: Path) -> None:
    cfg = gauge_session(session={"width": 80, "height": 64, "frames": 1, "hue_bands": 6, "repeats": 1},
                        phase_shift={"enabled": False}, scene={"blocks": "table1"})
    paths = hb.period_sweep(cfg, periods=(20, 40), out_root=tmp_path)
    assert [p.name for p in paths] == ["gauge-test-p20", "gauge-test-p40"]
    for p, period in zip(paths, (20, 40), strict=True):
        doc = yaml.safe_load((p / "session.yaml").read_text())
        assert doc["id"] == p.name and doc["pattern"]["period_px"] == period
        assert [s["name"] for s in doc["specimen"]["steps"]] == ["blue"]


def test_existing_non_session_folder_is_not_replaced(tmp_path: Path) -> None:
    target = tmp_path / "keep"
    target.mkdir()
    (target / "precious.txt").write_text("x")
    with pytest.raises(FileExistsError):
        hb.write_session(ideal(session={"width": 32, "height": 16}), target)
    assert (target / "precious.txt").exists()


# ------------------------------------------------------------------------------ scenes
def test_heightmap_and_mesh_scenes(tmp_path: Path) -> None:
    import trimesh

    hm = np.full((20, 30), np.nan, np.float32)
    hm[5:15, 10:20] = 2.0
    tifffile.imwrite(tmp_path / "h.tiff", hm)
    cfg = ideal(session={"width": 40, "height": 30},
                scene={"kind": "heightmap", "path": str(tmp_path / "h.tiff"), "offset_mm": [1.0, 1.0]})
    gt = Bench(cfg).ground_truth(None)
    assert gt[15, 20] == pytest.approx(2.0) and gt[2, 2] == 0.0

    box = trimesh.creation.box(extents=(3.0, 2.0, 1.5))
    box.apply_translation((4.0, 3.0, 0.75))
    box.export(tmp_path / "box.stl")
    cfg = ideal(session={"width": 40, "height": 30}, scene={"kind": "mesh", "path": str(tmp_path / "box.stl")})
    gt = Bench(cfg).ground_truth(None)
    assert gt[15, 20] == pytest.approx(1.5, abs=1e-5)  # X = 4, Y = 3: box centre
    assert gt[15, 5] == 0.0
    assert np.count_nonzero(gt > 0) == pytest.approx(15 * 10, abs=30)


def test_dental_scene_is_colourful_and_smooth() -> None:
    cfg = ideal(session={"width": 200, "height": 150, "pixel_pitch_mm": 0.4}, scene={"kind": "dental"})
    smp = Bench(cfg).object_surface(None, fine=False)
    h, refl = smp.height, smp.reflectance
    assert 4.0 < h.max() < 6.0
    assert np.abs(np.diff(h, axis=1)).max() < 0.4 * 2.5  # no cliffs: tooth flanks steeper than 70 deg
    on = h > 3.5
    assert refl[on][:, 2].mean() > 0.55 and refl[(h > 0.5) & (h < 1.5)][:, 1].mean() < 0.5  # ivory vs pink


# ------------------------------------------------------------------------------ configuration
def test_unknown_key_is_refused_naming_the_file(tmp_path: Path) -> None:
    raw = yaml.safe_load(hb.preset_path("demo").read_text())
    raw["session"]["colour"] = "red"
    bad = tmp_path / "bad-bench.yaml"
    bad.write_text(yaml.safe_dump(raw))
    with pytest.raises(BenchConfigError) as exc:
        hb.load_bench_config(bad)
    assert str(bad) in str(exc.value) and "colour" in str(exc.value) and "session" in str(exc.value)

    raw = yaml.safe_load(hb.preset_path("demo").read_text())
    raw["scene"]["block"] = "fig9"
    bad.write_text(yaml.safe_dump(raw))
    with pytest.raises(BenchConfigError, match=r"bad-bench\.yaml: .*scene.*'block'"):
        hb.load_bench_config(bad)

    raw = yaml.safe_load(hb.preset_path("demo").read_text())
    raw["session"]["planes_mm"] = [1.0, 2.0]
    bad.write_text(yaml.safe_dump(raw))
    with pytest.raises(BenchConfigError, match="planes_mm must contain 0"):
        hb.load_bench_config(bad)


@pytest.mark.parametrize("name", ["demo", "flat", "dental", "table1"])
def test_presets_are_valid(name: str) -> None:
    cfg = hb.load_bench_config(hb.preset_path(name))
    assert hb.validate_bench_config(cfg) == cfg  # completed configs are fixed points
    summary = hb.rig_summary(cfg)
    assert 25.0 <= summary["triangulation_angle_deg"]["centre"] <= 35.0
    assert summary["max_abs_dphi_object_over_pi"] < 0.6


def test_demo_preset_matches_the_brief() -> None:
    cfg = hb.load_bench_config("demo")
    s = cfg["session"]
    assert s["id"] == "gauge-blocks-demo" and s["frames"] == 10 and s["period_px"] == 60
    assert (s["hue_bands"], s["repeats"], s["planes_mm"]) == (64, 3, [0.0, 3.0, 6.0])
    assert cfg["phase_shift"]["enabled"] and cfg["vibration"]["amplitude_mm"] > 0
    doc = hb.session_document(cfg)
    assert [st["nominal_mm"] for st in doc["specimen"]["steps"]] == [3.0, 1.0, 4.0]
    t1 = hb.load_bench_config("table1")
    assert t1["session"]["frames"] == 30 and t1["phase_shift"]["enabled"] and t1["vibration"]["amplitude_mm"] > 0
    assert [(st["name"], st["nominal_mm"]) for st in hb.session_document(t1)["specimen"]["steps"]] == [("blue", 1.0)]


def test_bench_writes_capture_date_and_operator_when_configured() -> None:
    cfg = hb.validate_bench_config(gauge_session(session={"captured_at": "2026-11-30T14:05:00Z", "operator": "J. Doe"}))
    prov = hb.session_document(cfg)["provenance"]
    assert prov["captured_at"] == "2026-11-30T14:05:00Z" and prov["operator"] == "J. Doe" and prov["simulated"] is True
    from huefringe.bench.writer import dump_session_yaml

    text = dump_session_yaml(hb.session_document(cfg))
    assert yaml.safe_load(text)["provenance"]["simulated"] is True


# ------------------------------------------------------------------------------ projector image files
def _image_rig(defocus: float) -> hb.Rig:
    cfg = ideal(projector={"pixel_mm": 0.1, "defocus_sigma_px": defocus, "gamma": [2.2, 2.0, 2.4], "x_origin_mm": 1.3})
    return hb.Rig.from_config(cfg)


@pytest.mark.parametrize("defocus", [0.0, 0.8])
def test_projector_image_emits_the_analytic_trapezoid(defocus: float) -> None:
    rig = _image_rig(defocus)  # period 40 px x 0.2 mm = 8 mm = 80 projector px of 0.1 mm
    period = rig.period_mm / rig.projector_pixel_mm
    codes = patterns.projector_image(1024, 8, period)
    x0 = np.linspace(-3.0, 40.0, 5001)
    c = (x0 - rig.x_origin_mm) / rig.projector_pixel_mm
    x0 = x0[np.abs(c - np.floor(c) - 0.5) > 1e-6]  # not on a pixel border (either pixel is right there)
    analytic = hb.emitted_rgb(Pattern.trapezoid(), x0, rig)
    shift = 5 * period  # a whole number of periods keeps every code phase
    image = hb.emitted_rgb(Pattern.image(codes, period, col_shift=shift), x0, rig)
    # the same projector pixels, codes and gamma; but at T = 80 px one column in eight has a code exactly
    # half-way between two steps (6 j / 80 * 255 = 19.125 j), which may round the other way along the
    # file's float path: one code, <= gamma / 255 in output
    assert np.max(np.abs(image - analytic)) < 2.4 / 255
    if defocus == 0.0:
        same = np.mean(np.all(image == analytic, axis=-1))
        assert 0.8 < same < 1.0


def test_projector_image_rows_and_uniform_images() -> None:
    rig = _image_rig(0.0)
    white = Pattern.image(np.full((6, 9, 3), 255, np.uint8), 80.0)
    assert white == Pattern.white()  # a uniform file is the uniform pattern of its codes
    band = patterns.quantise(patterns.band_rgb(3, 16))
    assert Pattern.image(np.broadcast_to(band, (4, 4, 3)).copy(), 80.0) == Pattern("uniform", tuple(band / 255.0))
    # an image whose rows differ: top half the trapezoid, bottom half black; rows centred on y_centre_mm
    codes = patterns.projector_image(1024, 200, 80.0)
    codes[100:] = 0
    pat = Pattern.image(codes, 80.0, y_centre_mm=10.0, col_shift=160.0)
    x0 = np.linspace(0.0, 60.0, 301)
    top = hb.emitted_rgb(pat, x0, rig, np.full_like(x0, 10.0 - 5.0))  # 50 rows above the centre
    bottom = hb.emitted_rgb(pat, x0, rig, np.full_like(x0, 10.0 + 5.0))
    np.testing.assert_allclose(top, hb.emitted_rgb(Pattern.trapezoid(), x0, rig), atol=2.4 / 255)
    assert np.all(bottom == 0.0)
    with pytest.raises(ValueError, match="y0"):
        hb.emitted_rgb(pat, x0, rig)
    # with defocus, the exact 2-D box-Gaussian weights agree with the 1-D table far from the edge
    blurred = _image_rig(1.5)
    far = hb.emitted_rgb(pat, x0, blurred, np.full_like(x0, 5.0))
    np.testing.assert_allclose(far, hb.emitted_rgb(Pattern.image(codes[:100], 80.0, col_shift=160.0), x0, blurred),
                               atol=2e-3)
    edge = hb.emitted_rgb(pat, x0, blurred, np.full_like(x0, 10.0 - 0.05))  # half a pixel above the step
    assert 0.3 < float(np.mean(edge / np.maximum(far, 1e-6))[()]) < 0.7


def test_bench_capture_of_an_image_whose_rows_differ() -> None:
    from huefringe.bench.projector import image_placement

    b = Bench(ideal())  # 160 x 60 px at 0.2 mm; continuous projector: pixels of P / T = 0.1 mm
    shift, y_centre = image_placement(b, 1024, 768, 80.0)
    assert shift % 80.0 == 0.0 and y_centre == pytest.approx(0.5 * 59 * 0.2)
    codes = patterns.projector_image(1024, 768, 80.0)
    codes[384:] = 0  # the lower half of the projector image is black: rows below the field's centre
    img = b.capture(Pattern.image(codes, 80.0, col_shift=shift, y_centre_mm=y_centre))
    full = b.capture(Pattern.trapezoid())
    assert img.max() > 0 and np.all(img[31:] == 0)
    np.testing.assert_allclose(img[:29].astype(float), full[:29].astype(float), atol=0.01 * 65535)
    with pytest.raises(hb.ProjectionError, match="projector columns are needed"):
        image_placement(b, 200, 768, 80.0)
    with pytest.raises(hb.ProjectionError, match="projector rows are needed"):
        image_placement(b, 1024, 100, 80.0)
