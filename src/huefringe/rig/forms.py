"""Form fits on triangulated points (mm, camera frame): plane, sphere, plane-to-plane distance."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

__all__ = ["Plane", "Sphere", "fit_plane", "fit_sphere", "form_deviation", "plane_distance"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Plane:
    """A least-squares plane: ``normal . (p - centroid) = 0``; ``rms_mm`` of the orthogonal residuals."""

    centroid: F64
    normal: F64
    rms_mm: float
    n: int

    def distance(self, points: ArrayLike) -> F64:
        """Signed orthogonal distances of ``points`` (N, 3), positive along ``normal``."""
        return (np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.centroid) @ self.normal


@dataclass(frozen=True)
class Sphere:
    """A least-squares sphere; ``rms_mm`` of the radial residuals."""

    centre: F64
    radius: float
    rms_mm: float
    n: int


def _finite(points: ArrayLike) -> F64:
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return p[np.isfinite(p).all(axis=1)]


def fit_plane(points: ArrayLike) -> Plane:
    """Total least-squares plane of the finite ``points``; the normal points towards the origin (the camera)."""
    p = _finite(points)
    if len(p) < 3:
        raise ValueError(f"a plane needs 3 points; {len(p)} given")
    c = p.mean(axis=0)
    n = np.linalg.svd(p - c, full_matrices=False)[2][-1]
    if n @ c > 0:
        n = -n
    r = (p - c) @ n
    return Plane(c, n, float(np.sqrt(np.mean(r**2))), len(p))


def fit_sphere(points: ArrayLike) -> Sphere:
    """Geometric least-squares sphere (algebraic start, then radial residuals) of the finite ``points``."""
    p = _finite(points)
    if len(p) < 4:
        raise ValueError(f"a sphere needs 4 points; {len(p)} given")
    A = np.column_stack([2 * p, np.ones(len(p))])
    sol = np.linalg.lstsq(A, (p**2).sum(axis=1), rcond=None)[0]
    c0 = sol[:3]
    r0 = np.sqrt(sol[3] + c0 @ c0)

    def res(x: F64) -> F64:
        return np.linalg.norm(p - x[:3], axis=1) - x[3]

    x = least_squares(res, np.r_[c0, r0], method="lm").x
    r = res(x)
    return Sphere(x[:3], float(x[3]), float(np.sqrt(np.mean(r**2))), len(p))


def plane_distance(base: Plane, points: ArrayLike) -> float:
    """Mean distance of ``points`` from ``base`` along its normal (a step height), mm."""
    return float(np.mean(base.distance(_finite(points))))


def form_deviation(plane: Plane, points: ArrayLike, degree: int = 4) -> float:
    """RMS of the systematic departure of ``points`` from ``plane``, mm.

    The residuals are fitted by a polynomial of ``degree`` in the plane's own coordinates; its RMS
    is the form error (bowing, tilt of parts) without the points' random noise.
    """
    p = _finite(points)
    r = plane.distance(p)
    a = np.cross(plane.normal, [1.0, 0.0, 0.0] if abs(plane.normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(plane.normal, a)
    s, t = (p - plane.centroid) @ a, (p - plane.centroid) @ b
    s, t = s / np.abs(s).max(), t / np.abs(t).max()
    cols = [s**i * t**j for i in range(degree + 1) for j in range(degree + 1 - i)]
    A = np.column_stack(cols)
    fit = A @ np.linalg.lstsq(A, r, rcond=None)[0]
    return float(np.sqrt(np.mean(fit**2)))
