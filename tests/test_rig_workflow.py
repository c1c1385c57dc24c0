"""Structured-light sessions through the workflow: the bench's calibration session (printed-board
poses) and gauge (blocks of 2, 5, 10 mm and a 12.5 mm ball on a tilted base, with projector
shadows) on the holdout-wide rig, from captures to report.html with no CLI step; the report's
figures against the bench's truth, the per-pixel X, Y, Z outputs, reproducibility, archives."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile
import yaml
from bench_helpers import CONFIG, REPO

from huefringe.archive import verify_archive
from huefringe.io import tiff_pixel_pitch_mm
from huefringe.report import validate_report


def rig_workdir(path: Path, session: str = "rig-gauge", others: tuple[str, ...] = ("rig-poses",)) -> Path:
    """A run folder whose config lists bench preset ``session`` only (``sessions/<session>``): the
    sessions it names (its calibration session, a one-shot reference: ``others``) join the run by
    themselves; the bench writes every one."""
    path.mkdir(parents=True, exist_ok=True)
    cfg = json.loads(json.dumps(CONFIG))
    cfg["sessions"] = [f"sessions/{session}"]
    cfg["bench_sessions"] = {f"sessions/{s}": s for s in (session, *others)}
    cfg["render"].update(width=320, height=240)
    cfg["codecs"]["noise"] = {"read_dn": 1.0, "full_well_e": None}  # the bench rig's camera: 1 DN read noise, no shot noise
    cfg.pop("table1", None)
    (path / "config.yaml").write_text(yaml.safe_dump(cfg))
    return path


def snakemake(workdir: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(workdir), *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "PYTHONHASHSEED": "0"})
    if proc.returncode != 0:
        raise AssertionError(f"snakemake failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-5000:]}")
    return proc


def outputs(workdir: Path) -> dict[str, str]:
    return {str(f.relative_to(workdir)): hashlib.sha256(f.read_bytes()).hexdigest()
            for top in ("sessions", "results") for f in sorted((workdir / top).rglob("*")) if f.is_file()}


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    work = rig_workdir(tmp_path_factory.mktemp("rigwf"))
    (work / "run.stderr").write_text(snakemake(work, "--cores", "2").stderr)
    return work


def test_the_run_ends_with_the_gauges_decision_and_its_report(run: Path) -> None:
    tail = (run / "run.stderr").read_text().split("huefringe: results")[-1]
    doc = json.loads((run / "results/rig-gauge/metrology/report.json").read_text())
    c = doc["conformity"]
    assert f"  rig-gauge: {c['decision'].upper()} (ISO 14253-1) - {c['reason']}" in tail
    assert "report: results/rig-gauge/metrology/report.html" in tail
    assert "rig-poses" not in tail  # the calibration session is calibrated, not measured
    assert not (run / "results/rig-poses/metrology").exists()


def test_every_figure_against_the_bench_truth(run: Path) -> None:
    doc = json.loads((run / "results/rig-gauge/metrology/report.json").read_text())
    validate_report(doc)
    assert doc["method"] == "coded-light-triangulation" and doc["frames"] == 1
    steps = {s["name"]: s for s in doc["steps"]}
    assert sorted(steps) == ["block-10", "block-2", "block-5"]
    figures = doc["steps"] + [e for v in doc["forms"].values() for e in v]
    assert len(figures) == 13
    for f in figures:
        # the bench's truth is each figure's nominal (flat tops, parallel faces, the ball's radius)
        assert abs(f["error_mm"]) <= f["U_mm"], f
        budget = f["uncertainty_budget"]
        assert budget["points_mm"] > 0 and budget["calibration_mm"] >= 0, f
        assert f["U_mm"] == pytest.approx(2 * np.sqrt(sum(v**2 for v in budget.values())))
    for s in steps.values():
        assert abs(s["error_mm"]) < 0.01 * s["nominal_mm"], s  # measured: +0.81 / +0.23 / +0.02 %
    assert abs(steps["block-10"]["error_pct"]) < 0.3
    (ball,) = doc["forms"]["spheres"]
    assert abs(ball["error_mm"]) < 0.05 and ball["points"] > 500
    cal = doc["rig_calibration"]
    for flat in doc["forms"]["flatness"]:
        assert flat["mean_mm"] <= flat["U_mm"]  # flat tops: FLTq within its U of 0
        # the form floor measured on the calibration boards is one of its terms
        assert flat["uncertainty_budget"]["form_floor_mm"] == cal["form_floor"]["rms_form_mm"] >= 0
    cal = doc["rig_calibration"]
    assert len(cal["poses"]) == 8 and cal["rms_px"]["stereo"] < 0.1 and len(cal["jackknife_poses"]) == 8
    assert set(cal["rms_definitions"]) >= {"camera", "projector", "stereo"}


def test_per_pixel_xyz_on_the_camera_grid(run: Path) -> None:
    res = run / "results/rig-gauge"
    xyz = tifffile.imread(res / "xyz/frame_0000.tiff")
    sigma = tifffile.imread(res / "xyz/frame_0000_sigma.tiff")
    u = tifffile.imread(res / "xyz/frame_0000_u.tiff")
    assert xyz.shape == (480, 640, 3) and xyz.dtype == np.float32 and u.shape == sigma.shape == (480, 640, 4)
    valid = np.isfinite(xyz).all(axis=-1)
    assert (np.isfinite(sigma).all(axis=-1) == valid).all() and (np.isfinite(u).all(axis=-1) == valid).all()
    # the combined u holds the noise and the calibration's term: never below the noise
    assert (u[valid] >= sigma[valid] - 1e-7).all()
    truth = tifffile.imread(run / "sessions/rig-gauge/ground_truth/xyz.tiff")
    acc = json.loads((res / "accuracy.json").read_text())
    # no pixel without direct projector light is measured (the scene has blocks' and the ball's shadows)
    assert acc["valid_without_truth"] == 0 and int((valid & ~np.isfinite(truth).all(axis=-1)).sum()) == 0
    # the decoding's own error (same calibration, true projector coordinates) against its sigma
    assert 0.92 <= acc["decoding"]["within_2sigma"] <= 0.99, acc["decoding"]
    # the organised cloud: one vertex per valid pixel, with its row and column
    from plyfile import PlyData

    v = PlyData.read(str(res / "cloud/frame_0000.ply"))["vertex"]
    assert len(v) == int(valid.sum())
    rows, cols = np.asarray(v["row"]).astype(int), np.asarray(v["col"]).astype(int)
    assert valid[rows, cols].all()
    np.testing.assert_allclose(np.asarray(v["z"]), xyz[rows, cols, 2], rtol=1e-6)
    for k in ("sigma_x", "sigma_y", "sigma_z", "u_x", "u_y", "u_z"):
        assert np.isfinite(np.asarray(v[k])).all(), k
    # the height over the base plane: pitch tags, an X3P, a mesh, renders
    pitch = tiff_pixel_pitch_mm(res / "height/frame_0000.tiff")
    assert 0.2 < pitch < 0.5
    h = tifffile.imread(res / "height/frame_0000.tiff")
    assert np.nanpercentile(h, 99.9) == pytest.approx(12.5 * 2, abs=1.0)  # the ball's top stands 25 mm over the base
    for rel in ("x3p/frame_0000.x3p", "mesh/frame_0000.ply", "mesh/frame_0000.stl", "renders/frame_0000_top.png",
                "qa/frame_0000_decode.png", "metrology/report.html"):
        assert (res / rel).stat().st_size > 1000, rel


def test_reruns_are_byte_identical_on_one_core(run: Path, tmp_path: Path) -> None:
    other = rig_workdir(tmp_path / "again")
    snakemake(other, "--cores", "1")
    want, got = outputs(run), outputs(other)
    assert sorted(got) == sorted(want) and len(want) > 40
    assert [f for f in want if got[f] != want[f]] == []


def test_archive_target_packs_the_rig_session_and_its_calibration_session(run: Path) -> None:
    import zipfile

    snakemake(run, "--cores", "2", "archive")
    for sid in ("rig-gauge", "rig-poses"):
        v = verify_archive(run / f"results/{sid}.archive.zip")
        assert v.ok, v.summary()
    with zipfile.ZipFile(run / "results/rig-gauge.archive.zip") as zf:
        names = set(zf.namelist())
    # the gauge's archive holds the calibration it was measured with, byte for byte the calibration session's
    assert {"results/calib/rig.yml", "results/calib/rig.jackknife.json", "session/features.yaml"} <= names
    assert (run / "results/rig-gauge/calib/rig.yml").read_bytes() == (run / "results/rig-poses/calib/rig.yml").read_bytes()
    with zipfile.ZipFile(run / "results/rig-poses.archive.zip") as zf:
        assert any(n.startswith("session/poses/pose_07/") for n in zf.namelist())
    index = json.loads((run / "results/archives.json").read_text())
    assert sorted(a["session"] for a in index["archives"]) == ["rig-gauge", "rig-poses"]


def test_a_phase_only_sequence_is_refused_as_a_user_meets_it(tmp_path: Path, capsys) -> None:
    """A rig's 12-step phase shifting without Gray code: sl-session and check take it (it decodes),
    but neither rig-measure nor the workflow triangulates it; each says which block is missing."""
    import cv2

    from huefringe import codecs as C
    from huefringe.bench.rig import RIGS
    from huefringe.cli import main

    seq = {"projector": {"width": 800, "height": 600}, "frames": "img_*.png",
           "blocks": [{"phase": {"axis": "x", "period_px": 40, "steps": 12}}]}
    caps = tmp_path / "caps"
    caps.mkdir()
    spec = C.sequence_from_mapping(seq, tmp_path / "seq.yaml", caps)
    for i, im in enumerate(C.generate(spec)):
        cv2.imwrite(str(caps / f"img_{i + 1}.png"), np.round(20 + 0.8 * im[:480, :640]).astype(np.uint8))
    (tmp_path / "seq.yaml").write_text(yaml.safe_dump(seq))
    from huefringe.rig import write_calibration

    write_calibration(tmp_path / "rig.yml", RIGS["tune"].calibration)
    assert main(["sl-session", str(caps), str(tmp_path / "seq.yaml"), str(tmp_path / "s"),
                 "--calibration", str(tmp_path / "rig.yml")]) == 0
    assert main(["check", "--deep", str(tmp_path / "s")]) == 0
    capsys.readouterr()
    assert main(["rig-measure", str(tmp_path / "s"), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "axis x: the phase block (period 40 px) has no absolute order (no Gray code or second period on x)" in err
    assert "cannot triangulate a relative projector coordinate" in err and not (tmp_path / "out").exists()
    work = rig_workdir(tmp_path / "wf")
    cfg = yaml.safe_load((work / "config.yaml").read_text())
    cfg["sessions"], cfg["bench_sessions"] = [str(tmp_path / "s")], {}
    (work / "config.yaml").write_text(yaml.safe_dump(cfg))
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(work), "--cores", "1"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode != 0 and "has no absolute order" in proc.stderr and "Traceback" not in proc.stderr
    assert not (work / "results").exists()


def test_a_calibration_file_without_poses_is_said_in_every_figure_and_the_headline(run: Path, tmp_path: Path, capsys) -> None:
    from huefringe.cli import main

    seq = yaml.safe_load((run / "sessions/rig-gauge/sequence.yaml").read_text())
    (tmp_path / "seq.yaml").write_text(yaml.safe_dump(seq))
    assert main(["sl-session", str(run / "sessions/rig-gauge/captures"), str(tmp_path / "seq.yaml"), str(tmp_path / "s"),
                 "--calibration", str(run / "results/rig-poses/calib/rig.yml"),
                 "--features", str(run / "sessions/rig-gauge/features.yaml")]) == 0
    assert main(["rig-measure", str(tmp_path / "s"), str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "every U lacks the calibration's term" in out
    doc = json.loads((tmp_path / "out/metrology/report.json").read_text())
    for f in doc["steps"] + [e for v in doc["forms"].values() for e in v]:
        assert f["uncertainty_budget"]["calibration_mm"].startswith("not available"), f
    # the same decoded points as the workflow's, which had the calibration's poses beside it
    a = tifffile.imread(tmp_path / "out/xyz/frame_0000.tiff")
    b = tifffile.imread(run / "results/rig-gauge/xyz/frame_0000.tiff")
    np.testing.assert_array_equal(a, b)
