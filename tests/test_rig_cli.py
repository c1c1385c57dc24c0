"""rig-calibrate and rig-measure end to end on bench captures decoded by huefringe.codecs; refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from huefringe.bench.rig import RIGS, PlaneScene, write_captures, write_pose_folders
from huefringe.cli import main
from huefringe.codecs import load_sequence
from huefringe.rig import Board, read_calibration

SEQ = {"projector": {"width": 800, "height": 600}, "frames": "cap_*.png", "blocks": [
    {"phase": {"axis": "x", "period_px": 16, "steps": 4}}, {"gray": {"axis": "x", "cells": 50, "cell_px": 16}},
    {"phase": {"axis": "y", "period_px": 16, "steps": 4}}, {"gray": {"axis": "y", "cells": 38, "cell_px": 16}},
    "white", "black"]}


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    root = tmp_path_factory.mktemp("rig")
    (root / "seq.yaml").write_text(yaml.safe_dump(SEQ))
    spec = load_sequence(root / "seq.yaml")
    rig = RIGS["holdout-wide"]
    write_pose_folders(rig, Board(9, 7, 12.0), spec, 6, 4, root / "poses")
    xyz, ok = PlaneScene(point=(0.0, 0.0, 430.0)).cast(rig.rays)
    m = rig.coordinates(xyz, ok, np.random.default_rng(0), 0.0)
    write_captures(rig, spec, root / "plane", m["u_true"], m["v_true"], m["valid"], np.random.default_rng(1))
    return root, rig


def test_captures_to_calibration_to_cloud(bench, capsys):
    from huefringe.io import read_tiff
    from huefringe.metrology import flatness_u

    root, rig = bench
    assert main(["rig-calibrate", str(root / "poses"), str(root / "seq.yaml"), str(root / "calib.yml"),
                 "--board", "9x7", "--pitch-mm", "12"]) == 0
    out = capsys.readouterr().out
    assert "camera alone" in out and "stereo (joint model)" in out and "leave-one-pose-out" in out
    calib = read_calibration(root / "calib.yml")
    truth = rig.calibration
    assert abs(calib.camera_matrix[0, 0] / truth.camera_matrix[0, 0] - 1) < 0.003
    assert abs(calib.projector_matrix[0, 0] / truth.projector_matrix[0, 0] - 1) < 0.003
    assert abs(calib.baseline_mm - truth.baseline_mm) < 0.3
    report = json.loads((root / "calib.report.json").read_text())
    assert [p["name"] for p in report["poses"]] == [f"pose_{i:02d}" for i in range(6)]
    assert set(report["rms_definitions"]) >= {"camera", "projector", "stereo"}
    assert len(json.loads((root / "calib.jackknife.json").read_text())["left_out"]) == 6
    # captures in a folder: assembled into OUTDIR/session, then measured as the workflow measures a session
    assert main(["rig-measure", str(root / "plane"), str(root / "seq.yaml"), str(root / "calib.yml"), str(root / "out")]) == 0
    out = capsys.readouterr().out
    assert "no features.yaml in the session, so no metrology report" in out
    assert (root / "out" / "session" / "session.yaml").is_file()
    xyz, sigma = read_tiff(root / "out/xyz/frame_0000.tiff"), read_tiff(root / "out/xyz/frame_0000_sigma.tiff")[..., :3]
    ok = np.isfinite(xyz).all(axis=-1)
    flat = flatness_u(xyz[ok], sigma[ok])
    assert flat["rms_form_mm"] < 0.02 and flat["rms_mm"] < 2 * np.median(np.linalg.norm(sigma[ok], axis=-1)) + 0.01
    for name in ("cloud/frame_0000.ply", "mesh/frame_0000.ply", "height/frame_0000.tiff", "x3p/frame_0000.x3p",
                 "renders/frame_0000_top.png"):
        assert (root / "out" / name).stat().st_size > 1000, name
    assert not (root / "out" / "metrology").exists()
    # the ray test: counted in the QA record, its thresholds from --configfile as every codecs threshold
    v = json.loads((root / "out/qa/frames/frame_0000.json").read_text())["validity"]
    assert v["ray_test"]["dropped"] == 0 and v["ray_test"]["tested"] == int(ok.sum())
    assert v["ray_test"]["ray_floor_px"] == 0.75 and v["dropped_pixels"]["x"]["ray"] == 0
    strict = root / "strict.yaml"
    strict.write_text("codecs: {max_ray_sigma: 0.5, ray_floor_px: 0.0}\n")
    assert main(["rig-measure", str(root / "plane"), str(root / "seq.yaml"), str(root / "calib.yml"), str(root / "out2"),
                 "--configfile", str(strict)]) == 0
    v2 = json.loads((root / "out2/qa/frames/frame_0000.json").read_text())["validity"]
    assert v2["ray_test"]["max_ray_sigma"] == 0.5 and v2["ray_test"]["dropped"] > 0.2 * v2["ray_test"]["tested"]
    assert v2["dropped_pixels"]["x"]["ray"] == v2["dropped_pixels"]["y"]["ray"] == v2["ray_test"]["dropped"]
    capsys.readouterr()


def test_refusals_name_the_files(bench, tmp_path, capsys):
    root, _ = bench
    assert main(["rig-calibrate", str(tmp_path), str(root / "seq.yaml"), str(tmp_path / "c.yml"),
                 "--board", "9x7", "--pitch-mm", "12"]) == 2
    assert f"{tmp_path}: no pose folders" in capsys.readouterr().err
    assert main(["rig-calibrate", str(root / "poses"), str(root / "seq.yaml"), str(tmp_path / "c.yml"),
                 "--board", "8x6", "--pitch-mm", "12"]) == 2
    err = capsys.readouterr().err
    assert "pose_00: the 8 x 6 chessboard was not found" in err and "pose_05" in err
    assert not (tmp_path / "c.yml").exists()
    # pose folders without a board named: refused before any work
    assert main(["rig-calibrate", str(root / "poses"), str(root / "seq.yaml"), str(tmp_path / "c.yml")]) == 2
    assert "--board COLSxROWS and --pitch-mm MM" in capsys.readouterr().err
    assert main(["rig-measure", str(root / "plane"), str(root / "seq.yaml"), str(tmp_path / "none.yml"),
                 str(tmp_path / "out")]) == 2
    assert "none.yml: missing calibration file" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_an_slmaster_folder_measures_as_it_was_written(tmp_path, capsys):
    """A folder as an SLMaster rig leaves it: BMP frames, four-step fringes of one Gray cell's period
    then the complementary Gray code, no inverses, no white or black, and its caliInfo.yml: the
    cloud lies on the true plane."""
    from huefringe.io import read_tiff
    from huefringe.rig import write_calibration

    rig = RIGS["holdout-wide"]
    seq = {"projector": {"width": 800, "height": 600}, "frames": "*.bmp", "blocks": [
        {"phase": {"axis": "x", "period_px": 16, "steps": 4, "origin_px": 8}},
        {"gray": {"axis": "x", "bits": 6, "cell_px": 16, "inverse": False, "complementary": True}},
        {"phase": {"axis": "y", "period_px": 16, "steps": 4, "origin_px": 8}},
        {"gray": {"axis": "y", "bits": 6, "cell_px": 16, "inverse": False, "complementary": True}}]}
    (tmp_path / "sequence.yaml").write_text(yaml.safe_dump(seq))
    spec = load_sequence(tmp_path / "sequence.yaml")
    xyz_true, ok = PlaneScene(point=(0.0, 0.0, 430.0)).cast(rig.rays)
    m = rig.coordinates(xyz_true, ok, np.random.default_rng(0), 0.0)
    write_captures(rig, spec, tmp_path / "scan", m["u_true"], m["v_true"], m["valid"], np.random.default_rng(1),
                   name="{:d}.bmp")
    write_calibration(tmp_path / "caliInfo.yml", rig.calibration, layout="slmaster")
    assert main(["rig-measure", str(tmp_path / "scan"), str(tmp_path / "sequence.yaml"), str(tmp_path / "caliInfo.yml"),
                 str(tmp_path / "out")]) == 0
    capsys.readouterr()
    xyz = read_tiff(tmp_path / "out/xyz/frame_0000.tiff")
    sigma = read_tiff(tmp_path / "out/xyz/frame_0000_sigma.tiff")[..., :3]
    got = np.isfinite(xyz).all(axis=-1)
    assert got[m["valid"]].mean() > 0.99 and not got[~m["valid"]].any()
    err = np.linalg.norm(xyz[got] - xyz_true[got], axis=-1)
    assert np.median(err) < 0.02 and np.percentile(err, 99.9) < 5 * np.median(np.linalg.norm(sigma[got], axis=-1))
