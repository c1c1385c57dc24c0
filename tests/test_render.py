"""Tests of huefringe.render: off-screen PyVista renders and matplotlib figures."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh

from huefringe import mesh as hm
from huefringe import render

PITCH = 0.2
H, W = 150, 200
SIZE = (400, 300)
CLIM = (0.0, 4.6)
BG = np.array([255, 255, 255])


def step_height(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    h = np.full((H, W), 0.5) + rng.normal(0, 0.01, (H, W))
    h[20:70, 20:80] += 3.0
    h[90:130, 30:90] += 1.0
    h[40:120, 120:180] += 4.0
    h[60:80, 100:110] = np.nan
    return h.astype(np.float32)


@pytest.fixture(scope="module")
def cameras():
    return render.camera_for_field((W - 1) * PITCH, (H - 1) * PITCH, CLIM, size=SIZE)


def read_rgb(path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, path
    return img[..., ::-1]


def foreground(img: np.ndarray) -> np.ndarray:
    return np.any(img != BG, axis=-1)


def test_render_views_writes_sensible_pngs(tmp_path, cameras):
    m = hm.height_to_mesh(step_height(), PITCH)
    paths = render.render_views(m, tmp_path / "renders", "frame_0000", clim=CLIM, camera=cameras, size=SIZE)
    assert [p.name for p in paths] == ["frame_0000_top.png", "frame_0000_oblique1.png", "frame_0000_oblique2.png"]
    assert sorted(p.name for p in (tmp_path / "renders").iterdir()) == sorted(p.name for p in paths)
    for p in paths:
        img = read_rgb(p)
        assert img.shape == (SIZE[1], SIZE[0], 3)
        assert img.std() > 20  # not blank
        share = foreground(img).mean()
        assert 0.10 < share < 0.95, (p.name, share)
    top = read_rgb(paths[0])
    assert foreground(top).mean() > 0.5  # the top view fills most of the window


def test_same_camera_gives_identical_framing(tmp_path, cameras):
    m = hm.height_to_mesh(step_height(), PITCH)
    a = render.render_views(m, tmp_path, "a", clim=CLIM, camera=cameras, size=SIZE)
    b = render.render_views(m, tmp_path, "b", clim=CLIM, camera=cameras, size=SIZE)
    for pa, pb in zip(a, b, strict=True):
        ia, ib = read_rgb(pa), read_rgb(pb)
        assert np.array_equal(foreground(ia), foreground(ib))
        assert np.array_equal(ia, ib)
    # another frame (new noise) with the session camera: framing unchanged up to noise
    m2 = hm.height_to_mesh(step_height(seed=9), PITCH)
    c = render.render_views(m2, tmp_path, "c", clim=CLIM, camera=cameras, size=SIZE, views=("top",))
    assert np.mean(foreground(read_rgb(c[0])) != foreground(read_rgb(a[0]))) < 0.005
    # without the session camera, a cropped frame is framed differently (that is what `camera` is for)
    crop = hm.height_to_mesh(step_height()[: H // 2, : W // 2], PITCH)
    d = render.render_views(crop, tmp_path, "d", clim=CLIM, size=SIZE, views=("top",))
    e = render.render_views(crop, tmp_path, "e", clim=CLIM, camera=cameras, size=SIZE, views=("top",))
    fd, fe = foreground(read_rgb(d[0])), foreground(read_rgb(e[0]))
    assert fe.mean() < 0.5 * fd.mean()


def test_top_view_has_the_camera_orientation(tmp_path, cameras):
    # only the top-left image corner is valid: it must appear top-left in the top view
    h = np.full((H, W), np.nan, np.float32)
    h[: H // 3, : W // 3] = 1.0
    m = hm.height_to_mesh(h, PITCH)
    (p,) = render.render_views(m, tmp_path, "o", clim=CLIM, camera=cameras, size=SIZE, views=("top",))
    fg = foreground(read_rgb(p))
    fg[:, int(0.78 * SIZE[0]) :] = False  # ignore the scalar bar strip
    rows, cols = np.nonzero(fg)
    assert rows.mean() < 0.4 * SIZE[1] and cols.mean() < 0.35 * SIZE[0]


def test_colours_follow_clim(tmp_path, cameras):
    flat = hm.height_to_mesh(np.full((H, W), 4.6, np.float32), PITCH)
    low = hm.height_to_mesh(np.full((H, W), 0.0, np.float32), PITCH)
    (a,) = render.render_views(flat, tmp_path, "hi", clim=CLIM, camera=cameras, size=SIZE, views=("top",))
    (b,) = render.render_views(low, tmp_path, "lo", clim=CLIM, camera=cameras, size=SIZE, views=("top",))
    ca, cb = read_rgb(a)[SIZE[1] // 2, SIZE[0] // 3], read_rgb(b)[SIZE[1] // 2, SIZE[0] // 3]
    assert ca[0] > 150 and ca[1] > 150 and ca[2] < 120  # viridis top: yellow
    assert cb[2] > cb[1] and cb[0] > cb[1]  # viridis bottom: dark purple


def test_empty_mesh_still_renders(tmp_path):
    m = hm.height_to_mesh(np.full((5, 5), np.nan, np.float32), PITCH)
    paths = render.render_views(m, tmp_path, "empty", size=SIZE)
    assert len(paths) == 3 and all(p.exists() for p in paths)
    # an empty PLY loads as an (empty) trimesh.Scene: still rendered
    hm.export_mesh(m, tmp_path / "empty.ply")
    loaded = trimesh.load(tmp_path / "empty.ply", process=False)
    assert len(render.render_views(loaded, tmp_path, "loaded", size=SIZE, views=("top",))) == 1


def test_camera_for_field_rejects_bad_input():
    with pytest.raises(ValueError):
        render.camera_for_field(0.0, 10.0, (0, 1))
    with pytest.raises(ValueError):
        render.camera_for_field(10.0, 10.0, (0, 1), views=("nowhere",))


def _png_size(path) -> tuple[int, int]:
    img = read_rgb(path)
    return img.shape[1], img.shape[0]


def test_height_map_figure(tmp_path):
    h = step_height()
    out = render.height_map_figure(h, PITCH, tmp_path / "fig" / "height.png", clim=CLIM, title="frame 0")
    img = read_rgb(out)
    assert _png_size(out) == (960, 720)  # 6.4 x 4.8 in at 150 dpi
    assert img.std() > 20
    assert sorted(p.name for p in out.parent.iterdir()) == ["height.png"]


def test_wrapped_phase_figure(tmp_path):
    phase = np.mod(np.add.outer(np.zeros(H), np.arange(W) * 0.3), 2 * np.pi)
    phase[10:20, 10:20] = np.nan
    out = render.wrapped_phase_figure(phase, tmp_path / "phase.png", pitch_mm=PITCH)
    assert out.exists() and read_rgb(out).std() > 20


def test_profile_figure(tmp_path):
    h = step_height()
    out = render.profile_figure(h, 45, PITCH, tmp_path / "profile.png", reference=np.where(np.arange(W) < 20, 0.5, 3.5))
    assert _png_size(out) == (960, 540) and read_rgb(out).std() > 10
    with pytest.raises(IndexError):
        render.profile_figure(h, H, PITCH, tmp_path / "bad.png")


def test_profile_figure_names_its_row(tmp_path, monkeypatch):
    from huefringe.render import _figures

    seen = []
    save = _figures._save_figure
    monkeypatch.setattr(_figures, "_save_figure", lambda fig, out, dpi: (seen.append(fig), save(fig, out, dpi))[1])
    render.profile_figure(step_height(), 45, PITCH, tmp_path / "p.png", title="demo frame 0000: cross-section")
    render.profile_figure(step_height(), -1, PITCH, tmp_path / "q.png")
    (ax,), (ax2,) = seen[0].axes, seen[1].axes
    y = 45 * PITCH
    assert ax.get_title() == f"demo frame 0000: cross-section\nat image row v = 45 px (Y = {y:.2f} mm)"
    assert f"row v = 45 px (Y = {y:.2f} mm)" in ax.get_xlabel() and "(mm)" in ax.get_xlabel()
    assert ax2.get_title() == f"Profile at image row v = {H - 1} px (Y = {(H - 1) * PITCH:.2f} mm)"
    # the plotted line is that row of the map
    np.testing.assert_array_equal(ax.lines[0].get_ydata(), step_height()[45])


def test_colour_by_vertex_rgb(tmp_path):
    red = np.zeros((H, W, 3), np.float32)
    red[..., 0] = 1.0
    m = hm.height_to_mesh(np.full((H, W), 1.0, np.float32), PITCH, colours=red)
    cams = render.camera_for_field((W - 1) * PITCH, (H - 1) * PITCH, CLIM, size=SIZE, scalar_bar=False)
    (p,) = render.render_views(m, tmp_path, "rgb", camera=cams, size=SIZE, views=("top",), colour_by="rgb")
    c = read_rgb(p)[SIZE[1] // 2, SIZE[0] // 2].astype(int)
    assert c[0] > 150 and c[1] < 60 and c[2] < 60
    with pytest.raises(ValueError):
        render.render_views(hm.height_to_mesh(np.ones((H, W), np.float32), PITCH), tmp_path, "x", colour_by="rgb")
