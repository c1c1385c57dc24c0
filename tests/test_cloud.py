"""Tests of huefringe.cloud: point clouds from height maps and their PLY files."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
import trimesh

from huefringe import cloud

PITCH = 0.2


def scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    h = np.full((150, 200), 0.5) + rng.normal(0, 0.01, (150, 200))
    h[20:70, 20:80] += 3.0
    h[60:80, 100:110] = np.nan
    h[rng.random(h.shape) < 0.02] = np.nan
    white = rng.random((150, 200, 3)).astype(np.float32)
    return h.astype(np.float32), white


def test_one_point_per_valid_pixel_in_mm():
    h, white = scene()
    pcd = cloud.height_to_cloud(h, PITCH, colours=white)
    pts = np.asarray(pcd.points)
    valid = np.isfinite(h)
    assert len(pts) == valid.sum() == 150 * 200 - np.isnan(h).sum()
    v, u = np.nonzero(valid)  # row-major, like the cloud
    assert np.array_equal(pts[:, 0], u * PITCH)
    assert np.array_equal(pts[:, 1], v * PITCH)
    assert np.array_equal(pts[:, 2], h[v, u].astype(np.float64))
    assert pts[:, 0].max() == pytest.approx(199 * PITCH) and pts[:, 1].max() == pytest.approx(149 * PITCH)
    cols = np.asarray(pcd.colors)
    assert np.allclose(cols, white[v, u], atol=1e-7)


def test_without_colours_and_integer_images():
    h, white = scene(1)
    assert not cloud.height_to_cloud(h, PITCH).has_colors()
    u8 = np.rint(white * 255).astype(np.uint8)
    cols = np.asarray(cloud.height_to_cloud(h, PITCH, colours=u8).colors)
    v, u = np.nonzero(np.isfinite(h))
    assert np.allclose(cols, u8[v, u] / 255.0)
    with pytest.raises(ValueError):
        cloud.height_to_cloud(h, PITCH, colours=white[:, :-1])
    with pytest.raises(ValueError):
        cloud.height_to_cloud(h, -1.0)


def test_write_cloud_round_trip(tmp_path):
    h, white = scene(2)
    pcd = cloud.height_to_cloud(h, PITCH, colours=white)
    out = cloud.write_cloud(tmp_path / "cloud" / "frame_0000.ply", pcd)
    assert out.exists() and [p.name for p in out.parent.iterdir()] == ["frame_0000.ply"]
    assert b"format binary_little_endian" in out.read_bytes()[:100]
    back = o3d.io.read_point_cloud(str(out))
    assert np.array_equal(np.asarray(back.points), np.asarray(pcd.points))  # doubles, exact
    assert np.abs(np.asarray(back.colors) - np.asarray(pcd.colors)).max() <= 0.5 / 255 + 1e-9
    tm = trimesh.load(out)  # other readers see the same cloud
    assert len(tm.vertices) == np.isfinite(h).sum()


def test_empty_cloud_is_a_valid_ply(tmp_path):
    pcd = cloud.height_to_cloud(np.full((4, 4), np.nan, np.float32), PITCH, colours=np.zeros((4, 4, 3)))
    out = cloud.write_cloud(tmp_path / "e.ply", pcd)
    assert len(o3d.io.read_point_cloud(str(out)).points) == 0
    assert b"element vertex 0" in out.read_bytes()
    with pytest.raises(ValueError):
        cloud.write_cloud(tmp_path / "e.pcd", pcd)


def test_cloud_frames_stage_writes_the_clouds_of_a_batch_from_its_height_maps(tmp_path):
    """stages.cloud_frames (the workflow's cloud_* jobs): the same PLY bytes as building the cloud
    from the in-memory height map with the session's white image, one file per frame."""
    from session_factory import make_session

    from huefringe import stages
    from huefringe.io import write_tiff
    from huefringe.session import load_session, read_rgb

    root = make_session(tmp_path / "s", frames=3)
    s = load_session(root)
    rng = np.random.default_rng(4)
    frames = [0, 2]
    heights, clouds, maps = [], [], []
    for n in frames:
        h = rng.normal(1.0, 0.3, (s.height, s.width)).astype(np.float32)
        h[rng.random(h.shape) < 0.1] = np.nan
        heights.append(str(tmp_path / "height" / f"frame_{n:04d}.tiff"))
        clouds.append(str(tmp_path / "cloud" / f"frame_{n:04d}.ply"))
        write_tiff(heights[-1], h)
        maps.append(h)
    stages.cloud_frames(str(root), frames, heights, clouds)
    white = read_rgb(s.object_white)
    for h, path in zip(maps, clouds, strict=True):
        direct = tmp_path / "direct.ply"  # Open3D's own writer is the reference
        assert o3d.io.write_point_cloud(str(direct), cloud.height_to_cloud(h, s.pixel_pitch_mm, colours=white),
                                        write_ascii=False)
        with open(path, "rb") as f:
            assert f.read() == direct.read_bytes()
        assert len(o3d.io.read_point_cloud(path).points) == np.isfinite(h).sum()
    assert sorted(p.name for p in (tmp_path / "cloud").iterdir()) == ["frame_0000.ply", "frame_0002.ply"]
    with pytest.raises(ValueError):
        stages.cloud_frames(str(root), frames, heights[:1], clouds)


# --------------------------------------------------------------------------- the PLY writer


def open3d_bytes(tmp_path, pcd) -> bytes:
    ref = tmp_path / "open3d.ply"
    assert o3d.io.write_point_cloud(str(ref), pcd, format="ply", write_ascii=False, compressed=False)
    return ref.read_bytes()


def test_colour_bytes_round_halves_up_like_open3d(tmp_path):
    k = np.arange(255, dtype=np.float64)
    c = np.concatenate([(k + 0.5) / 255, (k + 0.4999) / 255, (k + 0.5001) / 255, k / 255, [-0.2, 1.0, 1.7]])
    codes = cloud.colour_bytes(c)
    assert codes[:255].tolist() == list(range(1, 256))  # halves away from zero, not to even
    assert codes[255:510].tolist() == list(range(255)) and codes[510:765].tolist() == list(range(1, 256))
    assert codes[-3:].tolist() == [0, 255, 255]
    rgb = np.resize(c, (len(c) // 3 * 3,)).reshape(-1, 3)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.zeros((len(rgb), 3))))
    pcd.colors = o3d.utility.Vector3dVector(rgb)
    back = o3d.io.read_point_cloud(str(cloud.write_cloud(tmp_path / "c.ply", pcd)))
    assert np.array_equal(np.rint(np.asarray(back.colors) * 255).astype(np.uint8), cloud.colour_bytes(rgb))
    assert (tmp_path / "c.ply").read_bytes() == open3d_bytes(tmp_path, pcd)


@pytest.mark.parametrize("kind", ["float", "uint8", "uint16", "grey", "none", "normals"])
def test_ply_is_byte_for_byte_what_open3d_writes(tmp_path, kind):
    h, white = scene(5)
    colours = {"float": white, "uint8": np.rint(white * 255).astype(np.uint8),
               "uint16": np.rint(white * 65535).astype(np.uint16), "grey": white[..., 0], "none": None,
               "normals": white}[kind]
    pcd = cloud.height_to_cloud(h, PITCH, colours=colours)
    if kind == "normals":
        pcd.estimate_normals()
    ours = cloud.write_cloud(tmp_path / "ours.ply", pcd).read_bytes()
    assert ours == open3d_bytes(tmp_path, pcd)
    if kind != "normals":
        n = cloud.write_height_cloud(tmp_path / "direct.ply", h, PITCH, colours=colours)
        assert n == np.isfinite(h).sum()
        assert (tmp_path / "direct.ply").read_bytes() == ours


def _read_all(path):
    """The cloud as each reader sees it: (points float64, colours uint8) per reader."""
    import plyfile
    import pymeshlab

    out = {}
    leg = o3d.io.read_point_cloud(str(path))
    out["open3d"] = (np.asarray(leg.points), np.rint(np.asarray(leg.colors) * 255).astype(np.uint8))
    ten = o3d.t.io.read_point_cloud(str(path))
    out["open3d.t"] = (ten.point.positions.numpy().astype(np.float64), ten.point.colors.numpy())
    tm = trimesh.load(path)
    out["trimesh"] = (np.asarray(tm.vertices, np.float64), np.asarray(tm.colors)[:, :3].astype(np.uint8))
    ms = pymeshlab.MeshSet()  # MeshLab's own PLY importer
    ms.load_new_mesh(str(path))
    m = ms.current_mesh()
    out["meshlab"] = (m.vertex_matrix().astype(np.float64), np.rint(m.vertex_color_matrix()[:, :3] * 255).astype(np.uint8))
    v = plyfile.PlyData.read(str(path))["vertex"]
    out["plyfile"] = (np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64),
                      np.stack([v["red"], v["green"], v["blue"]], axis=1))
    return out


def test_open3d_trimesh_and_meshlab_read_our_file_as_the_one_open3d_wrote(tmp_path):
    h, white = scene(6)
    pcd = cloud.height_to_cloud(h, PITCH, colours=white)
    ref = tmp_path / "open3d.ply"
    assert o3d.io.write_point_cloud(str(ref), pcd, write_ascii=False)
    ours = tmp_path / "ours.ply"
    cloud.write_height_cloud(ours, h, PITCH, colours=white)
    got, want = _read_all(ours), _read_all(ref)
    v, u = np.nonzero(np.isfinite(h))
    for reader in want:
        assert np.array_equal(got[reader][0], want[reader][0]), reader
        assert np.array_equal(got[reader][1], want[reader][1]), reader
        assert len(got[reader][0]) == len(v)
        assert np.allclose(got[reader][0][:, 2], h[v, u], atol=1e-6), reader  # MeshLab: float32
    assert np.array_equal(got["open3d"][0], np.asarray(pcd.points))
    assert np.array_equal(got["plyfile"][1], cloud.colour_bytes(white[v, u]))


def test_extra_float_properties_are_read_back_and_leave_the_rest_alone(tmp_path):
    import plyfile

    h, white = scene(7)
    sigma = np.random.default_rng(7).random(h.shape).astype(np.float32) * 0.01
    ref = tmp_path / "plain.ply"
    cloud.write_height_cloud(ref, h, PITCH, colours=white)
    ours = tmp_path / "sigma.ply"
    cloud.write_height_cloud(ours, h, PITCH, colours=white, scalars={"sigma_mm": sigma})
    assert b"property float sigma_mm\nend_header" in ours.read_bytes()[:400]
    v, u = np.nonzero(np.isfinite(h))
    ten = o3d.t.io.read_point_cloud(str(ours))
    assert np.array_equal(ten.point["sigma_mm"].numpy().ravel(), sigma[v, u])
    assert np.array_equal(plyfile.PlyData.read(str(ours))["vertex"]["sigma_mm"], sigma[v, u])
    tm = trimesh.load(ours)
    assert np.array_equal(np.asarray(tm.metadata["_ply_raw"]["vertex"]["data"]["sigma_mm"]).ravel(), sigma[v, u])
    got, want = _read_all(ours), _read_all(ref)
    for reader in want:  # points and colours unchanged for every reader
        assert np.array_equal(got[reader][0], want[reader][0]), reader
        assert np.array_equal(got[reader][1], want[reader][1]), reader
    with pytest.raises(ValueError, match="sigma_mm"):
        cloud.write_height_cloud(tmp_path / "bad.ply", h, PITCH, scalars={"sigma_mm": sigma[:-1]})
    with pytest.raises(ValueError, match="property name"):
        cloud.write_points(tmp_path / "bad.ply", np.zeros((2, 3)), scalars={"x": np.zeros(2)})
    assert not (tmp_path / "bad.ply").exists()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_packed_height_cloud_is_the_gathered_one_byte_for_byte(tmp_path, dtype):
    """The compiled packing of write_height_cloud gives the bytes of write_points on the gathered
    points, colours and scalars (float32 and float64 heights, image and per-pixel code colours,
    two scalars, an all-NaN map)."""
    h, white = scene(11)
    h = h.astype(dtype)
    rng = np.random.default_rng(11)
    s1 = rng.random(h.shape).astype(np.float32)
    s2 = rng.random(h.shape)  # float64: written as float32
    pts, pix = cloud.height_to_points(h, PITCH)
    codes = cloud.colour_bytes(white.reshape(-1, 3))
    cloud.write_points(tmp_path / "ref.ply", pts, codes[pix],
                       scalars={"sigma_mm": s1.reshape(-1)[pix], "other": s2.reshape(-1)[pix].astype(np.float32)})
    for colours in (white, codes):
        n = cloud.write_height_cloud(tmp_path / "ours.ply", h, PITCH, colours=colours, scalars={"sigma_mm": s1, "other": s2})
        assert n == pix.size
        assert (tmp_path / "ours.ply").read_bytes() == (tmp_path / "ref.ply").read_bytes()
    empty = np.full(h.shape, np.nan, dtype)
    assert cloud.write_height_cloud(tmp_path / "empty.ply", empty, PITCH, colours=white) == 0
    cloud.write_points(tmp_path / "empty_ref.ply", np.zeros((0, 3)), np.zeros((0, 3), np.uint8))
    assert (tmp_path / "empty.ply").read_bytes() == (tmp_path / "empty_ref.ply").read_bytes()
