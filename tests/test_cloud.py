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
        direct = cloud.write_cloud(tmp_path / "direct.ply", cloud.height_to_cloud(h, s.pixel_pitch_mm, colours=white))
        with open(path, "rb") as f:
            assert f.read() == direct.read_bytes()
        assert len(o3d.io.read_point_cloud(path).points) == np.isfinite(h).sum()
    assert sorted(p.name for p in (tmp_path / "cloud").iterdir()) == ["frame_0000.ply", "frame_0002.ply"]
    with pytest.raises(ValueError):
        stages.cloud_frames(str(root), frames, heights[:1], clouds)
