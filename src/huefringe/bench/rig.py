"""The bench's projector-camera rig: entocentric camera and projector with distortion, ground truth.

A :class:`BenchRig` is two pinhole devices with OpenCV distortion and the projector's pose
(``X_p = R X_c + T``, camera frame, mm). It renders

* checkerboard poses (:meth:`BenchRig.board_pose`): the corners the camera sees (truth and with
  detection noise), the decoded projector coordinates ``u, v`` at every camera pixel on the board
  (truth plus the decoder's noise) and a rendered image of the board for corner detection;
* object scenes (:class:`PlaneScene`, :class:`SphereScene`, :class:`StepsScene`,
  :class:`CompositeScene`): ``u, v`` at every camera pixel and the true ``X, Y, Z`` the pixel sees,
  and where the projector lights it directly (``lit``: a surface between the point and the
  projector centre casts a shadow; a face turned away from the projector is dark);
* fringe sequences of either (:meth:`BenchRig.capture`): the projector images of a
  ``huefringe.codecs`` sequence sampled at each camera pixel's projector coordinate.

Camera rays are cast backwards exactly as the measuring code's model says (undistorted pixel,
ray, surface, projected into the projector with its distortion), so truth and model agree to
machine precision and every difference a test sees is the calibration's or the decoder's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from huefringe.rig.calibrate import Board
from huefringe.rig.model import RigCalibration
from huefringe.rig.triangulation import camera_rays, project

__all__ = ["RIGS", "BenchRig", "CompositeScene", "PlaneScene", "SphereScene", "StepsScene", "pose_set", "rot",
           "segment_hits_box", "segment_hits_sphere", "write_captures", "write_pose_folders"]

F64 = NDArray[np.float64]


def rot(rx_deg: float = 0.0, ry_deg: float = 0.0, rz_deg: float = 0.0) -> F64:
    """Rotation matrix ``Rz @ Ry @ Rx`` from angles in degrees."""
    return cv2.Rodrigues(np.radians([0, 0, rz_deg]))[0] @ cv2.Rodrigues(np.radians([0, ry_deg, 0]))[0] \
        @ cv2.Rodrigues(np.radians([rx_deg, 0, 0]))[0]


@dataclass(frozen=True)
class BenchRig:
    """A projector-camera rig with known truth (all lengths mm, angles degrees, pixels px)."""

    camera_size: tuple[int, int] = (640, 480)
    camera_f: float = 1400.0
    camera_pp: tuple[float, float] = (322.0, 236.0)
    camera_dist: tuple[float, ...] = (-0.08, 0.12, 0.0005, -0.0003, 0.0)
    projector_size: tuple[int, int] = (800, 600)
    projector_f: float = 1500.0
    projector_pp: tuple[float, float] = (400.0, 560.0)
    projector_dist: tuple[float, ...] = (0.04, -0.05, 0.0, 0.0, 0.0)
    baseline_mm: float = 140.0
    convergence_mm: float = 400.0
    roll_deg: float = 1.0

    @cached_property
    def calibration(self) -> RigCalibration:
        """The truth as a :class:`RigCalibration`."""
        C = np.array([self.baseline_mm, 0.0, 0.0])
        yaw = np.degrees(np.arctan2(self.baseline_mm, self.convergence_mm))
        # projector axis turned towards the camera's axis, its image centre (not its principal
        # point) aimed at the convergence point
        pitch = np.degrees(np.arctan((self.projector_pp[1] - (self.projector_size[1] - 1) / 2) / self.projector_f))
        R = rot(self.roll_deg + pitch, yaw, 0.0)
        T = -R @ C
        Kc = np.array([[self.camera_f, 0, self.camera_pp[0]], [0, self.camera_f, self.camera_pp[1]], [0, 0, 1]])
        Kp = np.array([[self.projector_f, 0, self.projector_pp[0]], [0, self.projector_f, self.projector_pp[1]], [0, 0, 1]])
        return RigCalibration(Kc, np.array(self.camera_dist), Kp, np.array(self.projector_dist), R, T,
                              self.camera_size, self.projector_size)

    @cached_property
    def rays(self) -> F64:
        """Ray direction ``(x, y, 1)`` of every camera pixel, shape (H, W, 3)."""
        w, h = self.camera_size
        yy, xx = np.mgrid[0:h, 0:w]
        return camera_rays(self.calibration, np.column_stack([xx.ravel(), yy.ravel()])).reshape(h, w, 3)

    def to_projector(self, xyz: F64) -> F64:
        """Projector pixels of camera-frame points (N, 3)."""
        c = self.calibration
        return project(xyz, c.projector_matrix, c.projector_distortion, c.R, c.T)

    def to_camera(self, xyz: F64) -> F64:
        """Camera pixels of camera-frame points (N, 3)."""
        c = self.calibration
        return project(xyz, c.camera_matrix, c.camera_distortion)

    def coordinates(self, xyz: F64, seen: NDArray[np.bool_], rng: np.random.Generator, sigma_px: float) -> dict[str, Any]:
        """Decoded-like ``u, v`` maps of surface points ``xyz`` (H, W, 3) seen where ``seen``."""
        h, w = seen.shape
        u = np.full((h, w), np.nan)
        v = np.full((h, w), np.nan)
        uv = self.to_projector(xyz[seen])
        pw, ph = self.projector_size
        lit = (uv[:, 0] >= 0) & (uv[:, 0] <= pw - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= ph - 1)
        idx = np.flatnonzero(seen.ravel())[lit]
        u.ravel()[idx], v.ravel()[idx] = uv[lit, 0], uv[lit, 1]
        valid = np.isfinite(u)
        ut, vt = u.copy(), v.copy()
        u[valid] += rng.normal(0.0, sigma_px, valid.sum())
        v[valid] += rng.normal(0.0, sigma_px, valid.sum())
        return {"u": u, "v": v, "valid": valid, "u_true": ut, "v_true": vt,
                "sigma": np.where(valid, sigma_px, np.nan)}

    def board_pose(self, board: Board, R_b: F64, t_b: F64, rng: np.random.Generator, *,
                   corner_sigma_px: float, coord_sigma_px: float, image: bool = False) -> dict[str, Any]:
        """One checkerboard pose (board frame ``X_c = R_b X_b + t_b``): corners, ``u, v`` maps, image."""
        obj = board.object_points().astype(np.float64)
        corners_xyz = obj @ R_b.T + t_b
        cam_true = self.to_camera(corners_xyz)
        proj_true = self.to_projector(corners_xyz)
        n = R_b[:, 2]
        d = self.rays
        t = (n @ t_b) / (d @ n)
        xyz = d * t[..., None]
        local = (xyz - t_b) @ R_b                        # board coordinates of each pixel
        margin = board.pitch_mm
        on = ((local[..., 0] > -margin) & (local[..., 0] < (board.cols - 1) * board.pitch_mm + margin)
              & (local[..., 1] > -margin) & (local[..., 1] < (board.rows - 1) * board.pitch_mm + margin) & (t > 0))
        out = self.coordinates(xyz, on, rng, coord_sigma_px)
        out.update(camera_true=cam_true, projector_true=proj_true,
                   camera=cam_true + rng.normal(0.0, corner_sigma_px, cam_true.shape), xyz=xyz, on=on)
        if image:
            out["image"] = _checker_image(local, on, board)
        return out

    def capture(self, patterns: NDArray[np.number], u: F64, v: F64, valid: NDArray[np.bool_],
                rng: np.random.Generator, *, albedo: float | F64 = 0.8, ambient: float = 0.05,
                noise_dn: float = 1.0) -> NDArray[np.uint8]:
        """Camera frames (F, H, W) of projector ``patterns`` (F, Hp, Wp) at coordinates ``u, v``.

        Bilinear sampling of each pattern at the pixel's true projector coordinate, a linear
        camera (``albedo``, a scalar or an (H, W) map, and ``ambient`` in full scale), Gaussian read noise in DN, 8-bit.
        """
        pats = np.asarray(patterns, dtype=np.float32)
        if pats.ndim == 4:
            pats = pats.mean(axis=3)
        scale = 255.0 if np.asarray(patterns).dtype == np.uint8 else 65535.0
        mapx = np.where(valid, u, -10).astype(np.float32)
        mapy = np.where(valid, v, -10).astype(np.float32)
        frames = np.empty((len(pats), *u.shape), dtype=np.uint8)
        for k, p in enumerate(pats):
            s = cv2.remap(p / scale, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            img = 255.0 * (ambient + albedo * s) + rng.normal(0.0, noise_dn, u.shape)
            frames[k] = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        return frames

    def capture_rgb(self, patterns: NDArray[np.number] | list[NDArray[np.number]], u: F64, v: F64, valid: NDArray[np.bool_],
                    rng: np.random.Generator, *, albedo: float | F64 = 0.8, ambient: float = 0.05,
                    noise_dn: float = 1.0, gamma: tuple[float, float, float] = (1.0, 1.0, 1.0),
                    crosstalk: F64 | None = None, signal_only: bool = False) -> NDArray[Any]:
        """Colour camera frames (F, H, W, 3), R, G, B, of colour projector ``patterns`` (F, Hp, Wp, 3)
        (an array, or a list of (Hp, Wp, 3) images: a repeated image may be the same object).

        Each channel of each pattern sampled bilinearly at the pixel's true projector coordinate
        (projector pixels hold their value at their centres), the projector's per-channel
        response ``value ** gamma``, the surface's ``albedo`` (a scalar, an (H, W) map or an
        (H, W, 3) colour), ``ambient`` light, the camera's channel mixing ``crosstalk`` (3 x 3,
        rows: camera channel, columns: projector primary; identity when None), Gaussian read
        noise in DN, 8-bit. A pixel outside ``valid`` gets ambient light and noise only.
        ``signal_only``: the noiseless signal in DN (float64, not rounded), ``rng`` untouched (to be
        averaged over the instants of an exposure, then given noise and rounded).
        """
        pats = patterns
        dtype = np.asarray(pats[0]).dtype
        scale = 255.0 if dtype == np.uint8 else (65535.0 if dtype == np.uint16 else 1.0)
        alb = np.asarray(albedo, dtype=np.float64)
        alb = alb[..., None] if alb.ndim == 2 else alb
        M = np.eye(3) if crosstalk is None else np.asarray(crosstalk, dtype=np.float64)
        mapx = np.where(valid, u, -10).astype(np.float32)
        mapy = np.where(valid, v, -10).astype(np.float32)
        frames = np.empty((len(pats), *u.shape, 3), dtype=np.float64 if signal_only else np.uint8)
        g = np.asarray(gamma, dtype=np.float64)
        for k, p in enumerate(pats):
            s = cv2.remap(np.ascontiguousarray(p, dtype=np.float32) / scale, mapx, mapy, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            light = np.clip(s, 0.0, 1.0) ** g
            if signal_only:
                frames[k] = 255.0 * (ambient + (alb * light) @ M.T)
                continue
            img = 255.0 * (ambient + (alb * light) @ M.T) + rng.normal(0.0, noise_dn, (*u.shape, 3))
            frames[k] = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        return frames


def _checker_image(local: F64, on: NDArray[np.bool_], board: Board) -> NDArray[np.uint8]:
    """The board seen by the camera under white light, edges box-filtered to the pixel, 8-bit."""
    fx, fy = local[..., 0] / board.pitch_mm, local[..., 1] / board.pitch_mm
    s = []
    for f in (fx, fy):
        gy, gx = np.gradient(f)
        g = np.hypot(gx, gy) + 1e-12
        s.append(np.clip(np.sin(np.pi * f) / (np.pi * g), -0.5, 0.5) * 2)
    inside = ((fx > 0) & (fx < board.cols - 1) & (fy > 0) & (fy < board.rows - 1))
    val = np.where(on, 0.5 + 0.5 * s[0] * s[1], 0.15)
    frame = (fx > -1) & (fx < board.cols) & (fy > -1) & (fy < board.rows)
    val = np.where(frame & ~inside & on, np.where(frame, val, 1.0), val)
    return np.clip(np.rint(30 + 200 * val), 0, 255).astype(np.uint8)


def pose_set(rig: BenchRig, board: Board, n: int, seed: int, *, distance_mm: tuple[float, float] = (340.0, 460.0),
             tilt_deg: float = 40.0, margin_px: float = 20.0,
             aim: tuple[float, float] = (0.06, 0.05)) -> list[tuple[F64, F64]]:
    """``n`` board poses with every corner inside both images (``margin_px`` from the edges).

    Each board's centre is aimed at a random point within ``aim`` (x, y) times its distance off
    the camera's axis: the default keeps the boards near the middle of the image; wider (about
    ``(0.14, 0.11)`` on the 640 x 480 rigs) spreads them over the field, into its corners.
    """
    rng = np.random.default_rng(seed)
    centre = np.array([(board.cols - 1) * board.pitch_mm / 2, (board.rows - 1) * board.pitch_mm / 2, 0.0])
    obj = board.object_points().astype(np.float64)
    out: list[tuple[F64, F64]] = []
    for _ in range(10000):
        if len(out) == n:
            break
        R_b = rot(180 + rng.uniform(-tilt_deg, tilt_deg), rng.uniform(-tilt_deg, tilt_deg), rng.uniform(-15, 15))
        z = rng.uniform(*distance_mm)
        at = np.array([rng.uniform(-aim[0], aim[0]) * z, rng.uniform(-aim[1], aim[1]) * z, z])
        t_b = at - R_b @ centre
        pts = obj @ R_b.T + t_b
        if (pts[:, 2] <= 0).any() or R_b[2, 2] > -0.5:
            continue
        ok = True
        for uv, (w, h) in ((rig.to_camera(pts), rig.camera_size), (rig.to_projector(pts), rig.projector_size)):
            ok &= bool(((uv >= margin_px) & (uv <= np.array([w, h]) - 1 - margin_px)).all())
        if ok:
            out.append((R_b, t_b))
    if len(out) < n:
        raise ValueError(f"only {len(out)} of {n} board poses fit both images")
    return out


@dataclass(frozen=True)
class PlaneScene:
    """A flat board: the plane through ``point`` with unit ``normal`` (camera frame, mm)."""

    point: tuple[float, float, float] = (20.0, 0.0, 400.0)
    tilt_deg: tuple[float, float] = (10.0, -8.0)

    def cast(self, rays: F64) -> tuple[F64, NDArray[np.bool_]]:
        """Surface points seen along ``rays`` (H, W, 3) and where there is surface."""
        n = rot(self.tilt_deg[0], self.tilt_deg[1]) @ np.array([0.0, 0.0, -1.0])
        p = np.asarray(self.point)
        t = (n @ p) / (rays @ n)
        return rays * t[..., None], t > 0

    def normal(self) -> F64:
        """Unit normal of the plane, towards the camera."""
        return rot(self.tilt_deg[0], self.tilt_deg[1]) @ np.array([0.0, 0.0, -1.0])

    def lit(self, rig: BenchRig, xyz: F64, seen: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Where the projector lights the seen points ``xyz`` (H, W, 3) directly: the plane faces it."""
        return seen & _facing(rig, xyz, self.normal(), np.asarray(self.point, dtype=np.float64))


@dataclass(frozen=True)
class SphereScene:
    """A sphere of ``radius`` at ``centre`` in front of a background plane."""

    centre: tuple[float, float, float] = (15.0, 5.0, 380.0)
    radius: float = 25.0
    background: PlaneScene = field(default_factory=lambda: PlaneScene(point=(0.0, 0.0, 420.0), tilt_deg=(3.0, -2.0)))

    def cast(self, rays: F64) -> tuple[F64, NDArray[np.bool_], NDArray[np.bool_]]:
        """Points, surface mask and sphere mask."""
        c = np.asarray(self.centre)
        a = np.einsum("...i,...i", rays, rays)
        b = rays @ c
        disc = b * b - a * (c @ c - self.radius**2)
        hit = disc > 0
        t = np.where(hit, (b - np.sqrt(np.where(hit, disc, 0))) / a, np.inf)
        bg, bg_ok = self.background.cast(rays)
        xyz = np.where(hit[..., None], rays * np.where(hit, t, 0)[..., None], bg)
        return xyz, hit | bg_ok, hit

    def lit(self, rig: BenchRig, xyz: F64, seen: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Where the projector lights the seen points ``xyz`` (H, W, 3) directly: not behind the
        sphere (its cast shadow on the background, its own far side) and on the background's lit side."""
        c = rig.calibration.projector_centre
        occluded = segment_hits_sphere(c, xyz, np.asarray(self.centre, dtype=np.float64), self.radius)
        bg = self.background
        on_bg = _facing(rig, xyz, bg.normal(), np.asarray(bg.point, dtype=np.float64))
        on_sphere = np.abs(np.linalg.norm(xyz - np.asarray(self.centre), axis=-1) - self.radius) < 1e-6
        return seen & ~occluded & (on_sphere | on_bg)


@dataclass(frozen=True)
class StepsScene:
    """Rectangular blocks of known heights on a base plane (plane frame: ``R_o``, origin ``t_o``).

    ``blocks`` are ``(x0, y0, x1, y1, height)`` in the plane's frame, heights towards the camera.
    """

    tilt_deg: tuple[float, float] = (6.0, -5.0)
    origin: tuple[float, float, float] = (0.0, 0.0, 420.0)
    blocks: tuple[tuple[float, float, float, float, float], ...] = (
        (-60.0, -30.0, -25.0, 30.0, 2.0), (-15.0, -30.0, 20.0, 30.0, 5.0), (30.0, -30.0, 65.0, 30.0, 10.0))

    def frame(self) -> tuple[F64, F64]:
        """``R_o`` (columns: plane x, y, normal towards the camera) and origin."""
        R = rot(180 + self.tilt_deg[0], self.tilt_deg[1])
        return R, np.asarray(self.origin)

    def cast(self, rays: F64) -> tuple[F64, NDArray[np.bool_], NDArray[np.int64]]:
        """Points, surface mask and the face label (0 base, k block k)."""
        R, o = self.frame()
        n = R[:, 2]
        best_t = np.full(rays.shape[:-1], np.inf)
        label = np.zeros(rays.shape[:-1], dtype=np.int64)
        dn = rays @ n
        for k, (x0, y0, x1, y1, h) in enumerate(((-1e9, -1e9, 1e9, 1e9, 0.0), *self.blocks)):
            t = ((o + h * n) @ n) / dn
            loc = (rays * t[..., None] - o) @ R
            inside = (loc[..., 0] >= x0) & (loc[..., 0] <= x1) & (loc[..., 1] >= y0) & (loc[..., 1] <= y1) & (t > 0)
            better = inside & (t < best_t)
            best_t = np.where(better, t, best_t)
            label = np.where(better, k, label)
        xyz = rays * np.where(np.isfinite(best_t), best_t, 0)[..., None]
        return xyz, np.isfinite(best_t), label

    def as_composite(self) -> CompositeScene:
        """The same blocks as solids (with side walls) in a :class:`CompositeScene`."""
        return CompositeScene(tilt_deg=self.tilt_deg, origin=self.origin, blocks=self.blocks, spheres=())

    def lit(self, rig: BenchRig, xyz: F64, seen: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Where the projector lights the seen points ``xyz`` (H, W, 3) directly: no block (a solid
        from the base to its height) between the point and the projector centre."""
        return self.as_composite().lit(rig, xyz, seen)


_TOL_MM = 1e-6
"""A segment ending on a surface does not hit that surface: entry within this distance of its end."""


def _facing(rig: BenchRig, xyz: F64, normal: F64, point: F64) -> NDArray[np.bool_]:
    """Points whose plane (``normal``, through ``point``) faces the projector and the camera alike."""
    c = rig.calibration.projector_centre
    return np.broadcast_to(((c - point) @ normal > 0) & ((-point) @ normal > 0), xyz.shape[:-1]).copy()


def segment_hits_box(c: F64, p: F64, R: F64, o: F64, box: tuple[float, float, float, float, float],
                     tol_mm: float = _TOL_MM) -> NDArray[np.bool_]:
    """Whether the segments from ``c`` (3,) to the points ``p`` (..., 3) pass through a block.

    The block is ``x0 <= x <= x1, y0 <= y <= y1, 0 <= z <= h`` (``box = (x0, y0, x1, y1, h)``) in the
    frame ``X = R q + o``. A segment that only touches the block at its end point (a point on the
    block's lit surface) does not hit it. Slab method, vectorised over the points.
    """
    x0, y0, x1, y1, h = box
    lo, hi = np.array([x0, y0, min(0.0, h)]), np.array([x1, y1, max(0.0, h)])
    qc = (np.asarray(c, dtype=np.float64) - o) @ R
    e = (np.asarray(p, dtype=np.float64) - c) @ R
    length = np.linalg.norm(e, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (lo - qc) / e
        b = (hi - qc) / e
    near, far = np.minimum(a, b), np.maximum(a, b)
    # an axis the segment runs parallel to: inside the slab (any s) or outside (none)
    par = e == 0
    inside = (qc >= lo) & (qc <= hi)
    near = np.where(par, np.where(inside, -np.inf, np.inf), near)
    far = np.where(par, np.where(inside, np.inf, -np.inf), far)
    s_in, s_out = near.max(axis=-1), far.min(axis=-1)
    return (s_in < s_out) & (s_in < 1.0 - tol_mm / np.maximum(length, 1e-300)) & (s_out > 0.0)


def segment_hits_sphere(c: F64, p: F64, centre: F64, radius: float, tol_mm: float = _TOL_MM) -> NDArray[np.bool_]:
    """Whether the segments from ``c`` (3,) to the points ``p`` (..., 3) enter the sphere before their
    end (a point on the sphere's lit side does not count; one on its far side does)."""
    e = np.asarray(p, dtype=np.float64) - c
    w = np.asarray(c, dtype=np.float64) - centre
    a = np.einsum("...i,...i", e, e)
    b = e @ w
    disc = b * b - a * (w @ w - radius**2)
    root = np.sqrt(np.maximum(disc, 0.0))
    s_in, s_out = (-b - root) / a, (-b + root) / a
    return (disc > 0) & (s_in < 1.0 - tol_mm / np.sqrt(a)) & (s_out > 0.0)


@dataclass(frozen=True)
class CompositeScene:
    """A tilted base plane carrying rectangular blocks and spheres, all solids (plane frame as
    :class:`StepsScene`: ``X = R_o q + origin``, ``q_z`` the height above the base towards the camera).

    ``blocks`` are ``(x0, y0, x1, y1, height)`` in the plane frame (mm); ``spheres`` are
    ``(x, y, radius)``: a ball resting on the base, its centre ``radius`` above ``(x, y)``.
    Face labels (:meth:`cast`): 0 the base, ``k`` the top of block ``k`` (1-based), ``len(blocks) + j``
    sphere ``j`` (1-based), ``-k`` a side wall of block ``k``.
    """

    tilt_deg: tuple[float, float] = (4.0, -3.0)
    origin: tuple[float, float, float] = (0.0, 0.0, 430.0)
    blocks: tuple[tuple[float, float, float, float, float], ...] = (
        (-80.0, 5.0, -50.0, 45.0, 2.0), (-30.0, 5.0, 0.0, 45.0, 5.0), (20.0, 5.0, 50.0, 45.0, 10.0))
    spheres: tuple[tuple[float, float, float], ...] = ((-15.0, -38.0, 12.5),)

    def frame(self) -> tuple[F64, F64]:
        """``R_o`` (columns: plane x, y, normal towards the camera) and origin."""
        return rot(180 + self.tilt_deg[0], self.tilt_deg[1]), np.asarray(self.origin, dtype=np.float64)

    def sphere_centres(self) -> F64:
        """Camera-frame centres of the spheres, (n, 3)."""
        R, o = self.frame()
        return np.array([o + R @ np.array([x, y, r]) for x, y, r in self.spheres]).reshape(-1, 3)

    def cast(self, rays: F64) -> tuple[F64, NDArray[np.bool_], NDArray[np.int64]]:
        """Points the camera sees along ``rays`` (H, W, 3), where there is surface, and the face labels."""
        R, o = self.frame()
        n = R[:, 2]
        dn = rays @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t_base = (o @ n) / dn
        best_t = np.where(t_base > 0, t_base, np.inf)
        label = np.zeros(rays.shape[:-1], dtype=np.int64)
        qd = rays @ R
        q0 = -o @ R
        for k, (x0, y0, x1, y1, h) in enumerate(self.blocks, start=1):
            lo, hi = np.array([x0, y0, 0.0]), np.array([x1, y1, h])
            with np.errstate(divide="ignore", invalid="ignore"):
                a, b = (lo - q0) / qd, (hi - q0) / qd
            near, far = np.minimum(a, b), np.maximum(a, b)
            near = np.where(qd == 0, np.where((q0 >= lo) & (q0 <= hi), -np.inf, np.inf), near)
            far = np.where(qd == 0, np.where((q0 >= lo) & (q0 <= hi), np.inf, -np.inf), far)
            t_in, t_out = near.max(axis=-1), far.min(axis=-1)
            better = (t_in < t_out) & (t_in > 0) & (t_in < best_t)
            best_t = np.where(better, t_in, best_t)
            label = np.where(better, np.where(near.argmax(axis=-1) == 2, k, -k), label)
        for j, (c, (_, _, r)) in enumerate(zip(self.sphere_centres(), self.spheres, strict=True), start=1):
            a = np.einsum("...i,...i", rays, rays)
            b = rays @ c
            disc = b * b - a * (c @ c - r**2)
            t = np.where(disc > 0, (b - np.sqrt(np.maximum(disc, 0.0))) / a, np.inf)
            better = (t > 0) & (t < best_t)
            best_t = np.where(better, t, best_t)
            label = np.where(better, len(self.blocks) + j, label)
        ok = np.isfinite(best_t)
        return rays * np.where(ok, best_t, 0.0)[..., None], ok, label

    def lit(self, rig: BenchRig, xyz: F64, seen: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Where the projector lights the seen points ``xyz`` (H, W, 3) directly: the base faces the
        projector and no block or sphere lies between the point and the projector centre."""
        R, o = self.frame()
        c = rig.calibration.projector_centre
        out = seen & _facing(rig, xyz, R[:, 2], o)
        for box in self.blocks:
            out &= ~segment_hits_box(c, xyz, R, o, box)
        for centre, (_, _, r) in zip(self.sphere_centres(), self.spheres, strict=True):
            out &= ~segment_hits_sphere(c, xyz, centre, r)
        return out

    def names(self) -> dict[int, str]:
        """Face label -> name (``base``, ``block-<height>``, ``ball`` / ``ball-<j>``)."""
        out = {0: "base"}
        for k, b in enumerate(self.blocks, start=1):
            out[k] = f"block-{b[4]:g}".replace(".", "p")
        for j in range(1, len(self.spheres) + 1):
            out[len(self.blocks) + j] = "ball" if len(self.spheres) == 1 else f"ball-{j}"
        return out


RIGS: dict[str, BenchRig] = {
    "tune": BenchRig(),
    "holdout-wide": BenchRig(baseline_mm=220.0, convergence_mm=450.0, camera_f=1250.0, projector_f=1700.0,
                             camera_dist=(-0.15, 0.2, -0.0008, 0.0006, 0.0), projector_dist=(0.07, -0.1, 0.0005, 0.0, 0.0),
                             camera_pp=(315.0, 245.0), projector_pp=(410.0, 590.0), roll_deg=-2.0),
    "holdout-narrow": BenchRig(baseline_mm=90.0, convergence_mm=350.0, camera_f=1600.0, projector_f=1350.0,
                               camera_dist=(0.05, -0.08, 0.0, 0.0008, 0.0), projector_dist=(-0.03, 0.04, 0.0, -0.0004, 0.0),
                               camera_pp=(330.0, 230.0), projector_pp=(390.0, 300.0), roll_deg=0.0),
}
"""Named rigs: ``tune`` (the one the defaults were chosen on) and hold-outs varying the baseline,
convergence, focal lengths, principal points and distortion."""


def write_captures(rig: BenchRig, spec: Any, folder: Any, u: F64, v: F64, valid: NDArray[np.bool_],
                   rng: np.random.Generator, *, noise_dn: float = 1.0, albedo: float | F64 = 0.8,
                   ambient: float = 0.05, name: str = "cap_{:02d}.png") -> None:
    """Write the camera frames of ``spec`` (a :class:`huefringe.codecs.SequenceSpec`) as PNGs
    (``name`` formatted with the frame index, default ``cap_NN.png``; ``albedo``: a scalar or one
    value per camera pixel; ``ambient``: full-scale fraction of light on every pixel). A pixel
    outside ``valid`` gets no projector light: ambient light and noise only."""
    from pathlib import Path

    from huefringe.codecs import generate

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    frames = rig.capture(generate(spec), u, v, valid, rng, noise_dn=noise_dn, albedo=albedo, ambient=ambient)
    for k, f in enumerate(frames):
        cv2.imwrite(str(out / name.format(k)), f)


def write_pose_folders(rig: BenchRig, board: Board, spec: Any, n: int, seed: int, out: Any, *,
                       corner_image: bool = True, printed: bool = False, noise_dn: float = 1.0,
                       ambient: float = 0.05, folder_name: str = "pose_{:02d}",
                       frame_name: str = "cap_{:02d}.png") -> list[tuple[F64, F64]]:
    """Board-pose folders under ``out`` (``folder_name``, default ``pose_NN``): coded captures
    (``frame_name``) and (``corner_image``) ``board.png``.

    With ``printed`` the board's squares are on the captures (each pixel's albedo is the board's
    white-light image), as a real board looks under the sequence: its corners are then found in
    the mean of the captures, and the folders hold nothing but the sequence (a
    structured-light session's ``poses/``).
    """
    from pathlib import Path

    rng = np.random.default_rng(seed)
    poses = pose_set(rig, board, n, seed)
    for i, (R, t) in enumerate(poses):
        p = rig.board_pose(board, R, t, rng, corner_sigma_px=0.0, coord_sigma_px=0.0, image=corner_image or printed)
        folder = Path(out) / folder_name.format(i)
        write_captures(rig, spec, folder, p["u_true"], p["v_true"], p["valid"], rng, noise_dn=noise_dn,
                       albedo=p["image"] / 255.0 if printed else 0.8, ambient=ambient, name=frame_name)
        if corner_image:
            img = np.clip(p["image"] + rng.normal(0, 2, p["image"].shape), 0, 255).astype(np.uint8)
            cv2.imwrite(str(folder / "board.png"), img)
    return poses
