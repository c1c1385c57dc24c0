"""Triangle meshes from height maps: grid triangulation without bridging jumps, clean-up, export.

A height map is a float32 ``(H, W)`` array in mm, NaN where invalid; pixel ``(v, u)`` is the
vertex ``(u * pitch, v * pitch, height[v, u])`` (telecentric camera, see ``docs/design.md``).

Triangulation
-------------
Every 2x2 block of pixels (a *quad*) with corners ``a = (v, u)``, ``b = (v, u+1)``,
``c = (v+1, u+1)``, ``d = (v+1, u)`` gives the two triangles ``(a, b, c)`` and ``(a, c, d)``
(fixed diagonal a-c; both wind counter-clockwise seen from +Z, so normals point towards the
camera). A triangle is kept only if its three heights are finite **and** its height span
``max(z) - min(z)`` is strictly below the jump threshold, so no face ever touches an invalid
pixel or bridges a height discontinuity. Only vertices used by a kept face are stored, in
row-major pixel order, and faces are ordered by quad then triangle.

Jump threshold
--------------
Unless ``jump_mm`` is given, :func:`jump_threshold` sets ::

    jump_mm = noise_k * noise_mm + max_slope * sqrt(2) * pitch_mm        (defaults 8, 1.0)

The second term is the largest span a *smooth* surface of slope ``max_slope`` (dz/dx; 1.0 is
45 degrees) produces over a triangle, whose longest side is the quad diagonal ``sqrt(2)
pitch``. The first bounds the span of three noisy samples: for Gaussian noise the range of
three samples exceeds 8 sigma with probability about 5e-8, i.e. well under one spurious break
per 10 million faces. ``noise_mm`` (one-sigma height noise) is estimated from the map itself by
:func:`estimate_noise` when not given. Steps lower than ``jump_mm`` are meshed as steep walls;
steps higher are left open.

Examples
--------
>>> m = height_to_mesh(height, 0.2, colours=white)            # doctest: +SKIP
>>> m = clean_mesh(m, min_island_faces=100)                    # doctest: +SKIP
>>> stats = export_mesh(m, "mesh/frame_0000.ply")              # doctest: +SKIP
"""

from __future__ import annotations

from ._build import (  # noqa: F401
    _MAD_TO_SIGMA,
    estimate_noise,
    jump_threshold,
    height_to_mesh,
    place_vertices,
    attach_sigma,
    vertex_pixels,
)
from ._clean import (  # noqa: F401
    to_open3d,
    from_open3d,
    clean_mesh,
    _corner_labels,
    non_manifold_vertices,
    split_pinch_vertices,
    decimate,
    _edge_tables,
    _face_labels,
    _face_components,
)
from ._stats import (  # noqa: F401
    boundary_loops,
    _cycle_rank,
    mesh_stats,
    stats_path,
    export_mesh,
)

__all__ = [
    "attach_sigma",
    "boundary_loops",
    "clean_mesh",
    "decimate",
    "estimate_noise",
    "export_mesh",
    "from_open3d",
    "height_to_mesh",
    "jump_threshold",
    "mesh_stats",
    "non_manifold_vertices",
    "split_pinch_vertices",
    "stats_path",
    "to_open3d",
    "vertex_pixels",
]
