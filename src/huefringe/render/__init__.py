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

from ._views import (  # noqa: F401
    VIEW_ANGLES,
    DEFAULT_VIEWS,
    DISPLAY_MIRROR_Y,
    _FIT_X_WITH_BAR,
    _FIT_X_NO_BAR,
    _FIT_Y,
    _configure_vtk_backend,
    _pyvista,
    _to_display,
    Camera,
    _view_basis,
    camera_for_field,
    mesh_to_polydata,
    _as_trimesh,
    render_views,
)
from ._figures import (  # noqa: F401
    _as_map,
    _new_figure,
    _save_figure,
    _image_extent,
    height_map_figure,
    _map_figure,
    wrapped_phase_figure,
    profile_figure,
    uncertainty_map_figure,
    reliability_figure,
)

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
