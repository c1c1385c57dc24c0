"""The bench and calibration stages (``workflow/rules/bench.smk``, ``calibration.smk``): a bench session, the camera record, the session check, the hue table, the plane calibration, the pattern compensation."""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from huefringe.colour import hue as hue_of
from huefringe.colour import white_balance
from huefringe.compensation import compensate_pattern, hue_cross_section_figure, qa_stats, residual_map_figure
from huefringe.height import PlaneCalibration
from huefringe.huetable import HueTable
from huefringe.io import write_json, write_png_rgb
from huefringe.phase import wrap
from huefringe.pipeline import session_camera_record, session_corrections, session_hue_table, session_plane_calibration
from huefringe.session import load_session

log = logging.getLogger("huefringe")


# --------------------------------------------------- workflow/rules/bench.smk


def bench_session(config: str, out: str, period_px: float | None = None) -> None:
    """Write a session with the virtual bench (a preset or bench YAML): a capture session
    (optionally at another period), or for ``format: huefringe-sl-bench/1`` a structured-light
    session of the bench rig (:func:`huefringe.bench.write_sl_session`)."""
    from huefringe import bench
    from huefringe.plan import bench_config_for, bench_yaml

    path = bench_yaml(config)
    if bench.bench_kind(path) == "structured-light-session/1":
        if period_px is not None:
            raise ValueError(f"{config}: a structured-light bench session has no period sweep")
        bench.write_sl_session(bench.load_sl_bench_config(path), Path(out))
        return
    bench.write_session(bench_config_for(config, period_px=period_px), Path(out), progress=False)


# --------------------------------------------- workflow/rules/calibration.smk


def camera_calibration(session: str, camera: Mapping[str, Any], calibration: Mapping[str, Any], record: str) -> None:
    """The camera corrections of a session (``calib/camera.json``): the X, Y model (the session's
    ``camera`` block, or telecentric with ``camera.lens_model: false``) and the lateral
    chromatic-aberration estimate from the reference planes, applied as
    ``camera.chromatic_registration`` decides (:func:`huefringe.camera.camera_record`)."""
    s = load_session(session)
    t0 = time.perf_counter()
    rec = session_camera_record(s, camera, calibration)
    reg = rec["chromatic_registration"]
    if "estimate" in reg:
        est = reg["estimate"]
        log.info("lateral CA: R %+.2e, B %+.2e (corner %.3f / %.3f px), registration %s", est["scale"]["R"],
                 est["scale"]["B"], est["corner_displacement_px"]["R"], est["corner_displacement_px"]["B"],
                 "applied" if reg["applied"] else "not applied")
    write_json(record, rec)  # no timing in it: the same session and config give the same file
    log.info("camera corrections estimated in %.2f s", time.perf_counter() - t0)



def check_session(session: str, summary: str) -> None:
    """Deep-validate a session (decode every image) and write a summary."""
    s = load_session(session, deep=True)
    write_json(
        summary,
        {
            "session": s.id,
            "root": str(s.root),
            "size": [s.width, s.height],
            "bit_depth": s.bit_depth,
            "frames": len(s.frames),
            "phase_shift": len(s.phase_shift),
            "ground_truth": len(s.ground_truth),
            "files": len(s.input_files()),
            "ok": True,
        },
    )


def hue_table(session: str, which: str, hue_model: str, calibration: Mapping[str, Any],
              table: str, stats: str, camera_json: str = "") -> None:
    """Build the per-pixel hue table of the reference plate or of the object (streamed)."""
    s = load_session(session)
    t0 = time.perf_counter()
    built = session_hue_table(s, which, hue_model, calibration, reader=session_corrections(s, camera_json)[1])
    built.save(table)
    info = dict(built.stats)
    info.update({"which": which, "hue_model": hue_model})
    write_json(stats, info)
    log.info("%s table built in %.2f s", which, time.perf_counter() - t0)


def plane_calibration(session: str, table: str, hue_model: str, calibration: Mapping[str, Any],
                      model: str, stats: str, phase_error_table: str | None = None,
                      phase_error_figure: str | None = None, phase_error_summary: str | None = None,
                      camera_json: str = "", object_table: str | None = None) -> None:
    """Fit the per-pixel phase-to-height model on the calibration planes (after the phase-error
    table, :mod:`huefringe.phase_error`, as ``calibration.phase_error.enabled`` decides; auto: the
    leave-one-plane-out test), and record the camera blur of the texture-edge correction
    (``calibration.texture_blur_px2``; ``auto`` estimates it from the object frames with
    ``object_table``: :func:`session_texture_blur`)."""
    s = load_session(session)
    cal = session_plane_calibration(s, HueTable.load(table), hue_model, calibration,
                                    phase_error_table=phase_error_table, phase_error_figure=phase_error_figure,
                                    phase_error_summary=phase_error_summary,
                                    reader=session_corrections(s, camera_json)[1],
                                    object_table=None if object_table is None else HueTable.load(object_table))
    cal.save(model)
    info = dict(cal.stats)
    info["hue_model"] = hue_model
    write_json(stats, info)


def compensation(session: str, table: str, model: str, hue_model: str, calibration: Mapping[str, Any],
                 pattern: str, history: str, cross_section: str, residual_map: str, camera_json: str = "") -> None:
    """Pre-distorted projector pattern (paper Fig. 6) and the calibration QA figures (Fig. 7)."""
    s = load_session(session)
    t = HueTable.load(table)
    cal = PlaneCalibration.load(model)
    comp = calibration["compensation"]
    image, steps = compensate_pattern(
        t,
        period_px_projector=comp["period_px"],
        projector_size=(comp["projector_width"], comp["projector_height"]),
        threshold_rad=comp["threshold_rad"],
        max_iter=comp["max_iter"],
        gain=comp["gain"],
    )
    write_png_rgb(pattern, image)
    # QA on the reference plane z = 0: raw hue and corrected phase against the plate's phase model
    reader = session_corrections(s, camera_json)[1]
    white = reader.rgb(s.reference_white)
    balanced = white_balance(reader.rgb(s.planes[0.0]), white)
    hue = hue_of(balanced, hue_model, min_saturation=calibration["min_saturation"])
    phase = t.to_phase(hue)
    if s.predistortion is not None:
        phase = s.predistortion.decode(phase)
    truth = cal.phi_ref.astype(np.float64)
    row = s.height // 2
    hue_cross_section_figure(hue[row], phase[row], truth[row], cross_section)
    residual_map_figure(wrap(phase - truth), residual_map)
    qa = qa_stats(hue, phase, true_phase=truth, table=t, raw_rgb=balanced)
    write_json(history, {"hue_model": hue_model, "history": steps, "qa_reference_plane": qa,
                             "predistorted_session": s.predistortion is not None,
                             "pattern_size": [comp["projector_width"], comp["projector_height"]],
                             "period_px_projector": comp["period_px"]})
