"""Triangulation: camera pixel and decoded projector coordinate in, X, Y, Z (mm, camera frame) out.

With one decoded axis (the projector column ``u``, or the row ``v``) each camera ray meets the
projector's surface of constant coordinate: the point ``t d`` on the ray whose projection through
the projector's model (lens distortion included) has that coordinate, found by Newton's method on
``t`` with the model's analytic derivatives, started from the undistorted plane's closed-form
intersection. With both axes the point is the least-squares (midpoint) intersection of the camera
ray and the projector ray.

Where both axes are decoded the two rays should meet: :func:`epipolar_residual` is the distance of
the decoded projector pixel from the camera pixel's epipolar line (the rays' miss, seen in the
projector's image) with its standard uncertainty from the decoded coordinates' uncertainties.

Camera rays come from the undistorted pixels (:func:`undistort`, Newton's method to convergence;
a whole camera grid's rays are kept per calibration and image size). The uncertainty is propagated
to ``X, Y, Z`` to first order from the decoded coordinates' standard uncertainties through the
analytic derivatives of the same solution (implicit differentiation of the ray-surface equation,
or of the midpoint's normal equations); the camera pixel is the sampling position, exact by
definition.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from huefringe.rig.model import RigCalibration

__all__ = ["Triangulated", "camera_rays", "epipolar_residual", "project", "triangulate", "undistort"]

F64 = NDArray[np.float64]
_ITER = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
_NEWTON = 30
"""Newton steps at most (quadratic convergence takes 3 to 6 on real lenses)."""
_GRID_RAYS: dict[tuple[bytes, bytes, tuple[int, int]], F64] = {}
_GRID_KEEP = 12


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


def _five(dist: ArrayLike) -> F64 | None:
    """The coefficients ``k1, k2, p1, p2, k3`` of ``dist``, or None when it uses OpenCV's longer model
    (a non-zero coefficient past the fifth)."""
    d = np.asarray(dist, dtype=np.float64).reshape(-1)
    if d.size > 5 and np.any(d[5:] != 0):
        return None
    out = np.zeros(5)
    out[: min(d.size, 5)] = d[:5]
    return out


def _distort(x: F64, y: F64, dist: ArrayLike) -> tuple[F64, F64, F64, F64, F64, F64]:
    """OpenCV's lens distortion of normalised undistorted ``(x, y)`` and its Jacobian, any model.

    Returns ``xd, yd`` and ``dxd/dx, dxd/dy, dyd/dx, dyd/dy`` from ``cv2.projectPoints`` with its
    Jacobian (a point ``(x, y, 1)`` under the identity pose and intrinsics, whose derivative along
    the translation is the one along ``(x, y)``): the longer models' (rational, thin prism, tilt)
    path; the five-coefficient model has its compiled analytic form (:func:`_distort5`).
    """
    n = x.size
    out = np.empty((6, n))
    dd = np.asarray(dist, dtype=np.float64)
    for lo in range(0, n, 1 << 16):                          # bounded memory for the Jacobian
        hi = min(n, lo + (1 << 16))
        pts = np.ascontiguousarray(np.column_stack([x[lo:hi], y[lo:hi], np.ones(hi - lo)]).reshape(-1, 1, 3))
        img, jac = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), np.eye(3), dd)
        j = jac[:, 3:5].reshape(hi - lo, 2, 2)                  # d(xd, yd) / d(X, Y) at Z = 1
        out[0, lo:hi], out[1, lo:hi] = img.reshape(-1, 2).T
        out[2, lo:hi], out[3, lo:hi], out[4, lo:hi], out[5, lo:hi] = j[:, 0, 0], j[:, 0, 1], j[:, 1, 0], j[:, 1, 1]
    return out[0], out[1], out[2], out[3], out[4], out[5]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _distort5(x, y, d):  # pragma: no cover - numba
    """The five-coefficient model at one point: ``xd, yd`` and the Jacobian (as :func:`_distort`)."""
    k1, k2, p1, p2, k3 = d[0], d[1], d[2], d[3], d[4]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    g2 = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))
    xy = x * y
    cross = g2 * xy + 2.0 * p1 * x + 2.0 * p2 * y
    return (x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x), y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy,
            radial + g2 * x * x + 2.0 * p1 * y + 6.0 * p2 * x, cross, cross, radial + g2 * y * y + 6.0 * p1 * y + 2.0 * p2 * x)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _undistort5_point(xd, yd, d):  # pragma: no cover - numba
    """Newton's method on the five-coefficient distortion at one point: ``x, y`` (NaN if it does not converge)."""
    x, y = xd, yd
    for _ in range(_NEWTON):
        fx, fy, a, b, c, e = _distort5(x, y, d)
        rx, ry = fx - xd, fy - yd
        det = a * e - b * c
        sx, sy = (e * rx - b * ry) / det, (a * ry - c * rx) / det
        x, y = x - sx, y - sy
        if abs(sx) < 1e-14 and abs(sy) < 1e-14:
            return x, y
        if not (math.isfinite(x) and math.isfinite(y)):
            break
    return math.nan, math.nan


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _undistort5_kernel(xd, yd, d, out):  # pragma: no cover - numba
    for i in range(xd.size):
        out[i, 0], out[i, 1] = _undistort5_point(xd[i], yd[i], d)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _plane5_kernel(rays, coord, axis, kp, d, R, T, t_out, slope_out):  # pragma: no cover - numba
    """Per ray: Newton on ``t`` of ``pixel[axis](project(t d)) = coord`` (see :func:`_plane_solve`)."""
    fx, sk, cx, fy, cy = kp[0, 0], kp[0, 1], kp[0, 2], kp[1, 1], kp[1, 2]
    for i in range(coord.size):
        a0 = R[0, 0] * rays[i, 0] + R[0, 1] * rays[i, 1] + R[0, 2] * rays[i, 2]
        a1 = R[1, 0] * rays[i, 0] + R[1, 1] * rays[i, 1] + R[1, 2] * rays[i, 2]
        a2 = R[2, 0] * rays[i, 0] + R[2, 1] * rays[i, 1] + R[2, 2] * rays[i, 2]
        c = coord[i]
        if axis == 0:
            n0, n1, n2 = fx, sk, cx - c
        else:
            n0, n1, n2 = 0.0, fy, cy - c
        t = -(n0 * T[0] + n1 * T[1] + n2 * T[2]) / (n0 * a0 + n1 * a1 + n2 * a2)
        t_out[i], slope_out[i] = math.nan, math.nan
        for _ in range(_NEWTON + 1):
            if not math.isfinite(t):
                break
            X, Y, Z = t * a0 + T[0], t * a1 + T[1], t * a2 + T[2]
            x, y = X / Z, Y / Z
            dx, dy = (a0 * Z - a2 * X) / (Z * Z), (a1 * Z - a2 * Y) / (Z * Z)
            xd, yd, jxx, jxy, jyx, jyy = _distort5(x, y, d)
            if axis == 0:
                f = fx * xd + sk * yd + cx - c
                df = fx * (jxx * dx + jxy * dy) + sk * (jyx * dx + jyy * dy)
            else:
                f = fy * yd + cy - c
                df = fy * (jyx * dx + jyy * dy)
            if abs(f) < 1e-10:
                if df != 0.0 and math.isfinite(df):
                    t_out[i], slope_out[i] = t, 1.0 / df
                break
            t = t - f / df


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _ray5_kernel(rays, u, v, kp, d, R, c, grads, pts, gu, gv):  # pragma: no cover - numba
    """Per ray: the midpoint of the camera ray and the projector ray of ``(u, v)`` and, where
    ``grads`` asks, its derivatives along ``u`` and ``v`` (see :func:`_ray_solve`)."""
    fx, sk, cx, fy, cy = kp[0, 0], kp[0, 1], kp[0, 2], kp[1, 1], kp[1, 2]
    for i in range(u.size):
        ydn = (v[i] - cy) / fy
        xdn = (u[i] - cx - sk * ydn) / fx
        x, y = _undistort5_point(xdn, ydn, d)
        e0 = R[0, 0] * x + R[1, 0] * y + R[2, 0]
        e1 = R[0, 1] * x + R[1, 1] * y + R[2, 1]
        e2 = R[0, 2] * x + R[1, 2] * y + R[2, 2]
        d0, d1, d2 = rays[i, 0], rays[i, 1], rays[i, 2]
        a = d0 * d0 + d1 * d1 + d2 * d2
        b = d0 * e0 + d1 * e1 + d2 * e2
        cc = e0 * e0 + e1 * e1 + e2 * e2
        dc = d0 * c[0] + d1 * c[1] + d2 * c[2]
        ec = e0 * c[0] + e1 * c[1] + e2 * c[2]
        den = a * cc - b * b
        t = (dc * cc - b * ec) / den
        s = (b * dc - a * ec) / den
        pts[i, 0] = 0.5 * (d0 * t + c[0] + e0 * s)
        pts[i, 1] = 0.5 * (d1 * t + c[1] + e1 * s)
        pts[i, 2] = 0.5 * (d2 * t + c[2] + e2 * s)
        if not (grads[0] or grads[1]):
            continue
        _, _, jxx, jxy, jyx, jyy = _distort5(x, y, d)
        det = jxx * jyy - jxy * jyx
        for k in range(2):
            if not grads[k]:
                continue
            if k == 0:
                q0, q1 = 1.0 / fx, 0.0
            else:
                q0, q1 = -sk / (fx * fy), 1.0 / fy
            gx = (jyy * q0 - jxy * q1) / det
            gy = (jxx * q1 - jyx * q0) / det
            de0 = R[0, 0] * gx + R[1, 0] * gy
            de1 = R[0, 1] * gx + R[1, 1] * gy
            de2 = R[0, 2] * gx + R[1, 2] * gy
            db = d0 * de0 + d1 * de1 + d2 * de2
            dcc = 2.0 * (e0 * de0 + e1 * de1 + e2 * de2)
            dec = de0 * c[0] + de1 * c[1] + de2 * c[2]
            dden = a * dcc - 2.0 * b * db
            dt = (dc * dcc - db * ec - b * dec - t * dden) / den
            ds = (db * dc - a * dec - s * dden) / den
            g = gu if k == 0 else gv
            g[i, 0] = 0.5 * (d0 * dt + de0 * s + e0 * ds)
            g[i, 1] = 0.5 * (d1 * dt + de1 * s + e1 * ds)
            g[i, 2] = 0.5 * (d2 * dt + de2 * s + e2 * ds)


def undistort(points: ArrayLike, K: F64, dist: F64) -> F64:
    """Normalised undistorted coordinates ``(x, y)`` of pixel ``points`` (N, 2).

    For OpenCV's five-coefficient model (``k1, k2, p1, p2, k3``) Newton's method on the
    distortion with its analytic Jacobian (compiled), per point to a step below 1e-14 in
    normalised units (NaN where it does not converge: a pixel outside the model's invertible
    region); longer models go through ``cv2.undistortPoints`` iterated to 1e-12.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if p.shape[0] == 0:
        return np.zeros((0, 2))
    d = _five(dist)
    if d is None:
        return cv2.undistortPoints(np.ascontiguousarray(p.reshape(-1, 1, 2)), K, dist, None, None, None, _ITER).reshape(-1, 2)
    xd = (p[:, 0] - K[0, 2] - K[0, 1] * (p[:, 1] - K[1, 2]) / K[1, 1]) / K[0, 0]
    yd = (p[:, 1] - K[1, 2]) / K[1, 1]
    if not d.any():
        return np.column_stack([xd, yd])
    out = np.empty((len(xd), 2))
    _undistort5_kernel(xd, yd, d, out)
    return out


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


def _grid_rays(calib: RigCalibration, shape: tuple[int, int]) -> F64:
    """The rays of every pixel of a camera grid of ``shape`` (H * W, 3) in row-major order, computed
    once per camera model and size (the last few are kept)."""
    key = (np.concatenate([calib.camera_matrix.ravel(), calib.camera_distortion.ravel()]).tobytes(),
           str(calib.camera_distortion.size).encode(), (int(shape[0]), int(shape[1])))
    rays = _GRID_RAYS.pop(key, None)
    if rays is None:
        rays = camera_rays(calib, _pixels(shape, None))
        rays.flags.writeable = False
    _GRID_RAYS[key] = rays                                  # most recent last
    while len(_GRID_RAYS) > _GRID_KEEP:
        _GRID_RAYS.pop(next(iter(_GRID_RAYS)))
    return rays


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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _plane_finish(d, t, slope, s, want, R, T, idx, xyz, sigma, sigma_ray, good):  # pragma: no cover - numba
    """:func:`triangulate`'s outputs for one coordinate, per ray ``i`` of pixel ``idx[i]``: the point
    ``p = t d``, kept where it lies in front of both devices and is finite, with ``sigma`` per axis
    ``|d slope s|`` and along the unit ray ``|(d slope) . d / |d|| s|`` (0 without ``want``): the
    NumPy expressions of the two-coordinate path, operation for operation, with the dot product
    along the ray summed in order (NumPy's ``einsum`` may pair its three terms otherwise: the
    same bits but for ``sigma_ray``'s last bit)."""
    for i in range(t.size):
        ti = t[i]
        p0, p1, p2 = d[i, 0] * ti, d[i, 1] * ti, d[i, 2] * ti
        if not (p2 > 0 and R[2, 0] * p0 + R[2, 1] * p1 + R[2, 2] * p2 + T[2] > 0):
            continue
        if not (math.isfinite(p0) and math.isfinite(p1) and math.isfinite(p2)):
            continue
        j = idx[i]
        xyz[j, 0], xyz[j, 1], xyz[j, 2] = p0, p1, p2
        good[j] = True
        if not want:
            sigma[j, 0], sigma[j, 1], sigma[j, 2], sigma_ray[j] = 0.0, 0.0, 0.0, 0.0
            continue
        si, sl = s[i], slope[i]
        g0, g1, g2 = d[i, 0] * sl, d[i, 1] * sl, d[i, 2] * sl
        v0, v1, v2 = g0 * si, g1 * si, g2 * si
        sigma[j, 0], sigma[j, 1], sigma[j, 2] = math.sqrt(v0 * v0), math.sqrt(v1 * v1), math.sqrt(v2 * v2)
        nrm = math.sqrt(d[i, 0] * d[i, 0] + d[i, 1] * d[i, 1] + d[i, 2] * d[i, 2])
        dot = g0 * (d[i, 0] / nrm) + g1 * (d[i, 1] / nrm) + g2 * (d[i, 2] / nrm)
        r = dot * si
        sigma_ray[j] = math.sqrt(r * r)


def _plane_solve(calib: RigCalibration, d: F64, coord: F64, axis: int) -> tuple[F64, F64]:
    """Where rays ``d`` meet the projector surface ``pixel[axis] = coord``, and ``dt / dcoord``.

    Newton's method on the ray parameter ``t`` (the point ``t d``) of
    ``f(t) = pixel[axis](project(t d)) - coord`` with the projector model's analytic derivative,
    started from the plane of the undistorted coordinate, per ray to a residual below 1e-10
    projector px. Returns ``t`` (NaN where it does not converge or the ray runs parallel to the
    surface) and ``1 / f'(t)``, the derivative of ``t`` along the coordinate at the solution.
    """
    Kp, R, T = calib.projector_matrix, calib.R, calib.T
    d5 = _five(calib.projector_distortion)
    if d5 is not None:
        t, slope = np.empty(len(coord)), np.empty(len(coord))
        _plane5_kernel(np.ascontiguousarray(d), np.ascontiguousarray(coord), axis, Kp, d5, R, T, t, slope)
        return t, slope
    fx, s, cx, fy, cy = Kp[0, 0], Kp[0, 1], Kp[0, 2], Kp[1, 1], Kp[1, 2]
    a = d @ R.T                                                    # R d: X_p = t a + T
    # the undistorted plane n . X_p = 0 through the projector centre starts the iteration
    if axis == 0:
        n = np.column_stack([np.full(len(coord), fx), np.full(len(coord), s), cx - coord])
    else:
        n = np.column_stack([np.zeros(len(coord)), np.full(len(coord), fy), cy - coord])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(n @ T) / np.einsum("ij,ij->i", n, a)
    slope = np.full(len(coord), np.nan)
    todo = np.flatnonzero(np.isfinite(t))
    dist = calib.projector_distortion
    for _ in range(_NEWTON + 1):
        if todo.size == 0:
            break
        ti, ai = t[todo], a[todo]
        X, Y, Z = ti * ai[:, 0] + T[0], ti * ai[:, 1] + T[1], ti * ai[:, 2] + T[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = X / Z, Y / Z
            dx, dy = (ai[:, 0] * Z - ai[:, 2] * X) / (Z * Z), (ai[:, 1] * Z - ai[:, 2] * Y) / (Z * Z)
            xd, yd, jxx, jxy, jyx, jyy = _distort(x, y, dist)
            if axis == 0:
                f = fx * xd + s * yd + cx - coord[todo]
                df = fx * (jxx * dx + jxy * dy) + s * (jyx * dx + jyy * dy)
            else:
                f = fy * yd + cy - coord[todo]
                df = fy * (jyx * dx + jyy * dy)
            done = np.abs(f) < 1e-10
            slope[todo[done]] = 1.0 / df[done]
            t[todo[~done]] = ti[~done] - f[~done] / df[~done]
        todo = todo[~done & np.isfinite(t[todo])]
    t[todo] = np.nan
    t[~np.isfinite(slope)] = np.nan
    return t, slope


def _ray_solve(calib: RigCalibration, d: F64, u: F64, v: F64, grads: tuple[bool, bool] = (False, False)
               ) -> tuple[F64, list[F64 | None]]:
    """Least-squares intersection (midpoint) of camera rays ``d`` and projector rays of ``(u, v)``,
    and where ``grads`` asks, its derivatives along ``u`` and ``v`` (N, 3; None where not asked):
    the normal equations differentiated, the projector ray's derivative through the inverse of the
    distortion's Jacobian."""
    Kp, dp = calib.projector_matrix, calib.projector_distortion
    d5 = _five(dp)
    if d5 is not None:
        n = len(u)
        pts, gu, gv = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        _ray5_kernel(np.ascontiguousarray(d), np.ascontiguousarray(u), np.ascontiguousarray(v), Kp, d5, calib.R,
                     calib.projector_centre, np.array(grads), pts, gu, gv)
        return pts, [gu if grads[0] else None, gv if grads[1] else None]
    xp = undistort(np.column_stack([u, v]), Kp, dp)
    e = np.column_stack([xp, np.ones(len(xp))]) @ calib.R        # R^T (x, y, 1)
    c = calib.projector_centre
    # minimise |t d - (c + s e)|^2 over (t, s)
    a, b, cc = np.einsum("ij,ij->i", d, d), np.einsum("ij,ij->i", d, e), np.einsum("ij,ij->i", e, e)
    dc, ec = d @ c, e @ c
    den = a * cc - b * b
    t = (dc * cc - b * ec) / den
    s = (b * dc - a * ec) / den
    pts = 0.5 * (d * t[:, None] + (c + e * s[:, None]))
    out: list[F64 | None] = [None, None]
    if not any(grads):
        return pts, out
    _, _, jxx, jxy, jyx, jyy = _distort(xp[:, 0], xp[:, 1], dp)
    # d(x, y)/d(u, v) = J^-1 K2^-1 with K2 = [[fx, skew], [0, fy]]
    fx, sk, fy = Kp[0, 0], Kp[0, 1], Kp[1, 1]
    det = jxx * jyy - jxy * jyx
    for i, want in enumerate(grads):
        if not want:
            continue
        q = (1.0 / fx, 0.0) if i == 0 else (-sk / (fx * fy), 1.0 / fy)   # column i of K2^-1
        gx = (jyy * q[0] - jxy * q[1]) / det
        gy = (jxx * q[1] - jyx * q[0]) / det
        de = np.column_stack([gx, gy, np.zeros(len(gx))]) @ calib.R
        db, dcc, dec = np.einsum("ij,ij->i", d, de), 2 * np.einsum("ij,ij->i", e, de), de @ c
        dden = a * dcc - 2 * b * db
        dt = (dc * dcc - db * ec - b * dec - t * dden) / den
        ds = (db * dc - a * dec - s * dden) / den
        out[i] = 0.5 * (d * dt[:, None] + de * s[:, None] + e * ds[:, None])
    return pts, out


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
    if pixels is not None or len(shape) != 2:
        pix = _pixels(shape, pixels)
    coords = {k: np.asarray(given[k], dtype=np.float64).reshape(-1) for k in need}
    sig = {k: (np.zeros(ref.size) if s is None else np.broadcast_to(np.asarray(s, dtype=np.float64), shape).reshape(-1))
           for k, s in (("u", sigma_u), ("v", sigma_v)) if k in need}
    ok = np.ones(ref.size, dtype=bool) if valid is None else np.asarray(valid, dtype=bool).reshape(-1).copy()
    for k in need:
        ok &= np.isfinite(coords[k])
    idx = np.flatnonzero(ok)
    if pixels is None and 4 * idx.size >= ref.size:          # most of a camera grid: its rays, kept per calibration
        d = _grid_rays(calib, shape)[idx]
    elif pixels is None:
        d = camera_rays(calib, np.column_stack([idx % shape[1], idx // shape[1]]).astype(np.float64))
    else:
        d = camera_rays(calib, pix[idx])
    sub = {k: coords[k][idx] for k in need}
    s_sub = {k: sig[k][idx] for k in need}
    wants = {k: bool(np.any(s_sub[k] > 0)) for k in need}
    if mode != "both":  # one coordinate: the points, their terms and the grids in one compiled pass
        t, slope = _plane_solve(calib, d, sub[mode], 0 if mode == "u" else 1)
        xyz = np.full((ref.size, 3), np.nan)
        sigma = np.full((ref.size, 3), np.nan)
        sigma_ray = np.full(ref.size, np.nan)
        good = np.zeros(ref.size, dtype=bool)
        _plane_finish(np.ascontiguousarray(d), t, slope, s_sub[mode], wants[mode], calib.R, calib.T, idx, xyz, sigma,
                      sigma_ray, good)
        return Triangulated(xyz.reshape(*shape, 3), sigma.reshape(*shape, 3), good.reshape(shape),
                            sigma_ray.reshape(shape))
    pts, (gu, gv) = _ray_solve(calib, d, sub["u"], sub["v"], (wants["u"], wants["v"]))
    grads = {k: g for k, g in (("u", gu), ("v", gv)) if g is not None}
    var = np.zeros_like(pts)
    var_ray = np.zeros(len(pts))
    ray = d / np.linalg.norm(d, axis=1, keepdims=True)
    for k, grad in grads.items():
        s = s_sub[k]
        var += (grad * s[:, None]) ** 2
        var_ray += (np.einsum("ij,ij->i", grad, ray) * s) ** 2
    R, T = calib.R, calib.T
    with np.errstate(invalid="ignore"):
        in_front = (pts[:, 2] > 0) & (R[2, 0] * pts[:, 0] + R[2, 1] * pts[:, 1] + R[2, 2] * pts[:, 2] + T[2] > 0)
    in_front &= np.isfinite(pts).all(axis=1)
    xyz = np.full((ref.size, 3), np.nan)
    sigma = np.full((ref.size, 3), np.nan)
    sigma_ray = np.full(ref.size, np.nan)
    xyz[idx[in_front]] = pts[in_front]
    sigma[idx[in_front]] = np.sqrt(var[in_front])
    sigma_ray[idx[in_front]] = np.sqrt(var_ray[in_front])
    good = np.zeros(ref.size, dtype=bool)
    good[idx[in_front]] = True
    return Triangulated(xyz.reshape(*shape, 3), sigma.reshape(*shape, 3), good.reshape(shape), sigma_ray.reshape(shape))
