"""The archive stages (``workflow/rules/archive.smk``): the step uncertainty added to the report, the session's archive and the archive index."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe.archive import ArchiveError, archive_index, verify_archive, write_archive
from huefringe.camera import CameraModel
from huefringe.height import PlaneCalibration
from huefringe.huetable import HueTable
from huefringe.io import write_json
from huefringe.uncertainty import conformance, pixel_budget, step_budget

log = logging.getLogger("huefringe")


# ------------------------------------------------- workflow/rules/archive.smk


def add_step_uncertainty(method: dict[str, Any], heights: Sequence[NDArray[np.floating]],
                         uncertainties: Sequence[NDArray[np.floating]], specimen: Mapping[str, Any], pitch_mm: float,
                         cal: PlaneCalibration, table: HueTable, *, edge_exclusion: float, denoise_radius: int,
                         supports: Sequence[NDArray[np.floating]] | None = None, workers: int = 1,
                         camera: CameraModel | None = None, lateral_px: float,
                         lateral_step_px: float) -> None:
    """Add ``u_mm``, ``U_mm`` (k = 2), ``conformance`` and ``uncertainty_budget`` to each step of an
    :func:`huefringe.metrology.evaluate_session` block, and ``verdict_with_uncertainty`` to the block.

    ``pass`` stays ``|error| <= tolerance`` (the contract); ``conformance`` is the ISO 14253-1
    decision with U: ``pass``, ``fail`` or ``undecided``. ``camera``: the lens model the steps were
    evaluated with (the budget's plane lever arms at each pixel's X, Y); ``lateral_px``: the
    ``measurement.lateral_uncertainty_px`` the maps were made with, ``lateral_step_px`` its
    ``measurement.lateral_step_px`` (the budget takes the lateral term out).
    """
    budgets = step_budget(heights, uncertainties, specimen, pitch_mm, cal.a, cal.b, pixel_budget(table, cal),
                              edge_exclusion=edge_exclusion, denoise_radius=denoise_radius, supports=supports,
                              workers=workers, camera=camera, lateral_px=lateral_px,
                              lateral_step_px=lateral_step_px)
    tol = float(method["tolerance_mm"])
    for step, bud in zip(method["steps"], budgets, strict=True):
        step["u_mm"] = bud["u_mm"]
        step["U_mm"] = bud["U_mm"]
        step["conformance"] = conformance(step["error_mm"], tol, bud["U_mm"])
        step["uncertainty_budget"] = {k: v for k, v in bud.items() if k not in ("name", "u_mm", "U_mm")}
    zones = {st["conformance"] for st in method["steps"]}
    method["verdict_with_uncertainty"] = "FAIL" if "fail" in zones else ("UNDECIDED" if "undecided" in zones else "PASS")


def archive_session(session: str, results: str, config: Mapping[str, Any], archive: str) -> None:
    """Pack a session and its results with RO-Crate metadata, then read the archive back once."""
    write_archive(session, results, archive, config=dict(config))
    check = verify_archive(archive)
    if not check.ok:
        raise ArchiveError(check.summary())
    log.info("%s", check.summary())


def archive(archives: Sequence[str], index: str) -> None:
    """The run's archives in one index (``results/archives.json``): size and SHA-256 of each ZIP
    and its crate's summary (:func:`huefringe.archive.archive_index`)."""
    table = archive_index(list(archives))
    write_json(index, table)
    log.info("%d archives, %d bytes", len(table["archives"]), sum(r["bytes"] for r in table["archives"]))
