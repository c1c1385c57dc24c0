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


# SLMaster's caliInfo.yml as its software writes it (cv::FileStorage of OpenCV 4.5: the %YAML:1.0
# header, %.16e doubles, keys in the order of its projector calibration: M1 D1 S M4 D4 Rlp Tlp K1).
SLMASTER_CALIINFO = """%YAML:1.0
---
M1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1.7500000000000000e+03, 0., 6.4050000000000000e+02, 0.,
       1.7492500000000000e+03, 5.1175000000000000e+02, 0., 0., 1. ]
D1: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -7.0000000000000007e-02, -1.7999999999999999e-01,
       2.5000000000000001e-04, -5.5000000000000003e-04,
       1.8000000000000000e+00 ]
S: !!opencv-matrix
   rows: 2
   cols: 1
   dt: d
   data: [ 1280., 1024. ]
M4: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 2.5000000000000000e+03, 0., 9.6000000000000000e+02, 0.,
       2.4990000000000000e+03, 1.0240000000000000e+03, 0., 0., 1. ]
D4: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -4.2500000000000003e-02, 1.2000000000000000e-01,
       0., 0., 0. ]
Rlp: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 9.9619469809174555e-01, 0., 8.7155742747658166e-02, 0., 1.,
       0., -8.7155742747658166e-02, 0., 9.9619469809174555e-01 ]
Tlp: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ -1.0800000000000000e+02, -5.1500000000000004e+00,
       -1.5750000000000000e+01 ]
K1: !!opencv-matrix
   rows: 8
   cols: 1
   dt: d
   data: [ 1., 0., 0., 0., 0., 0., 0., 1. ]
"""


def _slmaster_truth() -> RigCalibration:
    c, s = np.cos(np.radians(5.0)), np.sin(np.radians(5.0))
    return RigCalibration(
        camera_matrix=np.array([[1750.0, 0, 640.5], [0, 1749.25, 511.75], [0, 0, 1]]),
        camera_distortion=np.array([-0.07, -0.18, 2.5e-4, -5.5e-4, 1.8]),
        projector_matrix=np.array([[2500.0, 0, 960.0], [0, 2499.0, 1024.0], [0, 0, 1]]),
        projector_distortion=np.array([-0.0425, 0.12, 0.0, 0.0, 0.0]),
        R=np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]), T=np.array([-108.0, -5.15, -15.75]),
        camera_size=(1280, 1024))


def test_slmaster_caliinfo_as_its_software_writes_it(tmp_path):
    path = tmp_path / "caliInfo.yml"
    path.write_text(SLMASTER_CALIINFO)
    calib = read_calibration(path)
    truth = _slmaster_truth()
    _same(calib, truth)
    assert calib.camera_size == (1280, 1024) and calib.projector_size == (0, 0) and calib.errors == {}
    assert calib.baseline_mm == pytest.approx(np.linalg.norm([108.0, 5.15, 15.75]), rel=1e-12)
    # the file as SLMaster's sample data holds it (no K1, no newline at the end) reads the same
    path.write_text(SLMASTER_CALIINFO.split("K1:")[0].rstrip())
    _same(read_calibration(path), truth)


def test_slmaster_file_triangulates_as_the_huefringe_one(tmp_path):
    """A point seen through the SLMaster file's calibration projects and triangulates as huefringe's."""
    from huefringe.rig.triangulation import project, triangulate

    (tmp_path / "caliInfo.yml").write_text(SLMASTER_CALIINFO)
    slm = read_calibration(tmp_path / "caliInfo.yml")
    ours = read_calibration(write_calibration(tmp_path / "ours.yml", _slmaster_truth()))
    xyz = np.array([[12.5, -30.0, 480.0], [-80.0, 45.0, 620.0], [0.0, 0.0, 550.0]])
    cam = project(xyz, ours.camera_matrix, ours.camera_distortion)
    proj = project(xyz, ours.projector_matrix, ours.projector_distortion, ours.R, ours.T)
    np.testing.assert_allclose(project(xyz, slm.camera_matrix, slm.camera_distortion), cam, atol=1e-9)
    np.testing.assert_allclose(project(xyz, slm.projector_matrix, slm.projector_distortion, slm.R, slm.T), proj,
                               atol=1e-9)
    # the inverse pose (projector to camera) would put these points elsewhere in the projector
    inverse = project(xyz, slm.projector_matrix, slm.projector_distortion, slm.R.T, -slm.R.T @ slm.T)
    assert np.abs(inverse - proj).max() > 100.0
    tri = triangulate(slm, proj[:, 0], proj[:, 1], pixels=cam)
    np.testing.assert_allclose(tri.xyz, xyz, atol=1e-6)


def test_slmaster_round_trip_in_its_key_order(tmp_path):
    truth = _slmaster_truth()
    path = write_calibration(tmp_path / "caliInfo.yml", truth, layout="slmaster")
    text = path.read_text()
    keys = [line.split(":")[0] for line in text.splitlines() if line and not line.startswith((" ", "%", "-"))]
    assert keys == ["M1", "D1", "S", "M4", "D4", "Rlp", "Tlp"]
    assert "D1: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d" in text
    assert "S: !!opencv-matrix\n   rows: 2\n   cols: 1\n   dt: d\n   data: [ 1280., 1024. ]" in text
    back = read_calibration(path)
    _same(back, truth)
    assert back.camera_size == (1280, 1024)


def test_slmaster_file_without_its_pose_is_refused(tmp_path):
    path = tmp_path / "caliInfo.yml"
    path.write_text("".join(b for b in SLMASTER_CALIINFO.split("\nR")[:1]) + "\n")  # M1 D1 S M4 D4, no Rlp Tlp
    assert "Rlp" not in path.read_text() and "D4" in path.read_text()
    with pytest.raises(CalibrationFileError) as err:
        read_calibration(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: not a projector-camera calibration in a known layout")
    assert "slmaster lacks Rlp, Tlp" in msg and "keys found: D1, D4, M1, M4, S" in msg


def test_slmaster_and_opencv_stereo_keys_together_are_refused(tmp_path):
    path = tmp_path / "caliInfo.yml"
    path.write_text(SLMASTER_CALIINFO)
    fs = cv2.FileStorage(str(tmp_path / "more.yml"), cv2.FILE_STORAGE_WRITE)
    for key, value in (("M2", np.eye(3)), ("D2", np.zeros((1, 5))), ("R", np.eye(3)), ("T", np.zeros((3, 1)))):
        fs.write(key, value)
    fs.release()
    with pytest.raises(CalibrationFileError, match=r"keys of several layouts \(opencv-stereo, slmaster\); pass layout="):
        read_calibration(path, tmp_path / "more.yml")
    _same(read_calibration(path, tmp_path / "more.yml", layout="slmaster"), _slmaster_truth())
