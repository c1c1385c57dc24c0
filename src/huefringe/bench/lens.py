"""The bench camera's lens: pinhole (entocentric) projection, radial distortion, lateral CA.

Without any of the keys ``camera.model``, ``camera.distortion`` and ``camera.lateral_ca_px``
the bench keeps its ideal camera (telecentric, distortion-free: pixel ``(u, v)`` sees
``X = u * pitch``, ``Y = v * pitch``) and :meth:`Lens.from_config` returns ``None``.

With a lens, each photosite looks along its own ray, found backwards from the sensor as a real
lens forms the image forwards:

1. **lateral chromatic aberration**: the R and B images are the G image magnified about the
   optical centre ``c = ((W-1)/2, (H-1)/2)``; channel ``k`` at pixel ``p`` sees what G sees at
   ``c + (p - c) (1 - a_k / r_c)``, so that at the image corners (distance ``r_c`` from ``c``)
   the channel's image lies ``a_k`` pixels further out than G's (``camera.lateral_ca_px:
   [a_R, a_B]``; negative = inwards);
2. **distortion**: OpenCV's model (``k1, k2, p1, p2[, k3 ...]``, ``cv2.projectPoints``) maps the
   ideal image point to where it is recorded; the bench inverts it with
   ``cv2.undistortPoints`` (300 iterations) to machine precision;
3. **projection**: ``telecentric``: the undistorted pixel ``(u', v')`` sees
   ``X = u' pitch, Y = v' pitch`` at every height; ``pinhole``: the ray from the camera centre
   at ``working_distance_mm`` above the reference plane through the undistorted pixel, cast
   against the scene's height field (:meth:`Lens.cast`).

The camera matrix is the one a lab's ``cv2.calibrateCamera`` would report for this camera:
pinhole ``fx = fy = working_distance_mm / pitch`` (the pitch holds on the reference plane at the
image centre), telecentric ``fx = fy = 1 / pitch`` (distortion coefficients in plate millimetres
about the optical centre); ``cx, cy`` at the image centre. The plate pose (pinhole) is the
board ``(X, Y, -h)`` in camera coordinates: ``rvec = 0``, ``tvec = (-cx pitch, -cy pitch, Zc)``,
so that on the reference plane pixel ``(u, v)`` sees ``X = u pitch, Y = v pitch`` without
distortion (the capture-session contract's origin).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Lens"]

F64 = NDArray[np.float64]

# the inverse of the distortion to machine precision (the default 5 iterations leave 1e-3 px
# at the corners of a strongly distorted lens)
_UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 300, 1e-15)


@dataclass(frozen=True, eq=False)
class Lens:
    """The lens of a bench camera (see the module docstring).

    Parameters
    ----------
    kind : {'telecentric', 'pinhole'}
    width, height : int
        Image size in pixels.
    pitch_mm : float
        Pixel pitch on the reference plane (pinhole: at the image centre).
    working_distance_mm : float or None
        Camera centre above the reference plane (pinhole only).
    distortion : ndarray or None
        OpenCV distortion coefficients (4, 5, 8, 12 or 14 values).
    lateral_ca_px : (float, float)
        Radial displacement of the R and B images against G at the image corners, pixels,
        positive outwards.
    """

    kind: str
    width: int
    height: int
    pitch_mm: float
    working_distance_mm: float | None = None
    distortion: F64 | None = None
    lateral_ca_px: tuple[float, float] = (0.0, 0.0)

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> Lens | None:
        """The lens of a validated bench configuration, ``None`` for the ideal camera."""
        cam, s = cfg["camera"], cfg["session"]
        if not any(k in cam for k in ("model", "distortion", "lateral_ca_px")):
            return None
        dist = cam.get("distortion")
        ca = cam.get("lateral_ca_px") or [0.0, 0.0]
        wd = cam.get("working_distance_mm")
        return cls(
            kind=str(cam.get("model", "telecentric")),
            width=int(s["width"]),
            height=int(s["height"]),
            pitch_mm=float(s["pixel_pitch_mm"]),
            working_distance_mm=None if wd is None else float(wd),
            distortion=None if not dist or not any(dist) else np.asarray(dist, np.float64),
            lateral_ca_px=(float(ca[0]), float(ca[1])),
        )

    # ------------------------------------------------------------------ intrinsics
    @property
    def centre(self) -> tuple[float, float]:
        """Optical centre ``(cx, cy)`` in pixels (the image centre)."""
        return (self.width - 1) / 2.0, (self.height - 1) / 2.0

    @property
    def corner_radius_px(self) -> float:
        """Distance of the corner pixels' centres from the optical centre."""
        return float(np.hypot(*self.centre))

    @property
    def matrix(self) -> F64:
        """OpenCV camera matrix in pixels (see the module docstring)."""
        f = (self.working_distance_mm if self.kind == "pinhole" else 1.0) / self.pitch_mm
        cx, cy = self.centre
        return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> F64:
        """Distortion coefficients for OpenCV (five zeros without distortion)."""
        return np.zeros(5) if self.distortion is None else self.distortion

    @property
    def rvec(self) -> F64:
        """Plate pose rotation (Rodrigues), camera looking straight down: zero."""
        return np.zeros(3)

    @property
    def tvec(self) -> F64:
        """Plate pose translation (mm): the board origin (pixel 0, 0's plate point) in camera coordinates."""
        cx, cy = self.centre
        return np.array([-cx * self.pitch_mm, -cy * self.pitch_mm, float(self.working_distance_mm or 0.0)])

    def session_camera(self) -> dict[str, Any]:
        """The lens keys of session.yaml's ``camera`` block (docs/design.md), true values.

        Nothing for a telecentric, distortion-free lens (chromatic aberration is not part of the
        block: the method estimates it from the session).
        """
        out: dict[str, Any] = {}
        if self.kind == "telecentric" and self.distortion is None:
            return out
        out["model"] = self.kind
        out["matrix"] = [[float(v) for v in row] for row in self.matrix]
        if self.distortion is not None:
            out["distortion"] = [float(v) for v in self.distortion]
        if self.kind == "pinhole":
            out["plate_pose"] = {"rvec": [float(v) for v in self.rvec], "tvec": [float(v) for v in self.tvec]}
        return out

    # ------------------------------------------------------------------ image side
    def ca_scale(self, channel: int) -> float:
        """Factor ``1 - a_k / r_c`` of channel ``channel`` (0 R, 1 G, 2 B); 1 for G."""
        if channel == 1:
            return 1.0
        a = self.lateral_ca_px[0 if channel == 0 else 1]
        return 1.0 - a / self.corner_radius_px

    def ideal_pixels(self, u: ArrayLike, v: ArrayLike, channel: int = 1) -> tuple[F64, F64]:
        """Undistorted pixel coordinates ``(u', v')`` that channel ``channel`` at ``(u, v)`` records.

        The chromatic magnification is removed first, then the distortion
        (``cv2.undistortPoints`` (300 iterations) with ``P = matrix``).
        """
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        cx, cy = self.centre
        sc = self.ca_scale(channel)
        ug, vg = cx + (u - cx) * sc, cy + (v - cy) * sc
        if self.distortion is None:
            return ug, vg
        pts = np.stack([ug.ravel(), vg.ravel()], axis=-1).reshape(-1, 1, 2)
        k = self.matrix
        und = cv2.undistortPoints(pts, k, self.distortion, P=k, criteria=_UNDISTORT).reshape(-1, 2)
        return und[:, 0].reshape(u.shape), und[:, 1].reshape(u.shape)

    def distorted_pixels(self, u_ideal: ArrayLike, v_ideal: ArrayLike) -> tuple[F64, F64]:
        """Where the G image records the undistorted pixel ``(u', v')``: OpenCV's forward model."""
        u, v = np.broadcast_arrays(np.asarray(u_ideal, np.float64), np.asarray(v_ideal, np.float64))
        if self.distortion is None:
            return u.copy(), v.copy()
        k = self.matrix
        xn = np.stack([(u.ravel() - k[0, 2]) / k[0, 0], (v.ravel() - k[1, 2]) / k[1, 1], np.ones(u.size)], axis=-1)
        img, _ = cv2.projectPoints(xn, np.zeros(3), np.zeros(3), k, self.distortion)
        img = img.reshape(-1, 2)
        return img[:, 0].reshape(u.shape), img[:, 1].reshape(u.shape)

    # ------------------------------------------------------------------ object side
    def rays(self, u_ideal: F64, v_ideal: F64) -> tuple[F64, F64]:
        """Camera centre and ray directions in plate coordinates (pinhole).

        Returns ``c`` (3,) and ``d`` (..., 3): the board point ``c + s d``; board z is ``-h``.
        """
        k = self.matrix
        dn = np.stack([(u_ideal - k[0, 2]) / k[0, 0], (v_ideal - k[1, 2]) / k[1, 1], np.ones(u_ideal.shape)], axis=-1)
        rot, _ = cv2.Rodrigues(self.rvec)
        return -rot.T @ self.tvec, dn @ rot  # R^T d per row

    def plate_xy(self, u_ideal: F64, v_ideal: F64, h: ArrayLike = 0.0) -> tuple[F64, F64]:
        """Plate ``(X, Y)`` (mm) seen by undistorted pixel ``(u', v')`` at height ``h``."""
        if self.kind == "telecentric":
            return u_ideal * self.pitch_mm, v_ideal * self.pitch_mm
        c, d = self.rays(u_ideal, v_ideal)
        s = (-np.asarray(h, np.float64) - c[2]) / d[..., 2]
        return c[0] + s * d[..., 0], c[1] + s * d[..., 1]

    def cast(
        self,
        u_ideal: F64,
        v_ideal: F64,
        height_at: Callable[[F64, F64], F64],
        h_range: tuple[float, float],
        step_mm: float,
    ) -> tuple[F64, F64, F64]:
        """Where each pixel's ray first meets the height field: ``(X, Y, h)``.

        Parameters
        ----------
        u_ideal, v_ideal : ndarray
            Undistorted pixel coordinates.
        height_at : callable
            ``height_at(X, Y)``: the surface height (mm) at plate positions (interpolated).
        h_range : (float, float)
            Lowest and highest height of the surface.
        step_mm : float
            Largest lateral step of the march along a ray (about half a sample of the height
            field); the crossing is then bisected to 1e-9 of a step.

        Notes
        -----
        A telecentric ray is vertical: ``h = height_at(X, Y)`` directly. A pinhole ray is
        marched down from the highest height in steps of at most ``step_mm`` sideways; the
        first step below the surface brackets the hit, which is bisected (so a ray that grazes
        a block's top edge sees the wall, as a real camera would).
        """
        if self.kind == "telecentric":
            x, y = self.plate_xy(u_ideal, v_ideal)
            return x, y, height_at(x, y)
        lo, hi = float(h_range[0]), float(h_range[1])
        shape = u_ideal.shape
        c, d = self.rays(u_ideal.ravel(), v_ideal.ravel())

        def xy(h: F64, sel: Any = slice(None)) -> tuple[F64, F64]:
            ds = d[sel]
            s = (-h - c[2]) / ds[:, 2]
            return c[0] + s * ds[:, 0], c[1] + s * ds[:, 1]

        m = d.shape[0]
        if hi - lo <= 1e-12:
            x, y = xy(np.full(m, hi))
            return x.reshape(shape), y.reshape(shape), np.full(shape, hi)
        slope = float(np.max(np.hypot(d[:, 0], d[:, 1]) / np.abs(d[:, 2])))
        n = max(1, int(np.ceil((hi - lo) * slope / step_mm)))
        dh = (hi - lo) / n
        top = np.full(m, hi)  # the ray is above the surface here (or touches it)
        bottom = np.full(m, lo)
        x, y = xy(top)
        found = hi - height_at(x, y) <= 0.0
        bottom[found] = hi
        for j in range(1, n + 1):
            idx = np.flatnonzero(~found)
            if idx.size == 0:
                break
            hj = hi - j * dh if j < n else lo
            hh = np.full(idx.size, hj)
            x, y = xy(hh, idx)
            below = hh - height_at(x, y) <= 0.0
            top[idx[~below]] = hj
            bottom[idx[below]] = hj
            found[idx[below]] = True
        # bisection between the last height above the surface and the first at or below it
        idx = np.flatnonzero(top > bottom)
        t_, b_ = top[idx], bottom[idx]
        for _ in range(36):
            mid = 0.5 * (t_ + b_)
            x, y = xy(mid, idx)
            below = mid - height_at(x, y) <= 0.0
            b_ = np.where(below, mid, b_)
            t_ = np.where(below, t_, mid)
        h = bottom.copy()
        h[idx] = 0.5 * (t_ + b_)
        x, y = xy(h)
        return x.reshape(shape), y.reshape(shape), h.reshape(shape)
