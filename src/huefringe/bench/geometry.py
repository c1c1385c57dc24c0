"""Bench geometry: telecentric camera, pinhole projector, triangulation, shading, cast shadows.

Conventions (capture-session spec, ``docs/design.md``): the camera looks straight down; pixel
``(u, v)`` sees the point ``X = u * pitch``, ``Y = v * pitch`` at the surface height ``h(u, v)``.
The projector is a pinhole at ``(Xp, Yp, H)`` whose image plane is parallel to the plate, so the
pattern lands on the reference plane ``z = 0`` as a linear fringe of period ``P`` mm. A surface
point ``(X, h)`` is lit by the projector ray that meets ``z = 0`` at
``X0 = Xp + (X - Xp) H / (H - h)`` and therefore carries the code phase
``phi(X0) = 2 pi (X0 - X_origin) / P``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "Grid",
    "analytic_phase_difference",
    "cast_shadow_mask",
    "code_phase",
    "lambert_cosine",
    "lambert_from_parts",
    "lambert_parts",
    "projector_ray_x0",
    "triangulation_angle_deg",
]

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class Grid:
    """The camera's sampling grid on the plate, optionally supersampled.

    Parameters
    ----------
    width, height : int
        Camera image size in pixels.
    pitch_mm : float
        Pixel pitch on the reference plane.
    supersample : int
        Sub-samples per pixel and axis; the image is the box average of the sub-samples.
    """

    width: int
    height: int
    pitch_mm: float
    supersample: int = 1

    @property
    def fine_pitch_mm(self) -> float:
        """Spacing of the sub-sample grid in mm."""
        return self.pitch_mm / self.supersample

    def axes(self, fine: bool = True) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """1-D X and Y coordinates (mm) of the (sub-)sample centres.

        Pixel ``u`` is centred on ``X = u * pitch``; its ``n`` sub-samples sit at
        ``(u + (i + 0.5) / n - 0.5) * pitch``.
        """
        n = self.supersample if fine else 1
        off = (np.arange(n) + 0.5) / n - 0.5
        xs = ((np.arange(self.width)[:, None] + off[None, :]) * self.pitch_mm).ravel()
        ys = ((np.arange(self.height)[:, None] + off[None, :]) * self.pitch_mm).ravel()
        return xs, ys

    def mesh(self, fine: bool = True) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """2-D X, Y coordinate arrays (rows = Y) of the (sub-)sample centres."""
        xs, ys = self.axes(fine)
        return np.meshgrid(xs, ys)

    def downsample(self, fine_img: NDArray[np.floating]) -> NDArray[np.float32]:
        """Box-average a sub-sampled image ``(n H, n W, ...)`` to the camera grid ``(H, W, ...)``."""
        a = np.asarray(fine_img, dtype=np.float32)
        if self.supersample == 1:
            return a
        # INTER_AREA with an integer factor is the exact box average
        return cv2.resize(a, (self.width, self.height), interpolation=cv2.INTER_AREA)


def projector_ray_x0(
    x_mm: ArrayLike, h_mm: ArrayLike, projector_x_mm: float, projector_height_mm: float
) -> NDArray[np.float64]:
    """Where the projector ray through the surface point ``(X, h)`` meets the reference plane.

    ``X0 = Xp + (X - Xp) H / (H - h)``.
    """
    x = np.asarray(x_mm, dtype=np.float64)
    h = np.asarray(h_mm, dtype=np.float64)
    big_h = float(projector_height_mm)
    return projector_x_mm + (x - projector_x_mm) * (big_h / (big_h - h))


def code_phase(
    x_mm: ArrayLike,
    h_mm: ArrayLike,
    *,
    projector_x_mm: float,
    projector_height_mm: float,
    period_mm: float,
    x_origin_mm: float = 0.0,
    wrap: bool = False,
) -> NDArray[np.float64]:
    """Code phase carried by the surface point ``(X, h)``: ``2 pi (X0 - X_origin) / P``.

    Parameters
    ----------
    x_mm, h_mm : array_like
        Plate coordinate X and surface height h (mm), broadcastable.
    projector_x_mm, projector_height_mm : float
        Projector pinhole position ``Xp`` and height ``H``.
    period_mm : float
        Fringe period ``P`` on the reference plane.
    x_origin_mm : float
        X on the reference plane where the code phase is zero.
    wrap : bool
        Return the phase modulo 2 pi (default: continuous).
    """
    x0 = projector_ray_x0(x_mm, h_mm, projector_x_mm, projector_height_mm)
    phi = TWO_PI * (x0 - x_origin_mm) / period_mm
    return np.mod(phi, TWO_PI) if wrap else phi


def analytic_phase_difference(
    x_mm: ArrayLike, h_mm: ArrayLike, *, projector_x_mm: float, projector_height_mm: float, period_mm: float
) -> NDArray[np.float64]:
    """Triangulation formula ``dphi = k (X - Xp) h / (H - h)``, ``k = 2 pi / P`` (design.md).

    Written independently of :func:`code_phase` so that one can check the other.
    """
    x = np.asarray(x_mm, dtype=np.float64)
    h = np.asarray(h_mm, dtype=np.float64)
    k = TWO_PI / period_mm
    return k * (x - projector_x_mm) * h / (projector_height_mm - h)


def triangulation_angle_deg(x_mm: ArrayLike, projector_x_mm: float, projector_height_mm: float) -> NDArray[np.float64]:
    """Angle between the camera axis (vertical) and the projector ray at plate position X."""
    x = np.asarray(x_mm, dtype=np.float64)
    return np.degrees(np.arctan2(np.abs(x - projector_x_mm), projector_height_mm))


def lambert_cosine(
    x_mm: NDArray[np.floating],
    y_mm: NDArray[np.floating],
    h_mm: NDArray[np.floating],
    grad_x: NDArray[np.floating],
    grad_y: NDArray[np.floating],
    projector_xyz: tuple[float, float, float],
) -> NDArray[np.floating]:
    """Cosine between the surface normal and the direction to the projector, clipped at 0.

    The normal of the height field ``h(X, Y)`` is ``(-dh/dX, -dh/dY, 1)`` normalised; the
    direction to the projector is ``(Xp - X, Yp - Y, H - h)`` normalised.
    """
    px, py, pz = projector_xyz
    parts = lambert_parts(x_mm, y_mm, grad_x, grad_y, (px, py))
    return lambert_from_parts(parts, pz - np.asarray(h_mm))


def lambert_parts(
    x_mm: NDArray[np.floating],
    y_mm: NDArray[np.floating],
    grad_x: NDArray[np.floating],
    grad_y: NDArray[np.floating],
    projector_xy: tuple[float, float],
) -> tuple[NDArray[np.floating], NDArray[np.floating], NDArray[np.floating]]:
    """The height-independent parts of :func:`lambert_cosine`.

    Returns ``(a, g, l2)`` with ``a = -(gx lx + gy ly)``, ``g = 1 + gx^2 + gy^2`` and
    ``l2 = lx^2 + ly^2`` where ``lx = Xp - X``, ``ly = Yp - Y``; then
    ``cos = (a + lz) / sqrt(g (l2 + lz^2))`` with ``lz = H - h``. A surface moved only
    vertically keeps these, which saves most of the work for a vibrating object.
    """
    lx = projector_xy[0] - x_mm
    ly = projector_xy[1] - y_mm
    a = -(grad_x * lx + grad_y * ly)
    g = 1.0 + grad_x * grad_x + grad_y * grad_y
    return a, g, lx * lx + ly * ly


def lambert_from_parts(
    parts: tuple[NDArray[np.floating], NDArray[np.floating], NDArray[np.floating]], lz: NDArray[np.floating]
) -> NDArray[np.floating]:
    """``clip((a + lz) / sqrt(g (l2 + lz^2)), 0, 1)`` (see :func:`lambert_parts`)."""
    a, g, l2 = parts
    return np.clip((a + lz) / np.sqrt(g * (l2 + lz * lz)), 0.0, 1.0)


def cast_shadow_mask(
    height_mm: NDArray[np.floating],
    x_axis_mm: NDArray[np.floating],
    projector_x_mm: float,
    projector_height_mm: float,
    tol_mm: float = 1e-6,
    x0_mm: NDArray[np.floating] | None = None,
) -> NDArray[np.bool_]:
    """Samples in the projector's cast shadow.

    A sample at ``(X, h)`` is shadowed if, somewhere between it and the projector along x in the
    same row, the surface rises above the ray from the sample to the projector. (The ray's
    excursion in y towards the projector's ``Yp`` is neglected: shadows are cast along rows,
    the direction in which the fringes vary.)

    Parameters
    ----------
    height_mm : ndarray, shape (rows, cols)
        Surface heights on a regular grid.
    x_axis_mm : ndarray, shape (cols,)
        Increasing X coordinates of the columns.
    projector_x_mm, projector_height_mm : float
        Projector pinhole ``Xp`` and ``H``.
    tol_mm : float
        An occluder must rise above the ray by more than about this to cast a shadow.
    x0_mm : ndarray, optional
        The samples' ray footprints (:func:`projector_ray_x0`) if already computed.

    Notes
    -----
    Every ray is labelled by its footprint ``X0`` on the reference plane
    (:func:`projector_ray_x0`); on the projector's side of a sample, surface points above the
    sample's ray have ``X0`` further from ``Xp`` than the sample's own. So, walking each row
    away from the projector, a sample is shadowed exactly when its ``X0`` falls short of the
    running extreme of the ``X0`` of the samples before it: one ``maximum.accumulate`` (or
    ``minimum``) per side of the projector, O(rows x cols).
    """
    h = np.asarray(height_mm, dtype=np.float64)
    xs = np.asarray(x_axis_mm, dtype=np.float64)
    shadow = np.zeros(h.shape, dtype=bool)
    if h.shape[1] < 2 or float(h.max() - h.min()) <= tol_mm:
        return shadow
    big_h = float(projector_height_mm)
    x0 = projector_ray_x0(xs[None, :], h, projector_x_mm, big_h) if x0_mm is None else np.asarray(x0_mm)
    # tolerance in X0 units: a height excess tol at distance d from Xp moves X0 by ~ tol d / H
    tol_x0 = tol_mm * (np.abs(xs - projector_x_mm) / big_h + 1e-3)[None, :]
    jr = int(np.searchsorted(xs, projector_x_mm))  # columns < jr have the projector on their +x side
    if jr < h.shape[1]:  # projector at -x of these columns: walk towards +x, X0 grows with height
        sub = x0[:, jr:]
        prev = np.maximum.accumulate(sub, axis=1)
        shadow[:, jr + 1 :] = sub[:, 1:] < prev[:, :-1] - tol_x0[:, jr + 1 :]
    if jr > 0:  # projector at +x: walk towards -x, X0 shrinks with height
        rev = x0[:, jr - 1 :: -1]
        tol_rev = tol_x0[:, jr - 1 :: -1]
        prev = np.minimum.accumulate(rev, axis=1)
        sh_rev = np.zeros(rev.shape, dtype=bool)
        sh_rev[:, 1:] = rev[:, 1:] > prev[:, :-1] + tol_rev[:, 1:]
        shadow[:, :jr] = sh_rev[:, ::-1]
    return shadow
