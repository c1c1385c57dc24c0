"""The virtual bench: a physically based simulator of the trapezoidal HSI fringe-projection rig.

It writes complete capture sessions (``capture-session/1``) with ground truth, from one bench
YAML file (schema: ``bench.schema.json`` in this package; presets: :func:`preset_path`).

Public API
----------
load_bench_config(path) -> dict
    Read, validate (unknown keys refused) and complete a bench YAML; raises
    :class:`BenchConfigError` naming the file and the problem.
write_session(config, out_dir, progress=False) -> Path
    Simulate and write one session folder (session.yaml last, atomically moved into place).
period_sweep(config, periods=(20, 40, 60, 80, 100), out_root) -> list[Path]
    The same bench at several fringe periods, ids suffixed ``-p20`` etc.
preset_path(name) -> Path
    A packaged preset: ``demo``, ``flat``, ``dental``, ``table1``.
code_phase, projector_ray_x0, analytic_phase_difference, simulate_capture, Bench, Pattern
    Lower-level pure pieces used by the tests.

The measuring modules never import this package (design.md).
"""

from __future__ import annotations

from .config import (
    BenchConfigError,
    available_presets,
    bench_schema,
    load_bench_config,
    preset_path,
    validate_bench_config,
)
from .geometry import (
    Grid,
    analytic_phase_difference,
    cast_shadow_mask,
    code_phase,
    lambert_cosine,
    projector_ray_x0,
    triangulation_angle_deg,
)
from .radiometry import Pattern, Rig, camera_response, dmd_levels, emitted_rgb
from .scenes import build_scene
from .simulator import Bench, noise_rng, simulate_capture
from .writer import period_sweep, rig_summary, session_document, sweep_config, write_session

__all__ = [
    "Bench",
    "BenchConfigError",
    "Grid",
    "Pattern",
    "Rig",
    "analytic_phase_difference",
    "available_presets",
    "bench_schema",
    "build_scene",
    "camera_response",
    "cast_shadow_mask",
    "code_phase",
    "dmd_levels",
    "emitted_rgb",
    "lambert_cosine",
    "load_bench_config",
    "noise_rng",
    "period_sweep",
    "sweep_config",
    "preset_path",
    "projector_ray_x0",
    "rig_summary",
    "session_document",
    "simulate_capture",
    "triangulation_angle_deg",
    "validate_bench_config",
    "write_session",
]
