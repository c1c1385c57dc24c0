"""The measurement stages (``workflow/rules/measurement.smk``): heights, clouds, X3P files, the baseline, the accuracy report and its lateral block."""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from huefringe import uncertainty
from huefringe.camera import CameraModel
from huefringe.cloud import check_colours, colour_bytes, write_height_cloud
from huefringe.colour import intensity
from huefringe.height import PlaneCalibration, accuracy, coverage, xy_accuracy
from huefringe.huetable import HueTable
from huefringe.io import read_tiff, write_json, write_tiff
from huefringe.perframe import shadow_mask
from huefringe.phase import three_step_phase, unwrap, wrap
from huefringe.pipeline import frame_results, session_corrections
from huefringe.render import reliability_figure
from huefringe.session import Session, load_session
from huefringe.settings import software_identity
from huefringe.x3p import write_height_x3p

log = logging.getLogger("huefringe")


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
    shadow = shadow_mask(white, measurement["shadow_fraction"], own_light=bool(measurement["shadow_own_light"]))
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
    lit = ~shadow_mask(reader.rgb(s.object_white), measurement["shadow_fraction"],
                       own_light=bool(measurement["shadow_own_light"]))  # the pixels the chains may measure

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
