"""Off-screen 3-D renders of meshes (PyVista/VTK) and 2-D figures of height and phase (matplotlib).

3-D renders
-----------
:func:`render_views` colours a mesh by height (scalar bar "Height (mm)") and writes one PNG
per view: a top view and two oblique views (as in Fig. 10 e, f of the paper). All views use
a parallel projection. For a session, derive the cameras once from the field of view with
:func:`camera_for_field` and pass the same ``camera`` and ``clim`` for every frame: the framing
and colours are then identical across frames, so frames can be compared or animated.

Off-screen rendering: no display is needed. VTK >= 9.4 picks its OpenGL window at run time
(X, then EGL, then OSMesa). On a Linux machine without ``DISPLAY``/``WAYLAND_DISPLAY`` this
module sets ``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`` before importing PyVista, but only
when the variable is unset and ``libEGL`` is present; that skips the failing X attempt (and its
"bad X server connection" warning). Set ``VTK_DEFAULT_OPENGL_WINDOW=vtkOSOpenGLRenderWindow``
to force OSMesa instead. Plotters are always created with ``off_screen=True``; the global
``pyvista.OFF_SCREEN`` is left alone.

Orientation: the mesh frame of ``docs/design.md`` (``X = u * pitch``, ``Y = v * pitch``, ``Z``
towards the camera) is left-handed with respect to the scene, i.e. the mirror image of the
physical object. For display only, renders map ``(X, Y, Z) -> (X, -Y, z_scale * Z)``
(:data:`DISPLAY_MIRROR_Y`), so every view shows the object as it physically is and the top
view has the camera's orientation (``u`` to the right, image rows downwards), like the 2-D
figures. Colours and the scalar bar always use the true heights.

2-D figures
-----------
:func:`height_map_figure` (Fig. 10 d), :func:`wrapped_phase_figure` (Fig. 10 c) and
:func:`profile_figure` (Fig. 9 d) use matplotlib's object API (no pyplot state, any backend).
Image-like figures keep the camera's orientation: ``Y`` (rows) grows downwards.

Every PNG is written atomically (:func:`huefringe.io.atomic_path`).
"""

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
from numpy.typing import ArrayLike, NDArray

from huefringe.io import write_figure_png, write_png_rgb

if TYPE_CHECKING:
    import trimesh
    from matplotlib.figure import Figure

__all__ = [
    "DEFAULT_VIEWS",
    "DISPLAY_MIRROR_Y",
    "VIEW_ANGLES",
    "Camera",
    "camera_for_field",
    "height_map_figure",
    "mesh_to_polydata",
    "profile_figure",
    "render_views",
    "wrapped_phase_figure",
]

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


# --------------------------------------------------------------------------------------------
# 2-D figures (matplotlib)
# --------------------------------------------------------------------------------------------
def _as_map(x: ArrayLike, name: str) -> NDArray[np.float64]:
    """``x`` as a float64 2-D map, or ValueError naming it."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2:
        raise ValueError(f"{name} must be 2-D, got {a.shape}")
    return a


def _new_figure(figsize: tuple[float, float]) -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: PLC0415
    from matplotlib.figure import Figure  # noqa: PLC0415

    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save_figure(fig: Figure, out_png: str | os.PathLike[str], dpi: int) -> Path:
    return write_figure_png(fig, out_png, dpi)


def _image_extent(shape: tuple[int, ...], pitch_mm: float | None) -> tuple[float, float, float, float]:
    """imshow extent (left, right, bottom, top) with pixel centres at ``u * pitch``, rows down."""
    p = 1.0 if pitch_mm is None else float(pitch_mm)
    H, W = shape[:2]
    return (-0.5 * p, (W - 0.5) * p, (H - 0.5) * p, -0.5 * p)


def height_map_figure(
    height: ArrayLike,
    pitch_mm: float,
    out_png: str | os.PathLike[str],
    *,
    clim: tuple[float, float] | None = None,
    title: str | None = "Height map",
    cmap: str = "viridis",
    figsize: tuple[float, float] = (6.4, 4.8),
    dpi: int = 150,
) -> Path:
    """Height map as an image with axes in mm and a colour bar in mm (Fig. 10 d).

    Parameters
    ----------
    height : array_like, shape (H, W)
        Height in mm, NaN where invalid (drawn light grey).
    pitch_mm : float
        Pixel pitch; the axes show ``X = u * pitch`` and ``Y = v * pitch`` (rows downwards).
    out_png : path-like
        Output PNG.
    clim : (float, float), optional
        Colour limits in mm; default the finite range.
    title : str, optional
        Axes title.
    cmap : str, default "viridis"
    figsize : (float, float), default (6.4, 4.8)
        Inches.
    dpi : int, default 150

    Returns
    -------
    pathlib.Path
        ``out_png``.
    """
    h = _as_map(height, "height")
    if clim is None:
        finite = h[np.isfinite(h)]
        clim = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    return _map_figure(h, pitch_mm, out_png, cmap=cmap, clim=clim, title=title, label="Height (mm)",
                       figsize=figsize, dpi=dpi)


def _map_figure(values: NDArray[np.floating], pitch_mm: float, out_png: str | os.PathLike[str], *, cmap: str,
                clim: tuple[float, float], title: str | None, label: str, figsize: tuple[float, float],
                dpi: int) -> Path:
    """A map in mm axes (X = u pitch, Y = v pitch, rows downwards), NaN light grey, with a colour bar."""
    import matplotlib as mpl  # noqa: PLC0415

    fig = _new_figure(figsize)
    ax = fig.add_subplot()
    cm = mpl.colormaps[cmap].with_extremes(bad="0.85")
    im = ax.imshow(
        np.ma.masked_invalid(values), cmap=cm, vmin=clim[0], vmax=clim[1],
        extent=_image_extent(values.shape, pitch_mm), interpolation="nearest", origin="upper",
    )  # fmt: skip
    ax.set_xlabel("X (mm)")
    ax.set_ylabel("Y (mm)")
    ax.set_aspect("equal")
    if title:
        ax.set_title(title)
    fig.colorbar(im, ax=ax, label=label)
    return _save_figure(fig, out_png, dpi)


def wrapped_phase_figure(
    phase: ArrayLike,
    out_png: str | os.PathLike[str],
    *,
    pitch_mm: float | None = None,
    title: str | None = "Wrapped phase",
    figsize: tuple[float, float] = (6.4, 4.8),
    dpi: int = 150,
) -> Path:
    """Wrapped phase with the cyclic ``twilight`` colour map over [0, 2 pi) (Fig. 10 c).

    Parameters
    ----------
    phase : array_like, shape (H, W)
        Phase in radians (any range; shown modulo 2 pi), NaN where invalid.
    out_png : path-like
        Output PNG.
    pitch_mm : float, optional
        If given, axes in mm; otherwise in pixels.
    title : str, optional
    figsize : (float, float), default (6.4, 4.8)
    dpi : int, default 150

    Returns
    -------
    pathlib.Path
        ``out_png``.
    """
    import matplotlib as mpl  # noqa: PLC0415

    ph = _as_map(phase, "phase")
    two_pi = 2.0 * np.pi
    fig = _new_figure(figsize)
    ax = fig.add_subplot()
    cm = mpl.colormaps["twilight"].with_extremes(bad="0.5")
    im = ax.imshow(
        np.ma.masked_invalid(np.mod(ph, two_pi)), cmap=cm, vmin=0.0, vmax=two_pi,
        extent=_image_extent(ph.shape, pitch_mm), interpolation="nearest", origin="upper",
    )  # fmt: skip
    unit = "mm" if pitch_mm is not None else "px"
    ax.set_xlabel(f"X ({unit})" if pitch_mm is not None else "u (px)")
    ax.set_ylabel(f"Y ({unit})" if pitch_mm is not None else "v (px)")
    ax.set_aspect("equal")
    if title:
        ax.set_title(title)
    cbar = fig.colorbar(im, ax=ax, label="Wrapped phase (rad)")
    cbar.set_ticks([0.0, np.pi / 2, np.pi, 1.5 * np.pi, two_pi], labels=["0", "π/2", "π", "3π/2", "2π"])
    return _save_figure(fig, out_png, dpi)


def profile_figure(
    height: ArrayLike,
    row: int,
    pitch_mm: float,
    out_png: str | os.PathLike[str],
    *,
    reference: ArrayLike | None = None,
    reference_label: str = "reference",
    title: str | None = None,
    ylim: tuple[float, float] | None = None,
    figsize: tuple[float, float] = (6.4, 3.6),
    dpi: int = 150,
) -> Path:
    """Cross-section of a height map along one image row (Fig. 9 d).

    Parameters
    ----------
    height : array_like, shape (H, W)
        Height in mm, NaN where invalid (gaps in the line).
    row : int
        Image row ``v`` (``Y = row * pitch``); negative values count from the end.
    pitch_mm : float
        Pixel pitch; the abscissa is ``X = u * pitch`` in mm.
    out_png : path-like
        Output PNG.
    reference : array_like, shape (W,), optional
        A profile to overlay (e.g. the nominal or a ground-truth profile), dashed.
    reference_label : str, default "reference"
    title : str, optional
        Default ``"Profile"``; the row is always added (``"...\\nat image row v = 247 px
        (Y = 49.40 mm)"``) and also named on the X axis, so the figure says which row it cuts.
    ylim : (float, float), optional
        Height axis limits in mm.
    figsize : (float, float), default (6.4, 3.6)
    dpi : int, default 150

    Returns
    -------
    pathlib.Path
        ``out_png``.
    """
    h = _as_map(height, "height")
    H, W = h.shape
    if not -H <= row < H:
        raise IndexError(f"row {row} outside 0..{H - 1}")
    row = row % H
    x = np.arange(W) * float(pitch_mm)
    fig = _new_figure(figsize)
    ax = fig.add_subplot()
    ax.plot(x, h[row], lw=1.2, color="C0", label="measured")
    if reference is not None:
        ref = np.asarray(reference, dtype=np.float64)
        if ref.shape != (W,):
            raise ValueError(f"reference must have shape ({W},), got {ref.shape}")
        ax.plot(x, ref, lw=1.0, ls="--", color="C3", label=reference_label)
        ax.legend(loc="best")
    where = f"row v = {row} px (Y = {row * float(pitch_mm):.2f} mm)"
    ax.set_xlabel(f"X = u · pitch (mm), along image {where}")
    ax.set_ylabel("Height (mm)")
    ax.set_xlim(x[0], x[-1] if W > 1 else x[0] + 1.0)
    if ylim is not None:
        ax.set_ylim(*ylim)
    ax.grid(True, alpha=0.3)
    ax.set_title(f"Profile at image {where}" if title is None else f"{title}\nat image {where}", fontsize=10)
    return _save_figure(fig, out_png, dpi)


def uncertainty_map_figure(
    u: ArrayLike,
    pitch_mm: float,
    out_png: str | os.PathLike[str],
    *,
    title: str | None = "Height uncertainty",
    clim: tuple[float, float] | None = None,
    dpi: int = 150,
) -> Path:
    """Standard-uncertainty map (mm) beside the height figure: same axes, colour bar in µm.

    ``clim`` defaults to [0, 99th percentile] so a few edge pixels do not wash the map out;
    NaN (no height) is drawn light grey.
    """
    s = _as_map(u, "uncertainty") * 1000.0
    finite = s[np.isfinite(s)]
    if clim is None:
        clim = (0.0, float(np.percentile(finite, 99)) if finite.size else 1.0)
    else:
        clim = (clim[0] * 1000.0, clim[1] * 1000.0)
    return _map_figure(s, pitch_mm, out_png, cmap="magma", clim=clim, title=title, label="u (µm)",
                       figsize=(6.4, 4.8), dpi=dpi)


def reliability_figure(rel: Mapping[str, Any], out_png: str | os.PathLike[str], *, title: str | None = None,
                       dpi: int = 150) -> Path:
    """Reliability plot of a predicted uncertainty: observed rms error against predicted rms u per
    bin of u (:func:`huefringe.uncertainty.reliability`), with the line of perfect calibration."""
    bins = rel.get("bins", [])
    fig = _new_figure((5.2, 4.4))
    ax = fig.add_subplot()
    if bins:
        x = np.array([b["u_mm"] for b in bins]) * 1000
        y = np.array([b["observed_rms_mm"] for b in bins]) * 1000
        lo, hi = float(min(x.min(), y.min())) * 0.8, float(max(x.max(), y.max())) * 1.25
        ax.plot([lo, hi], [lo, hi], color="0.5", lw=1, label="observed = predicted")
        ax.plot(x, y, "o-", label="rms |error| per bin of u")
        if all("observed_p68_mm" in b for b in bins):
            ax.plot(x, np.array([b["observed_p68_mm"] for b in bins]) * 1000, "s--",
                    label="68th percentile of |error| (robust 1 sigma)")
        ax.set_xscale("log")
        ax.set_yscale("log")
    cov = rel.get("coverage_2u")
    ax.set_xlabel("predicted u (µm, rms in bin)")
    ax.set_ylabel("observed |error| in bin (µm)")
    ax.legend(title=None if cov is None else f"|error| ≤ 2u: {100 * cov:.1f} % of pixels", fontsize=8)
    if title:
        ax.set_title(title, fontsize=9)
    return _save_figure(fig, out_png, dpi)
