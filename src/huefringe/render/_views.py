"""3-D views of a mesh: the view angles, the orthographic camera that fits the field, off-screen PyVista rendering."""

from __future__ import annotations

import ctypes.util
import math
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from huefringe.io import write_png_rgb

if TYPE_CHECKING:
    import trimesh


#: View name -> (azimuth, elevation) in degrees. Azimuth 0: the viewer stands at the bottom edge
#: of the image (large ``v``) looking across the field; positive azimuth moves the viewer
#: towards +X (anticlockwise seen from above); elevation 90 looks straight down.
VIEW_ANGLES: dict[str, tuple[float, float]] = {
    "top": (0.0, 90.0),
    "oblique1": (-35.0, 35.0),
    "oblique2": (145.0, 35.0),
    "front": (0.0, 20.0),
    "side": (90.0, 20.0),
}
DEFAULT_VIEWS: tuple[str, ...] = ("top", "oblique1", "oblique2")

#: Renders mirror Y (display frame ``(X, -Y, Z)``) because the mesh frame is the mirror image
#: of the physical scene; set to False if the design's frame becomes right-handed.
DISPLAY_MIRROR_Y = True

# Screen layout in normalised device coordinates ([-1, 1] across the window): the surface is
# fitted into this box; the right strip holds the scalar bar, the top band an optional title.
_FIT_X_WITH_BAR = (-0.94, 0.60)
_FIT_X_NO_BAR = (-0.94, 0.94)
_FIT_Y = (-0.92, 0.82)


def _configure_vtk_backend() -> None:
    """Prefer EGL off-screen rendering on a display-less Linux box (only if nothing is set)."""
    if "VTK_DEFAULT_OPENGL_WINDOW" in os.environ or not sys.platform.startswith("linux"):
        return
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return
    if ctypes.util.find_library("EGL"):
        os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = "vtkEGLRenderWindow"


def _pyvista() -> ModuleType:
    """Import PyVista lazily (the 2-D figures do not need VTK), configuring VTK first."""
    if "pyvista" not in sys.modules:
        _configure_vtk_backend()
    import pyvista  # noqa: PLC0415

    return pyvista


def _to_display(points: np.ndarray, z_scale: float) -> np.ndarray:
    """Mesh frame -> display frame (see :data:`DISPLAY_MIRROR_Y`); returns a new array."""
    out = np.array(points, dtype=np.float64, copy=True).reshape(-1, 3)
    if DISPLAY_MIRROR_Y:
        out[:, 1] *= -1.0
    out[:, 2] *= float(z_scale)
    return out


# --------------------------------------------------------------------------------------------
# cameras
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Camera:
    """A fixed parallel-projection camera (VTK conventions, coordinates in mm).

    Attributes
    ----------
    position, focal_point, view_up : tuple of 3 floats
        Camera placement; ``view_up`` need not be orthogonal to the view direction.
    parallel_scale : float
        Half the height of the window in world units (mm).
    """

    position: tuple[float, float, float]
    focal_point: tuple[float, float, float]
    view_up: tuple[float, float, float]
    parallel_scale: float

    def apply(self, plotter: Any) -> None:
        """Set this camera on a PyVista plotter (and reset the clipping range)."""
        cam = plotter.camera
        cam.position = self.position
        cam.focal_point = self.focal_point
        cam.up = self.view_up
        cam.enable_parallel_projection()
        cam.parallel_scale = self.parallel_scale
        plotter.renderer.ResetCameraClippingRange()


def _view_basis(azimuth_deg: float, elevation_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unit vectors of a view: towards the camera ``o``, screen right ``r``, screen up ``s``,
    and the ``view_up`` to give VTK (+Z, or the horizontal facing direction when looking
    straight down, so that the top view at azimuth 0 has +X right and +Y up)."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    o = np.array([math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)])
    facing = np.array([-math.sin(az), math.cos(az), 0.0])
    up = facing if math.cos(el) < 1e-6 else np.array([0.0, 0.0, 1.0])
    d = -o
    r = np.cross(d, up)
    r /= np.linalg.norm(r)
    s = np.cross(r, d)
    return o, r, s, up


def camera_for_field(
    width_mm: float,
    height_mm: float,
    zrange: tuple[float, float],
    *,
    origin: tuple[float, float] = (0.0, 0.0),
    views: Sequence[str] = DEFAULT_VIEWS,
    size: tuple[int, int] = (1024, 768),
    scalar_bar: bool = True,
    z_scale: float = 1.0,
) -> dict[str, Camera]:
    """Fixed cameras that frame a whole field of view, one per view.

    The box ``[x0, x0 + width_mm] x [y0, y0 + height_mm] x zrange`` is projected on each view's
    screen plane and fitted (parallel projection, same scale in both directions) into the part
    of the window not used by the scalar bar and the title band. Pass the result, with the
    same ``size``, to :func:`render_views` for every frame of a session.

    Parameters
    ----------
    width_mm, height_mm : float
        Field of view in mm, e.g. ``(W - 1) * pitch`` and ``(H - 1) * pitch``.
    zrange : (float, float)
        Height range to keep in view, e.g. the session's colour limits.
    origin : (float, float), default (0, 0)
        ``(X, Y)`` of the field's first pixel.
    views : sequence of str
        Names from :data:`VIEW_ANGLES`.
    size : (int, int)
        Window ``(width, height)`` in pixels the cameras are made for.
    scalar_bar : bool, default True
        Leave the right strip free for the scalar bar.
    z_scale : float, default 1.0
        Vertical exaggeration the renders will use (pass the same to :func:`render_views`).

    Returns
    -------
    dict of str to Camera
    """
    if width_mm <= 0 or height_mm <= 0:
        raise ValueError("width_mm and height_mm must be > 0")
    z0, z1 = float(min(zrange)), float(max(zrange))
    if z1 - z0 <= 0:
        z1 = z0 + 1e-3 * max(width_mm, height_mm)
    x0, y0 = map(float, origin)
    corners = _to_display(
        [[x, y, z] for x in (x0, x0 + width_mm) for y in (y0, y0 + height_mm) for z in (z0, z1)], z_scale
    )
    centre = corners.mean(axis=0)
    diag = float(np.linalg.norm(corners.max(0) - corners.min(0)))
    aspect = size[0] / size[1]
    ax, bx = _FIT_X_WITH_BAR if scalar_bar else _FIT_X_NO_BAR
    ay, by = _FIT_Y
    cams: dict[str, Camera] = {}
    for name in views:
        if name not in VIEW_ANGLES:
            raise ValueError(f"unknown view {name!r}; known: {sorted(VIEW_ANGLES)}")
        o, r, s, up = _view_basis(*VIEW_ANGLES[name])
        pr, ps = corners @ r, corners @ s
        scale = max((pr.max() - pr.min()) / ((bx - ax) * aspect), (ps.max() - ps.min()) / (by - ay))
        # world offsets (along r and s) of the focal point so that the box lands in the fit box
        fr = 0.5 * (pr.max() + pr.min()) - 0.5 * (ax + bx) * scale * aspect
        fs = 0.5 * (ps.max() + ps.min()) - 0.5 * (ay + by) * scale
        focal = r * fr + s * fs + o * float(centre @ o)
        position = focal + o * 2.0 * diag
        view_up = tuple(float(c) for c in up)
        cams[name] = Camera(
            position=tuple(float(c) for c in position),  # type: ignore[arg-type]
            focal_point=tuple(float(c) for c in focal),  # type: ignore[arg-type]
            view_up=view_up,  # type: ignore[arg-type]
            parallel_scale=float(scale),
        )
    return cams


# --------------------------------------------------------------------------------------------
# 3-D renders
# --------------------------------------------------------------------------------------------
def mesh_to_polydata(mesh: trimesh.Trimesh, *, display: bool = False, z_scale: float = 1.0) -> Any:
    """Convert a trimesh mesh to ``pyvista.PolyData``.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Surface in mm.
    display : bool, default False
        Return the display-frame copy used by the renders (Y mirrored per
        :data:`DISPLAY_MIRROR_Y`, Z times ``z_scale``, winding reversed with the mirror so
        normals still point up). False keeps the mesh coordinates.
    z_scale : float, default 1.0
        Vertical exaggeration (display frame only).

    Returns
    -------
    pyvista.PolyData
        With point data ``height`` (true Z in mm) and, when the mesh has vertex colours,
        ``rgb`` (uint8).
    """
    pv = _pyvista()
    vertices = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    points = _to_display(vertices, z_scale) if display else vertices.copy()
    if display and DISPLAY_MIRROR_Y:
        faces = faces[:, ::-1]
    cells = np.hstack([np.full((len(faces), 1), 3, dtype=np.int64), faces]).ravel()
    poly = pv.PolyData(points, cells) if len(faces) else pv.PolyData(points)
    poly.point_data["height"] = vertices[:, 2].copy()
    visual = getattr(mesh, "visual", None)
    if visual is not None and visual.kind == "vertex" and len(visual.vertex_colors) == len(vertices):
        poly.point_data["rgb"] = np.asarray(visual.vertex_colors)[:, :3].astype(np.uint8)
    return poly


def _as_trimesh(mesh: Any) -> trimesh.Trimesh:
    """Accept what ``trimesh.load`` returns: a mesh, or a Scene (an empty PLY loads as one)."""
    import trimesh  # noqa: PLC0415

    if isinstance(mesh, trimesh.Trimesh):
        return mesh
    if isinstance(mesh, trimesh.Scene):
        parts = [g for g in mesh.geometry.values() if isinstance(g, trimesh.Trimesh)]
        if not parts:
            return trimesh.Trimesh()
        return parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)
    raise TypeError(f"expected a trimesh.Trimesh or trimesh.Scene, got {type(mesh).__name__}")


def render_views(
    mesh: trimesh.Trimesh,
    out_dir: str | os.PathLike[str],
    stem: str,
    *,
    clim: tuple[float, float] | None = None,
    camera: Mapping[str, Camera] | None = None,
    views: Sequence[str] = DEFAULT_VIEWS,
    size: tuple[int, int] = (1024, 768),
    cmap: str = "viridis",
    colour_by: Literal["height", "rgb"] = "height",
    title: str | None = None,
    background: str = "white",
    smooth_shading: bool = True,
    z_scale: float = 1.0,
) -> list[Path]:
    """Render a mesh off-screen from several views and write one PNG per view.

    Parameters
    ----------
    mesh : trimesh.Trimesh or trimesh.Scene
        Surface in mm (a Scene, as ``trimesh.load`` returns for an empty PLY, is merged).
    out_dir : path-like
        Folder for the PNGs (created if needed).
    stem : str
        File stem; files are ``out_dir / f"{stem}_{view}.png"``.
    clim : (float, float), optional
        Colour limits in mm; default the mesh's Z range. Pass the session's limits so that
        colours mean the same in every frame.
    camera : mapping of view name to Camera, optional
        Fixed cameras (:func:`camera_for_field`, made for the same ``size``); default: fitted
        to this mesh's bounds, which differs from frame to frame.
    views : sequence of str, default ("top", "oblique1", "oblique2")
        View names (keys of ``camera``, or of :data:`VIEW_ANGLES` when ``camera`` is None).
    size : (int, int), default (1024, 768)
        Image ``(width, height)`` in pixels.
    cmap : str, default "viridis"
        Matplotlib colour map for the height.
    colour_by : {"height", "rgb"}, default "height"
        Colour by height (with the "Height (mm)" scalar bar) or by the mesh's vertex colours.
    title : str, optional
        Text in the top-left corner of every view.
    background : str, default "white"
        Background colour.
    smooth_shading : bool, default True
        Phong shading with vertex normals (False: flat facets).
    z_scale : float, default 1.0
        Vertical exaggeration of the drawn surface (colours keep the true heights); use the
        same value as for ``camera``.

    Returns
    -------
    list of pathlib.Path
        The written PNGs, in the order of ``views``.
    """
    if colour_by not in ("height", "rgb"):
        raise ValueError(f"colour_by must be 'height' or 'rgb', got {colour_by!r}")
    mesh = _as_trimesh(mesh)
    pv = _pyvista()
    out_dir = Path(out_dir)
    views = tuple(views)
    has_faces = len(mesh.faces) > 0
    use_bar = colour_by == "height"
    if camera is None:
        if has_faces:
            lo, hi = np.asarray(mesh.bounds, dtype=float)
        else:
            lo, hi = np.zeros(3), np.ones(3)
        camera = camera_for_field(
            max(hi[0] - lo[0], 1e-6), max(hi[1] - lo[1], 1e-6), (lo[2], hi[2]),
            origin=(lo[0], lo[1]), views=views, size=size, scalar_bar=use_bar, z_scale=z_scale,
        )  # fmt: skip
    missing = [v for v in views if v not in camera]
    if missing:
        raise ValueError(f"no camera for views {missing}")
    if clim is None:
        z = np.asarray(mesh.vertices)[:, 2] if has_faces else np.zeros(1)
        clim = (float(z.min()), float(z.max()) if z.max() > z.min() else float(z.min()) + 1e-3)
    clim = (float(clim[0]), float(clim[1]))

    # a fresh default theme: renders do not depend on pyvista.global_theme
    plotter = pv.Plotter(off_screen=True, window_size=[int(size[0]), int(size[1])], theme=pv.themes.Theme())
    try:
        plotter.set_background(background)
        font_px = max(8, int(round(size[1] / 40)))
        if has_faces:
            poly = mesh_to_polydata(mesh, display=True, z_scale=z_scale)
            if colour_by == "rgb":
                if "rgb" not in poly.point_data:
                    raise ValueError("colour_by='rgb' needs a mesh with vertex colours")
                plotter.add_mesh(poly, scalars="rgb", rgb=True, smooth_shading=smooth_shading)
            else:
                plotter.add_mesh(
                    poly, scalars="height", cmap=cmap, clim=clim, smooth_shading=smooth_shading,
                    show_scalar_bar=False,
                )  # fmt: skip
        else:
            plotter.add_text("no valid surface", position="upper_edge", font_size=font_px, color="black")
        if use_bar and has_faces:
            plotter.add_scalar_bar(
                title="Height (mm)", vertical=True, position_x=0.83, position_y=0.08, width=0.07, height=0.78,
                n_labels=6, fmt="%.2f", color="black", title_font_size=font_px, label_font_size=font_px,
                unconstrained_font_size=True,
            )  # fmt: skip
        if title:
            plotter.add_text(title, position="upper_left", font_size=max(6, int(round(size[1] / 64))), color="black")
        written = []
        for name in views:
            camera[name].apply(plotter)
            plotter.render()
            img = np.asarray(plotter.screenshot(return_img=True))[..., :3]
            path = out_dir / f"{stem}_{name}.png"
            write_png_rgb(path, np.ascontiguousarray(img, dtype=np.uint8))
            written.append(path)
    finally:
        plotter.close()
    return written
