"""A height map to a triangle mesh: the jump threshold from the map's own noise, vertex placement, per-vertex sigma."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from huefringe.cloud import check_colours, check_height


#: MAD -> sigma for a Gaussian.
_MAD_TO_SIGMA = 1.482602218505602


# --------------------------------------------------------------------------------------------
# noise and threshold
# --------------------------------------------------------------------------------------------
def estimate_noise(height: ArrayLike) -> float:
    """Robust one-sigma estimate of the per-pixel height noise, in the height's units.

    Uses the second differences along rows and columns,
    ``d = z[i-1] - 2 z[i] + z[i+1]``, which cancel any locally linear surface (planes, slopes,
    tilt) and have variance ``6 sigma^2`` for white noise. Their median absolute deviation is
    insensitive to the few large values at steps and edges::

        sigma = 1.4826 * MAD(d) / sqrt(6)

    Parameters
    ----------
    height : array_like, shape (H, W), float
        Height map, NaN where invalid. Only triples of three finite pixels are used.

    Returns
    -------
    float
        Noise sigma (>= 0); 0.0 when fewer than 16 valid triples exist. Spatially correlated
        (smoothed) noise is under-estimated, which makes the jump threshold tighter.
    """
    h = np.asarray(height, dtype=np.float64)
    if h.ndim != 2:
        raise ValueError(f"height must be 2-D, got shape {h.shape}")
    parts = []
    if h.shape[1] >= 3:
        parts.append((h[:, :-2] - 2.0 * h[:, 1:-1] + h[:, 2:]).ravel())
    if h.shape[0] >= 3:
        parts.append((h[:-2, :] - 2.0 * h[1:-1, :] + h[2:, :]).ravel())
    if not parts:
        return 0.0
    d = np.concatenate(parts)
    d = d[np.isfinite(d)]
    if d.size < 16:
        return 0.0
    mad = float(np.median(np.abs(d - np.median(d))))
    return _MAD_TO_SIGMA * mad / math.sqrt(6.0)


def jump_threshold(
    pitch_mm: float,
    noise_mm: float,
    *,
    max_slope: float = 1.0,
    noise_k: float = 8.0,
) -> float:
    """Largest height span (mm) a triangle may have before it is treated as bridging a jump.

    Parameters
    ----------
    pitch_mm : float
        Pixel pitch in mm.
    noise_mm : float
        One-sigma height noise in mm (e.g. from :func:`estimate_noise`).
    max_slope : float, default 1.0
        Steepest surface slope ``dz/dx`` still meshed as continuous (1.0 = 45 degrees).
    noise_k : float, default 8.0
        Noise allowance in sigmas.

    Returns
    -------
    float
        ``noise_k * noise_mm + max_slope * sqrt(2) * pitch_mm``.
    """
    if pitch_mm <= 0 or noise_mm < 0 or max_slope < 0 or noise_k < 0:
        raise ValueError("pitch_mm must be > 0 and noise_mm, max_slope, noise_k >= 0")
    return float(noise_k * noise_mm + max_slope * math.sqrt(2.0) * pitch_mm)


# --------------------------------------------------------------------------------------------
# triangulation
# --------------------------------------------------------------------------------------------
def height_to_mesh(
    height: ArrayLike,
    pitch_mm: float,
    *,
    colours: ArrayLike | None = None,
    jump_mm: float | None = None,
    noise_mm: float | None = None,
    max_slope: float = 1.0,
    noise_k: float = 8.0,
) -> trimesh.Trimesh:
    """Triangulate the valid pixels of a height map without bridging jumps or holes.

    Vertices sit at ``(u * pitch, v * pitch, height)``; :func:`place_vertices` then moves them to
    a lens model's X, Y (after the pixel-based steps: cleaning, ``sigma_mm``).

    Parameters
    ----------
    height : array_like, shape (H, W), float
        Height in mm, NaN where invalid.
    pitch_mm : float
        Pixel pitch in mm.
    colours : array_like, shape (H, W, 3), optional
        Per-pixel RGB in [0, 1] (or ``uint8``/``uint16``), stored as vertex colours.
    jump_mm : float, optional
        A triangle is kept only if its height span is strictly below this. Default: see
        :func:`jump_threshold`.
    noise_mm : float, optional
        Height noise sigma for the default threshold; estimated with :func:`estimate_noise`
        when omitted. Ignored when ``jump_mm`` is given.
    max_slope, noise_k : float
        Parameters of the default threshold (:func:`jump_threshold`).

    Returns
    -------
    trimesh.Trimesh
        Mesh in mm (float64 vertices; ``Z`` equals the float32 height exactly). ``metadata``
        holds ``pitch_mm``, ``jump_mm``, ``noise_mm`` (None when ``jump_mm`` was given) and
        ``grid_shape``. :func:`vertex_pixels` maps vertices back to pixels.

    Notes
    -----
    Fully vectorised; a fully valid flat ``H x W`` map gives ``2 (H-1)(W-1)`` faces. One
    invalid interior pixel removes exactly the 6 faces that would touch it.
    """
    h = check_height(height, pitch_mm)
    H, W = h.shape
    if jump_mm is None:
        if noise_mm is None:
            noise_mm = estimate_noise(h)
        jump_mm = jump_threshold(pitch_mm, noise_mm, max_slope=max_slope, noise_k=noise_k)
        used_noise: float | None = float(noise_mm)
    else:
        used_noise = None if noise_mm is None else float(noise_mm)
    if not jump_mm > 0:
        raise ValueError(f"jump_mm must be > 0, got {jump_mm!r}")
    rgba = None
    if colours is not None:
        rgb = check_colours(colours, (H, W)).reshape(-1, 3)
        rgba = np.empty((H * W, 4), dtype=np.uint8)
        rgba[:, :3] = np.rint(rgb * 255.0).astype(np.uint8)
        rgba[:, 3] = 255

    vertices = np.empty((0, 3), dtype=np.float64)
    faces = np.empty((0, 3), dtype=np.int64)
    vcolours = None if rgba is None else rgba[:0]
    if H >= 2 and W >= 2:
        with np.errstate(invalid="ignore"):
            z = h.astype(np.float64, copy=False)
            za, zb, zc, zd = z[:-1, :-1], z[:-1, 1:], z[1:, 1:], z[1:, :-1]
            # NaN anywhere makes the span NaN and the comparison False: invalid pixels drop out.
            hi_ac, lo_ac = np.maximum(za, zc), np.minimum(za, zc)
            keep = np.empty((H - 1, W - 1, 2), dtype=bool)
            keep[..., 0] = (np.maximum(hi_ac, zb) - np.minimum(lo_ac, zb)) < jump_mm
            keep[..., 1] = (np.maximum(hi_ac, zd) - np.minimum(lo_ac, zd)) < jump_mm
        qv, qu, t = np.nonzero(keep)  # row-major quad order, triangle 0 before 1
        a = qv.astype(np.int64) * W + qu
        faces_px = np.empty((a.size, 3), dtype=np.int64)
        faces_px[:, 0] = a
        faces_px[:, 1] = np.where(t == 0, a + 1, a + W + 1)
        faces_px[:, 2] = np.where(t == 0, a + W + 1, a + W)
        used = np.zeros(H * W, dtype=bool)
        used[faces_px.ravel()] = True
        pix = np.flatnonzero(used)
        remap = np.cumsum(used, dtype=np.int64) - 1
        faces = remap[faces_px]
        v, u = np.divmod(pix, W)
        vertices = np.empty((pix.size, 3), dtype=np.float64)
        vertices[:, 0] = u * float(pitch_mm)
        vertices[:, 1] = v * float(pitch_mm)
        vertices[:, 2] = h.ravel()[pix]
        if rgba is not None:
            vcolours = rgba[pix]

    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, vertex_colors=vcolours, process=False, validate=False)
    mesh.metadata.update(
        pitch_mm=float(pitch_mm), jump_mm=float(jump_mm), noise_mm=used_noise, grid_shape=(int(H), int(W))
    )
    return mesh


def place_vertices(mesh: trimesh.Trimesh, xy_at: Callable[..., tuple[NDArray[np.float64], NDArray[np.float64]]],
                   pitch_mm: float | None = None) -> trimesh.Trimesh:
    """Move a mesh's vertices from ``(u * pitch, v * pitch, Z)`` to a lens model's X, Y, in place.

    ``xy_at(u, v, h)`` is :meth:`huefringe.camera.CameraModel.xy_at`; every vertex (on the pixel
    grid or, after :func:`decimate`, between pixels) goes to the X, Y its pixel coordinates see at
    its own height Z. Do this last: :func:`attach_sigma` and :func:`vertex_pixels` read pixels
    from ``u * pitch``. ``metadata["xy"]`` becomes ``"lens model"``.
    """
    if pitch_mm is None:
        pitch_mm = mesh.metadata.get("pitch_mm")
        if pitch_mm is None:
            raise ValueError("pitch_mm not given and not in mesh.metadata")
    verts = np.array(mesh.vertices, dtype=np.float64)
    x, y = xy_at(verts[:, 0] / float(pitch_mm), verts[:, 1] / float(pitch_mm), verts[:, 2])
    verts[:, 0], verts[:, 1] = x, y
    mesh.vertices = verts
    mesh.metadata["xy"] = "lens model"
    return mesh


def attach_sigma(mesh: trimesh.Trimesh, sigma: NDArray[np.floating], pitch_mm: float | None = None) -> trimesh.Trimesh:
    """Give every vertex the height uncertainty ``sigma_mm`` of its pixel (in place; returned).

    The value of the uncertainty map at the vertex's pixel: exact for grid meshes, also after
    :func:`clean_mesh` (its pinch-split copies keep their pixel); after :func:`decimate`, whose
    vertices leave the grid, the nearest pixel. Written by :func:`export_mesh` as two float
    vertex properties with the same values: ``sigma_mm`` (Open3D's tensor reader,
    ``o3d.t.io.read_point_cloud``, and trimesh read it) and ``quality`` (MeshLab's per-vertex
    scalar; MeshLab ignores other names).
    """
    if pitch_mm is None:
        pitch_mm = mesh.metadata.get("pitch_mm")
        if pitch_mm is None:
            raise ValueError("pitch_mm not given and not in mesh.metadata")
    s = np.asarray(sigma, np.float32)
    xy = np.asarray(mesh.vertices)[:, :2] / float(pitch_mm)
    u = np.clip(np.rint(xy[:, 0]).astype(np.intp), 0, s.shape[1] - 1)
    v = np.clip(np.rint(xy[:, 1]).astype(np.intp), 0, s.shape[0] - 1)
    values = s[v, u]
    mesh.vertex_attributes["sigma_mm"] = values
    mesh.vertex_attributes["quality"] = values
    return mesh


def vertex_pixels(
    mesh: trimesh.Trimesh, pitch_mm: float | None = None
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Pixel ``(v, u)`` of each vertex of a grid mesh (also after :func:`clean_mesh`).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Mesh from :func:`height_to_mesh` (possibly cleaned, not decimated).
    pitch_mm : float, optional
        Pixel pitch; default ``mesh.metadata["pitch_mm"]``.

    Returns
    -------
    v, u : ndarray of intp
        Row and column of every vertex.

    Raises
    ------
    ValueError
        If a vertex is not on the pixel grid (e.g. after decimation).
    """
    if pitch_mm is None:
        pitch_mm = mesh.metadata.get("pitch_mm")
        if pitch_mm is None:
            raise ValueError("pitch_mm not given and not in mesh.metadata")
    xy = np.asarray(mesh.vertices)[:, :2] / float(pitch_mm)
    idx = np.rint(xy)
    if idx.size and np.max(np.abs(xy - idx)) > 1e-6:
        raise ValueError("mesh vertices are not on the pixel grid")
    return idx[:, 1].astype(np.intp), idx[:, 0].astype(np.intp)
