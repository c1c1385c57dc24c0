"""Calibration files: FileStorage round trips, others' layouts by their key map, refusals."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from huefringe.bench.rig import RIGS
from huefringe.rig import KEY_MAPS, CalibrationFileError, RigCalibration, read_calibration, write_calibration


def _same(a: RigCalibration, b: RigCalibration) -> None:
    for f in ("camera_matrix", "camera_distortion", "projector_matrix", "projector_distortion", "R", "T"):
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("suffix", [".yml", ".xml", ".json"])
@pytest.mark.parametrize("layout", list(KEY_MAPS))
def test_round_trip(tmp_path, suffix, layout):
    truth = RIGS["holdout-wide"].calibration
    calib = RigCalibration(**{f: getattr(truth, f) for f in ("camera_matrix", "camera_distortion", "projector_matrix",
                                                             "projector_distortion", "R", "T")},
                           camera_size=truth.camera_size, projector_size=truth.projector_size,
                           errors={"camera": 0.05, "projector": 0.07, "stereo": 0.06})
    path = write_calibration(tmp_path / f"calib{suffix}", calib, layout=layout)
    back = read_calibration(path)
    _same(back, calib)
    if "camera_width" in KEY_MAPS[layout]:
        assert back.camera_size == calib.camera_size and back.projector_size == calib.projector_size
    if "stereo" in KEY_MAPS[layout]:
        assert back.errors["stereo"] == pytest.approx(0.06)
    assert back.baseline_mm == pytest.approx(220.0)


def test_slstudio_file_written_by_opencv(tmp_path):
    """An SLStudio-style file as its C++ writes it (Matx and Vec nodes, scalars), read by the key map."""
    truth = RIGS["tune"].calibration
    path = tmp_path / "calibration.xml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("Kc", truth.camera_matrix), ("kc", truth.camera_distortion.reshape(1, -1)),
                       ("Kp", truth.projector_matrix), ("kp", truth.projector_distortion.reshape(-1, 1)),
                       ("Rp", truth.R), ("Tp", truth.T.reshape(3, 1))):
        fs.write(key, value.astype(np.float32))
    fs.write("cam_error", 0.1)
    fs.write("frameWidth", 640)
    fs.write("frameHeight", 480)
    fs.release()
    calib = read_calibration(path)
    np.testing.assert_allclose(calib.projector_matrix, truth.projector_matrix, rtol=1e-6)
    np.testing.assert_allclose(calib.T, truth.T, rtol=1e-6)
    assert calib.camera_size == (640, 480) and calib.errors == {"camera": pytest.approx(0.1)}


def test_opencv_stereo_sample_pair_of_files(tmp_path):
    truth = RIGS["holdout-narrow"].calibration
    fs = cv2.FileStorage(str(tmp_path / "intrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for key, value in (("M1", truth.camera_matrix), ("D1", truth.camera_distortion.reshape(1, -1)),
                       ("M2", truth.projector_matrix), ("D2", truth.projector_distortion.reshape(1, -1))):
        fs.write(key, value)
    fs.release()
    fs = cv2.FileStorage(str(tmp_path / "extrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("R", truth.R)
    fs.write("T", truth.T.reshape(3, 1))
    fs.write("Q", np.eye(4))
    fs.release()
    _same(read_calibration(tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml"), truth)
    with pytest.raises(CalibrationFileError, match=r"intrinsics\.yml: not a projector-camera calibration.*opencv-stereo lacks R, T"):
        read_calibration(tmp_path / "intrinsics.yml")


def test_refusals_name_the_file_and_the_cause(tmp_path):
    missing = tmp_path / "nope.yml"
    junk = tmp_path / "junk.yml"
    junk.write_text("this is not FileStorage\n")
    with pytest.raises(CalibrationFileError) as err:
        read_calibration(missing, junk)
    assert "nope.yml: no such file" in str(err.value) and "junk.yml" in str(err.value)
    bad = tmp_path / "bad.yml"
    fs = cv2.FileStorage(str(bad), cv2.FILE_STORAGE_WRITE)
    for key in ("Kc", "Kp", "Rp"):
        fs.write(key, np.eye(3))
    fs.write("kc", np.zeros((1, 3)))
    fs.write("kp", np.zeros((1, 5)))
    fs.write("Tp", np.zeros((3, 1)))
    fs.release()
    with pytest.raises(CalibrationFileError, match=r"bad\.yml \(slstudio layout\): camera_distortion has 3 coefficients"):
        read_calibration(bad)
    with pytest.raises(CalibrationFileError, match="unknown layout"):
        read_calibration(bad, layout="matlab")
    with pytest.raises(CalibrationFileError, match=r"\.txt"):
        write_calibration(tmp_path / "c.txt", RIGS["tune"].calibration)
    assert not (tmp_path / "c.txt").exists()
