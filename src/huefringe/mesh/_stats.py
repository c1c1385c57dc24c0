"""A mesh's topology figures (boundary loops, components, genus) and its export with the stats beside it."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import trimesh
from numpy.typing import NDArray

from huefringe.io import atomic_path, write_json
from ._clean import _edge_tables, _face_components, non_manifold_vertices


def boundary_loops(mesh: trimesh.Trimesh) -> int:
    """Number of closed boundary loops (outer outlines plus holes).

    Boundary edges are edges used by exactly one face. For an edge-manifold, consistently
    oriented mesh (every grid mesh) the loops are followed half-edge by half-edge; at a vertex
    where several loops touch (two faces meeting at a single corner) the walk turns through
    the fan of faces, so loops touching at a vertex count separately. Otherwise the cycle
    rank ``E - V + C`` of the boundary-edge graph is returned.

    Parameters
    ----------
    mesh : trimesh.Trimesh

    Returns
    -------
    int
        0 for a closed (watertight) or empty mesh; 1 for a disc; 1 + holes for a disc with holes.
    """
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if faces.size == 0:
        return 0
    n = max(len(mesh.vertices), int(faces.max()) + 1)
    src, dst, inv, counts = _edge_tables(faces, n)
    is_b = counts[inv] == 1
    bidx = np.flatnonzero(is_b)  # boundary half-edges (global indices)
    if bidx.size == 0:
        return 0
    dkey = src * n + dst
    order = np.argsort(dkey, kind="stable")
    sorted_keys = dkey[order]
    oriented = counts.max() <= 2 and not np.any(sorted_keys[1:] == sorted_keys[:-1])
    if not oriented:
        return _cycle_rank(src[bidx], dst[bidx], n)

    # position of each boundary half-edge's successor along its loop
    bsrc, bdst = src[bidx], dst[bidx]
    out_deg = np.bincount(bsrc, minlength=n)
    first_out = np.full(n, -1, dtype=np.int64)
    first_out[bsrc[::-1]] = np.arange(bidx.size - 1, -1, -1)  # any; unique where out_deg == 1
    nxt = first_out[bdst]
    pos_of = np.full(src.size, -1, dtype=np.int64)
    pos_of[bidx] = np.arange(bidx.size)
    for i in np.flatnonzero(out_deg[bdst] > 1):  # pinch vertices: rotate through the face fan
        he = int(bidx[i])
        for _ in range(src.size):
            f, k = divmod(he, 3)
            step = 3 * f + (k + 1) % 3  # t -> x in the same face
            if is_b[step]:
                nxt[i] = pos_of[step]
                break
            key = dst[step] * n + src[step]  # twin x -> t in the neighbouring face
            he = int(order[np.searchsorted(sorted_keys, key)])
        else:  # pragma: no cover - malformed fan
            return _cycle_rank(bsrc, bdst, n)
    if np.any(nxt < 0):  # pragma: no cover - cannot happen for an oriented manifold
        return _cycle_rank(bsrc, bdst, n)
    m = bidx.size
    graph = scipy.sparse.coo_matrix((np.ones(m), (np.arange(m), nxt)), shape=(m, m))
    n_loops, _ = scipy.sparse.csgraph.connected_components(graph, directed=True, connection="weak")
    return int(n_loops)


def _cycle_rank(bsrc: NDArray[np.int64], bdst: NDArray[np.int64], n: int) -> int:
    verts, e = np.unique(np.concatenate([bsrc, bdst]), return_inverse=True)
    e = e.reshape(2, -1)
    g = scipy.sparse.coo_matrix((np.ones(e.shape[1]), (e[0], e[1])), shape=(verts.size, verts.size))
    n_comp, _ = scipy.sparse.csgraph.connected_components(g, directed=False)
    n_edges = np.unique(np.sort(np.stack([bsrc, bdst]), axis=0), axis=1).shape[1]
    return int(n_edges - verts.size + n_comp)


def mesh_stats(mesh: trimesh.Trimesh) -> dict[str, Any]:
    """Summary numbers of a mesh, JSON-ready.

    Returns
    -------
    dict
        ``vertices`` and ``faces`` (int), ``area_mm2`` (float), ``boundary_loops``
        (:func:`boundary_loops`), ``components`` (edge-connected face groups), ``watertight``
        (bool, every edge shared by exactly two faces), ``non_manifold_vertices`` (int, pinch
        vertices, :func:`non_manifold_vertices`; 0 after :func:`clean_mesh`), ``bounds_mm`` (``[[xmin, ymin, zmin],
        [xmax, ymax, zmax]]`` or None when empty), and the triangulation parameters
        ``pitch_mm``, ``jump_mm``, ``noise_mm`` from ``mesh.metadata`` when present.
    """
    faces = np.asarray(mesh.faces, dtype=np.int64)
    n_vertices = len(mesh.vertices)
    stats: dict[str, Any] = {
        "vertices": int(n_vertices),
        "faces": int(len(faces)),
        "area_mm2": float(mesh.area) if len(faces) else 0.0,
        "boundary_loops": boundary_loops(mesh),
        "components": _face_components(faces, max(n_vertices, 1)),
        "watertight": bool(len(faces) > 0 and mesh.is_watertight),
        "non_manifold_vertices": int(non_manifold_vertices(mesh).size),
        "bounds_mm": None if n_vertices == 0 else np.asarray(mesh.bounds, dtype=float).tolist(),
    }
    for key in ("pitch_mm", "jump_mm", "noise_mm"):
        if key in mesh.metadata:
            value = mesh.metadata[key]
            stats[key] = None if value is None else float(value)
    return stats


# --------------------------------------------------------------------------------------------
# export
# --------------------------------------------------------------------------------------------
def stats_path(ply_path: str | os.PathLike[str]) -> Path:
    """Where :func:`export_mesh` writes the statistics of ``ply_path``: ``<stem>.stats.json``."""
    return Path(ply_path).with_suffix(".stats.json")


def export_mesh(
    mesh: trimesh.Trimesh,
    ply_path: str | os.PathLike[str],
    stl_path: str | os.PathLike[str] | None = None,
    *,
    write_stats: bool = True,
) -> dict[str, Any]:
    """Write a mesh as binary PLY (with vertex colours), optionally binary STL, and its stats.

    Every file is written atomically (:func:`huefringe.io.atomic_path`).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Mesh in mm.
    ply_path : path-like
        Target ``.ply`` (float32 vertices, int32 faces, RGBA vertex colours when present).
    stl_path : path-like, optional
        Target binary ``.stl`` (geometry only).
    write_stats : bool, default True
        Also write :func:`mesh_stats` as JSON to :func:`stats_path` (``<stem>.stats.json``).

    Returns
    -------
    dict
        The statistics (:func:`mesh_stats`).
    """
    ply_path = Path(ply_path)
    if ply_path.suffix.lower() != ".ply":
        raise ValueError(f"{ply_path}: expected a .ply file name")
    with_sigma = "sigma_mm" in mesh.vertex_attributes  # attach_sigma's two properties, nothing else
    if with_sigma:
        keep = {k: mesh.vertex_attributes[k] for k in ("sigma_mm", "quality")}
        mesh = mesh.copy()
        mesh.vertex_attributes.clear()
        mesh.vertex_attributes.update(keep)
    data = trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=False, include_attributes=with_sigma)
    with atomic_path(ply_path) as tmp:
        tmp.write_bytes(data)
    if stl_path is not None:
        stl_path = Path(stl_path)
        if stl_path.suffix.lower() != ".stl":
            raise ValueError(f"{stl_path}: expected a .stl file name")
        data = trimesh.exchange.stl.export_stl(mesh)
        with atomic_path(stl_path) as tmp:
            tmp.write_bytes(data)
    stats = mesh_stats(mesh)
    if write_stats:
        write_json(stats_path(ply_path), stats)
    return stats
