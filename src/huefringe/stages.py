"""Workflow stages: each function is what one Snakemake script calls, once, and has its rule's name.

Rule ``NAME`` (in ``workflow/rules/<file>.smk``) runs ``scripts/NAME.py``, which calls
:func:`NAME` here (tests/test_stages.py checks it); the stages are in the order of the rule files,
one section per file (``bench``, ``calibration``, ``measurement``, ``surfaces``, ``metrology``,
``archive``). Every stage reads its inputs, calls the library, and writes its outputs atomically;
the measuring ones call :mod:`huefringe.pipeline`, which :func:`huefringe.measure` calls too.
Nothing here is Snakemake-specific except :func:`run_from_snakemake`, the adapter the scripts use.
"""

from __future__ import annotations

import inspect
import json as jsonlib
import logging
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray

from huefringe.archive import ArchiveError, archive_index, verify_archive, write_archive
from huefringe import uncertainty
from huefringe.camera import CameraModel
from huefringe.cloud import check_colours, colour_bytes, write_height_cloud
from huefringe.colour import hue as hue_of
from huefringe.colour import intensity, white_balance
from huefringe.compensation import compensate_pattern, hue_cross_section_figure, qa_stats, residual_map_figure
from huefringe.height import PlaneCalibration, PlaneCalibrationError, accuracy, coverage, xy_accuracy
from huefringe.huetable import HueTable, HueTableError
from huefringe.io import read_tiff, remove_stale_parts, write_json, write_png_rgb, write_tiff
from huefringe.mesh import attach_sigma, clean_mesh, decimate, export_mesh, height_to_mesh, place_vertices, stats_path
from huefringe.metrology import MetrologyError, evaluate_session
from huefringe.perframe import FrameError, shadow_mask
from huefringe.phase import three_step_phase, unwrap, wrap
from huefringe.pipeline import (frame_results, session_camera_record, session_corrections, session_hue_table,
                                session_plane_calibration)
from huefringe.render import (camera_for_field, height_map_figure, profile_figure, reliability_figure, render_views,
                              uncertainty_map_figure, wrapped_phase_figure)
from huefringe.report import build_report_json, collect_provenance, per_frame_figure, write_report_html
from huefringe.session import Session, SessionError, load_session
from huefringe.settings import software_identity
from huefringe.uncertainty import conformance, pixel_budget, step_budget
from huefringe.table1 import table1_rows, write_table1
from huefringe.x3p import X3PError, write_height_x3p

log = logging.getLogger("huefringe")


# --------------------------------------------------- workflow/rules/bench.smk


def bench_session(config: str, out: str, period_px: float | None = None) -> None:
    """Write a capture session with the virtual bench (a preset or bench YAML, optionally at another period)."""
    from huefringe import bench
    from huefringe.plan import bench_config_for

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


# --------------------------------------------- workflow/rules/measurement.smk


def measure_frames(session: str, frames: Sequence[int], table: str, model: str, hue_model: str,
                   measurement: Mapping[str, Any], calibration: Mapping[str, Any],
                   heights: Sequence[str], qa: Sequence[str], phases: Sequence[str] = (),
                   hues: Sequence[str] = (), map_frames: Sequence[int] | None = None,
                   uncertainties: Sequence[str] = (), supports: Sequence[str] = (), camera_json: str = "") -> None:
    """Measure a batch of frames: height TIFF and QA JSON per frame, phase and hue maps of some.

    Parameters
    ----------
    heights, qa : sequence of str
        One height TIFF and one QA JSON per frame of ``frames``.
    phases, hues : sequence of str
        Phase and hue map TIFFs of the frames in ``map_frames`` (in that order).
    map_frames : sequence of int, optional
        The frames whose maps are written (the workflow: those it renders, or all with
        ``measurement.maps: all``); default: every frame of ``frames``.
    uncertainties : sequence of str
        One standard-uncertainty TIFF (mm, NaN where the height is NaN;
        :mod:`huefringe.uncertainty`) per frame of ``frames``, or none.
    supports : sequence of str
        One uint16 TIFF per frame (with ``uncertainties``): how many raw pixels the phase filter
        averaged into each height (0 where the height is NaN), which the step budget needs
        (:func:`huefringe.uncertainty.step_budget`).

    The coloured point clouds are written from the height TIFFs by :func:`cloud_frames`, a stage
    (and workflow job) of its own.

    With ``measurement.kernel`` (and reference-relative unwrapping) each frame goes through the
    fused kernel (:mod:`huefringe.kernel`), prepared once per batch; it gives the same heights as
    :func:`measure_frame`, the reference implementation used otherwise (the QA flags come from
    the kernel's float32 phase difference instead of a float64 one).
    """
    map_frames = list(frames) if map_frames is None else list(map_frames)
    if len(phases) != len(map_frames) or len(hues) != len(map_frames):
        raise ValueError(f"measure_frames: {len(map_frames)} map frames, {len(phases)} phase and {len(hues)} hue maps")
    maps = {n: (phases[k], hues[k]) for k, n in enumerate(map_frames)}
    if not set(maps) <= set(frames):
        raise ValueError(f"measure_frames: map frames {sorted(set(maps) - set(frames))} are not in the batch")
    if uncertainties and len(uncertainties) != len(frames):
        raise ValueError(f"measure_frames: {len(frames)} frames, {len(uncertainties)} uncertainty maps")
    if supports and len(supports) != len(uncertainties):
        raise ValueError(f"measure_frames: {len(uncertainties)} uncertainty maps, {len(supports)} support maps")
    s = load_session(session)
    results = frame_results(s, HueTable.load(table), PlaneCalibration.load(model), frames, hue_model, measurement,
                            set(maps), want_uncertainty=bool(uncertainties), reader=session_corrections(s, camera_json)[1])
    for i, r in enumerate(results):
        n = r.frame
        write_tiff(heights[i], r.height, pixel_pitch_mm=s.pixel_pitch_mm)
        if uncertainties:
            write_tiff(uncertainties[i], r.uncertainty, pixel_pitch_mm=s.pixel_pitch_mm)
        if supports:
            write_tiff(supports[i], np.rint(r.support).astype(np.uint16))
        if n in maps:
            write_tiff(maps[n][0], r.phase)
            write_tiff(maps[n][1], r.hue)
        write_json(qa[i], {"frame": n, "file": str(s.frames[n]), **r.stats})
        log.info("frame %04d: %.1f %% valid, median %.3f mm", n, 100 * r.stats["valid_fraction"],
                 r.stats["median_height_mm"] or float("nan"))


def cloud_frames(session: str, frames: Sequence[int], heights: Sequence[str], clouds: Sequence[str],
                 uncertainties: Sequence[str] = (), camera_json: str = "") -> None:
    """Coloured point clouds of a batch of measured frames, from their height TIFFs.

    Parameters
    ----------
    session : str
        Session folder; gives the pixel pitch and the object's white image (the colours, read
        once per batch).
    frames : sequence of int
        Frame numbers of the batch (for the log only).
    heights : sequence of str
        Height TIFFs written by :func:`measure_frames`, one per frame, in the order of ``frames``.
    clouds : sequence of str
        Target ``.ply`` files, one per frame, written atomically by
        :func:`huefringe.cloud.write_height_cloud` (the bytes Open3D would write).
    uncertainties : sequence of str, optional
        The frames' uncertainty TIFFs: each point then carries a float ``sigma_mm`` property.
    camera_json : str, optional
        ``calib/camera.json`` (:func:`camera_calibration`): the X, Y model (each pixel at its own
        height for a pinhole camera) and the reader of the white image; default: the session's.

    Raises
    ------
    ValueError
        If ``frames``, ``heights`` and ``clouds`` differ in length, or a height map does not
        match the white image's size.
    """
    if not len(frames) == len(heights) == len(clouds):
        raise ValueError(f"cloud_frames: {len(frames)} frames, {len(heights)} height maps, {len(clouds)} clouds")
    s = load_session(session)
    model, reader = session_corrections(s, camera_json)
    white = reader.rgb(s.object_white)
    if uncertainties and len(uncertainties) != len(frames):
        raise ValueError(f"cloud_frames: {len(frames)} frames, {len(uncertainties)} uncertainty maps")
    rgb = colour_bytes(check_colours(white, white.shape[:2]).reshape(-1, 3))  # once per batch
    for i, (n, height, cloud) in enumerate(zip(frames, heights, clouds, strict=True)):
        h = read_tiff(height)
        if h.shape != white.shape[:2]:
            raise ValueError(f"{height}: height map {h.shape} does not match the white image {white.shape[:2]}")
        scalars = {"sigma_mm": read_tiff(uncertainties[i])} if uncertainties else None
        xy = None if model.plain else model.xy(h)
        points = write_height_cloud(cloud, h, s.pixel_pitch_mm, colours=rgb, scalars=scalars, xy=xy)
        log.info("frame %04d: %d points", n, points)


def x3p_frames(session: str, frames: Sequence[int], heights: Sequence[str], x3p: Sequence[str]) -> None:
    """X3P files (ISO 25178-72) of a batch of measured frames, from their height TIFFs.

    Parameters
    ----------
    session : str
        Session folder; gives the pixel pitch (the increments), the id and the provenance block
        (the record's date, operator and instrument).
    frames : sequence of int
        Frame numbers of the batch (named in each record's comment).
    heights : sequence of str
        Height TIFFs written by :func:`measure_frames`, in the order of ``frames``.
    x3p : sequence of str
        Target ``.x3p`` files, one per frame, written atomically by
        :func:`huefringe.x3p.write_height_x3p`.

    Raises
    ------
    ValueError
        If ``frames``, ``heights`` and ``x3p`` differ in length.
    X3PError
        If a map cannot be written (the message names the file).
    """
    if not len(frames) == len(heights) == len(x3p):
        raise ValueError(f"x3p_frames: {len(frames)} frames, {len(heights)} height maps, {len(x3p)} X3P files")
    s = load_session(session)
    software = software_identity()
    for n, height, out in zip(frames, heights, x3p, strict=True):
        t0 = time.perf_counter()
        write_height_x3p(out, read_tiff(height), s.pixel_pitch_mm, provenance=s.provenance, session_id=s.id,
                         frame=n, software=software)
        log.info("frame %04d: %s, %d bytes, %.3f s", n, out, Path(out).stat().st_size, time.perf_counter() - t0)


def baseline_frames(session: str, frames: Sequence[int], model: str, object_table: str,
                    measurement: Mapping[str, Any], heights: Sequence[str], qa: Sequence[str],
                    min_modulation: float = 0.1, camera_json: str = "") -> None:
    """Traditional three-step phase shifting through the same plane calibration."""
    s = load_session(session)
    cal = PlaneCalibration.load(model)
    reader = session_corrections(s, camera_json)[1]
    white = reader.rgb(s.object_white)
    shadow = shadow_mask(white, measurement["shadow_fraction"])
    for i, n in enumerate(frames):
        imgs = [intensity(reader.rgb(p)) for p in s.phase_shift[n]]
        phi, mod = three_step_phase(*imgs)
        valid = (mod > min_modulation) & ~shadow
        un = unwrap(wrap(phi.astype(np.float64) - cal.phi_ref), valid, measurement["unwrap"])
        h = cal.height(un.dphi)
        h = np.where(valid & np.isfinite(h), h, np.nan).astype(np.float32)
        write_tiff(heights[i], h, pixel_pitch_mm=s.pixel_pitch_mm)
        write_json(qa[i], {"frame": n, "method": "three-step-phase-shift", "valid_fraction": float(np.isfinite(h).mean()),
                           "median_modulation": float(np.median(mod))})


def accuracy_report(session: str, heights: Sequence[str], baseline: Sequence[str], report: str,
                    measurement: Mapping[str, Any], uncertainties: Sequence[str] = (), reliability: str = "",
                    camera_json: str = "") -> None:
    """Height error against the bench's ground truth, for the method and the baseline.

    Where the session holds X/Y ground truth (``ground_truth/xy``), the method's block gains
    ``xy``: the cloud's X, Y (the lens model of ``camera_json`` at each measured height) against
    it, per frame and averaged (:func:`huefringe.height.xy_accuracy`).

    With ``uncertainties`` the method's block gains ``uncertainty``: the fraction of the valid
    pixels with ``|error| <= 2 u`` (per frame and pooled) and the binned reliability curve
    (:func:`huefringe.uncertainty.reliability`), drawn to ``reliability`` (PNG).
    """
    s = load_session(session)
    lens, reader = session_corrections(s, camera_json)
    lit = ~shadow_mask(reader.rgb(s.object_white), measurement["shadow_fraction"])

    def block(paths: Sequence[str], frames: Sequence[int]) -> dict[str, Any]:
        per = []
        for p, n in zip(paths, frames, strict=True):
            truth = read_tiff(s.ground_truth[n])
            h = read_tiff(p)
            a = accuracy(h, truth)
            a["coverage_lit"] = coverage(h, truth, region=lit)
            a["frame"] = n
            per.append(a)
        keys = ["rms_mm", "median_abs_mm", "p95_abs_mm", "coverage", "coverage_lit"]
        summary = {k: float(np.mean([f[k] for f in per])) for k in keys}
        return {"summary": summary, "per_frame": per}

    out: dict[str, Any] = {"session": s.id, "method": "trapezoidal-hsi", "trapezoidal-hsi": block(heights, s.frame_ids)}
    if uncertainties:
        errs, us, per = [], [], []
        for p, q, n in zip(heights, uncertainties, s.frame_ids, strict=True):
            e = (read_tiff(p).astype(np.float64) - read_tiff(s.ground_truth[n]))
            u = read_tiff(q).astype(np.float64)
            r = uncertainty.reliability(e, u)
            per.append({"frame": n, "coverage_2u": r["coverage_2u"], "rms_u_mm": r.get("rms_u_mm")})
            errs.append(e.ravel())
            us.append(u.ravel())
        pooled = uncertainty.reliability(np.concatenate(errs), np.concatenate(us))
        pooled["per_frame"] = per
        out["trapezoidal-hsi"]["uncertainty"] = pooled
        if reliability:
            reliability_figure(pooled, reliability, title=f"{s.id}: observed error against predicted u")
    if s.ground_truth_xy:
        out["trapezoidal-hsi"]["xy"] = xy_block(s, lens, heights)
    if baseline:
        out["three-step-phase-shift"] = block(baseline, sorted(s.phase_shift))
    write_json(report, out)


def xy_block(s: Session, model: CameraModel, heights: Sequence[str]) -> dict[str, Any]:
    """X, Y of the measured clouds against the session's X/Y ground truth: per frame and the mean
    (:func:`huefringe.height.xy_accuracy`; ``model`` the X, Y model the clouds were written with)."""
    per = []
    for p, n in zip(heights, s.frame_ids, strict=True):
        if n not in s.ground_truth_xy:
            continue
        x, y = model.xy(read_tiff(p))
        a: dict[str, Any] = {k: (None if np.isnan(v) else v) for k, v in
                             xy_accuracy(x, y, read_tiff(s.ground_truth_xy[n])).items()}  # JSON: no NaN
        a["frame"] = n
        per.append(a)
    keys = [k for k in per[0] if k != "frame"] if per else []
    summary = {}
    for k in keys:
        vals = [f[k] for f in per if f[k] is not None]
        summary[k] = float(np.mean(vals)) if vals else None
    return {"model": model.kind if not model.plain else "telecentric (u * pitch)", "summary": summary,
            "per_frame": per}


# ------------------------------------------------ workflow/rules/surfaces.smk


def _height_limits(s: Session) -> tuple[float, float]:
    """Colour limits shared by every frame of a session: the calibrated depth range."""
    return (min(0.0, min(s.planes_mm)), max(s.planes_mm))


def mesh(session: str, height: str, mesh: Mapping[str, Any], ply: str, stl: str, stats: str,
         uncertainty: str | None = None, camera_json: str = "") -> None:
    """Triangle mesh of one height map (no bridging of jumps), cleaned, exported as PLY + STL; the
    PLY's vertices carry ``sigma_mm`` from the uncertainty map (:func:`huefringe.mesh.attach_sigma`)."""
    s = load_session(session)
    model, reader = session_corrections(s, camera_json)
    h = read_tiff(height)
    m = height_to_mesh(h, s.pixel_pitch_mm, colours=reader.rgb(s.object_white))
    m = clean_mesh(m, min_island_faces=mesh["min_island_faces"])
    if mesh["decimate_faces"]:
        m = decimate(m, mesh["decimate_faces"])
    if uncertainty is not None:
        attach_sigma(m, read_tiff(uncertainty), s.pixel_pitch_mm)
    if not model.plain:  # last: the steps above find pixels from u * pitch
        place_vertices(m, model.xy_at, s.pixel_pitch_mm)
    export_mesh(m, ply, stl)
    if stats_path(ply) != Path(stats):
        raise RuntimeError(f"mesh statistics went to {stats_path(ply)}, the workflow expects {stats}")


def render(session: str, mesh: str, height: str, phase: str, render: Mapping[str, Any], frame: str,
           top: str, oblique1: str, oblique2: str, height_map: str, phase_map: str,
           uncertainty: str = "", uncertainty_map: str = "", camera_json: str = "") -> None:
    """Off-screen renders (top and two oblique views) and the height and phase figures of one frame
    (and, given the frame's ``uncertainty`` TIFF, the uncertainty figure beside the height's)."""
    s = load_session(session)
    size = (int(render["width"]), int(render["height"]))
    clim = _height_limits(s)
    model = session_corrections(s, camera_json)[0]
    if model.plain:
        cams = camera_for_field((s.width - 1) * s.pixel_pitch_mm, (s.height - 1) * s.pixel_pitch_mm, clim,
                                          size=size)
    else:  # the lens model's field on the plate (the mesh's vertices are in its X, Y)
        x0, x1, y0, y1 = model.field_mm()
        cams = camera_for_field(x1 - x0, y1 - y0, clim, origin=(x0, y0), size=size)
    m = trimesh.load(mesh, process=False, force="mesh")
    out_dir = Path(top).parent
    written = render_views(m, out_dir, f"frame_{frame}", clim=clim, camera=cams, size=size,
                                     title=f"{s.id} frame {frame}")
    expected = {Path(top), Path(oblique1), Path(oblique2)}
    if not expected <= set(written):
        raise RuntimeError(f"render wrote {written}, expected {sorted(map(str, expected))}")
    height_map_figure(read_tiff(height), s.pixel_pitch_mm, height_map, clim=clim,
                                title=f"{s.id} frame {frame}: height (mm)")
    wrapped_phase_figure(read_tiff(phase), phase_map, pitch_mm=s.pixel_pitch_mm,
                                   title=f"{s.id} frame {frame}: corrected code phase")
    if uncertainty and uncertainty_map:
        uncertainty_map_figure(read_tiff(uncertainty), s.pixel_pitch_mm, uncertainty_map,
                                         title=f"{s.id} frame {frame}: height uncertainty u")


# ----------------------------------------------- workflow/rules/metrology.smk


def metrology(session: str, heights: Sequence[str], qa: Sequence[str], baseline: Sequence[str], planes: str, tables: str,
                     cross_section: str, render: str, height_map: str, accuracy: Sequence[str],
                     config: Mapping[str, Any], json: str, html: str, profile: str, per_frame: str,
                     uncertainties: Sequence[str] = (), model: str = "", object_table: str = "",
                     supports: Sequence[str] = (), threads: int = 1, camera_json: str = "") -> None:
    """Step-height metrology of every frame: report.json (results contract) and report.html.

    With ``uncertainties`` (one map per height map), the phase-to-height ``model`` and the
    ``object_table``, each step also gets ``u_mm``, ``U_mm``, its ISO 14253-1 ``conformance``
    and its ``uncertainty_budget`` (:func:`add_step_uncertainty`); ``supports`` (the filter's
    support maps, one per frame) give the budget each pixel's actual support (without them:
    the fixed window's). ``threads``: frames whose step budgets are computed at once.
    """
    s = load_session(session)
    spec = s.specimen
    if spec is None:
        raise ValueError(f"{s.root / 'session.yaml'}: no specimen block, nothing to evaluate")
    range_mm = max(s.planes_mm) - min(s.planes_mm)
    edge = float(config["metrology"]["edge_exclusion"])
    lens = session_corrections(s, camera_json)[0]

    def evaluate(paths: Sequence[str], **kw: Any) -> dict[str, Any]:
        try:
            # a generator: one height map in memory at a time (1000 frames held at once were
            # 1.2 GB, twice over with the profile's list: 2.5 GB peak)
            return evaluate_session((read_tiff(p) for p in paths), spec, s.pixel_pitch_mm,
                                              range_mm=range_mm, edge_exclusion=edge, camera=lens, **kw)
        except MetrologyError as exc:
            where = paths[exc.frame] if exc.frame is not None and exc.frame < len(paths) else s.root / "session.yaml"
            raise MetrologyError(f"{where}: {exc} (specimen in {s.root / 'session.yaml'})") from exc

    method = evaluate(heights)
    if uncertainties:
        add_step_uncertainty(method, _TiffMaps(heights), _TiffMaps(uncertainties), spec, s.pixel_pitch_mm,
                             PlaneCalibration.load(model), HueTable.load(object_table), edge_exclusion=edge,
                             denoise_radius=int(config["measurement"]["denoise_radius"]),
                             supports=_TiffMaps(supports) if supports else None, workers=threads, camera=lens,
                             lateral_px=float(config["measurement"]["lateral_uncertainty_px"]),
                             lateral_step_px=float(config["measurement"]["lateral_step_px"]))
    base = evaluate(baseline, method="three-step-phase-shift") if baseline else None
    plane_stats = jsonlib.loads(Path(planes).read_text())
    table_stats = jsonlib.loads(Path(tables).read_text())
    provenance = collect_provenance(s.id, dict(config), s.input_files(), root=s.root)
    provenance["capture"] = s.provenance  # session.yaml provenance: report header, simulated notice
    extras: dict[str, Any] = {
        "hue_model": config["hue_model"],
        "unwrap": config["measurement"]["unwrap"],
        "calibration": {
            "plane_fit_residual_rms_mm": plane_stats.get("fit_residual_rms_mm"),
            "unambiguous_range_mm": plane_stats.get("unambiguous_range_mm"),
            "object_table_valid_fraction": table_stats.get("valid_fraction"),
        },
    }
    if accuracy:
        extras["accuracy"] = jsonlib.loads(Path(accuracy[0]).read_text())
    frame_qa = [jsonlib.loads(Path(p).read_text()) for p in qa]
    extras["frame_qa"] = {
        "phase_ambiguity_suspected": [q["frame"] for q in frame_qa if q["phase_ambiguity_suspected"]],
        "valid_fraction_min": min(q["valid_fraction"] for q in frame_qa),
        "clipped_fraction_max": max(q["clipped_fraction"] for q in frame_qa),
    }
    if extras["frame_qa"]["phase_ambiguity_suspected"]:
        log.warning("frames %s: phase ambiguity suspected (a step may be too tall for the fringe period)",
                    extras["frame_qa"]["phase_ambiguity_suspected"])
    doc = build_report_json(s.id, spec, method, base, extras=extras)
    # a profile through the middle of the steps' ROIs (paper Fig. 9 d)
    rows = [(st["roi"][1] + st["roi"][3]) // 2 for st in spec["steps"]]
    profile_figure(read_tiff(heights[0]), int(np.median(rows)), s.pixel_pitch_mm, profile,
                             title=f"{s.id} frame {s.frame_ids[0]:04d}: cross-section")
    per_frame_figure(doc, per_frame)
    figures = {"profile": Path(profile), "height": Path(height_map), "render": Path(render),
               "per_frame": Path(per_frame), "calibration_qa": Path(cross_section)}
    write_json(json, doc)
    write_report_html(html, doc, figures, provenance, pixel_pitch_mm=s.pixel_pitch_mm,
                             box_mm=None if lens.plain else lens.box_mm)


class _TiffMaps(Sequence):
    """TIFF maps as a sequence that reads each one when it is taken (one map in memory at a time
    while it is iterated: 1000 frames held at once are 1.2 GB per kind)."""

    def __init__(self, paths: Sequence[str]):
        self.paths = list(paths)

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, i):  # type: ignore[override]
        if isinstance(i, slice):
            return _TiffMaps(self.paths[i])
        return read_tiff(self.paths[i])


def table1(reports: Sequence[str], periods: Sequence[float], step: str, nominal_mm: float,
           markdown: str, csv: str, figure: str, uncertainty_ratio: str = "") -> None:
    """The paper's Table 1 from the metrology reports of a period sweep, beside the published values.

    ``uncertainty_ratio`` (JSON): per period, the step's observed std over the frames against the
    predicted independent part of one frame's u (``uncertainty_budget.independent_per_frame_mm``).
    """
    results = {}
    for period, path in zip(periods, reports, strict=True):
        doc = jsonlib.loads(Path(path).read_text())
        results[int(period)] = {"method": {"steps": doc["steps"]}}
        if doc.get("baseline"):
            results[int(period)]["baseline"] = doc["baseline"]
    rows = table1_rows(results, step_name=step, nominal=nominal_mm)
    write_table1(rows, markdown, csv, figure)
    if uncertainty_ratio:
        ratios = {}
        for period, res in results.items():
            st = next((x for x in res["method"]["steps"] if x["name"] == step), None)
            bud = (st or {}).get("uncertainty_budget")
            if st is None or bud is None or st.get("std_mm") is None:
                continue
            ind = float(bud["independent_per_frame_mm"])
            ratios[str(period)] = {"frames": len(st["per_frame_mm"]), "std_mm": st["std_mm"],
                                   "independent_per_frame_mm": ind, "ratio": st["std_mm"] / ind if ind > 0 else None,
                                   "u_mm": st.get("u_mm"), "error_mm": st["error_mm"]}
            log.info("period %s px: std %.4f mm, predicted independent u %.4f mm, ratio %.2f (target 0.7-1.4)",
                     period, st["std_mm"], ind, ratios[str(period)]["ratio"] or float("nan"))
        write_json(uncertainty_ratio, {"step": step, "target": [0.7, 1.4], "periods": ratios})


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


# --------------------------------------------------------------------------- without Snakemake

def measure_session(session: str | Path, out: str | Path, config: Mapping[str, Any], *,
                    frames: Sequence[int] | None = None, baseline: bool = False) -> dict[str, Any]:
    """Tables, plane calibration and height maps of a session into ``out``, without Snakemake.

    The same stages, in the same order, as the workflow's ``hue_table``, ``plane_calibration``,
    ``measure_frames``, ``cloud_frames`` (and ``baseline_frames``) jobs; for scripts, benchmarks and tests. Returns the
    output paths by kind (``heights``, ``clouds``, ``phases``, ``hues``, ``qa``, ``uncertainties``,
    ``supports``, optionally
    ``baseline``), the camera record ``camera`` (``camera.json``: X, Y model and channel
    registration, :func:`camera_calibration`) and the loaded ``session``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s = load_session(session)
    frames = s.frame_ids if frames is None else list(frames)
    model, cal = config["hue_model"], config["calibration"]
    cam = str(out / "camera.json")
    camera_calibration(str(session), config["camera"], cal, record=cam)
    for which in ("reference", "object"):
        hue_table(str(session), which, model, cal, table=str(out / f"table_{which}.json"),
                  stats=str(out / f"table_{which}.stats.json"), camera_json=cam)
    plane_calibration(str(session), str(out / "table_reference.json"), model, cal,
                      model=str(out / "model.npz"), stats=str(out / "planes.json"),
                      phase_error_table=str(out / "phase_error.npz"), phase_error_summary=str(out / "phase_error.json"),
                      camera_json=cam, object_table=str(out / "table_object.json"))
    paths: dict[str, Any] = {
        k: [str(out / k / f"frame_{n:04d}.{ext}") for n in frames]
        for k, ext in (("heights", "tiff"), ("clouds", "ply"), ("phases", "tiff"), ("hues", "tiff"), ("qa", "json"),
                       ("uncertainties", "tiff"), ("supports", "tiff"))
    }
    measure_frames(str(session), frames, str(out / "table_object.json"), str(out / "model.npz"), model,
                   config["measurement"], cal, heights=paths["heights"], phases=paths["phases"], hues=paths["hues"],
                   qa=paths["qa"], uncertainties=paths["uncertainties"], supports=paths["supports"], camera_json=cam)
    cloud_frames(str(session), frames, heights=paths["heights"], clouds=paths["clouds"],
                 uncertainties=paths["uncertainties"], camera_json=cam)
    if baseline:
        paths["baseline"] = [str(out / "baseline" / f"frame_{n:04d}.tiff") for n in frames]
        baseline_frames(str(session), frames, str(out / "model.npz"), str(out / "table_object.json"),
                        config["measurement"], heights=paths["baseline"],
                        qa=[str(out / "baseline" / f"frame_{n:04d}.json") for n in frames], camera_json=cam)
    paths["session"] = s
    paths["camera"] = cam
    return paths


# --------------------------------------------------------------------------- Snakemake adapter


def stage_kwargs(func: Callable[..., None], smk: Any, **extra: Any) -> dict[str, Any]:
    """The keyword arguments of stage ``func`` from a Snakemake job's named inputs, params and outputs.

    Wildcards are passed when the stage takes them (``sid``, ``batch`` are structural), and so are
    the job's ``threads`` (the cores Snakemake gave it); every named input, param and output (and
    ``extra``) must be a parameter of the stage.

    Raises
    ------
    TypeError
        Naming the keys the stage does not accept (a misspelt key with a default would otherwise
        be dropped silently) and the stage's parameters.
    """
    accepted = inspect.signature(func).parameters
    kwargs: dict[str, Any] = {k: v for k, v in smk.wildcards.items() if k in accepted}
    if "threads" in accepted and getattr(smk, "threads", None):
        kwargs["threads"] = int(smk.threads)
    for source in (smk.input, smk.params, smk.output):
        for key, value in source.items():
            kwargs[key] = value
    kwargs.update(extra)
    unknown = sorted(set(kwargs) - set(accepted))
    if unknown:
        raise TypeError(f"stage {func.__name__} does not accept {', '.join(map(repr, unknown))} "
                        f"(rule inputs, params and outputs must be among its parameters: {', '.join(accepted)})")
    return kwargs


def run_from_snakemake(smk: Any, func: Callable[..., None], **extra: Any) -> None:
    """Call ``func`` with the job's named inputs, outputs and params as keyword arguments.

    Logging goes to the job's log file. Known input problems end the job with a one-paragraph
    message naming the file (no traceback); outputs are written atomically by the stages, so a
    failed job leaves none behind.
    """
    logfile = smk.log[0] if len(smk.log) else None
    handlers: list[logging.Handler] = [logging.StreamHandler(sys.stderr)]
    if logfile:
        Path(logfile).parent.mkdir(parents=True, exist_ok=True)
        handlers.append(logging.FileHandler(logfile, mode="w"))
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s", handlers=handlers, force=True)
    kwargs = stage_kwargs(func, smk, **extra)  # before anything is touched: a rule naming an unknown key fails here
    for out in smk.output:
        for stale in remove_stale_parts(out):
            log.info("removed %s, left by an interrupted run", stale)
    t0 = time.perf_counter()
    try:
        func(**kwargs)
    except (SessionError, FrameError, HueTableError, PlaneCalibrationError, MetrologyError, ArchiveError,
            X3PError) as exc:
        log.error("%s", exc)
        sys.stderr.write(f"\nhuefringe: {exc}\n")
        sys.exit(1)
    log.info("%s done in %.2f s", func.__name__, time.perf_counter() - t0)
