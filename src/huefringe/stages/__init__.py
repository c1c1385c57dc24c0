"""Workflow stages: each function is what one Snakemake script calls, once, and has its rule's name.

Rule ``NAME`` (in ``workflow/rules/<file>.smk``) runs ``scripts/NAME.py``, which calls
:func:`NAME` here (tests/test_stages.py checks it); each private module holds the stages of
one or two rule files (``_calibration``: ``bench``, ``calibration``; ``_measurement``; ``_surfaces``:
``surfaces``, ``metrology``; ``_archive``), ``_run`` the runners. Every stage reads its inputs, calls the library, and writes its outputs atomically;
the measuring ones call :mod:`huefringe.pipeline`, which :func:`huefringe.measure` calls too.
Nothing here is Snakemake-specific except :func:`run_from_snakemake`, the adapter the scripts use.
Each name is imported from its private module on first use, so a job's script loads only what
its stage needs.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the names as type checkers and editors see them; at run time __getattr__ imports them
    from ._archive import add_step_uncertainty, archive, archive_session  # noqa: F401
    from ._calibration import (  # noqa: F401
        bench_session, camera_calibration, check_session, compensation, hue_table, plane_calibration)
    from ._measurement import (  # noqa: F401
        accuracy_report, baseline_frames, cloud_frames, measure_frames, x3p_frames, xy_block)
    from ._rig import (  # noqa: F401
        rig_accuracy, rig_calibrate, rig_calibration_from, rig_measure, rig_metrology, rig_oneshot, rig_surfaces)
    from ._run import (  # noqa: F401
        RIG_OUTPUTS, calibrate_rig_session, log, measure_rig_session, measure_session, run_from_snakemake,
        stage_kwargs)
    from ._surfaces import _height_limits, _TiffMaps, metrology, mesh, render, table1  # noqa: F401

#: Each public name and the private module that defines it, imported on first use, so that a
#: job's script loads only its own stage's libraries (a measurement job neither Open3D nor trimesh).
_WHERE: dict[str, str] = {
    **dict.fromkeys(("bench_session", "camera_calibration", "check_session", "hue_table", "plane_calibration",
                     "compensation"), "_calibration"),
    **dict.fromkeys(("measure_frames", "cloud_frames", "x3p_frames", "baseline_frames", "accuracy_report",
                     "xy_block"), "_measurement"),
    **dict.fromkeys(("_height_limits", "mesh", "render", "metrology", "_TiffMaps", "table1"), "_surfaces"),
    **dict.fromkeys(("rig_accuracy", "rig_calibrate", "rig_calibration_from", "rig_measure", "rig_metrology",
                     "rig_oneshot", "rig_surfaces"), "_rig"),
    **dict.fromkeys(("add_step_uncertainty", "archive_session", "archive"), "_archive"),
    **dict.fromkeys(("log", "measure_session", "RIG_OUTPUTS", "calibrate_rig_session", "measure_rig_session",
                     "stage_kwargs", "run_from_snakemake"), "_run"),
}


def __getattr__(name: str) -> Any:
    """Import the module defining ``name`` on first use (PEP 562) and keep the name here."""
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_WHERE})


__all__ = [
    "rig_accuracy",
    "rig_calibrate",
    "rig_calibration_from",
    "rig_measure",
    "rig_metrology",
    "rig_oneshot",
    "rig_surfaces",
    "accuracy_report",
    "add_step_uncertainty",
    "archive",
    "archive_session",
    "baseline_frames",
    "bench_session",
    "camera_calibration",
    "check_session",
    "cloud_frames",
    "compensation",
    "hue_table",
    "measure_frames",
    "measure_session",
    "RIG_OUTPUTS",
    "calibrate_rig_session",
    "measure_rig_session",
    "mesh",
    "metrology",
    "plane_calibration",
    "render",
    "run_from_snakemake",
    "stage_kwargs",
    "table1",
    "x3p_frames",
    "xy_block",
]
