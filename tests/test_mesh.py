"""Tests of huefringe.mesh: grid triangulation, jump threshold, clean-up, export, statistics."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from huefringe import mesh as hm

PITCH = 0.2
H, W = 150, 200
NOISE = 0.01
BASE = 0.5
# (rows, cols, step height above the base in mm)
BLOCKS = [((20, 70), (20, 80), 3.0), ((90, 130), (30, 90), 1.0), ((40, 120), (120, 180), 4.0)]
HOLE = ((60, 80), (100, 110))


def step_scene(seed: int = 0, noise: float = NOISE) -> tuple[np.ndarray, np.ndarray]:
    """Height map (float32, mm) with a 0.5 mm base, three blocks, noise and a NaN hole,
    plus the label map (0 base, 1..3 blocks, -1 hole)."""
    rng = np.random.default_rng(seed)
    labels = np.zeros((H, W), dtype=np.int64)
    h = np.full((H, W), BASE)
    for i, ((r0, r1), (c0, c1), dz) in enumerate(BLOCKS, start=1):
        labels[r0:r1, c0:c1] = i
        h[r0:r1, c0:c1] += dz
    h += rng.normal(0.0, noise, h.shape)
    (r0, r1), (c0, c1) = HOLE
    h[r0:r1, c0:c1] = np.nan
    labels[r0:r1, c0:c1] = -1
    return h.astype(np.float32), labels


def face_pixels(mesh: trimesh.Trimesh, width: int) -> np.ndarray:
    """Faces as flat pixel indices (v * width + u)."""
    v, u = hm.vertex_pixels(mesh)
    return (v * width + u)[np.asarray(mesh.faces)]


def reference_faces(valid_same: np.ndarray) -> set[tuple[int, int, int]]:
    """Brute-force expected faces: triangles (a,b,c), (a,c,d) of each quad whose three pixels
    are valid and belong to the same region (`valid_same` is the label map, -1 = invalid)."""
    Hh, Ww = valid_same.shape
    out = set()
    for v in range(Hh - 1):
        for u in range(Ww - 1):
            a, b, c, d = v * Ww + u, v * Ww + u + 1, (v + 1) * Ww + u + 1, (v + 1) * Ww + u
            for tri in ((a, b, c), (a, c, d)):
                labs = {valid_same.flat[i] for i in tri}
                if len(labs) == 1 and -1 not in labs:
                    out.add(tri)
    return out


# ------------------------------------------------------------------------------------------
# triangulation
# ------------------------------------------------------------------------------------------
def test_flat_patch_has_analytic_face_count():
    h = np.full((H, W), 2.5, np.float32)
    m = hm.height_to_mesh(h, PITCH)
    assert len(m.faces) == 2 * (H - 1) * (W - 1)
    assert len(m.vertices) == H * W
    # every face normal points towards the camera (+Z)
    assert np.all(m.face_normals[:, 2] > 0.999)


def test_vertices_are_the_pixels_exactly():
    h, _ = step_scene()
    m = hm.height_to_mesh(h, PITCH)
    v, u = hm.vertex_pixels(m)
    verts = np.asarray(m.vertices)
    assert np.array_equal(verts[:, 2], h[v, u].astype(np.float64))  # exact, no rounding
    assert np.array_equal(verts[:, 0], u * PITCH)
    assert np.array_equal(verts[:, 1], v * PITCH)
    assert np.all(np.isfinite(verts))


def test_no_face_bridges_a_step_or_the_hole():
    h, labels = step_scene()
    m = hm.height_to_mesh(h, PITCH)
    jump = m.metadata["jump_mm"]
    z = np.asarray(m.vertices)[:, 2][np.asarray(m.faces)]
    span = z.max(axis=1) - z.min(axis=1)
    assert span.max() < jump
    assert jump < 1.0  # smaller than the smallest step, so steps must be open
    # stronger: the three pixels of every face lie on one plateau ...
    fl = labels.ravel()[face_pixels(m, W)]
    assert np.all(fl[:, 0] == fl[:, 1]) and np.all(fl[:, 1] == fl[:, 2])
    assert np.all(fl >= 0)
    # ... and the face set is exactly the brute-force set of same-plateau valid triangles
    got = {tuple(f) for f in face_pixels(m, W).tolist()}
    assert got == reference_faces(labels)


def test_nan_pixel_removes_exactly_its_faces():
    h = np.full((40, 50), 1.0, np.float32)
    full = hm.height_to_mesh(h, PITCH)
    full_faces = {tuple(f) for f in face_pixels(full, 50).tolist()}
    for (v, u), touching in {(10, 20): 6, (0, 0): 2, (0, 49): 1, (39, 0): 1, (39, 49): 2, (0, 7): 3, (7, 0): 3}.items():
        hh = h.copy()
        hh[v, u] = np.nan
        m = hm.height_to_mesh(hh, PITCH)
        p = v * 50 + u
        expected = {f for f in full_faces if p not in f}
        assert len(full_faces) - len(expected) == touching
        assert {tuple(f) for f in face_pixels(m, 50).tolist()} == expected


def test_noise_estimate_is_robust_to_steps_and_holes():
    h, _ = step_scene(seed=3)
    est = hm.estimate_noise(h)
    assert est == pytest.approx(NOISE, rel=0.08)
    # a tilt does not change it (second differences cancel planes)
    yy, xx = np.mgrid[0:H, 0:W]
    assert hm.estimate_noise(h + 0.03 * xx - 0.02 * yy) == pytest.approx(est, rel=0.02)
    assert hm.estimate_noise(np.full((10, 10), np.nan)) == 0.0


def test_default_threshold_rule():
    h, _ = step_scene(seed=1)
    m = hm.height_to_mesh(h, PITCH)
    noise = hm.estimate_noise(h)
    assert m.metadata["noise_mm"] == pytest.approx(noise)
    assert m.metadata["jump_mm"] == pytest.approx(8 * noise + math.sqrt(2) * PITCH)
    assert hm.jump_threshold(0.5, 0.01, max_slope=2.0, noise_k=5.0) == pytest.approx(0.05 + 2 * math.sqrt(2) * 0.5)


@pytest.mark.parametrize(("slope", "kept"), [(0.95, True), (1.05, False)])
def test_max_slope_separates_ramps_from_jumps(slope, kept):
    # noise-free ramp along the quad diagonal with gradient `slope`: triangle span = slope * sqrt(2) * pitch
    yy, xx = np.mgrid[0:30, 0:30] * PITCH
    h = (slope * (xx + yy) / math.sqrt(2)).astype(np.float64)
    m = hm.height_to_mesh(h, PITCH, noise_mm=0.0)
    assert len(m.faces) == (2 * 29 * 29 if kept else 0)


def test_explicit_jump_mm_bridges_or_splits_a_step():
    h = np.full((20, 20), 0.0, np.float32)
    h[:, 10:] = 1.0
    assert len(hm.height_to_mesh(h, PITCH, jump_mm=1.5).faces) == 2 * 19 * 19
    split = hm.height_to_mesh(h, PITCH, jump_mm=0.5)
    assert len(split.faces) == 2 * 19 * 18  # the column of quads across the step is gone
    assert split.metadata["jump_mm"] == 0.5 and split.metadata["noise_mm"] is None


def test_colours_become_vertex_colours():
    h, _ = step_scene()
    rgb = np.random.default_rng(5).random((H, W, 3)).astype(np.float32)
    m = hm.height_to_mesh(h, PITCH, colours=rgb)
    v, u = hm.vertex_pixels(m)
    vc = np.asarray(m.visual.vertex_colors)
    assert np.array_equal(vc[:, :3], np.rint(rgb[v, u] * 255).astype(np.uint8))
    assert np.all(vc[:, 3] == 255)
    with pytest.raises(ValueError):
        hm.height_to_mesh(h, PITCH, colours=rgb[:-1])


def test_input_validation():
    with pytest.raises(ValueError):
        hm.height_to_mesh(np.zeros((3, 3, 3)), PITCH)
    with pytest.raises(ValueError):
        hm.height_to_mesh(np.zeros((3, 3)), 0.0)
    with pytest.raises(TypeError):
        hm.height_to_mesh(np.zeros((3, 3), dtype=np.int32), PITCH)


def test_all_invalid_map_gives_an_empty_mesh(tmp_path):
    m = hm.height_to_mesh(np.full((5, 5), np.nan, np.float32), PITCH)
    assert len(m.faces) == 0 and len(m.vertices) == 0
    assert len(hm.clean_mesh(m).faces) == 0
    stats = hm.export_mesh(m, tmp_path / "e.ply", tmp_path / "e.stl")
    assert stats["faces"] == 0 and stats["area_mm2"] == 0.0 and stats["bounds_mm"] is None
    assert stats["boundary_loops"] == 0 and stats["components"] == 0


# ------------------------------------------------------------------------------------------
# clean-up and decimation
# ------------------------------------------------------------------------------------------
def test_clean_mesh_removes_islands_and_keeps_pixels():
    h = np.full((40, 60), 0.5, np.float32)
    h[10:13, 10:13] = 3.5  # 3x3 plateau -> an island of 8 faces
    h[30, 40] = 9.0  # isolated spike pixel -> no faces at all
    m = hm.height_to_mesh(h, PITCH)
    assert len(m.vertices) == 40 * 60 - 1  # spike vertex unreferenced, never stored
    c = hm.clean_mesh(m, min_island_faces=20)
    assert len(c.faces) == len(m.faces) - 8
    assert len(c.vertices) == len(m.vertices) - 9
    v, u = hm.vertex_pixels(c)
    assert np.array_equal(np.asarray(c.vertices)[:, 2], h[v, u].astype(np.float64))
    assert not np.any((v >= 10) & (v < 13) & (u >= 10) & (u < 13))
    assert c.metadata["jump_mm"] == m.metadata["jump_mm"]
    # islands bigger than the limit stay
    assert len(hm.clean_mesh(m, min_island_faces=8).faces) == len(m.faces)
    # area limit: the island has 4 quads of 0.04 mm^2 = 0.16 mm^2
    assert len(hm.clean_mesh(m, min_island_faces=0, min_island_area_mm2=0.2).faces) == len(m.faces) - 8


def test_clean_mesh_removes_degenerate_and_duplicated_faces():
    verts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 0]], float)  # 4 duplicates 0
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 2], [1, 1, 2], [4, 1, 2]])
    m = trimesh.Trimesh(verts, faces, process=False)
    c = hm.clean_mesh(m, min_island_faces=0)
    assert len(c.vertices) == 4
    assert sorted(map(sorted, c.faces.tolist())) == [[0, 1, 2], [0, 2, 3]]


def test_spike_removal():
    rng = np.random.default_rng(0)
    h = (0.5 + rng.normal(0, 0.005, (30, 40))).astype(np.float32)
    h[15, 20] += 0.25  # below the jump threshold, so it is meshed
    m = hm.height_to_mesh(h, PITCH)
    assert m.metadata["jump_mm"] > 0.3
    c = hm.clean_mesh(m, spike_mm=0.1, min_island_faces=0)
    assert len(m.faces) - len(c.faces) == 6 and len(m.vertices) - len(c.vertices) == 1
    v, u = hm.vertex_pixels(c)
    assert not np.any((v == 15) & (u == 20))
    assert len(hm.clean_mesh(m, min_island_faces=0).faces) == len(m.faces)  # off by default


def test_decimate_flat_patch_keeps_area():
    m = hm.height_to_mesh(np.full((60, 60), 1.0, np.float32), PITCH)
    d = hm.decimate(m, 500)
    assert 0 < len(d.faces) <= 500
    assert d.area == pytest.approx(m.area, rel=1e-4)
    assert np.allclose(np.asarray(d.vertices)[:, 2], 1.0)
    assert len(hm.decimate(m, 10**6).faces) == len(m.faces)


# ------------------------------------------------------------------------------------------
# statistics and export
# ------------------------------------------------------------------------------------------
def test_stats_of_a_flat_square(tmp_path):
    n = 50
    m = hm.height_to_mesh(np.full((n, n), 1.25, np.float32), PITCH)
    stats = hm.export_mesh(m, tmp_path / "sq.ply")
    assert stats["faces"] == 2 * (n - 1) ** 2 and stats["vertices"] == n * n
    assert stats["area_mm2"] == pytest.approx((n - 1) ** 2 * PITCH**2, rel=1e-12)
    assert stats["boundary_loops"] == 1 and stats["components"] == 1
    assert stats["watertight"] is False
    assert np.allclose(stats["bounds_mm"], [[0, 0, 1.25], [(n - 1) * PITCH, (n - 1) * PITCH, 1.25]])
    on_disk = json.loads(hm.stats_path(tmp_path / "sq.ply").read_text())
    assert on_disk == json.loads(json.dumps(stats))
    assert (tmp_path / "sq.stats.json").exists()


def test_boundary_loops_and_components():
    h = np.full((20, 20), 1.0, np.float32)
    h[5, 5] = np.nan
    h[12:15, 12:15] = np.nan
    s = hm.mesh_stats(hm.height_to_mesh(h, PITCH))
    assert s["boundary_loops"] == 3 and s["components"] == 1
    # two triangles touching at one corner (a pinch vertex): 2 loops, 2 components
    bow = np.zeros((3, 3), np.float32)
    bow[0, 2] = bow[1, 2] = bow[1, 0] = bow[2, 0] = np.nan
    m = hm.height_to_mesh(bow, 1.0)
    assert len(m.faces) == 2 and len(m.vertices) == 5
    assert hm.boundary_loops(m) == 2 and hm.mesh_stats(m)["components"] == 2
    # a closed surface has no boundary
    box = trimesh.creation.box()
    assert hm.boundary_loops(box) == 0 and hm.mesh_stats(box)["watertight"] is True


@pytest.mark.parametrize("seed", range(5))
def test_boundary_loops_match_euler_characteristic(seed):
    """Height-field meshes are planar: every component, with pinch vertices split, is a disc
    with holes, so loops = 2 C - (V' - E + F) with V' counting one vertex per face fan."""
    rng = np.random.default_rng(seed)
    h = np.where(rng.random((25, 25)) < 0.25, np.nan, 1.0).astype(np.float32)
    m = hm.height_to_mesh(h, PITCH)
    faces = np.asarray(m.faces)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    boundary = uniq[counts == 1]
    # fans per vertex = 1 for interior vertices, (boundary degree / 2) for boundary vertices
    bdeg = np.bincount(boundary.ravel(), minlength=len(m.vertices))
    fans = np.where(bdeg > 0, bdeg // 2, 1)
    chi = fans.sum() - len(uniq) + len(faces)
    comps = hm.mesh_stats(m)["components"]
    assert (bdeg > 2).any()  # the masks do produce pinch vertices
    assert hm.boundary_loops(m) == 2 * comps - chi


def test_ply_and_stl_round_trip(tmp_path):
    h, _ = step_scene()
    rgb = np.random.default_rng(2).random((H, W, 3))
    m = hm.clean_mesh(hm.height_to_mesh(h, PITCH, colours=rgb))
    stats = hm.export_mesh(m, tmp_path / "f.ply", tmp_path / "f.stl")
    ply = trimesh.load(tmp_path / "f.ply", process=False)
    stl = trimesh.load(tmp_path / "f.stl", process=False)
    for back in (ply, stl):
        assert len(back.faces) == len(m.faces) == stats["faces"]
        assert back.area == pytest.approx(m.area, rel=1e-6)
    assert len(ply.vertices) == len(m.vertices)
    assert np.array_equal(np.asarray(ply.vertices)[:, 2], np.asarray(m.vertices)[:, 2])  # float32 heights exact
    assert np.array_equal(ply.visual.vertex_colors, m.visual.vertex_colors)
    assert np.array_equal(ply.faces, m.faces)
    assert (tmp_path / "f.ply").read_bytes()[:3] == b"ply"
    assert b"binary_little_endian" in (tmp_path / "f.ply").read_bytes()[:200]
    assert not (tmp_path / "f.stl").read_bytes()[:5] == b"solid"  # binary STL
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.ply", "f.stats.json", "f.stl"]  # no temp files


def test_export_rejects_wrong_suffix(tmp_path):
    m = hm.height_to_mesh(np.ones((3, 3), np.float32), PITCH)
    with pytest.raises(ValueError):
        hm.export_mesh(m, tmp_path / "x.stl")
    with pytest.raises(ValueError):
        hm.export_mesh(m, tmp_path / "x.ply", tmp_path / "x.obj")


def test_island_backends_agree():
    rng = np.random.default_rng(4)
    h = np.where(rng.random((60, 60)) < 0.3, np.nan, 1.0).astype(np.float32)
    m = hm.height_to_mesh(h, PITCH)
    for limit in (2, 5, 30):
        a = hm.clean_mesh(m, min_island_faces=limit, island_backend="scipy")
        b = hm.clean_mesh(m, min_island_faces=limit, island_backend="open3d")
        assert 0 < len(a.faces) < len(m.faces)
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    labels, n = hm._face_labels(np.asarray(m.faces), len(m.vertices))
    o_labels, _, _ = hm.to_open3d(m).cluster_connected_triangles()
    o_labels = np.asarray(o_labels)
    assert n == o_labels.max() + 1
    # same partition: the label pairs are in one-to-one correspondence
    assert len(set(zip(labels.tolist(), o_labels.tolist(), strict=True))) == n


# ------------------------------------------------------------------------------------------
# two-manifold: pinch (bow-tie) vertices split
# ------------------------------------------------------------------------------------------
def _open3d_topology(m: trimesh.Trimesh) -> tuple[int, bool, bool]:
    o = hm.to_open3d(m)
    return len(o.get_non_manifold_vertices()), bool(o.is_vertex_manifold()), bool(o.is_edge_manifold())


def _trimesh_euler_ok(m: trimesh.Trimesh) -> bool:
    """Euler-Poincare for genus-0 surfaces with boundary: V - E + F == 2 C - B, counted by trimesh.

    trimesh's ``outline`` follows boundary edges; at a pinch vertex two loops share a vertex and
    V is one short, so the identity fails there."""
    m = trimesh.Trimesh(vertices=m.vertices, faces=m.faces, process=False, validate=False)
    n_comp = len(m.split(only_watertight=False))
    loops = len(m.outline().entities)
    return m.euler_number == 2 * n_comp - loops


def test_diagonal_gap_makes_a_bow_tie_that_clean_mesh_splits():
    # fixed diagonal a-c: invalid pixels at (v-1, u-1) and (v+1, u+1) leave two pairs of faces
    # that meet only at pixel (v, u)
    h = np.full((12, 12), 1.0, np.float32)
    h[4, 4] = h[6, 6] = np.nan
    raw = hm.height_to_mesh(h, PITCH)
    pinch = hm.non_manifold_vertices(raw)
    v, u = hm.vertex_pixels(raw)
    assert [(int(v[i]), int(u[i])) for i in pinch] == [(5, 5)]
    assert _open3d_topology(raw) == (1, False, True)  # Open3D agrees: one bow-tie, edges fine
    assert not _trimesh_euler_ok(raw)
    c = hm.clean_mesh(raw, min_island_faces=0)
    assert _open3d_topology(c) == (0, True, True)
    assert _trimesh_euler_ok(c)
    assert len(c.vertices) == len(raw.vertices) + 1 and c.metadata["split_pinch_vertices"] == 1
    # same faces, same places: every face's corners are the same points as before
    assert len(c.faces) == len(raw.faces)
    assert np.array_equal(np.asarray(c.vertices)[c.faces], np.asarray(raw.vertices)[raw.faces])
    assert c.area == pytest.approx(raw.area, rel=1e-12)
    cv, cu = hm.vertex_pixels(c)
    assert np.all(np.diff(cv * 12 + cu) >= 0)  # still row-major, the copy right after its pixel
    assert hm.mesh_stats(c)["non_manifold_vertices"] == 0 and hm.mesh_stats(raw)["non_manifold_vertices"] == 1
    # opting out keeps the bow-tie
    assert _open3d_topology(hm.clean_mesh(raw, min_island_faces=0, split_pinches=False))[0] == 1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_dropouts_and_steps_become_two_manifold(seed):
    h, _ = step_scene(seed)
    rng = np.random.default_rng(seed)
    h[rng.random(h.shape) < 0.15] = np.nan  # scattered dropouts make many pinches
    raw = hm.height_to_mesh(h, PITCH)
    n_pinch = hm.non_manifold_vertices(raw).size
    o3d_before = _open3d_topology(raw)
    assert o3d_before[0] == n_pinch > 50  # our count is Open3D's
    c = hm.split_pinch_vertices(raw)
    assert _open3d_topology(c) == (0, True, True)
    assert len(c.vertices) >= len(raw.vertices) + n_pinch  # a pinch has >= 2 fans
    assert _trimesh_euler_ok(c)
    assert np.array_equal(np.asarray(c.vertices)[c.faces], np.asarray(raw.vertices)[raw.faces])
    assert trimesh.Trimesh(c.vertices, c.faces, process=False).is_winding_consistent
    # splitting changes neither the islands nor the outline count (loops at a pinch were apart)
    assert hm.mesh_stats(c)["components"] == hm.mesh_stats(raw)["components"]
    assert hm.boundary_loops(c) == hm.boundary_loops(raw)
    # idempotent, and a two-manifold mesh is returned as it is
    assert hm.split_pinch_vertices(c) is c


def test_split_keeps_colours_and_survives_ply_round_trip(tmp_path):
    h = np.full((12, 12), 1.0, np.float32)
    h[4, 4] = h[6, 6] = np.nan
    rgb = np.random.default_rng(3).random((12, 12, 3)).astype(np.float32)
    c = hm.clean_mesh(hm.height_to_mesh(h, PITCH, colours=rgb), min_island_faces=0)
    v, u = hm.vertex_pixels(c)
    assert np.array_equal(np.asarray(c.visual.vertex_colors)[:, :3], np.rint(rgb[v, u] * 255).astype(np.uint8))
    hm.export_mesh(c, tmp_path / "m.ply")
    import open3d as o3d

    back = o3d.io.read_triangle_mesh(str(tmp_path / "m.ply"))
    assert len(back.vertices) == len(c.vertices) and back.is_vertex_manifold() and back.is_edge_manifold()
    assert json.loads((tmp_path / "m.stats.json").read_text())["non_manifold_vertices"] == 0


def test_decimated_mesh_is_two_manifold():
    h, _ = step_scene(4)
    h[np.random.default_rng(4).random(h.shape) < 0.05] = np.nan
    d = hm.decimate(hm.clean_mesh(hm.height_to_mesh(h, PITCH), min_island_faces=0), 5000)
    assert _open3d_topology(d)[:2] == (0, True)


def test_meshlab_topological_measures_agree():
    pymeshlab = pytest.importorskip("pymeshlab")
    h, _ = step_scene(5)
    h[np.random.default_rng(5).random(h.shape) < 0.1] = np.nan
    raw = hm.height_to_mesh(h, PITCH)
    c = hm.clean_mesh(raw, min_island_faces=0)

    def measures(m: trimesh.Trimesh) -> dict:
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(m.vertices), face_matrix=np.asarray(m.faces, np.int32)))
        return ms.get_topological_measures()

    before, after = measures(raw), measures(c)
    assert before["non_two_manifold_vertices"] == hm.non_manifold_vertices(raw).size > 0
    assert after["non_two_manifold_vertices"] == 0 and after["non_two_manifold_edges"] == 0
    assert after["is_mesh_two_manifold"]
    assert after["connected_components_number"] == hm.mesh_stats(c)["components"]
    assert after["boundary_edges"] == before["boundary_edges"]
    assert after["number_holes"] == hm.boundary_loops(c)


def test_mesh_vertices_carry_sigma_mm(tmp_path) -> None:
    """sigma_mm on the mesh PLY is the uncertainty map at each vertex's pixel, after clean_mesh
    (pinch vertices split) too; Open3D's tensor reader, trimesh and pymeshlab (as ``quality``,
    MeshLab's per-vertex scalar) read it back. After decimation: the nearest pixel's value."""
    import open3d as o3d
    import pymeshlab
    import trimesh

    from huefringe import mesh as meshing

    h = np.fromfunction(lambda v, u: 0.01 * u + 0.02 * v, (24, 32)).astype(np.float32)
    h[6:12, 6:12] += 3.0
    h[12:14, 12:14] = np.nan  # touching corners: a pinch for clean_mesh to split
    h[14:16, 14:16] = np.nan
    sigma = np.fromfunction(lambda v, u: 0.001 * (v * 32 + u), h.shape).astype(np.float32)
    m = meshing.clean_mesh(meshing.height_to_mesh(h, 0.5), min_island_faces=1)
    meshing.attach_sigma(m, sigma, 0.5)
    v, u = meshing.vertex_pixels(m)
    ply = tmp_path / "m.ply"
    meshing.export_mesh(m, ply, write_stats=False)
    pc = o3d.t.io.read_point_cloud(str(ply))
    np.testing.assert_array_equal(pc.point["sigma_mm"].numpy().ravel(), sigma[v, u])
    raw = trimesh.load(ply, process=False).metadata["_ply_raw"]["vertex"]["data"]
    np.testing.assert_array_equal(raw["sigma_mm"], sigma[v, u])
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(ply))
    np.testing.assert_allclose(ms.current_mesh().vertex_scalar_array(), sigma[v, u], rtol=1e-6)
    assert len(trimesh.load(ply, process=False).faces) == len(m.faces)
    d = meshing.decimate(m, 200)
    meshing.attach_sigma(d, sigma, 0.5)
    xy = np.rint(np.asarray(d.vertices)[:, :2] / 0.5).astype(int)
    np.testing.assert_array_equal(d.vertex_attributes["sigma_mm"], sigma[np.clip(xy[:, 1], 0, 23), np.clip(xy[:, 0], 0, 31)])
