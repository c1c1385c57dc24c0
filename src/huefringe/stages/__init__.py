"""Workflow stages: each function is what one Snakemake script calls, once, and has its rule's name.

Rule ``NAME`` (in ``workflow/rules/<file>.smk``) runs ``scripts/NAME.py``, which calls
:func:`NAME` here (tests/test_stages.py checks it); each private module holds the stages of
one or two rule files (``_calibration``: ``bench``, ``calibration``; ``_measurement``; ``_surfaces``:
``surfaces``, ``metrology``; ``_archive``), ``_run`` the runners. Every stage reads its inputs, calls the library, and writes its outputs atomically;
the measuring ones call :mod:`huefringe.pipeline`, which :func:`huefringe.measure` calls too.
Nothing here is Snakemake-specific except :func:`run_from_snakemake`, the adapter the scripts use.
"""

from __future__ import annotations

from ._calibration import (  # noqa: F401
    bench_session,
    camera_calibration,
    check_session,
    hue_table,
    plane_calibration,
    compensation,
)
from ._measurement import (  # noqa: F401
    measure_frames,
    cloud_frames,
    x3p_frames,
    baseline_frames,
    accuracy_report,
    xy_block,
)
from ._surfaces import (  # noqa: F401
    _height_limits,
    mesh,
    render,
    metrology,
    _TiffMaps,
    table1,
)
from ._rig import (  # noqa: F401
    rig_accuracy,
    rig_calibrate,
    rig_calibration_from,
    rig_measure,
    rig_metrology,
    rig_oneshot,
    rig_surfaces,
)
from ._archive import (  # noqa: F401
    add_step_uncertainty,
    archive_session,
    archive,
)
from ._run import (  # noqa: F401
    log,
    measure_session,
    RIG_OUTPUTS,
    calibrate_rig_session,
    measure_rig_session,
    stage_kwargs,
    run_from_snakemake,
)

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
