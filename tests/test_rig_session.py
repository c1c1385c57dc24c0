"""The rig route on structured-light sessions: the session's calibration checked as a full
projector-camera model, rig-measure's refusals, archives of a structured-light session."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from huefringe import codecs as C
from huefringe.archive import ArchiveError, verify_archive, write_archive
from huefringe.cli import main
from huefringe.rig import RigCalibration, write_calibration
from huefringe.session import SessionError
from huefringe.session import assemble_sl_session, calibration_problems, load_sl_session

SEQUENCE = {"projector": {"width": 64, "height": 48}, "frames": "img_*.png", "blocks": [
    {"phase": {"axis": "x", "period_px": 32, "steps": 4}}, {"gray": {"axis": "x", "bits": 3, "cell_px": 8}},
    {"phase": {"axis": "y", "period_px": 24, "steps": 4}}, {"gray": {"axis": "y", "cells": 6, "cell_px": 8}},
    "white", "black"]}


def _calib(size: tuple[int, int] = (64, 48), cx: float = 31.5) -> RigCalibration:
    K = np.array([[80.0, 0, cx], [0, 80.0, 23.5], [0, 0, 1]])
    return RigCalibration(K, np.zeros(5), np.array([[90.0, 0, 32], [0, 90.0, 24], [0, 0, 1]]), np.zeros(5),
                          np.eye(3), np.array([-100.0, 0.0, 0.0]), size, (64, 48))


@pytest.fixture
def captures(tmp_path: Path) -> tuple[Path, Path]:
    caps = tmp_path / "caps"
    caps.mkdir()
    spec = C.sequence_from_mapping(SEQUENCE, tmp_path / "seq.yaml", caps)
    for i, im in enumerate(C.generate(spec)):
        cv2.imwrite(str(caps / f"img_{i + 1}.png"), np.round(20 + 0.8 * im).astype(np.uint8))
    (tmp_path / "seq.yaml").write_text(yaml.safe_dump(SEQUENCE))
    return caps, tmp_path / "seq.yaml"


def test_calibration_is_read_as_the_full_model(tmp_path: Path) -> None:
    # the layouts read_calibration knows are accepted, with or without the camera size
    for layout in ("huefringe", "slstudio", "scan3d", "opencv-stereo", "slmaster"):
        assert calibration_problems(write_calibration(tmp_path / f"{layout}.yml", _calib(), layout), 64, 48) == []
    # a camera-only calibration (no projector, no pose) is not a rig's calibration
    fs = cv2.FileStorage(str(tmp_path / "camera.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", _calib().camera_matrix)
    fs.write("camera_distortion", np.zeros((1, 5)))
    fs.release()
    (p,) = calibration_problems(tmp_path / "camera.yml", 64, 48)
    assert p.path == tmp_path / "camera.yml" and "not a projector-camera calibration in a known layout" in p.message
    assert "huefringe lacks projector_matrix, projector_distortion, R, T" in p.message
    # another camera: by its size (slstudio's frameWidth/Height), by its principal point (scan3d: no size keys)
    (p,) = calibration_problems(write_calibration(tmp_path / "big.yml", _calib((1280, 1024)), "slstudio"), 64, 48)
    assert p.message == "calibrated for a 1280 x 1024 camera, the captures are 64 x 48"
    (p,) = calibration_problems(write_calibration(tmp_path / "caliInfo.yml", _calib((1280, 1024)), "slmaster"), 64, 48)
    assert p.message == "calibrated for a 1280 x 1024 camera, the captures are 64 x 48"  # SLMaster's S
    (p,) = calibration_problems(write_calibration(tmp_path / "off.yml", _calib((0, 0), cx=640.0), "scan3d"), 64, 48)
    assert p.message.startswith("principal point (640, 23.5) px lies outside the 64 x 48 captures")


def test_assembly_refuses_a_camera_only_calibration(captures, tmp_path: Path) -> None:
    caps, seq = captures
    fs = cv2.FileStorage(str(tmp_path / "camera.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("Kc", _calib().camera_matrix)
    fs.release()
    with pytest.raises(SessionError, match="camera.yml: not a projector-camera calibration"):
        assemble_sl_session(caps, seq, tmp_path / "out", calibration=tmp_path / "camera.yml")
    assert not (tmp_path / "out").exists()


def test_rig_commands_on_a_session_refuse_what_it_lacks(captures, tmp_path: Path, capsys) -> None:
    caps, seq = captures
    s = assemble_sl_session(caps, seq, tmp_path / "s")
    assert main(["rig-measure", str(s), str(tmp_path / "out")]) == 2
    assert f"{s / 'session.yaml'}: no calibration in the session" in capsys.readouterr().err
    assert main(["rig-calibrate", str(s), str(tmp_path / "c.yml"), "--board", "9x7", "--pitch-mm", "12"]) == 2
    assert f"{s / 'session.yaml'}: no calibration poses" in capsys.readouterr().err
    # a session's form is SESSION OUTDIR: a third positional is refused, naming both forms
    assert main(["rig-measure", str(s), str(tmp_path / "c.yml"), str(tmp_path / "out")]) == 2
    assert "SESSION OUTDIR" in capsys.readouterr().err
    assert not (tmp_path / "out").exists() and not (tmp_path / "c.yml").exists()


def test_a_structured_light_session_is_archived_and_verified(captures, tmp_path: Path) -> None:
    caps, seq = captures
    write_calibration(tmp_path / "rig.yml", _calib())
    s = load_sl_session(assemble_sl_session(caps, seq, tmp_path / "demo", calibration=tmp_path / "rig.yml"))
    results = tmp_path / "results" / "demo"
    results.mkdir(parents=True)
    (results / "report.json").write_text(json.dumps({"points": 3}))
    out = write_archive(s.root, results, tmp_path / "demo.archive.zip")
    with zipfile.ZipFile(out) as zf:
        names = set(zf.namelist())
        crate = json.loads(zf.read("ro-crate-metadata.json"))
    # every file of the session (SLSession.input_files) is in the archive
    assert {f"session/{p.relative_to(s.root).as_posix()}" for p in s.input_files()} <= names
    assert "results/report.json" in names
    assert "structured-light-session/1" in json.dumps(crate)
    v = verify_archive(out)
    assert v.ok, v.summary()
    # an altered calibration is refused before anything is written
    damaged = tmp_path / "damaged" / "demo"
    shutil.copytree(s.root, damaged)
    with open(damaged / "calibration/rig.yml", "a") as f:
        f.write("# edited\n")
    with pytest.raises(ArchiveError, match="sha256 differs"):
        write_archive(damaged, results, tmp_path / "damaged.zip")
    assert not (tmp_path / "damaged.zip").exists()
