"""The bench rig's structured-light sessions (huefringe.bench.rig_session): presets rig-poses,
rig-gauge, rig-board; projector shadows, features.yaml and ground truth against the scene's truth."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import tifffile
import yaml
from numpy.typing import NDArray

from huefringe import bench
from huefringe.bench.rig import RIGS, CompositeScene, SphereScene, StepsScene, segment_hits_box, segment_hits_sphere
from huefringe.bench.rig_session import load_sl_bench_config, scene_truth, sl_session_plan, write_sl_session
from huefringe.codecs import decode_sequence
from huefringe.rig import triangulate
from huefringe.session import load_sl_session

PRESETS = ("rig-poses", "rig-gauge", "rig-board")


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("rig-sessions")
    return {name: write_sl_session(load_sl_bench_config(name), root / name) for name in PRESETS}


@pytest.fixture(scope="module")
def gauge_truth() -> dict:
    return scene_truth(load_sl_bench_config("rig-gauge"))


@pytest.fixture(scope="module")
def gauge_decoded(sessions: dict[str, Path]) -> dict:
    s = load_sl_session(sessions["rig-gauge"])
    return decode_sequence(s.read_captures(), s.spec)


def test_sessions_are_deep_valid_and_hold_what_the_plan_says(sessions: dict[str, Path]) -> None:
    for name, path in sessions.items():
        s = load_sl_session(path, deep=True)
        plan = sl_session_plan(load_sl_bench_config(name))
        assert s.id == plan["id"] == name
        assert sorted(s.poses) == plan["pose_names"]
        assert (s.features is not None) == plan["features"]
        assert sorted(s.ground_truth) == ["x", "xyz", "y"]
        assert len(s.captures) == plan["frames"] == 38
        cal = s.calibration_session
        assert (None if cal is None else "../" + cal.name) == plan["calibration_session"]
    poses = load_sl_session(sessions["rig-poses"])
    assert len(poses.poses) == 8 and poses.meta["board"] == {"cols": 9, "rows": 7, "pitch_mm": 12.0, "kind": "chessboard"}
    assert poses.calibration_session is None and poses.features is None
    gauge = load_sl_session(sessions["rig-gauge"])
    assert gauge.meta["calibration"] == {"session": "../rig-poses"}
    assert gauge.calibration_session.resolve() == sessions["rig-poses"].resolve()
    assert not list(sessions["rig-gauge"].parent.glob(".*partial"))  # written atomically, nothing left behind


def test_ground_truth_triangulates_to_xyz(sessions: dict[str, Path], gauge_truth: dict) -> None:
    calib = RIGS["holdout-wide"].calibration
    # in float64: the true projector coordinates and the true calibration give the true points
    t = gauge_truth
    tri = triangulate(calib, t["u"], t["v"], valid=t["lit"])
    lit = t["lit"]
    assert np.array_equal(tri.valid, lit)
    assert np.nanmax(np.linalg.norm(tri.xyz[lit] - t["xyz"][lit], axis=1)) < 1e-6
    # the stored float32 files agree to their own resolution (a float32 ulp of ~430 mm is 3e-5 mm)
    for name in ("rig-gauge", "rig-board", "rig-poses"):
        gt = sessions[name] / "ground_truth"
        u, v, xyz = (tifffile.imread(gt / f).astype(np.float64) for f in ("x.tiff", "y.tiff", "xyz.tiff"))
        ok = np.isfinite(u)
        assert np.array_equal(ok, np.isfinite(xyz).all(axis=2)) and np.array_equal(ok, np.isfinite(v))
        err = np.linalg.norm(triangulate(calib, u, v, valid=ok).xyz[ok] - xyz[ok], axis=1)
        assert err.max() < 1e-4, (name, err.max())


def test_the_composite_scene_casts_shadows_and_shadows_carry_no_fringe(sessions: dict[str, Path], gauge_truth: dict) -> None:
    t = gauge_truth
    shadow = t["shadow"]
    names = t["names"]
    on_base = int((shadow & (t["label"] == 0)).sum())
    on_ball = int((shadow & (t["label"] == 4)).sum())
    assert names[4] == "ball"
    assert on_base > 3000 and on_ball > 100, (on_base, on_ball)
    xyz = tifffile.imread(sessions["rig-gauge"] / "ground_truth" / "xyz.tiff")
    assert np.isnan(xyz[shadow]).all()
    frames = np.stack(load_sl_session(sessions["rig-gauge"]).read_captures()).astype(np.float64)
    i0, i1, i2, i3 = frames[:4]                       # the four-step phase block on x
    modulation = 0.5 * np.hypot(i0 - i2, i1 - i3)
    # noise only in shadow: 1 DN read noise gives a Rayleigh amplitude of mean 0.63 DN
    assert modulation[shadow].mean() < 1.0 and np.percentile(modulation[shadow], 99.9) < 4.0
    assert abs(frames[:, shadow].mean() - 0.05 * 255) < 0.5      # ambient light only
    assert np.median(modulation[t["lit"]]) > 50.0


def test_features_lie_inside_their_faces(sessions: dict[str, Path], gauge_truth: dict) -> None:
    t = gauge_truth
    feats = yaml.safe_load((sessions["rig-gauge"] / "features.yaml").read_text())
    margin = load_sl_bench_config("rig-gauge")["features"]["margin_px"]
    label_of = {v: k for k, v in t["names"].items()}
    regions = [(0, b) for b in feats["base"]["boxes"]]
    regions += [(label_of[s["name"]], s["box"]) for s in feats["steps"]]
    regions += [(label_of["block-" + p["name"].removeprefix("top-")], p["box"]) for p in feats["planes"]]
    regions += [(label_of[s["name"]], s["box"]) for s in feats["spheres"]]
    assert len(feats["base"]["boxes"]) == 3 and len(feats["steps"]) == 3 and len(feats["spheres"]) == 1
    assert [s["nominal_mm"] for s in feats["steps"]] == [2.0, 5.0, 10.0]
    assert feats["spheres"][0]["nominal_radius_mm"] == 12.5
    assert {d["nominal_mm"] for d in feats["distances"]} == {2.0, 5.0, 10.0}
    for k, (x0, y0, x1, y1) in regions:
        face = (t["label"] == k) & t["lit"]
        # the box grown by the margin is still on the face and lit: no edge or shadow pixel within it
        grown = face[max(y0 - margin, 0):y1 + margin, max(x0 - margin, 0):x1 + margin]
        assert grown.all(), (k, (x0, y0, x1, y1))
        assert (x1 - x0) >= 20 and (y1 - y0) >= 20
    board = yaml.safe_load((sessions["rig-board"] / "features.yaml").read_text())
    assert board["planes"][0]["name"] == "board" and board["base"]["boxes"]


def test_the_gauge_decodes_to_the_truth(gauge_decoded: dict, gauge_truth: dict) -> None:
    t = gauge_truth
    lit, shadow = t["lit"], t["shadow"]
    for axis, truth in (("x", t["u"]), ("y", t["v"])):
        d = gauge_decoded[axis]
        ok = d.valid & lit
        # Gray cells half the fringe period: every order decided with a quarter period to spare, so
        # the lit pixels the decoder drops are the ones at the scene's edges and the ball's rim
        assert ok.sum() > 0.97 * lit.sum(), ok.sum() / lit.sum()
        err = d.coord[ok] - truth[ok]
        assert np.median(np.abs(err)) < 0.02 and np.abs(err).max() < 0.2, (axis, np.median(np.abs(err)), np.abs(err).max())
        assert np.percentile(np.abs(err) / d.sigma[ok], 99.9) < 5.0        # within the decoder's noise
        assert (~d.valid[shadow]).mean() > 0.99


def test_shadow_geometry() -> None:
    c = np.zeros(3)
    R, o = np.eye(3), np.zeros(3)
    box = (-1.0, -1.0, 1.0, 1.0, 2.0)
    p = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 2.0], [5.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    # through the block; ending on its face; beside it; ending on its near face (z = 0 is its bottom)
    assert segment_hits_box(c - [0, 0, 1], p, R, o, box).tolist() == [True, True, False, False]
    assert segment_hits_sphere(np.array([0.0, 0, -10]), np.array([[0.0, 0, -1], [0.0, 0, 1], [3.0, 0, 0]]),
                               np.zeros(3), 1.0).tolist() == [False, True, False]
    rig = RIGS["holdout-wide"]
    for scene in (StepsScene(), SphereScene(), CompositeScene()):
        xyz, seen = scene.cast(rig.rays)[:2]
        lit = scene.lit(rig, xyz, seen)
        assert 0 < (seen & ~lit).sum() < 0.1 * seen.sum(), type(scene).__name__


def test_stage_and_cli_dispatch_on_the_yaml(tmp_path: Path) -> None:
    from huefringe.cli import main
    from huefringe.stages import bench_session

    assert bench.bench_kind("rig-gauge") == "structured-light-session/1"
    assert bench.bench_kind("demo") == "capture-session/1"
    bench_session("rig-board", str(tmp_path / "a"))
    assert load_sl_session(tmp_path / "a").id == "rig-board"
    cfg = yaml.safe_load(bench.preset_path("rig-board").read_text())
    cfg.update(id="board-two", seed=9, camera={"noise_dn": 0.5})
    (tmp_path / "b.yaml").write_text(yaml.safe_dump(cfg))
    assert main(["bench", str(tmp_path / "b.yaml"), str(tmp_path / "b"), "--quiet"]) == 0
    s = load_sl_session(tmp_path / "b", deep=True)
    assert s.id == "board-two" and cv2.imread(str(s.captures[0]), cv2.IMREAD_UNCHANGED).shape == (480, 640)
    cfg["scene"]["unknown"] = 1
    with pytest.raises(bench.BenchConfigError, match="unknown|Additional"):
        bench.validate_sl_bench_config(cfg)


def test_oneshot_preset_writes_colour_captures_with_coated_blocks(tmp_path: Path) -> None:
    cfg = load_sl_bench_config("rig-oneshot")
    plan = sl_session_plan(cfg)
    assert plan["oneshot_frames"] == 3 and plan["frames"] == 4 + 14 + 2 + 96 + 3
    s = load_sl_session(write_sl_session(cfg, tmp_path / "rig-oneshot"), deep=True)
    assert s.meta["camera"]["channels"] == 3 and sorted(s.ground_truth) == ["x", "xyz"]   # the coded axis only
    truth = scene_truth(cfg)
    white = cv2.imread(str(s.captures[18]), cv2.IMREAD_UNCHANGED)[..., ::-1].astype(float)  # R, G, B
    lit = truth["lit"]
    for label, dominant in ((1, 1), (2, 2), (3, 0)):                  # green, blue, red coatings
        m = (truth["label"] == label) & lit
        rgb = white[m].mean(axis=0)
        assert np.argmax(rgb) == dominant and rgb[dominant] > 1.8 * np.sort(rgb)[1], (label, rgb)
    base = white[(truth["label"] == 0) & lit].mean(axis=0)
    assert np.ptp(base) < 0.15 * base.mean()                            # the base stays grey
    assert sl_session_plan(load_sl_bench_config("rig-gauge"))["oneshot_frames"] == 0
    bad = yaml.safe_load(bench.preset_path("rig-oneshot").read_text())
    bad["scene"]["colours"] = ["green"]
    with pytest.raises(bench.BenchConfigError, match="1 coatings for 3 blocks"):
        bench.validate_sl_bench_config(bad)


def test_vibration_moves_the_scene_between_the_oneshot_frames_only(tmp_path: Path) -> None:
    from huefringe.bench.rig_session import _albedo_map, _colour_patterns, _spec, displaced_config, vibration_displacements
    from huefringe.bench.oneshot import CROSSTALK

    cfg = load_sl_bench_config("rig-oneshot-vibrating")
    v = cfg["vibration"]
    d = vibration_displacements(cfg)
    assert d.shape == (5, 3) and sl_session_plan(cfg)["oneshot_frames"] == 5
    t = np.arange(5)[:, None] / 60.0 + np.array([-1, 0, 1])[None, :] * 3.5e-3 / 3
    np.testing.assert_allclose(d, 0.03 * np.sin(2 * np.pi * 29.0 * t + 0.4), atol=1e-15)   # the demo's membrane
    assert (v["amplitude_mm"], v["frequency_hz"], v["frame_rate_hz"]) == (0.03, 29.0, 60.0)
    # the still scene's truth moved along the base's normal: every point by d along it, the steps unchanged
    r0, r1 = scene_truth(cfg), scene_truth(displaced_config(cfg, 0.5))
    R, o = CompositeScene(tilt_deg=tuple(cfg["scene"]["tilt_deg"]), origin=tuple(cfg["scene"]["origin"])).frame()
    n = R[:, 2]
    both = (np.isfinite(r0["xyz"]).all(-1) & np.isfinite(r1["xyz"]).all(-1) & (r0["label"] == r1["label"])
            & (r0["label"] >= 0))                                     # the base and the tops, not the walls
    h0, h1 = (r0["xyz"][both] - o) @ n, (r1["xyz"][both] - o) @ n
    np.testing.assert_allclose(h1 - h0, 0.5, atol=1e-9)
    assert both.sum() > 0.95 * np.isfinite(r0["xyz"]).all(-1).sum()
    # a small session with a large motion: the one-shot frames are each the exposure's mean of the moving
    # scene (noise 1 DN), the other frames the still scene's
    small = {**cfg, "vibration": {**v, "amplitude_mm": 2.0, "frequency_hz": 7.0, "phase_rad": 1.0},
             "sequence": {**cfg["sequence"], "blocks": [*cfg["sequence"]["blocks"][:4], {"hue_bands": {"n": 12, "repeats": 1}},
                                                        {"trapezoid": {"axis": "x", "period_px": 36, "frames": 2}}]}}
    small = bench.validate_sl_bench_config(small)
    s = load_sl_session(write_sl_session(small, tmp_path / "vib"), deep=True)
    spec, pats = _spec(small), _colour_patterns(_spec(small))
    first = spec.n_frames - 2
    d = vibration_displacements(small)
    assert np.abs(d).min() > 1.0                                      # every instant well off the still scene
    gt = tifffile.imread(s.root / "ground_truth/xyz.tiff")            # where the first one-shot frame sees the scene
    want = scene_truth(displaced_config(small, float(d[0].mean())))["xyz"]
    np.testing.assert_array_equal(np.isfinite(gt), np.isfinite(want))
    np.testing.assert_allclose(gt[np.isfinite(gt)], want[np.isfinite(want)], atol=1e-4)

    def expected(k: int, ds: Any) -> NDArray[np.float64]:
        out = 0.0
        for x in ds:
            tr = scene_truth(displaced_config(small, float(x)))
            out = out + tr["rig"].capture_rgb([pats[k]], tr["u"], tr["v"], tr["lit"], None, albedo=_albedo_map(small, tr["label"]),
                                              ambient=small["camera"]["ambient"], crosstalk=CROSSTALK, signal_only=True)[0]
        return out / len(ds)

    for k, ds in ((first, d[0]), (first + 1, d[1]), (18, [0.0])):   # the two one-shot frames, the white frame
        img = cv2.imread(str(s.captures[k]), cv2.IMREAD_UNCHANGED)[..., ::-1].astype(float)
        moved, still = img - expected(k, ds), img - expected(k, [0.0])
        inside = (expected(k, ds) > 5) & (expected(k, ds) < 250)
        assert 0.9 < np.std(moved[inside]) < 1.2, k                   # read noise and rounding only
        if k >= first:
            assert np.std(still[inside]) > 3.0, k                     # not the still scene
    with pytest.raises(bench.BenchConfigError, match="vibration"):
        bench.validate_sl_bench_config({**load_sl_bench_config("rig-gauge"), "vibration": {"amplitude_mm": 0.03, "frequency_hz": 29.0}})
