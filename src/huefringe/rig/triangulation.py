"""Triangulation: camera pixel and decoded projector coordinate in, X, Y, Z (mm, camera frame) out.

With one decoded axis (the projector column ``u``, or the row ``v``) each camera ray meets the
projector's surface of constant coordinate: the plane through the projector centre and the
undistorted projector line, found by a fixed-point iteration on the other (predicted) coordinate
so that lens distortion bends the line exactly as the projector's model says. With both axes the
point is the least-squares (midpoint) intersection of the camera ray and the projector ray.

Where both axes are decoded the two rays should meet: :func:`epipolar_residual` is the distance of
the decoded projector pixel from the camera pixel's epipolar line (the rays' miss, seen in the
projector's image) with its standard uncertainty from the decoded coordinates' uncertainties.

Camera rays come from the undistorted pixels (:func:`undistort`, iterated to convergence); the uncertainty is propagated to ``X, Y, Z``
to first order from the decoded coordinates' standard uncertainties through central differences
of the same solution (the camera pixel is the sampling position, exact by definition).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from huefringe.rig.model import RigCalibration

__all__ = ["Triangulated", "camera_rays", "epipolar_residual", "project", "triangulate", "undistort"]

F64 = NDArray[np.float64]
_ITER = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
_DELTA_PX = 0.01


@dataclass(frozen=True, eq=False)
class Triangulated:
    """Triangulated points.

    Attributes
    ----------
    xyz : ndarray, shape (..., 3)
        Points in mm in the camera frame (NaN where not valid).
    sigma : ndarray, shape (..., 3)
        Standard uncertainties of ``X, Y, Z``, mm, from the decoded coordinates' uncertainties.
    valid : ndarray of bool, shape (...)
        Where a point was triangulated (a decoded, finite coordinate in front of both devices).
    sigma_ray : ndarray, shape (...)
        Standard uncertainty of the point along its camera ray (mm): with one axis decoded the
        whole error lies there; with both (ray-ray) the point also moves off the ray, which
        ``sigma`` holds and this does not.
    """

    xyz: F64
    sigma: F64
    valid: NDArray[np.bool_]
    sigma_ray: F64


def undistort(points: ArrayLike, K: F64, dist: F64) -> F64:
    """Normalised undistorted coordinates ``(x, y)`` of pixel ``points`` (N, 2).

    For OpenCV's five-coefficient model (``k1, k2, p1, p2, k3``) a vectorised fixed-point
    iteration (OpenCV's own scheme) run to 1e-13 in normalised units; longer models go through
    ``cv2.undistortPoints`` with the same criteria.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if p.shape[0] == 0:
        return np.zeros((0, 2))
    d = np.zeros(5)
    d[: min(len(dist), 5)] = np.asarray(dist, dtype=np.float64)[:5]
    if len(dist) > 5 and np.any(np.asarray(dist)[5:] != 0):
        return cv2.undistortPoints(np.ascontiguousarray(p.reshape(-1, 1, 2)), K, dist, None, None, None, _ITER).reshape(-1, 2)
    k1, k2, p1, p2, k3 = d
    xd = (p[:, 0] - K[0, 2] - K[0, 1] * (p[:, 1] - K[1, 2]) / K[1, 1]) / K[0, 0]
    yd = (p[:, 1] - K[1, 2]) / K[1, 1]
    x, y = xd.copy(), yd.copy()
    if not d.any():
        return np.column_stack([x, y])
    for _ in range(_ITER[1]):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        xn, yn = (xd - dx) / radial, (yd - dy) / radial
        step = max(float(np.max(np.abs(xn - x))), float(np.max(np.abs(yn - y))))
        x, y = xn, yn
        if step < 1e-13:
            break
    return np.column_stack([x, y])


def project(xyz: ArrayLike, K: F64, dist: F64, R: F64 | None = None, T: F64 | None = None) -> F64:
    """Pixel coordinates (N, 2) of points ``xyz`` (N, 3) in a device ``X_d = R X + T``."""
    p = np.ascontiguousarray(np.asarray(xyz, dtype=np.float64).reshape(-1, 1, 3))
    if p.shape[0] == 0:
        return np.zeros((0, 2))
    rvec = cv2.Rodrigues(np.eye(3) if R is None else np.asarray(R, dtype=np.float64))[0]
    tvec = np.zeros(3) if T is None else np.asarray(T, dtype=np.float64)
    return cv2.projectPoints(p, rvec, tvec, K, dist)[0].reshape(-1, 2)


def _pixels(shape: tuple[int, ...], pixels: ArrayLike | None) -> F64:
    """The camera pixels ``(x, y)`` (N, 2) of coordinate maps of ``shape``: ``pixels`` when given
    (one per coordinate), else every pixel of a 2-D map in row-major order."""
    n = int(np.prod(shape))
    if pixels is None:
        if len(shape) != 2:
            raise ValueError("coordinate vectors need their camera pixels (pixels=)")
        yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
        return np.column_stack([xx.ravel(), yy.ravel()]).astype(np.float64)
    pix = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    if pix.shape[0] != n:
        raise ValueError(f"{pix.shape[0]} pixels for {n} coordinates")
    return pix


def camera_rays(calib: RigCalibration, pixels: ArrayLike) -> F64:
    """Unnormalised ray directions ``(x, y, 1)`` (N, 3) of camera ``pixels`` (N, 2)."""
    xy = undistort(pixels, calib.camera_matrix, calib.camera_distortion)
    return np.column_stack([xy, np.ones(len(xy))])


def epipolar_residual(
    calib: RigCalibration,
    u: ArrayLike,
    v: ArrayLike,
    *,
    sigma_u: ArrayLike | None = None,
    sigma_v: ArrayLike | None = None,
    pixels: ArrayLike | None = None,
) -> tuple[F64, F64]:
    """How far the camera ray and the projector ray of ``(u, v)`` miss each other, in projector pixels.

    The decoded projector pixel's signed distance from the epipolar line of its camera pixel
    (``x_p . E x_c = 0`` with ``E = [T]x R`` for ``X_p = R X_c + T``, undistorted coordinates of
    both devices, the distance scaled to projector pixels by the projector's focal lengths), and
    its standard uncertainty from ``sigma_u, sigma_v``: the decoded coordinates' noise across the
    line, ``sqrt((n_u sigma_u)^2 + (n_v sigma_v)^2)`` with ``n`` the line's unit normal. A
    coordinate decoded with a wrong fringe order or Gray cell moves the pixel by a period or a
    cell; the test sees the part of that move across the epipolar line (errors along the line
    are the ones triangulation cannot tell from depth).

    Parameters
    ----------
    calib : RigCalibration
    u, v : array_like
        Decoded projector column and row: maps (H, W) at every camera pixel, or vectors (N,) at
        ``pixels``; NaN where not decoded.
    sigma_u, sigma_v : array_like, optional
        Their standard uncertainties (projector px); zero when not given.
    pixels : array_like, shape (N, 2), optional
        Camera pixel coordinates ``(x, y)`` of vector inputs.

    Returns
    -------
    residual, sigma : ndarray
        Of ``u``'s shape; NaN where ``u`` or ``v`` is not finite.

    Examples
    --------
    A rectified pair (projector 100 mm beside the camera, no distortion): epipolar lines are rows,
    so a row decoded 3 px off misses by 3 px and a column off by any amount does not miss.

    >>> K = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    >>> c = RigCalibration(K, np.zeros(5), K, np.zeros(5), np.eye(3), np.array([-100.0, 0, 0]), (640, 480), (640, 480))
    >>> px = np.array([[300.0, 200.0], [300.0, 200.0]])
    >>> r, s = epipolar_residual(c, [100.0, 130.0], [203.0, 200.0], sigma_u=0.1, sigma_v=0.2, pixels=px)
    >>> np.round(np.abs(r), 6).tolist(), np.round(s, 6).tolist()
    ([3.0, 0.0], [0.2, 0.2])
    """
    uu = np.asarray(u, dtype=np.float64)
    shape = uu.shape
    uu = uu.reshape(-1)
    vv = np.asarray(v, dtype=np.float64).reshape(-1)
    pix = _pixels(shape, pixels)
    su, sv = (np.zeros(uu.size) if s is None else np.broadcast_to(np.asarray(s, dtype=np.float64), shape).reshape(-1)
              for s in (sigma_u, sigma_v))
    idx = np.flatnonzero(np.isfinite(uu) & np.isfinite(vv))
    residual = np.full(uu.size, np.nan)
    sigma = np.full(uu.size, np.nan)
    if idx.size:
        T = np.asarray(calib.T, dtype=np.float64).reshape(3)
        E = np.array([[0.0, -T[2], T[1]], [T[2], 0.0, -T[0]], [-T[1], T[0], 0.0]]) @ calib.R
        line = camera_rays(calib, pix[idx]) @ E.T                 # epipolar lines in the projector's normalised image
        xp = undistort(np.column_stack([uu[idx], vv[idx]]), calib.projector_matrix, calib.projector_distortion)
        Kp = calib.projector_matrix
        nu, nv = line[:, 0] / Kp[0, 0], line[:, 1] / Kp[1, 1]    # the line's normal in projector pixels
        norm = np.hypot(nu, nv)
        residual[idx] = (line[:, 0] * xp[:, 0] + line[:, 1] * xp[:, 1] + line[:, 2]) / norm
        sigma[idx] = np.hypot(nu * su[idx], nv * sv[idx]) / norm
    return residual.reshape(shape), sigma.reshape(shape)


def _plane_solve(calib: RigCalibration, d: F64, coord: F64, axis: int, iterations: int = 4,
                 other: F64 | None = None) -> tuple[F64, F64]:
    """Intersection of rays ``d`` with the projector surface ``pixel[axis] = coord``, and the other coordinate.

    ``other`` starts the fixed-point iteration on the other projector coordinate (default: the
    principal point's).
    """
    Kp, dp, R, T = calib.projector_matrix, calib.projector_distortion, calib.R, calib.T
    other = np.full(len(coord), Kp[1 - axis, 2]) if other is None else other.copy()
    xyz = np.full((len(coord), 3), np.nan)
    for _ in range(iterations):
        pix = np.empty((len(coord), 2))
        pix[:, axis], pix[:, 1 - axis] = coord, other
        n = np.zeros((len(coord), 3))
        n[:, axis] = 1.0
        n[:, 2] = -undistort(pix, Kp, dp)[:, axis]        # n . X_p = 0 on the plane
        nc = n @ R                                         # R^T n, row-wise
        t = -(n @ T) / np.einsum("ij,ij->i", nc, d)
        xyz = d * t[:, None]
        ok = np.isfinite(xyz).all(axis=1)
        if ok.any():
            other[ok] = project(xyz[ok], Kp, dp, R, T)[:, 1 - axis]
    return xyz, other


def _ray_solve(calib: RigCalibration, d: F64, u: F64, v: F64) -> F64:
    """Least-squares intersection (midpoint) of camera rays ``d`` and projector rays of ``(u, v)``."""
    xp = undistort(np.column_stack([u, v]), calib.projector_matrix, calib.projector_distortion)
    e = np.column_stack([xp, np.ones(len(xp))]) @ calib.R        # R^T (x, y, 1)
    c = calib.projector_centre
    # minimise |t d - (c + s e)|^2 over (t, s)
    a, b, cc = np.einsum("ij,ij->i", d, d), np.einsum("ij,ij->i", d, e), np.einsum("ij,ij->i", e, e)
    dc, ec = d @ c, e @ c
    den = a * cc - b * b
    t = (dc * cc - b * ec) / den
    s = (b * dc - a * ec) / den
    return 0.5 * (d * t[:, None] + (c + e * s[:, None]))


def triangulate(
    calib: RigCalibration,
    u: ArrayLike | None = None,
    v: ArrayLike | None = None,
    *,
    sigma_u: ArrayLike | None = None,
    sigma_v: ArrayLike | None = None,
    valid: ArrayLike | None = None,
    pixels: ArrayLike | None = None,
    mode: Literal["auto", "u", "v", "both"] = "auto",
) -> Triangulated:
    """Triangulate decoded projector coordinates.

    Parameters
    ----------
    calib : RigCalibration
    u, v : array_like, optional
        Decoded projector column and/or row (projector pixels) per camera sample: maps of shape
        (H, W) sampled at every camera pixel, or vectors (N,) at ``pixels``.
    sigma_u, sigma_v : array_like, optional
        Their standard uncertainties (projector pixels); zero when not given.
    valid : array_like of bool, optional
        Where the coordinates were decoded.
    pixels : array_like, shape (N, 2), optional
        Camera pixel coordinates ``(x, y)`` of vector inputs.
    mode : {'auto', 'u', 'v', 'both'}
        ``'u'``/``'v'``: ray against the projector plane of that coordinate; ``'both'``: ray-ray
        least squares; ``'auto'``: ``'both'`` if both are given, else the one given.

    Returns
    -------
    Triangulated
    """
    if u is None and v is None:
        raise ValueError("triangulate needs a decoded projector coordinate (u, v or both)")
    if mode == "auto":
        mode = "both" if (u is not None and v is not None) else ("u" if u is not None else "v")
    need = {"u": ("u",), "v": ("v",), "both": ("u", "v")}[mode]
    given = {"u": u, "v": v}
    for k in need:
        if given[k] is None:
            raise ValueError(f"mode {mode!r} needs the decoded {k}")
    ref = np.asarray(given[need[0]], dtype=np.float64)
    shape = ref.shape
    pix = _pixels(shape, pixels)
    coords = {k: np.asarray(given[k], dtype=np.float64).reshape(-1) for k in need}
    sig = {k: (np.zeros(ref.size) if s is None else np.broadcast_to(np.asarray(s, dtype=np.float64), shape).reshape(-1))
           for k, s in (("u", sigma_u), ("v", sigma_v)) if k in need}
    ok = np.ones(ref.size, dtype=bool) if valid is None else np.asarray(valid, dtype=bool).reshape(-1).copy()
    for k in need:
        ok &= np.isfinite(coords[k])
    idx = np.flatnonzero(ok)
    d = camera_rays(calib, pix[idx])

    start: dict[str, F64] = {}

    def solve(c: dict[str, F64]) -> F64:
        if mode == "both":
            return _ray_solve(calib, d, c["u"], c["v"])
        if "other" in start:       # a small step from the solution: two iterations from its other coordinate
            return _plane_solve(calib, d, c[mode], 0 if mode == "u" else 1, 2, start["other"])[0]
        xyz, start["other"] = _plane_solve(calib, d, c[mode], 0 if mode == "u" else 1)
        return xyz

    sub = {k: coords[k][idx] for k in need}
    pts = solve(sub)
    var = np.zeros_like(pts)
    var_ray = np.zeros(len(pts))
    ray = d / np.linalg.norm(d, axis=1, keepdims=True)
    for k in need:
        s = sig[k][idx]
        if not np.any(s > 0):
            continue
        hi = solve({**sub, k: sub[k] + _DELTA_PX})
        lo = solve({**sub, k: sub[k] - _DELTA_PX})
        grad = (hi - lo) / (2 * _DELTA_PX)
        var += (grad * s[:, None]) ** 2
        var_ray += (np.einsum("ij,ij->i", grad, ray) * s) ** 2
    in_front = np.isfinite(pts).all(axis=1) & (pts[:, 2] > 0)
    in_front &= ((pts @ calib.R.T + calib.T)[:, 2] > 0)
    xyz = np.full((ref.size, 3), np.nan)
    sigma = np.full((ref.size, 3), np.nan)
    sigma_ray = np.full(ref.size, np.nan)
    xyz[idx[in_front]] = pts[in_front]
    sigma[idx[in_front]] = np.sqrt(var[in_front])
    sigma_ray[idx[in_front]] = np.sqrt(var_ray[in_front])
    good = np.zeros(ref.size, dtype=bool)
    good[idx[in_front]] = True
    return Triangulated(xyz.reshape(*shape, 3), sigma.reshape(*shape, 3), good.reshape(shape), sigma_ray.reshape(shape))
