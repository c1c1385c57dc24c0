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
capture_patterns(config, patterns_dir, out_dir) -> Path
    Show a ``huefringe patterns`` folder's image files in manifest order and save one camera
    file per row (``IMG_0001.png`` ...), for ``huefringe session``.
preset_path(name) -> Path
    A packaged preset: ``demo``, ``flat``, ``dental``, ``table1``, ... and the structured-light
    rig sessions ``rig-poses``, ``rig-gauge``, ``rig-board``, ``rig-oneshot`` (one-shot colour frames),
    ``rig-oneshot-vibrating`` (the same scene vibrating while its one-shot frames are captured).
bench_kind(ref) -> str
    The session format a bench YAML or preset writes: ``capture-session/1``, or
    ``structured-light-session/1`` for ``format: huefringe-sl-bench/1`` (:mod:`.rig_session`).
load_sl_bench_config(ref), write_sl_session(config, out_dir), sl_session_plan(config)
    Structured-light sessions of the bench rig (calibration poses, object scenes with projector
    shadows, features.yaml, ground truth); the plan says what a session holds without writing.
code_phase, projector_ray_x0, analytic_phase_difference, simulate_capture, Bench, Pattern
    Lower-level pure pieces used by the tests.
colour_sequence.ColourSequence, colour_sequence.Shutter, colour_sequence.row_weights
    A colour-sequential (single-chip DLP) projector and the camera's global or rolling shutter:
    the per-row channel weights of an image (bench keys ``projector.colour_sequence``,
    ``camera.shutter``).

The measuring modules never import this package (design.md).
"""

from __future__ import annotations

import importlib
from typing import Any

from .config import (
    BenchConfigError,
    available_presets,
    bench_schema,
    load_bench_config,
    preset_path,
    sweep_config,
    validate_bench_config,
)

# The simulator's modules (NumPy/SciPy-heavy) load on first use, so that planning a workflow
# (huefringe.plan: configurations and presets only) does not pay for them.
_LAZY = {
    "Grid": "geometry", "analytic_phase_difference": "geometry", "cast_shadow_mask": "geometry",
    "code_phase": "geometry", "lambert_cosine": "geometry", "projector_ray_x0": "geometry",
    "triangulation_angle_deg": "geometry",
    "Pattern": "radiometry", "Rig": "radiometry", "camera_response": "radiometry", "dmd_levels": "radiometry",
    "emitted_rgb": "radiometry",
    "build_scene": "scenes",
    "ProjectionError": "projector", "capture_patterns": "projector", "image_placement": "projector",
    "Bench": "simulator", "noise_rng": "simulator", "simulate_capture": "simulator",
    "period_sweep": "writer", "rig_summary": "writer", "session_document": "writer", "write_session": "writer",
    "bench_kind": "rig_session", "features_from_truth": "rig_session", "load_sl_bench_config": "rig_session",
    "scene_truth": "rig_session", "sl_session_plan": "rig_session", "validate_sl_bench_config": "rig_session",
    "write_sl_session": "rig_session",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "Bench",
    "BenchConfigError",
    "Grid",
    "Pattern",
    "ProjectionError",
    "Rig",
    "analytic_phase_difference",
    "available_presets",
    "bench_kind",
    "bench_schema",
    "build_scene",
    "camera_response",
    "capture_patterns",
    "cast_shadow_mask",
    "code_phase",
    "dmd_levels",
    "emitted_rgb",
    "features_from_truth",
    "image_placement",
    "lambert_cosine",
    "load_bench_config",
    "load_sl_bench_config",
    "noise_rng",
    "period_sweep",
    "sweep_config",
    "preset_path",
    "projector_ray_x0",
    "rig_summary",
    "scene_truth",
    "session_document",
    "simulate_capture",
    "sl_session_plan",
    "triangulation_angle_deg",
    "validate_bench_config",
    "validate_sl_bench_config",
    "write_session",
    "write_sl_session",
]
