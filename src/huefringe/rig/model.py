"""The projector-camera model: two pinhole devices with OpenCV distortion and the projector's pose."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["RigCalibration"]

F64 = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class RigCalibration:
    """A calibrated projector-camera rig.

    Parameters
    ----------
    camera_matrix, projector_matrix : ndarray, shape (3, 3)
        Intrinsic matrices ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels.
    camera_distortion, projector_distortion : ndarray
        OpenCV distortion coefficients ``k1, k2, p1, p2[, k3 ...]``.
    camera_size, projector_size : (int, int)
        Image sizes ``(width, height)`` in pixels (``(0, 0)`` when the file did not say).
    R, T : ndarray, shapes (3, 3) and (3,)
        The projector's pose: a point ``X_c`` in the camera frame (mm) is ``R @ X_c + T`` in the
        projector frame (``cv2.stereoCalibrate``'s convention, camera first).
    errors : dict
        RMS reprojection errors in pixels the calibration reported (``camera``, ``projector``,
        ``stereo``), where known.
    """

    camera_matrix: F64
    camera_distortion: F64
    projector_matrix: F64
    projector_distortion: F64
    R: F64
    T: F64
    camera_size: tuple[int, int] = (0, 0)
    projector_size: tuple[int, int] = (0, 0)
    errors: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, shape in (("camera_matrix", (3, 3)), ("projector_matrix", (3, 3)), ("R", (3, 3)), ("T", (3,))):
            a = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)
            if a.size != int(np.prod(shape)):
                raise ValueError(f"{name} has {a.size} values; {int(np.prod(shape))} expected")
            object.__setattr__(self, name, a.reshape(shape))
        for name in ("camera_distortion", "projector_distortion"):
            d = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)
            if d.size not in (0, 4, 5, 8, 12, 14):
                raise ValueError(f"{name} has {d.size} coefficients; OpenCV takes 4, 5, 8, 12 or 14")
            object.__setattr__(self, name, d if d.size else np.zeros(5))
        object.__setattr__(self, "camera_size", tuple(int(v) for v in self.camera_size))
        object.__setattr__(self, "projector_size", tuple(int(v) for v in self.projector_size))

    @property
    def baseline_mm(self) -> float:
        """Distance between the camera and projector centres, mm."""
        return float(np.linalg.norm(self.R.T @ self.T))

    @property
    def projector_centre(self) -> F64:
        """The projector's centre in the camera frame, mm."""
        return -self.R.T @ self.T
