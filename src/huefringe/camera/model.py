"""X, Y in one place: :class:`CameraModel`, the pixel-to-X/Y model (telecentric or pinhole with lens
distortion) every output that places a pixel reads.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray


CAMERA_MODELS = ("telecentric", "pinhole")
# cv2.undistortPoints inverts the distortion iteratively; its default (5 iterations) leaves
# micrometres at the corners of an ordinary lens, 200 iterations to 1e-14 reach 1e-9 mm
_UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)


@dataclass(frozen=True)
class CameraModel:
    """Where on the plate (X, Y in mm) a pixel looks, at the pixel's own height.

    The one place huefringe turns pixels into X, Y (clouds, meshes, renders, metrology boxes).
    Pixel ``(u, v)`` is column ``u``, row ``v``, its centre at integer coordinates (OpenCV's
    convention). Plate coordinates: a point at height ``h`` above the plate at plate position
    ``(X, Y)`` is OpenCV's board point ``(X, Y, -h)`` (the board's z points away from the camera,
    our heights towards it).

    ``telecentric`` without distortion
        ``X = u * pitch``, ``Y = v * pitch`` at every height (capture-session/1's meaning).
    ``telecentric`` with ``distortion``
        the pixel is first undistorted (``cv2.undistortPoints`` with ``P = matrix``) to
        ``(u', v')`` and ``X = u' * pitch``, ``Y = v' * pitch``. Without a ``matrix`` the
        coefficients are taken in plate millimetres about the image centre:
        ``matrix = [[1/pitch, 0, (W-1)/2], [0, 1/pitch, (H-1)/2], [0, 0, 1]]``.
    ``pinhole``
        the undistorted pixel's ray from the camera centre (``matrix``, ``distortion``) is
        intersected with the plane ``z = -h`` of the plate (``plate_pose``, the board in camera
        coordinates, mm).
    """

    kind: str
    pitch_mm: float
    width: int
    height: int
    matrix: NDArray[np.float64] | None = None
    distortion: NDArray[np.float64] | None = None
    rvec: NDArray[np.float64] | None = None
    tvec: NDArray[np.float64] | None = None
    _grid_cache: list[Any] = field(default_factory=list, repr=False, compare=False)

    @classmethod
    def from_meta(cls, meta: Mapping[str, Any], *, lens_model: bool = True) -> CameraModel:
        """The model of a session's ``session.yaml`` (``meta``, as :func:`huefringe.session.read_meta`
        checked it; the whole mapping or its ``camera`` block).

        ``lens_model=False`` ignores the lens (``model``, ``matrix``, ``distortion``): the plain
        telecentric ``u * pitch`` (config ``camera.lens_model: false``).
        """
        cam = meta.get("camera", meta)
        w, h, pitch = int(cam["width"]), int(cam["height"]), float(cam["pixel_pitch_mm"])
        if not lens_model:
            return cls("telecentric", pitch, w, h)
        kind = str(cam.get("model", "telecentric"))
        k = None if cam.get("matrix") is None else np.asarray(cam["matrix"], np.float64).reshape(3, 3)
        d = None if not cam.get("distortion") else np.asarray(cam["distortion"], np.float64).reshape(-1)
        if d is not None and not np.any(d):
            d = None if kind == "telecentric" else d
        if kind == "telecentric":
            if d is not None and k is None:
                k = np.array([[1.0 / pitch, 0.0, (w - 1) / 2.0], [0.0, 1.0 / pitch, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
            return cls(kind, pitch, w, h, k if d is not None else None, d)
        pose = cam["plate_pose"]
        return cls(kind, pitch, w, h, k, np.zeros(5) if d is None else d,
                   np.asarray(pose["rvec"], np.float64).reshape(3), np.asarray(pose["tvec"], np.float64).reshape(3))

    @property
    def plain(self) -> bool:
        """True for the telecentric camera without distortion: ``X = u * pitch`` exactly."""
        return self.kind == "telecentric" and self.distortion is None

    @property
    def centre(self) -> tuple[float, float]:
        """The optical (distortion) centre ``(cx, cy)`` in pixels: from ``matrix``, else the image centre."""
        if self.matrix is not None:
            return float(self.matrix[0, 2]), float(self.matrix[1, 2])
        return (self.width - 1) / 2.0, (self.height - 1) / 2.0

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary (results' camera.json)."""
        out: dict[str, Any] = {"model": self.kind, "pixel_pitch_mm": self.pitch_mm, "plain": self.plain}
        for key in ("matrix", "distortion", "rvec", "tvec"):
            val = getattr(self, key)
            if val is not None:
                out[key] = np.asarray(val).tolist()
        return out

    def _rays(self, u: NDArray, v: NDArray) -> tuple[NDArray, ...]:
        """Undistorted pixel coordinates (telecentric) or the rays in plate coordinates (pinhole)."""
        pts = np.stack([np.ravel(u), np.ravel(v)], axis=-1).astype(np.float64).reshape(-1, 1, 2)
        if self.kind == "telecentric":
            und = cv2.undistortPoints(pts, self.matrix, self.distortion, P=self.matrix, criteria=_UNDISTORT).reshape(-1, 2)
            return und[:, 0].reshape(np.shape(u)), und[:, 1].reshape(np.shape(u))
        xy = cv2.undistortPoints(pts, self.matrix, self.distortion, criteria=_UNDISTORT).reshape(-1, 2)
        rot, _ = cv2.Rodrigues(self.rvec)
        d = np.column_stack([xy, np.ones(len(xy))]) @ rot  # R^T d for each row d
        c = -rot.T @ self.tvec
        shape = np.shape(u)
        return c, d[:, 0].reshape(shape), d[:, 1].reshape(shape), d[:, 2].reshape(shape)

    def xy_at(self, u: ArrayLike, v: ArrayLike, h: ArrayLike = 0.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(X, Y)`` in mm of pixel coordinates ``(u, v)`` (any shape, fractional allowed) seen at
        height ``h`` (mm; broadcast). NaN where ``h`` is not finite."""
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        h = np.broadcast_to(np.asarray(h, np.float64), u.shape)
        bad = ~np.isfinite(h)
        if self.plain:
            x, y = u * self.pitch_mm, v * self.pitch_mm
        elif self.kind == "telecentric":
            uu, vv = self._rays(u, v)
            x, y = uu * self.pitch_mm, vv * self.pitch_mm
        else:
            c, dx, dy, dz = self._rays(u, v)
            s = (-h - c[2]) / dz
            x, y = c[0] + s * dx, c[1] + s * dy
        x, y = np.array(x, np.float64), np.array(y, np.float64)
        x[bad] = np.nan
        y[bad] = np.nan
        return x, y

    def xy(self, height: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(X, Y)`` maps in mm of a height map ``(H, W)``: each pixel at its own height (NaN
        where the height is NaN). The rays are computed once per model and reused."""
        height = np.asarray(height)
        if height.shape != (self.height, self.width):
            raise ValueError(f"height map {height.shape} does not match the camera's {self.height} x {self.width}")
        bad = ~np.isfinite(height)
        if self.kind == "pinhole":
            c, dx, dy, dz = self._grid()
            s = (-height.astype(np.float64) - c[2]) / dz
            x, y = c[0] + s * dx, c[1] + s * dy
        else:
            gx, gy = self._grid()
            x, y = gx.copy(), gy.copy()
        x[bad] = np.nan
        y[bad] = np.nan
        return x, y

    def _grid(self) -> tuple[Any, ...]:
        """Per-pixel X, Y (telecentric) or rays (pinhole), computed once per model (0.3 s for
        640 x 480 pinhole pixels: the iterative undistortion), then 3 ms per height map."""
        if not self._grid_cache:
            v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
            if self.plain:
                grid: tuple[Any, ...] = (u * self.pitch_mm, v * self.pitch_mm)
            elif self.kind == "telecentric":
                uu, vv = self._rays(u, v)
                grid = (uu * self.pitch_mm, vv * self.pitch_mm)
            else:
                grid = self._rays(u, v)
            self._grid_cache.append(grid)
        return self._grid_cache[0]

    def box_mm(self, box: Sequence[float], h: float = 0.0) -> list[float]:
        """A pixel box ``[u0, v0, u1, v1)`` as ``[X0, Y0, X1, Y1]`` in mm: its corners seen at
        height ``h`` (telecentric without distortion: ``[u0 * pitch, v0 * pitch, ...]`` exactly)."""
        if self.plain:
            return [float(x) * self.pitch_mm for x in box]
        x, y = self.xy_at(np.array([box[0], box[2]], np.float64), np.array([box[1], box[3]], np.float64), h)
        return [float(x[0]), float(y[0]), float(x[1]), float(y[1])]

    def field_mm(self) -> tuple[float, float, float, float]:
        """``(X0, X1, Y0, Y1)``: the plate-plane (h = 0) bounds of the image corners' centres."""
        u = np.array([0.0, self.width - 1.0, 0.0, self.width - 1.0])
        v = np.array([0.0, 0.0, self.height - 1.0, self.height - 1.0])
        x, y = self.xy_at(u, v, 0.0)
        return float(x.min()), float(x.max()), float(y.min()), float(y.max())
