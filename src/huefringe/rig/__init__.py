"""The projector-camera model: calibration from checkerboard poses, others' calibration files, triangulation.

The projector is an inverse camera (Zhang & Huang 2006): its pixel coordinates at each board
corner are read from the decoded fringe codes around the corner through a local homography
(Moreno & Taubin 2012), and OpenCV's ``calibrateCamera`` / ``stereoCalibrate`` calibrate it like
a second camera. A measurement then intersects each camera ray with the projector's plane of
constant decoded coordinate (or, where both coordinates are decoded, with the projector ray in
the least-squares sense): pixel and projector coordinate in, ``X, Y, Z`` in mm in the camera
frame and its standard uncertainty out.

Modules
-------
``model``
    :class:`RigCalibration`: both devices' intrinsics and distortion, the projector's pose.
``filestorage``
    OpenCV FileStorage reading and writing, with the key maps of the layouts rigs already write.
``calibrate``
    Corner detection, projector corners by local homographies, the stereo calibration and its
    per-pose report.
``decoded``
    Decoded coordinates to triangulation inputs: relative axes refused, invalid pixels dropped.
``triangulation``
    Ray-plane and ray-ray triangulation with first-order uncertainty propagation.
``oneshot``
    The paper's one-shot trapezoid frames on a calibrated rig: hue table, fringe order from a
    reference's absolute coordinate, triangulated X, Y, Z (imported as ``huefringe.rig.oneshot``).
"""

from __future__ import annotations

from huefringe.rig.calibrate import (
    Board,
    CalibrationReport,
    PoseObservation,
    calibrate_rig,
    calibrated_field,
    detect_corners,
    field_mask,
    projector_corners,
    refine_corners_fronto_parallel,
)
from huefringe.rig.decoded import RelativeCoordinateError, TriangulationInputs, relative_axes_problems, triangulation_inputs
from huefringe.rig.filestorage import KEY_MAPS, CalibrationFileError, read_calibration, write_calibration
from huefringe.rig.model import RigCalibration
from huefringe.rig.triangulation import Triangulated, triangulate

__all__ = [
    "KEY_MAPS",
    "Board",
    "CalibrationFileError",
    "CalibrationReport",
    "PoseObservation",
    "RelativeCoordinateError",
    "RigCalibration",
    "Triangulated",
    "TriangulationInputs",
    "calibrate_rig",
    "calibrated_field",
    "detect_corners",
    "field_mask",
    "projector_corners",
    "read_calibration",
    "refine_corners_fronto_parallel",
    "relative_axes_problems",
    "triangulate",
    "triangulation_inputs",
    "write_calibration",
]
