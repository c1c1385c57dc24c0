"""Coloured point clouds from height maps (Open3D).

A height map is a float32 ``(H, W)`` array of heights in mm, NaN where invalid, on the camera's
pixel grid. With the telecentric geometry of the capture-session spec every valid pixel
``(v, u)`` is the point ``(X, Y, Z) = (u * pitch, v * pitch, height[v, u])`` in mm.

Examples
--------
>>> pcd = height_to_cloud(height, 0.2, colours=white)      # doctest: +SKIP
>>> write_cloud("results/demo/cloud/frame_0000.ply", pcd)  # doctest: +SKIP
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import open3d as o3d
from numpy.typing import ArrayLike, NDArray

from huefringe.io import atomic_path

__all__ = ["height_to_cloud", "height_to_points", "write_cloud", "write_cloud_sigma"]


def _check_height(height: ArrayLike, pitch_mm: float) -> NDArray[np.floating]:
    h = np.asarray(height)
    if h.ndim != 2:
        raise ValueError(f"height must be a 2-D (H, W) array, got shape {h.shape}")
    if not np.issubdtype(h.dtype, np.floating):
        raise TypeError(f"height must be a float array (NaN = invalid), got {h.dtype}")
    if not (np.isfinite(pitch_mm) and pitch_mm > 0):
        raise ValueError(f"pitch_mm must be a positive finite number, got {pitch_mm!r}")
    return h


def _check_colours(colours: ArrayLike, shape: tuple[int, int]) -> NDArray[np.float64]:
    """Return ``colours`` as float64 ``(H, W, 3)`` in [0, 1] (uint8/uint16 are rescaled)."""
    c = np.asarray(colours)
    if c.ndim == 2:  # grey image
        c = np.repeat(c[..., None], 3, axis=-1)
    if c.shape[:2] != shape or c.ndim != 3 or c.shape[2] < 3:
        raise ValueError(f"colours must be (H, W, 3) with (H, W) = {shape}, got {c.shape}")
    c = c[..., :3]
    if c.dtype == np.uint8:
        return c.astype(np.float64) / 255.0
    if c.dtype == np.uint16:
        return c.astype(np.float64) / 65535.0
    return np.clip(c.astype(np.float64), 0.0, 1.0)


def height_to_points(height: ArrayLike, pitch_mm: float) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Valid pixels of a height map as 3-D points in mm.

    Parameters
    ----------
    height : array_like, shape (H, W), float
        Height in mm, NaN (or inf) where invalid.
    pitch_mm : float
        Pixel pitch in mm (object-side, telecentric).

    Returns
    -------
    points : ndarray, shape (N, 3), float64
        ``(u * pitch, v * pitch, height[v, u])`` for the N valid pixels in row-major order.
    pixel : ndarray, shape (N,), intp
        Flat (row-major) pixel index ``v * W + u`` of each point.
    """
    h = _check_height(height, pitch_mm)
    pixel = np.flatnonzero(np.isfinite(h))
    v, u = np.divmod(pixel, h.shape[1])
    points = np.empty((pixel.size, 3), dtype=np.float64)
    points[:, 0] = u * float(pitch_mm)
    points[:, 1] = v * float(pitch_mm)
    points[:, 2] = h.ravel()[pixel]
    return points, pixel


def height_to_cloud(
    height: ArrayLike,
    pitch_mm: float,
    colours: ArrayLike | None = None,
) -> o3d.geometry.PointCloud:
    """Point cloud of the valid pixels of a height map, optionally coloured.

    Parameters
    ----------
    height : array_like, shape (H, W), float
        Height in mm above the reference plane, NaN where invalid.
    pitch_mm : float
        Pixel pitch in mm: pixel ``(v, u)`` is at ``X = u * pitch_mm``, ``Y = v * pitch_mm``.
    colours : array_like, shape (H, W, 3), optional
        Per-pixel RGB, float in [0, 1] (e.g. the object's white image from
        :func:`huefringe.session.read_rgb`); ``uint8``/``uint16`` images are rescaled and a
        grey ``(H, W)`` image is accepted. Only the valid pixels' colours are kept.

    Returns
    -------
    open3d.geometry.PointCloud
        One point per valid pixel (row-major order), coordinates in mm (float64); colours
        in [0, 1] when given.

    Examples
    --------
    >>> h = np.full((2, 3), 1.5, np.float32); h[0, 0] = np.nan
    >>> pcd = height_to_cloud(h, 0.5)
    >>> np.asarray(pcd.points)[0].tolist()
    [0.5, 0.0, 1.5]
    """
    points, pixel = height_to_points(height, pitch_mm)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if colours is not None:
        shape = np.shape(height)
        rgb = _check_colours(colours, (shape[0], shape[1])).reshape(-1, 3)[pixel]
        pcd.colors = o3d.utility.Vector3dVector(np.ascontiguousarray(rgb))
    return pcd


def write_cloud(path: str | os.PathLike[str], pcd: o3d.geometry.PointCloud) -> Path:
    """Write a point cloud as binary PLY, atomically.

    Parameters
    ----------
    path : path-like
        Target ``.ply`` file; its folder is created if needed.
    pcd : open3d.geometry.PointCloud
        The cloud (points in mm; colours and normals are written when present).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    OSError
        If Open3D reports a failed write (nothing is left at ``path`` then).
    """
    path = Path(path)
    if path.suffix.lower() != ".ply":
        raise ValueError(f"{path}: write_cloud writes PLY; use a .ply file name")
    with atomic_path(path) as tmp:
        if len(pcd.points) == 0:  # Open3D refuses empty clouds; an all-invalid frame is legal
            tmp.write_bytes(_empty_ply_header(pcd.has_colors(), pcd.has_normals()))
        else:
            ok = o3d.io.write_point_cloud(str(tmp), pcd, format="ply", write_ascii=False, compressed=False)
            if not ok:
                raise OSError(f"{path}: Open3D could not write the point cloud")
    return path


def _empty_ply_header(colours: bool, normals: bool) -> bytes:
    """A valid binary PLY with zero vertices and the properties Open3D would write."""
    props = ["property double x", "property double y", "property double z"]
    if normals:
        props += ["property double nx", "property double ny", "property double nz"]
    if colours:
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    lines = ["ply", "format binary_little_endian 1.0", "comment Created by huefringe", "element vertex 0"]
    return ("\n".join(lines + props + ["end_header"]) + "\n").encode("ascii")


def write_cloud_sigma(path: str | os.PathLike[str], pcd: o3d.geometry.PointCloud, sigma_mm: ArrayLike) -> Path:
    """:func:`write_cloud` with a per-point scalar ``sigma_mm`` (the height's standard uncertainty).

    Written through Open3D's tensor API as a float vertex property after ``x y z`` (double) and
    ``red green blue`` (uchar), so Open3D (``o3d.t.io.read_point_cloud(...).point["sigma_mm"]``),
    trimesh and MeshLab (as a per-vertex scalar) read it back.

    Parameters
    ----------
    sigma_mm : array_like, shape (N,)
        One value per point, in the cloud's point order (for :func:`height_to_cloud`:
        ``u_map[np.isfinite(height)]``, row-major).
    """
    path = Path(path)
    if path.suffix.lower() != ".ply":
        raise ValueError(f"{path}: write_cloud_sigma writes PLY; use a .ply file name")
    sigma = np.asarray(sigma_mm, dtype=np.float32).reshape(-1)
    if sigma.size != len(pcd.points):
        raise ValueError(f"{path}: {sigma.size} sigma values for {len(pcd.points)} points")
    if sigma.size == 0:
        with atomic_path(path) as tmp:
            tmp.write_bytes(_empty_ply_header(pcd.has_colors(), pcd.has_normals())
                            .replace(b"end_header", b"property float sigma_mm\nend_header"))
        return path
    t = o3d.t.geometry.PointCloud()
    t.point["positions"] = o3d.core.Tensor(np.asarray(pcd.points, np.float64))
    if pcd.has_normals():
        t.point["normals"] = o3d.core.Tensor(np.asarray(pcd.normals, np.float64))
    if pcd.has_colors():
        rgb = np.rint(np.clip(np.asarray(pcd.colors), 0.0, 1.0) * 255.0).astype(np.uint8)
        t.point["colors"] = o3d.core.Tensor(rgb)
    t.point["sigma_mm"] = o3d.core.Tensor(sigma[:, None])
    with atomic_path(path) as tmp:
        if not o3d.t.io.write_point_cloud(str(tmp), t, write_ascii=False, compressed=False):
            raise OSError(f"{path}: Open3D could not write the point cloud")
    return path
