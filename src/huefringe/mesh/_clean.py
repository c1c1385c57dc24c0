"""Mesh repair: Open3D conversion, removing degenerate and duplicate pieces, splitting pinch vertices, decimation."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import trimesh
from numpy.typing import NDArray

if TYPE_CHECKING:
    import open3d as o3d


# --------------------------------------------------------------------------------------------
# Open3D round trip, clean-up, decimation
# --------------------------------------------------------------------------------------------
def to_open3d(mesh: trimesh.Trimesh) -> o3d.geometry.TriangleMesh:
    """Convert a trimesh mesh (with vertex colours if any) to an Open3D triangle mesh."""
    import open3d as o3d  # here, not at import: the render and metrology jobs load no Open3D

    out = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.ascontiguousarray(mesh.vertices, dtype=np.float64)),
        o3d.utility.Vector3iVector(np.ascontiguousarray(mesh.faces, dtype=np.int32)),
    )
    if mesh.visual.kind == "vertex" and len(mesh.visual.vertex_colors) == len(mesh.vertices):
        rgb = np.asarray(mesh.visual.vertex_colors)[:, :3].astype(np.float64) / 255.0
        out.vertex_colors = o3d.utility.Vector3dVector(np.ascontiguousarray(rgb))
    return out


def from_open3d(mesh: o3d.geometry.TriangleMesh, metadata: dict[str, Any] | None = None) -> trimesh.Trimesh:
    """Convert an Open3D triangle mesh (with vertex colours if any) to a trimesh mesh."""
    colours = None
    if mesh.has_vertex_colors():
        rgb = np.rint(np.clip(np.asarray(mesh.vertex_colors), 0.0, 1.0) * 255.0).astype(np.uint8)
        colours = np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1)
    out = trimesh.Trimesh(
        vertices=np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3),
        faces=np.asarray(mesh.triangles, dtype=np.int64).reshape(-1, 3),
        vertex_colors=colours,
        process=False,
        validate=False,
    )
    if metadata:
        out.metadata.update(metadata)
    return out


def clean_mesh(
    mesh: trimesh.Trimesh,
    *,
    min_island_faces: int = 100,
    min_island_area_mm2: float = 0.0,
    spike_mm: float | None = None,
    remove_non_manifold_edges: bool = False,
    island_backend: Literal["scipy", "open3d"] = "scipy",
    split_pinches: bool = True,
) -> trimesh.Trimesh:
    """Clean a mesh with Open3D: duplicates, degenerates, spikes, small islands, orphans.

    Steps, in order: merge duplicated vertices, remove degenerate triangles (a repeated
    vertex) and duplicated triangles (Open3D), optionally remove non-manifold edges,
    optionally remove single-vertex spikes, remove the connected islands (faces connected
    through shared edges, as :meth:`open3d.geometry.TriangleMesh.cluster_connected_triangles`
    defines them) with fewer than ``min_island_faces`` faces or less than ``min_island_area_mm2`` area,
    remove unreferenced vertices, and finally split pinch (bow-tie) vertices
    (:func:`split_pinch_vertices`) so the result is two-manifold. Vertex positions are never
    moved, so :func:`vertex_pixels` still works on the result.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Input mesh (not modified).
    min_island_faces : int, default 100
        Islands with fewer faces are removed (100 faces = 50 pixel quads). 0 keeps all.
    min_island_area_mm2 : float, default 0.0
        Islands with a smaller area (mm^2) are removed as well.
    spike_mm : float, optional
        Outlier removal: a vertex whose height differs from *every* vertex it shares an edge
        with by more than this loses all its faces (a one-pixel spike or pit that stayed
        below the jump threshold). A few times the noise plus ``slope * pitch`` is a sensible
        value; off by default. Spikes higher than the jump threshold never get faces in
        :func:`height_to_mesh` in the first place.
    remove_non_manifold_edges : bool, default False
        Also apply Open3D's ``remove_non_manifold_edges`` (never needed for grid meshes).
    island_backend : {"scipy", "open3d"}, default "scipy"
        How islands are labelled: ``scipy.sparse.csgraph.connected_components`` on the
        face-edge graph, or Open3D's ``cluster_connected_triangles``. Both give the same
        partition; scipy is about 20x faster (0.04 s against 0.4-0.9 s for 240 000 faces).
    split_pinches : bool, default True
        Split every vertex whose faces form several fans into one vertex per fan
        (:func:`split_pinch_vertices`); the islands are labelled before, through edges, so
        this changes no face.

    Returns
    -------
    trimesh.Trimesh
        Cleaned mesh, with ``metadata`` copied from the input.

    Notes
    -----
    Open3D's statistical outlier removal is deliberately not used: on a grid mesh it flags
    the border vertices (they have fewer close neighbours), eating the outline.
    """
    import open3d as o3d

    if len(mesh.faces) == 0:
        return from_open3d(o3d.geometry.TriangleMesh(), dict(mesh.metadata))
    m = to_open3d(mesh)
    m.remove_duplicated_vertices()
    m.remove_degenerate_triangles()
    m.remove_duplicated_triangles()
    if remove_non_manifold_edges:
        m.remove_non_manifold_edges()
    if spike_mm is not None and len(m.triangles):
        tri = np.asarray(m.triangles, dtype=np.int64)
        z = np.asarray(m.vertices)[:, 2]
        edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        dz = np.abs(z[edges[:, 0]] - z[edges[:, 1]])
        closest = np.full(len(z), np.inf)
        np.minimum.at(closest, edges[:, 0], dz)
        np.minimum.at(closest, edges[:, 1], dz)
        spike = closest > float(spike_mm)
        if spike.any():
            m.remove_triangles_by_mask(spike[tri].any(axis=1).tolist())
    if (min_island_faces > 0 or min_island_area_mm2 > 0) and len(m.triangles):
        if island_backend == "open3d":
            labels, n_faces, area = m.cluster_connected_triangles()
            labels = np.asarray(labels)
        elif island_backend == "scipy":
            tri = np.asarray(m.triangles, dtype=np.int64)
            verts = np.asarray(m.vertices)
            labels, n_comp = _face_labels(tri, len(verts))
            n_faces = np.bincount(labels, minlength=n_comp)
            e1, e2 = verts[tri[:, 1]] - verts[tri[:, 0]], verts[tri[:, 2]] - verts[tri[:, 0]]
            face_area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
            area = np.bincount(labels, weights=face_area, minlength=n_comp)
        else:
            raise ValueError(f"island_backend must be 'scipy' or 'open3d', got {island_backend!r}")
        small = (np.asarray(n_faces) < min_island_faces) | (np.asarray(area) < min_island_area_mm2)
        if small.any():
            m.remove_triangles_by_mask(small[labels].tolist())
    m.remove_unreferenced_vertices()
    out = from_open3d(m, dict(mesh.metadata))
    return split_pinch_vertices(out) if split_pinches else out


def _corner_labels(faces: NDArray[np.int64], n_vertices: int) -> tuple[NDArray[np.int64], int]:
    """Label the face corners by fan: corners at one vertex joined through shared edges.

    Corner ``3 f + k`` is vertex ``faces[f, k]`` in face ``f``. Two faces that share an edge join
    their corners at both ends of that edge; the connected groups of corners are the fans.
    """
    src, dst, inv, _ = _edge_tables(faces, n_vertices)
    n = src.size
    corner_src = np.arange(n, dtype=np.int64)  # half-edge 3f+k starts at corner k of face f
    f, k = np.divmod(corner_src, 3)
    corner_dst = 3 * f + (k + 1) % 3
    order = np.argsort(inv, kind="stable")
    same = inv[order[1:]] == inv[order[:-1]]  # consecutive half-edges of one edge
    h1, h2 = order[:-1][same], order[1:][same]
    parallel = src[h1] == src[h2]  # same direction (inconsistent orientation)
    a1 = np.where(parallel, corner_src[h2], corner_dst[h2])
    a2 = np.where(parallel, corner_dst[h2], corner_src[h2])
    rows = np.concatenate([corner_src[h1], corner_dst[h1]])
    cols = np.concatenate([a1, a2])
    g = scipy.sparse.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    n_comp, labels = scipy.sparse.csgraph.connected_components(g, directed=False)
    return labels.astype(np.int64), int(n_comp)


def non_manifold_vertices(mesh: trimesh.Trimesh) -> NDArray[np.intp]:
    """Indices of the pinch (bow-tie) vertices: vertices whose faces form more than one fan.

    A fan is a group of faces around the vertex connected through edges that contain the vertex
    (the definition of Open3D's ``get_non_manifold_vertices`` and MeshLab's non-manifold vertex
    count). Two squares of a grid mesh meeting at a single corner make that corner a pinch.

    Parameters
    ----------
    mesh : trimesh.Trimesh

    Returns
    -------
    ndarray of intp
        Sorted vertex indices; empty for a two-manifold (or empty) mesh.
    """
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if faces.size == 0:
        return np.zeros(0, dtype=np.intp)
    n = max(len(mesh.vertices), int(faces.max()) + 1)
    labels, n_comp = _corner_labels(faces, n)
    vertex_of = np.zeros(n_comp, dtype=np.int64)
    vertex_of[labels] = faces.ravel()
    fans = np.bincount(vertex_of, minlength=n)
    return np.flatnonzero(fans > 1).astype(np.intp)


def split_pinch_vertices(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Give every fan of faces at a pinch (bow-tie) vertex its own copy of the vertex.

    The faces and their order stay as they are; a vertex whose faces form ``k > 1`` fans
    (:func:`non_manifold_vertices`) becomes ``k`` vertices at the same position, with the same
    colour, placed right after it in the vertex order (so a grid mesh stays in row-major pixel
    order and :func:`vertex_pixels` maps each copy to its pixel). The surface is unchanged; only
    its topology is made two-manifold: every vertex then has a single disc or half-disc of faces
    around it, as slicers, CAD tools, Open3D's ``is_vertex_manifold`` and MeshLab require.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Input mesh (not modified). Unreferenced vertices are kept in place.

    Returns
    -------
    trimesh.Trimesh
        The mesh itself when there is no pinch vertex, else a new mesh with ``metadata``
        copied and ``metadata["split_pinch_vertices"]`` = number of pinch vertices split.

    Notes
    -----
    A pinch vertex of a grid mesh is a pixel where two parts of the surface touch diagonally
    (e.g. the corners of two valid regions across an invalid pixel pair, or a step wall that is
    left open on one side of a corner). Splitting it does not merge or drop anything, so the
    face count, the area and the islands (which are edge-connected) are unchanged; the boundary
    loops of the two parts, which touched at that vertex, are counted separately as before.
    Note that Open3D's ``remove_duplicated_vertices`` would merge the copies again.
    """
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if faces.size == 0:
        return mesh
    n = max(len(mesh.vertices), int(faces.max()) + 1)
    labels, n_comp = _corner_labels(faces, n)
    vertex_of = np.zeros(n_comp, dtype=np.int64)
    vertex_of[labels] = faces.ravel()
    fans = np.bincount(vertex_of, minlength=n)
    if not np.any(fans > 1):
        return mesh
    # first corner of each fan orders the copies of one vertex
    first = np.full(n_comp, np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(labels.size, dtype=np.int64))
    # new vertex list: every original vertex (referenced or not) once, plus the extra fans
    fan_order = np.lexsort((first, vertex_of))  # by vertex, then by first corner
    sorted_vertex = vertex_of[fan_order]
    is_first_fan = np.ones(n_comp, dtype=bool)
    is_first_fan[1:] = sorted_vertex[1:] != sorted_vertex[:-1]
    extra = fan_order[~is_first_fan]  # fans that need a copy
    # slot of each entry: original vertices at their index, copies right after their vertex
    keys_vertex = np.concatenate([np.arange(n, dtype=np.int64), vertex_of[extra]])
    keys_rank = np.concatenate([np.zeros(n, dtype=np.int64), np.arange(1, extra.size + 1, dtype=np.int64)])
    slot_order = np.lexsort((keys_rank, keys_vertex))
    new_index = np.empty(slot_order.size, dtype=np.int64)
    new_index[slot_order] = np.arange(slot_order.size, dtype=np.int64)
    fan_new = np.empty(n_comp, dtype=np.int64)
    fan_new[fan_order[is_first_fan]] = new_index[sorted_vertex[is_first_fan]]
    fan_new[extra] = new_index[n + np.arange(extra.size)]
    source = keys_vertex[slot_order]  # original vertex of every new vertex
    new_faces = fan_new[labels].reshape(-1, 3)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)[source]
    colours = None
    if mesh.visual.kind == "vertex" and len(mesh.visual.vertex_colors) == len(mesh.vertices):
        colours = np.asarray(mesh.visual.vertex_colors)[source]
    out = trimesh.Trimesh(vertices=vertices, faces=new_faces, vertex_colors=colours, process=False, validate=False)
    out.metadata.update(dict(mesh.metadata))
    out.metadata["split_pinch_vertices"] = int(np.count_nonzero(fans > 1))
    return out


def decimate(mesh: trimesh.Trimesh, target_faces: int, *, boundary_weight: float = 1.0) -> trimesh.Trimesh:
    """Reduce the face count with quadric error decimation (Open3D).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Input mesh (not modified).
    target_faces : int
        Target number of triangles (the result has at most about this many).
    boundary_weight : float, default 1.0
        Open3D's weight of the boundary-preserving quadrics; raise it to keep outlines.

    Returns
    -------
    trimesh.Trimesh
        Decimated mesh (vertex colours interpolated), pinch vertices split
        (:func:`split_pinch_vertices`); a copy when the mesh already has at most
        ``target_faces`` faces. Vertices are no longer on the pixel grid.
    """
    if target_faces < 1:
        raise ValueError(f"target_faces must be >= 1, got {target_faces}")
    if len(mesh.faces) <= target_faces:
        return mesh.copy()
    m = to_open3d(mesh).simplify_quadric_decimation(
        target_number_of_triangles=int(target_faces), boundary_weight=float(boundary_weight)
    )
    m.remove_degenerate_triangles()
    m.remove_unreferenced_vertices()
    meta = dict(mesh.metadata)
    meta["decimated_from_faces"] = len(mesh.faces)
    return split_pinch_vertices(from_open3d(m, meta))


# --------------------------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------------------------
def _edge_tables(
    faces: NDArray[np.int64], n_vertices: int
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.intp], NDArray[np.intp]]:
    """Half-edges ``src -> dst`` (face f, corner k is half-edge ``3 f + k``) and their edges."""
    src = faces.ravel()
    dst = np.roll(faces, -1, axis=1).ravel()
    und = np.minimum(src, dst) * n_vertices + np.maximum(src, dst)
    _, inv, counts = np.unique(und, return_inverse=True, return_counts=True)
    return src, dst, inv.ravel(), counts


def _face_labels(faces: NDArray[np.int64], n_vertices: int) -> tuple[NDArray[np.int64], int]:
    """Label the groups of faces connected through shared edges: ``(labels per face, count)``."""
    if faces.size == 0:
        return np.zeros(0, dtype=np.int64), 0
    _, _, inv, counts = _edge_tables(faces, n_vertices)
    n_faces, n_edges = len(faces), counts.size
    rows = np.repeat(np.arange(n_faces), 3)
    g = scipy.sparse.coo_matrix((np.ones(rows.size), (rows, n_faces + inv)), shape=(n_faces + n_edges,) * 2)
    n_comp, labels = scipy.sparse.csgraph.connected_components(g, directed=False)
    # every edge node hangs on a face, so the components are exactly the face groups
    return labels[:n_faces].astype(np.int64), int(n_comp)


def _face_components(faces: NDArray[np.int64], n_vertices: int) -> int:
    """Number of groups of faces connected through shared edges."""
    return _face_labels(faces, n_vertices)[1]
