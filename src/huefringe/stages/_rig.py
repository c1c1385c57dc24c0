"""The rig stages (``workflow/rules/rig.smk``): structured-light sessions calibrated, decoded,
triangulated, and turned into the same outputs and report as capture sessions."""

from __future__ import annotations

import logging
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from huefringe.codecs import Reason
from huefringe.codecs.output import quality_figure
from huefringe.cloud import write_points
from huefringe.io import atomic_path, read_tiff, tiff_pixel_pitch_mm, write_figure_png, write_json, write_tiff
from huefringe.mesh import attach_sigma, clean_mesh, export_mesh, height_to_mesh, stats_path
from huefringe.render import camera_for_field, height_map_figure, render_views, uncertainty_map_figure
from huefringe.rig import read_calibration
from huefringe.rig.measure import (
    RigError,
    RigFrame,
    calibrate_sl_session,
    calibration_spread,
    height_over_plane,
    measure_sl_frame,
    plane_grid,
    read_jackknife,
    write_rig_calibration,
)
from huefringe.rig.calibrate import Board
from huefringe.rig.metrology import base_plane, rig_report, xyz_accuracy
from huefringe.rig.oneshot import ONESHOT_GEOMETRY, is_oneshot, measure_oneshot_session
from huefringe.session import SLSession, load_sl_session
from huefringe.x3p import write_height_x3p

log = logging.getLogger("huefringe")


def rig_calibrate(session: str, config: Mapping[str, Any], calibration: str, report: str, jackknife: str,
                  board: Board | None = None) -> None:
    """Calibrate the rig from a structured-light session's poses: ``calib/rig.yml``, its report
    (per-pose RMS, poses left out, both RMS definitions) and the leave-one-pose-out calibrations;
    ``board`` overrides the session's."""
    s = load_sl_session(session)
    run = calibrate_sl_session(s, dict(config), board)
    files = write_rig_calibration(run, calibration)
    if (str(files["report"]), str(files["jackknife"])) != (report, jackknife):
        raise RuntimeError(f"calibration files went to {files}, the workflow expects {report}, {jackknife}")
    r = run.report.rms_px
    log.info("rig calibrated from %d poses (%s left out): RMS camera %.4f px, projector %.4f px, stereo %.4f px; baseline %.2f mm",
             len(run.report.poses), ", ".join(run.report.rejected) or "none", r.get("camera", np.nan),
             r.get("projector", np.nan), r.get("stereo", np.nan), run.calibration.baseline_mm)


def rig_calibration_from(source_calibration: str, source_report: str, source_jackknife: str, calibration: str,
                         report: str, jackknife: str) -> None:
    """The calibration of the session that calibrates this one, copied byte for byte into this
    session's ``calib/`` (so that its results and archive hold what it was measured with)."""
    for src, dst in ((source_calibration, calibration), (source_report, report), (source_jackknife, jackknife)):
        with atomic_path(dst) as tmp:
            shutil.copyfile(src, tmp)


def _one(files: Any) -> str:
    """A rule input given as an optional one-element list: the file, or ''."""
    return files if isinstance(files, str) else (str(files[0]) if len(files) else "")


def _calibration_file(s: SLSession, calibration: str) -> str:
    """The rule's calibration input, else the session's own ``calibration/`` file."""
    return calibration or str(s.calibration)


def rig_measure(session: str, config: Mapping[str, Any], calibration: str, xyz: str, xyz_sigma: str, xyz_u: str,
                decoded: str, cloud: str, height: str, uncertainty: str, x3p: str, qa: str, quality: str,
                jackknife: Any = "") -> None:
    """Decode and triangulate a structured-light session's captures: X, Y, Z on the camera grid with
    the decoded coordinates' noise (``xyz_sigma``) and the combined standard uncertainty with the
    calibration's term (``xyz_u``), the decoded coordinates, the organised cloud, the height over the
    base plane (features' ``base``, else every point) resampled on the plane's grid, its X3P, and
    the QA record and figure."""
    s = load_sl_session(session)
    if is_oneshot(s.spec):
        raise RigError(f"{s.root / 'sequence.yaml'}: a one-shot session (trapezoid blocks): measured by rig_oneshot, "
                       "every one-shot frame, not as one coded frame")
    cfg = dict(config)
    calib_file = _calibration_file(s, calibration)
    calib = read_calibration(calib_file)
    f = measure_sl_frame(s, calib, cfg)
    loo = read_jackknife(_one(jackknife)) if _one(jackknife) else []
    _write_frame(s, f, cfg, calib_file, loo, xyz=xyz, xyz_sigma=xyz_sigma, xyz_u=xyz_u, decoded=decoded, cloud=cloud,
                 height=height, uncertainty=uncertainty, x3p=x3p, qa=qa, quality=quality)


def rig_oneshot(session: str, config: Mapping[str, Any], calibration: str, xyz: Any, xyz_sigma: Any, xyz_u: Any,
                decoded: Any, cloud: Any, height: Any, uncertainty: Any, x3p: Any, qa: Any, quality: Any,
                jackknife: Any = "", reference: Any = ()) -> None:
    """A one-shot structured-light session (``trapezoid`` frames) measured frame after frame: the
    coded blocks decoded once as the order reference (or the coded captures of the reference
    session it names, ``oneshot: {reference: {session: PATH}}``, whose files the workflow gives as
    ``reference`` so that a changed reference re-measures it), the hue table from the bands, then each
    trapezoid frame to X, Y, Z with its uncertainties and the same files as :func:`rig_measure`
    writes (``frame_NNNN`` the one-shot frame's index), each saying the geometry that measured it
    (:data:`huefringe.rig.oneshot.ONESHOT_GEOMETRY`)."""
    import time

    s = load_sl_session(session)
    cfg = dict(config)
    calib_file = _calibration_file(s, calibration)
    calib = read_calibration(calib_file)
    t0 = time.perf_counter()
    run = measure_oneshot_session(s, calib, cfg)
    paths = {"xyz": xyz, "xyz_sigma": xyz_sigma, "xyz_u": xyz_u, "decoded": decoded, "cloud": cloud, "height": height,
             "uncertainty": uncertainty, "x3p": x3p, "qa": qa, "quality": quality}
    paths = {k: [v] if isinstance(v, str) else list(v) for k, v in paths.items()}
    if any(len(v) != len(run.frames) for v in paths.values()):
        raise RigError(f"{s.root}: {len(run.frames)} one-shot frames, the workflow expects "
                       f"{len(paths['xyz'])} (is the session's sequence.yaml newer than the run's plan?)")
    loo = read_jackknife(_one(jackknife)) if _one(jackknife) else []
    order = run.order_summary()
    prov = dict(s.meta.get("provenance") or {})
    ref_note = None if run.reference_session is None else f"order reference: session {run.reference_session}"
    prov["notes"] = "; ".join(x for x in (prov.get("notes"), f"geometry: {ONESHOT_GEOMETRY}", ref_note) if x)
    for k, f in enumerate(run.frames):
        counts = run.results[k].reason_counts()
        _write_frame(s, f, cfg, calib_file, loo, **{key: v[k] for key, v in paths.items()}, frame=k, provenance=prov,
                     title=f"{s.id}: one-shot frame {k}, projector coordinates",
                     extra_qa={"geometry": ONESHOT_GEOMETRY, "frame": k, "order": order,
                               "hue_table": {"bands": run.table.n_bands, "model": run.table.model},
                               "dropped_by_reason": {n: c for n, c in counts.items() if c}})
    log.info("%s: %d one-shot frames measured (%s) in %.1f s", s.id, len(run.frames), ONESHOT_GEOMETRY,
             time.perf_counter() - t0)


def _write_frame(s: SLSession, f: RigFrame, cfg: dict[str, Any], calib_file: str, loo: list[Any], *, xyz: str,
                 xyz_sigma: str, xyz_u: str, decoded: str, cloud: str, height: str, uncertainty: str, x3p: str, qa: str,
                 quality: str, frame: int = 0, provenance: Mapping[str, Any] | None = None,
                 title: str | None = None, extra_qa: Mapping[str, Any] | None = None) -> None:
    """One triangulated frame's files: X, Y, Z with sigma and u, decoded coordinates, cloud, height
    over the base plane and its uncertainty, X3P, QA record and figure."""
    u_cal, u_cal_ray = calibration_spread(f, loo)
    u_all = np.concatenate([np.hypot(f.sigma, u_cal), np.hypot(f.sigma_ray, u_cal_ray)[..., None]], axis=-1)
    write_tiff(xyz, f.xyz.astype(np.float32))
    write_tiff(xyz_sigma, np.concatenate([f.sigma, f.sigma_ray[..., None]], axis=-1).astype(np.float32))
    write_tiff(xyz_u, u_all.astype(np.float32))
    d = f.decoded
    nan = np.full(f.valid.shape, np.nan)
    maps = [d[k] if d[k] is not None else nan for k in ("u", "v", "sigma_u", "sigma_v")]
    write_tiff(decoded, np.stack(maps, axis=-1).astype(np.float32))
    _write_cloud(cloud, f, u_all)
    plane = base_plane(f, s.features)
    h_cam, u_cam = height_over_plane(f, plane.centroid, plane.normal)
    grid = plane_grid(f, h_cam, u_cam, plane.centroid, plane.normal)
    write_tiff(height, grid["height"], pixel_pitch_mm=grid["pitch_mm"])
    write_tiff(uncertainty, grid["uncertainty"], pixel_pitch_mm=grid["pitch_mm"])
    write_height_x3p(x3p, grid["height"], grid["pitch_mm"], session_id=s.id, frame=frame,
                     provenance=s.meta.get("provenance") if provenance is None else provenance)
    write_json(qa, {
        "session": s.id, "triangulation": f.mode, "valid_fraction": float(f.valid.mean()),
        "points": int(f.valid.sum()), "median_sigma_xyz_mm": np.nanmedian(f.sigma[f.valid], axis=0).tolist(),
        "base_plane": {"centroid_mm": plane.centroid.tolist(), "normal": plane.normal.tolist(), "rms_mm": plane.rms_mm,
                       "points": plane.n, "fitted_to": "features base" if s.features and s.features.base else "every point"},
        "grid": {k: v for k, v in grid.items() if k not in ("height", "uncertainty")},
        "calibration": calib_file,
        "validity": _validity(f, cfg),
        "calibration_term": {"leave_one_out_calibrations": len(loo),
                             "median_u_ray_mm": float(np.nanmedian(u_cal_ray)) if loo else None,
                             "note": "jackknife over the calibration's board poses" if loo else
                                     "not available: the calibration file comes without its board poses"},
        **(extra_qa or {}),
    })
    fig = quality_figure(d["decoded"], title or f"{s.id}: decoded projector coordinates", reasons=True)
    write_figure_png(fig, quality, dpi=90)
    log.info("%s: %d points (%.1f %% of the camera), triangulation %s, base plane RMS %.4f mm",
             s.id, int(f.valid.sum()), 100 * f.valid.mean(), f.mode, plane.rms_mm)


def _validity(f: RigFrame, cfg: Mapping[str, Any]) -> dict[str, Any]:
    """Camera pixels each validity test dropped, per axis (:class:`~huefringe.codecs.Reason`; a pixel
    may fail several), and the ray test's thresholds and misses."""
    dec = f.decoded["decoded"]
    out: dict[str, Any] = {"dropped_pixels": {a: {r.name.lower(): int(((d.reasons & r) != 0).sum()) for r in Reason}
                                              for a, d in dec.items() if d.reasons.size}}
    if f.ray_residual is not None:
        r = np.abs(f.ray_residual[np.isfinite(f.ray_residual)])
        out["ray_test"] = {
            "max_ray_sigma": float(cfg["codecs"]["max_ray_sigma"]), "ray_floor_px": float(cfg["codecs"]["ray_floor_px"]),
            "tested": int(r.size), "dropped": int(((dec["x"].reasons & Reason.RAY) != 0).sum()),
            "median_miss_px": float(np.median(r)) if r.size else None,
            "p99_miss_px": float(np.percentile(r, 99)) if r.size else None,
            "what": "distance of the decoded projector pixel from the camera pixel's epipolar line (projector px)"}
    return out


def _write_cloud(path: str, f: RigFrame, u: Any) -> None:
    """The organised cloud: every valid point with its camera pixel (row, column), the decoded
    coordinates' noise ``sigma_x/y/z``, the combined standard uncertainty ``u_x/y/z`` (with the
    calibration's term) and the mean capture as grey."""
    rows, cols = np.nonzero(f.valid)
    grey = f.decoded["mean"][rows, cols]
    top = float(np.nanmax(f.decoded["mean"])) or 1.0
    g = np.clip(np.round(255 * grey / top), 0, 255).astype(np.uint8)
    sig = f.sigma[rows, cols]
    write_points(path, f.xyz[rows, cols], np.repeat(g[:, None], 3, axis=1),
                 scalars={"row": rows.astype(np.float32), "col": cols.astype(np.float32),
                          "sigma_x": sig[:, 0], "sigma_y": sig[:, 1], "sigma_z": sig[:, 2],
                          "u_x": u[rows, cols, 0], "u_y": u[rows, cols, 1], "u_z": u[rows, cols, 2]})


def rig_surfaces(session: str, height: str, uncertainty: str, mesh: Mapping[str, Any], render: Mapping[str, Any],
                 ply: str, stl: str, stats: str, top: str, oblique1: str, oblique2: str, height_map: str,
                 uncertainty_map: str) -> None:
    """Mesh (PLY + STL, vertices with ``sigma_mm``), off-screen renders and the height and uncertainty
    figures of a structured-light session's height over its base plane."""
    s = load_sl_session(session)
    h = read_tiff(height)
    u = read_tiff(uncertainty)
    pitch = tiff_pixel_pitch_mm(height)
    m = clean_mesh(height_to_mesh(h, pitch), min_island_faces=mesh["min_island_faces"])
    attach_sigma(m, u, pitch)
    export_mesh(m, ply, stl)
    if stats_path(ply) != Path(stats):
        raise RuntimeError(f"mesh statistics went to {stats_path(ply)}, the workflow expects {stats}")
    finite = h[np.isfinite(h)]
    clim = (float(np.percentile(finite, 0.5)), float(np.percentile(finite, 99.5))) if finite.size else (-1.0, 1.0)
    size = (int(render["width"]), int(render["height"]))
    cams = camera_for_field((h.shape[1] - 1) * pitch, (h.shape[0] - 1) * pitch, clim, size=size)
    written = render_views(trimesh.load(ply, process=False, force="mesh"), Path(top).parent, "frame_0000", clim=clim,
                           camera=cams, size=size, title=f"{s.id}")
    if not {Path(top), Path(oblique1), Path(oblique2)} <= set(written):
        raise RuntimeError(f"render wrote {written}, expected {top}, {oblique1}, {oblique2}")
    height_map_figure(h, pitch, height_map, clim=clim, title=f"{s.id}: height above the base plane (mm)")
    uncertainty_map_figure(u, pitch, uncertainty_map, title=f"{s.id}: height uncertainty u")


def rig_metrology(session: str, config: Mapping[str, Any], calibration: str, xyz: Any, xyz_sigma: Any, decoded: Any,
                  qa: Any, render: str, height_map: str, quality: str, json: str, html: str,
                  jackknife: Any = "", calibration_report: Any = "", reference: Any = ()) -> None:
    """``metrology/report.json`` and ``report.html`` of a structured-light session: its features'
    steps, flatness, plane distances and parallelism, spheres, each with U (k = 2) and the ISO
    14253-1 decision, and the calibration's summary (:func:`huefringe.rig.metrology.rig_report`).

    ``xyz``, ``xyz_sigma``, ``decoded`` (and ``qa``) are one frame's files or, for a one-shot
    session, every one-shot frame's in capture order: each figure is then measured on every frame
    and reported as its per-frame series, mean and standard deviation. ``reference``: the files of the
    session a one-shot session takes its order from (named in its provenance and inputs' hashes)."""
    s = load_sl_session(session)
    xyz, xyz_sigma, decoded = ([p] if isinstance(p, str) else list(p) for p in (xyz, xyz_sigma, decoded))
    rig_report(s, dict(config), calibration=_calibration_file(s, calibration), xyz=[read_tiff(p) for p in xyz],
               sigma=[read_tiff(p)[..., :3] for p in xyz_sigma], decoded=[read_tiff(p) for p in decoded],
               jackknife=_one(jackknife),
               calibration_report=_one(calibration_report), json_path=json, html_path=html,
               figures={"render": render, "height": height_map, "decode_quality": quality},
               oneshot=is_oneshot(s.spec))


def rig_accuracy(session: str, calibration: str, xyz: str, xyz_sigma: str, xyz_u: str, accuracy: str) -> None:
    """Errors of the triangulated X, Y, Z against the session's ``ground_truth/xyz.tiff`` (benches):
    per-axis and along-ray statistics and the share of valid pixels with ``|e| <= 2u``; and the
    decoding's own error (the true projector coordinates triangulated with the same calibration)
    against the decoded coordinates' noise sigma (:func:`huefringe.rig.metrology.xyz_accuracy`)."""
    s = load_sl_session(session)
    if "xyz" not in s.ground_truth:
        raise RigError(f"{s.root}: no ground_truth/xyz.tiff")
    calib = read_calibration(_calibration_file(s, calibration))
    true_uv = {a: read_tiff(s.ground_truth[a]).astype(np.float64) for a in ("x", "y") if a in s.ground_truth}
    write_json(accuracy, xyz_accuracy(read_tiff(xyz), read_tiff(xyz_u), read_tiff(s.ground_truth["xyz"]),
                                      sigma=read_tiff(xyz_sigma), calibration=calib, true_uv=true_uv))


__all__ = ["rig_accuracy", "rig_calibrate", "rig_calibration_from", "rig_measure", "rig_metrology", "rig_oneshot",
           "rig_surfaces"]
