"""Projector-camera calibrations in OpenCV FileStorage files (YAML, XML or JSON), in several layouts.

:func:`write_calibration` writes a :class:`~huefringe.rig.model.RigCalibration` in huefringe's
layout (or any layout of :data:`KEY_MAPS`); :func:`read_calibration` reads one or more files
(e.g. OpenCV's ``intrinsics.yml`` + ``extrinsics.yml``) and recognises the layout by its keys:
the layout whose required keys are all present, never a guess from partial keys.

Key map (every layout stores the projector's pose as ``X_p = R X_c + T``, camera first; mm):

- ``huefringe``: ``camera_matrix``, ``camera_distortion``, ``projector_matrix``,
  ``projector_distortion``, ``R``, ``T``; optional ``camera_width``, ``camera_height``,
  ``projector_width``, ``projector_height``, ``camera_rms_px``, ``projector_rms_px``,
  ``stereo_rms_px``.
- ``slstudio``: ``Kc``, ``kc``, ``Kp``, ``kp``, ``Rp``, ``Tp``; optional ``frameWidth``,
  ``frameHeight``, ``screenResX``, ``screenResY``, ``cam_error``, ``proj_error``, ``stereo_error``.
- ``scan3d``: ``cam_K``, ``cam_kc``, ``proj_K``, ``proj_kc``, ``R``, ``T``; optional ``cam_error``,
  ``proj_error``, ``stereo_error``.
- ``opencv-stereo``: ``M1``, ``D1`` (camera), ``M2``, ``D2`` (projector), ``R``, ``T``.
- ``slmaster``: ``M1``, ``D1`` (camera), ``M4``, ``D4`` (projector), ``Rlp``, ``Tlp``; optional
  ``S`` (the camera's width and height as a 2 x 1 matrix).

``slstudio`` is SLStudio's ``CalibrationData`` (also its ``*_error`` scalars); ``scan3d`` is
Moreno & Taubin's *scan3d-capture* ``calibration.yml`` (``cam_error``, ``proj_error``,
``stereo_error``); ``opencv-stereo`` is OpenCV's ``samples/cpp/stereo_calib.cpp`` pair of files
with the camera as device 1 and the projector as device 2.

``slmaster`` is SLMaster's ``caliInfo.yml`` (Practice3DVision/SLMaster, read at commit d1a0fe4
for its conventions only). Its monocular (camera + projector) file holds, in this order, ``M1``,
``D1``, ``S``, ``M4``, ``D4``, ``Rlp``, ``Tlp`` (``src/calibration/caliPacker.cpp``,
``writeCaliInfo``, the projector branch; ``data/monocularCamera/caliInfo.yml``), every node an
``opencv-matrix`` of doubles, distortion as a 1 x 5 row. Its conventions, each verified in its
sources:

- ``M1``/``D1`` are the (left) camera, ``M4``/``D4`` the projector (``src/cameras/caliInfo.h``,
  the comments of ``M1_`` and ``M4_``); ``M2``/``D2`` (right camera) and ``M3``/``D3`` (colour
  camera) of its binocular and trinocular files are not read. ``K1`` (an eight-parameter
  phase-to-depth model) is not read either.
- ``Rlp``, ``Tlp`` map the camera frame to the projector frame, ``X_p = Rlp X_c + Tlp``: they come
  from ``cv::solvePnPRansac`` of board points expressed in the camera frame against their projector
  pixels (``gui/src/CalibrateEngine.cpp``, ``calibrateProjector``, lines 925-968), and the
  projector's projection matrix is ``M4 [Rlp | Tlp]`` with the camera at the origin
  (``gui/src/CameraEngine.cpp``, lines 737-750). This is huefringe's convention: no conversion.
- ``Tlp`` is in the board's unit (its feature distance), millimetres in SLMaster's GUI (depth
  limits 0-1500, ``gui/qml/res/config/monocularCameraConfig.json``).
- ``S`` is ``(cols, rows)`` = ``(width, height)`` of the camera images
  (``gui/src/CalibrateEngine.cpp`` line 83; read back as ``cv::Size(S(0), S(1))`` in
  ``src/cameras/binocular/binoocularCamer.cpp`` line 38). The projector's size is not in the file.
- Distortion is OpenCV's ``k1, k2, p1, p2, k3`` (``cv::calibrateCamera``'s output).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from huefringe.rig.model import RigCalibration

__all__ = ["KEY_MAPS", "CalibrationFileError", "read_calibration", "write_calibration"]

_FIELDS = ("camera_matrix", "camera_distortion", "projector_matrix", "projector_distortion", "R", "T")
_SIZES = ("camera_width", "camera_height", "projector_width", "projector_height")
_ERRORS = ("camera", "projector", "stereo")

KEY_MAPS: dict[str, dict[str, str]] = {
    "huefringe": {
        **{f: f for f in _FIELDS}, **{s: s for s in _SIZES},
        "camera": "camera_rms_px", "projector": "projector_rms_px", "stereo": "stereo_rms_px",
    },
    "slstudio": {
        "camera_matrix": "Kc", "camera_distortion": "kc", "projector_matrix": "Kp",
        "projector_distortion": "kp", "R": "Rp", "T": "Tp",
        "camera_width": "frameWidth", "camera_height": "frameHeight",
        "projector_width": "screenResX", "projector_height": "screenResY",
        "camera": "cam_error", "projector": "proj_error", "stereo": "stereo_error",
    },
    "scan3d": {
        "camera_matrix": "cam_K", "camera_distortion": "cam_kc", "projector_matrix": "proj_K",
        "projector_distortion": "proj_kc", "R": "R", "T": "T",
        "camera": "cam_error", "projector": "proj_error", "stereo": "stereo_error",
    },
    "opencv-stereo": {
        "camera_matrix": "M1", "camera_distortion": "D1", "projector_matrix": "M2",
        "projector_distortion": "D2", "R": "R", "T": "T",
    },
    "slmaster": {
        "camera_matrix": "M1", "camera_distortion": "D1", "projector_matrix": "M4",
        "projector_distortion": "D4", "R": "Rlp", "T": "Tlp", "camera_size": "S",
    },
}
"""Layout name -> {huefringe field: the file's key}; the six fields of ``_FIELDS`` are required.

``camera_size`` names a 2 x 1 matrix holding the camera's ``(width, height)``."""

_WRITE_ORDER: dict[str, tuple[str, ...]] = {
    "slmaster": ("camera_matrix", "camera_distortion", "camera_size", "projector_matrix", "projector_distortion",
                 "R", "T"),
}
"""Layouts written in their own software's key order (distortion as a 1 x N row); others in ``_FIELDS``'s."""


class CalibrationFileError(ValueError):
    """A calibration file that cannot be read or recognised (the message names the file)."""


def _read_nodes(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise CalibrationFileError(f"{path}: no such file")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):
        raise CalibrationFileError(f"{path}: not an OpenCV FileStorage file (YAML with %YAML:1.0, XML or JSON)") from None
    if not fs.isOpened():
        raise CalibrationFileError(f"{path}: not an OpenCV FileStorage file")
    out: dict[str, Any] = {}
    root = fs.root()
    for key in root.keys():
        node = root.getNode(key)
        if node.isMap() and not node.mat() is None:
            out[key] = node.mat()
        elif node.isSeq():
            out[key] = np.array([node.at(i).real() for i in range(node.size())])
        elif node.isReal() or node.isInt():
            out[key] = node.real()
        else:
            m = node.mat()
            if m is not None:
                out[key] = m
    fs.release()
    return out


def read_calibration(*paths: str | os.PathLike[str], layout: str | None = None) -> RigCalibration:
    """Read a projector-camera calibration from one or more FileStorage files.

    Parameters
    ----------
    *paths : path-like
        The files; keys of later files add to earlier ones (OpenCV's intrinsics + extrinsics).
    layout : str, optional
        One of :data:`KEY_MAPS`; by default the one layout whose required keys are all present.

    Raises
    ------
    CalibrationFileError
        A file that is missing or unreadable, no layout (or several) matching, a matrix of the
        wrong size: every problem at once, naming the files.
    """
    if not paths:
        raise CalibrationFileError("no calibration file given")
    files = [Path(p) for p in paths]
    nodes: dict[str, Any] = {}
    problems = []
    for f in files:
        try:
            nodes.update(_read_nodes(f))
        except CalibrationFileError as exc:
            problems.append(str(exc))
    names = ", ".join(str(f) for f in files)
    if problems:
        raise CalibrationFileError("; ".join(problems))
    if layout is not None and layout not in KEY_MAPS:
        raise CalibrationFileError(f"unknown layout {layout!r}; known: {', '.join(KEY_MAPS)}")
    candidates = [layout] if layout else list(KEY_MAPS)
    complete = [n for n in candidates if all(KEY_MAPS[n][f] in nodes for f in _FIELDS)]
    if not complete:
        missing = "; ".join(
            f"{n} lacks {', '.join(KEY_MAPS[n][f] for f in _FIELDS if KEY_MAPS[n][f] not in nodes)}" for n in candidates)
        raise CalibrationFileError(f"{names}: not a projector-camera calibration in a known layout ({missing}); "
                                   f"keys found: {', '.join(sorted(nodes)) or 'none'}")
    if len(complete) > 1:
        raise CalibrationFileError(f"{names}: keys of several layouts ({', '.join(complete)}); pass layout=")
    keys = KEY_MAPS[complete[0]]
    get = {f: nodes.get(keys[f]) for f in keys}
    sizes = [int(get[s]) if isinstance(get.get(s), float) else 0 for s in _SIZES]
    if "camera_size" in keys and get["camera_size"] is not None:
        wh = np.asarray(get["camera_size"], dtype=np.float64).reshape(-1)
        if wh.size != 2:
            raise CalibrationFileError(f"{names} ({complete[0]} layout): {keys['camera_size']} has {wh.size} values; "
                                       "2 expected (camera width, height)")
        sizes[0], sizes[1] = int(round(wh[0])), int(round(wh[1]))
    try:
        return RigCalibration(
            **{f: np.asarray(get[f], dtype=np.float64) for f in _FIELDS},
            camera_size=(sizes[0], sizes[1]), projector_size=(sizes[2], sizes[3]),
            errors={e: float(get[e]) for e in _ERRORS if isinstance(get.get(e), float)},
        )
    except ValueError as exc:
        raise CalibrationFileError(f"{names} ({complete[0]} layout): {exc}") from None


def write_calibration(path: str | os.PathLike[str], calib: RigCalibration, layout: str = "huefringe") -> Path:
    """Write ``calib`` as an OpenCV FileStorage file (format from the suffix: .yml, .yaml, .xml, .json).

    The file appears complete or not at all (written beside, then renamed).
    """
    if layout not in KEY_MAPS:
        raise CalibrationFileError(f"unknown layout {layout!r}; known: {', '.join(KEY_MAPS)}")
    out = Path(path)
    if out.suffix.lower() not in (".yml", ".yaml", ".xml", ".json"):
        raise CalibrationFileError(f"{out}: FileStorage writes .yml, .yaml, .xml or .json")
    keys = KEY_MAPS[layout]
    out.parent.mkdir(parents=True, exist_ok=True)  # the temporary file beside the target: one rename, one file system
    fd, tmp = tempfile.mkstemp(suffix=out.suffix, dir=out.parent)
    os.close(fd)
    try:
        fs = cv2.FileStorage(tmp, cv2.FILE_STORAGE_WRITE)
        if layout in _WRITE_ORDER:
            for f in _WRITE_ORDER[layout]:
                if f == "camera_size":
                    if all(calib.camera_size):
                        fs.write(keys[f], np.array(calib.camera_size, dtype=np.float64).reshape(2, 1))
                    continue
                a = np.asarray(getattr(calib, f), dtype=np.float64)
                fs.write(keys[f], a.reshape(1, -1) if f.endswith("distortion") else a.reshape(3, -1))
        else:
            for f in _FIELDS:
                a = np.asarray(getattr(calib, f), dtype=np.float64)
                fs.write(keys[f], a.reshape(-1, 1) if a.ndim == 1 else a)
        sizes = (*calib.camera_size, *calib.projector_size)
        for s, v in zip(_SIZES, sizes, strict=True):
            if s in keys and v:
                fs.write(keys[s], int(v))
        for e in _ERRORS:
            if e in keys and e in calib.errors:
                fs.write(keys[e], float(calib.errors[e]))
        fs.release()
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out
