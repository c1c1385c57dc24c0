"""Workflow stages: each function is what one Snakemake script calls, once, and has its rule's name.

Rule ``NAME`` (in ``workflow/rules/<file>.smk``) runs ``scripts/NAME.py``, which calls
:func:`NAME` here (tests/test_stages.py checks it); the stages are in the order of the rule files,
one section per file (``bench``, ``calibration``, ``measurement``, ``surfaces``, ``metrology``,
``archive``). Every stage reads its inputs, calls the library, and writes its outputs atomically.
The ``session_*`` and :func:`frame_results` helpers are the in-memory halves that
:func:`huefringe.measure` shares. Nothing here is Snakemake-specific except
:func:`run_from_snakemake`, the adapter the scripts use.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe import kernel
from huefringe.camera import CameraModel, CaptureReader, bayer_resampling, camera_record, corrections, mixing_band_pairs
from huefringe.colour import hue as hue_of
from huefringe.colour import intensity, white_balance
from huefringe.height import PlaneCalibration, PlaneCalibrationError, accuracy, calibrate_planes, coverage, xy_accuracy
from huefringe.huetable import HueTable, HueTableError, build_table
from huefringe import phase_error, texture
from huefringe.io import read_tiff, write_json, write_tiff
from huefringe.perframe import FrameError, clipped_mask, measure_frame, reference_frame_stats, remove_step_edges, shadow_mask
from huefringe.phase import three_step_phase, unwrap, wrap
from huefringe.session import Session, load_session
from huefringe.uncertainty import LATERAL_PX, LATERAL_STEP_PX, add_lateral, noise_correlation, pixel_budget, texture_term

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


def session_camera_record(s: Session, camera: Mapping[str, Any], calibration: Mapping[str, Any]) -> dict[str, Any]:
    """The ``calib/camera.json`` record of a session in memory (:func:`camera_calibration` writes it)."""
    read = CaptureReader(bayer=bayer_resampling(s.meta, camera.get("demosaic", "lanczos"))).rgb
    white = read(s.reference_white)
    mode = camera.get("chromatic_registration", "auto")
    planes = [] if mode is False or mode == "false" else [read(p) for p in s.planes.values()]
    demix = camera.get("colour_demixing", False)
    bands: dict[int, NDArray[np.floating]] = {}
    if planes or not (demix is False or demix == "false"):
        # the hue bands the channel-mixing estimate reads (repeats averaged): the registration's and the demixing's
        for _, first, last, _ in mixing_band_pairs(s.hue_bands):
            for i in (first, last):
                if i not in bands:
                    bands[i] = np.mean([read(p) for p in s.reference_bands[i]], axis=0)
    return camera_record(s.meta, camera, planes, white, shadow=shadow_mask(white, calibration["shadow_fraction"]),
                         bands=bands)


def session_corrections(s: Session, camera_json: str | Path | None = "") -> tuple[CameraModel, CaptureReader]:
    """The X, Y model and capture reader of ``calib/camera.json`` (:func:`camera_calibration`);
    without one: the session's own lens model and no channel registration."""
    import json

    record = json.loads(Path(camera_json).read_text()) if camera_json else None
    return corrections(record, s.meta)


def _calibration_opts(calibration: Mapping[str, Any]) -> dict[str, Any]:
    return {"min_saturation": calibration["min_saturation"], "min_intensity": calibration["min_intensity"]}


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


#: A hue table usable for fewer pixels than this is refused: the bands are not what they claim.
MIN_TABLE_VALID_FRACTION = 0.2
#: A white image with more clipped pixels than this is refused: white balance needs the true level.
MAX_WHITE_CLIPPED_FRACTION = 0.01

_TABLE_HINTS = {
    "low_signal": "the white image is too dark there (projector off, lens cap, exposure too short?)",
    "low_saturation": "the bands carry no colour there (projector off, or the sensor saturated?)",
    "noise": "the repeats of a band disagree (vibration, flicker or a changing exposure?)",
    "coverage": "the captured hue does not go once round the colour circle with the band index "
                "(bands mislabelled, out of order or captured with another pattern?)",
    "order": "the captured hue does not rise monotonically with the band index "
             "(bands mislabelled, out of order or captured with another pattern?)",
}


def _refuse_bad_table(folder: Path, stats: Mapping[str, Any], min_valid: float = MIN_TABLE_VALID_FRACTION) -> None:
    if stats["valid_fraction"] >= min_valid:
        return
    masked = stats["masked_by_reason"]
    worst = max(masked, key=masked.get)
    raise HueTableError(
        f"{folder}: the hue table is usable for only {100 * stats['valid_fraction']:.1f} % of the pixels "
        f"(limit {100 * min_valid:.0f} %); {100 * masked[worst] / stats['n_pixels']:.1f} % are masked as "
        f"'{worst}': {_TABLE_HINTS.get(worst, '')}"
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


def session_hue_table(s: Session, which: str, hue_model: str, calibration: Mapping[str, Any], *,
                      reader: CaptureReader | None = None) -> HueTable:
    """The hue table of a session's reference plate or object, in memory (:func:`hue_table` writes it);
    the captures read through ``reader`` (the camera corrections; default: as stored).

    Raises
    ------
    HueTableError
        Naming the white image (too many clipped pixels) or the band folder (too few usable pixels).
    """
    bands = s.reference_bands if which == "reference" else s.object_bands
    white_path = s.reference_white if which == "reference" else s.object_white
    reader = reader or CaptureReader()
    white = reader.rgb(white_path)
    clipped = float(clipped_mask(white, s.bit_depth).mean())
    limit = float(calibration.get("max_white_clipped_fraction", MAX_WHITE_CLIPPED_FRACTION))
    if clipped > limit:
        raise HueTableError(
            f"{white_path}: {100 * clipped:.1f} % of the pixels are clipped (sensor saturated; limit "
            f"{100 * limit:g} %, calibration.max_white_clipped_fraction): white balance needs the unclipped level; "
            "reduce the exposure"
        )
    built = build_table(bands, white, model=hue_model, progress=False, read=reader.rgb, **_calibration_opts(calibration))
    _refuse_bad_table(s.root / which / "hue", built.stats)
    if reader.bayer is not None and len(bands[0]) >= 2:  # re-demosaiced: its noise is correlated between neighbours
        built.stats["noise_correlation"] = bayer_noise_correlation(bands, white, reader, hue_model, calibration)
    return built


def noise_aware_adaptive(adaptive: Mapping[str, Any] | None, table: HueTable) -> Mapping[str, Any] | None:
    """The adaptive phase filter's settings (``measurement.denoise_adaptive``) for noise correlated
    between neighbours: ``target_sigma_rad`` and ``reject_sigma_rad`` over ``sqrt(k)``, ``k`` the
    table's ``noise_correlation`` factor (a re-demosaiced Bayer session, :func:`bayer_noise_correlation`;
    at least 1). The filter's sigma ``1 / sqrt(sum w)`` assumes independent pixels, so it reads
    ``sqrt(k)`` too low and stops growing too early. A table without the factor (three-chip): as given."""
    corr = (table.stats or {}).get("noise_correlation")
    if not adaptive or not corr:
        return adaptive
    scale = 1.0 / float(np.sqrt(max(1.0, float(corr["factor"]))))
    out = dict(adaptive)
    for key in ("target_sigma_rad", "reject_sigma_rad"):
        if out.get(key) is not None:
            out[key] = float(out[key]) * scale
    return out


#: hue bands (evenly spread) whose first two repeats give a Bayer session's noise correlation
NOISE_CORRELATION_BANDS = 12


def bayer_noise_correlation(bands: Sequence[Sequence[Path]], white: NDArray[np.floating], reader: CaptureReader,
                            hue_model: str, calibration: Mapping[str, Any]) -> dict[str, Any]:
    """:func:`huefringe.uncertainty.noise_correlation` of the hue differences between the first two
    repeats of :data:`NOISE_CORRELATION_BANDS` bands, read as the chain reads them (``reader``)."""
    picks = np.unique(np.linspace(0, len(bands) - 1, min(NOISE_CORRELATION_BANDS, len(bands))).round().astype(int))
    diffs = []
    for k in picks:
        h0, h1 = (hue_of(white_balance(reader.rgb(bands[k][r]), white), hue_model,
                         min_saturation=calibration["min_saturation"]) for r in (0, 1))
        diffs.append(np.angle(np.exp(1j * (np.asarray(h1, np.float64) - h0))))
    return noise_correlation(diffs)


def _plane_phases(s: Session, table: HueTable, hue_model: str, calibration: Mapping[str, Any],
                  reader: CaptureReader | None = None):
    reader = reader or CaptureReader()
    white = reader.rgb(s.reference_white)
    shadow = shadow_mask(white, calibration["shadow_fraction"])
    phases, valid = {}, {}
    for z, path in s.planes.items():
        hue = hue_of(white_balance(reader.rgb(path), white), hue_model, min_saturation=calibration["min_saturation"])
        phi = table.to_phase(hue)
        if s.predistortion is not None:
            phi = s.predistortion.decode(phi)
        phases[z] = phi
        valid[z] = np.isfinite(phi) & ~shadow
    return phases, valid


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


def session_plane_calibration(s: Session, t: HueTable, hue_model: str, calibration: Mapping[str, Any], *,
                              phase_error_table: str | None = None, phase_error_figure: str | None = None,
                              phase_error_summary: str | None = None,
                              reader: CaptureReader | None = None,
                              object_table: HueTable | None = None) -> PlaneCalibration:
    """The plane calibration of a session from its reference table, in memory (:func:`plane_calibration` writes it).

    The planes' phases are first corrected with the phase-error table learned from them
    (:mod:`huefringe.phase_error`, as ``calibration.phase_error.enabled`` decides); the table is kept
    in ``cal.phase_error`` (applied to every frame) and its figures in ``cal.stats["phase_error"]``.
    The table, its summary and QA figure are written to the paths given.

    Raises
    ------
    PlaneCalibrationError
        Naming the plane folder, the plane images and ``session.yaml``.
    """
    phases, valid = _plane_phases(s, t, hue_model, calibration, reader)
    lut = phase_error.from_calibration(phases, valid, calibration, phase_error=phase_error_table,
                                       figure=phase_error_figure, summary=phase_error_summary)
    phases = {z: phase_error.correct(p, None if lut is None else lut.error) for z, p in phases.items()}
    try:
        cal = calibrate_planes(phases, valid, smooth_degree=calibration["plane_smooth_degree"])
    except PlaneCalibrationError as exc:
        files = ", ".join(f"z = {z:g} mm: {p.name}" for z, p in s.planes.items())
        raise PlaneCalibrationError(
            f"{s.root / 'reference' / 'planes'}: {exc} (plane images {files}; heights from planes_mm in "
            f"{s.root / 'session.yaml'})"
        ) from exc
    cal.phase_error = None if lut is None else lut.error
    cal.stats["phase_error"] = None if lut is None else lut.stats
    blur = calibration.get("texture_blur_px2", 0.0)
    if blur == "auto":  # the camera's blur from the session's own object frames (needs the object table)
        info = (session_texture_blur(s, object_table, cal, hue_model, calibration, reader=reader) if object_table is not None
                else {"sigma2_px2": 0.0, "source": "auto, no object table given: off"})
    else:
        info = {"sigma2_px2": float(blur or 0.0), "source": "calibration.texture_blur_px2"}
    cal.texture_blur_px2 = float(info["sigma2_px2"])
    cal.texture_blur_u_px2 = texture.blur_uncertainty(info)  # the per-pixel texture term (docs/uncertainty.md)
    info = {**info, "u_px2": cal.texture_blur_u_px2}
    cal.stats["texture_blur"] = info
    if lut is not None:  # its residual on the planes (reported; not added to u: docs/uncertainty.md)
        from huefringe.uncertainty import phase_error_residual_rad

        cal.stats.setdefault("uncertainty", {})["phase_error_residual_u_rad"] = phase_error_residual_rad(lut.stats)
    return cal


#: object frames the texture-blur estimate reads (pairs of them)
TEXTURE_BLUR_FRAMES = 4


def session_texture_blur(s: Session, t: HueTable, cal: PlaneCalibration, hue_model: str,
                         calibration: Mapping[str, Any], *, reader: CaptureReader | None = None) -> dict[str, Any]:
    """The camera's blur variance (px^2) for the texture-edge correction, from the session's first
    object frames (up to :data:`TEXTURE_BLUR_FRAMES`, two at least): each frame's raw phase
    difference (the kernel, no phase filter) as captured and after :func:`huefringe.texture.correct`
    with ``sigma^2 = 1``, through :func:`huefringe.texture.blur_from_phases`. With one frame the
    estimate is 0 (off): the instrumental variable needs two.

    Where that estimate is refused (not significant or not plausible: a surface with little
    texture, such as gauge blocks) or the session has one frame, the blur is read from the white
    image's sharp edges instead (:func:`huefringe.texture.blur_from_white`); when that is refused
    too (no sharp edges: a flat plate) the correction is off.

    Returns the record kept in ``calib/planes.json`` (``texture_blur``): ``sigma2_px2``,
    ``raw_px2``, ``stderr_px2``, ``samples``, ``pairs``, ``frames``, ``source``, ``rejected`` when
    the phase estimate was refused and then ``white_edges`` (the white-image estimate's record:
    ``sigma2_px2``, ``edges``, ``quartiles_px2``, ``rejected`` when refused as well).
    """
    frames = s.frame_ids[:TEXTURE_BLUR_FRAMES]
    read = (reader or CaptureReader()).rgb  # the frames as the chains read them (re-demosaic, registration)
    white = read(s.object_white)

    def fallback(rec: dict[str, Any], why: str) -> dict[str, Any]:
        edges = texture.blur_from_white(white)
        rec = {**rec, "white_edges": edges, "sigma2_px2": float(edges["sigma2_px2"])}
        rec["source"] = (f"auto: {why}; read from the white image's edges" if "rejected" not in edges
                         else f"auto: {why}, and no white-image estimate (see white_edges): correction off")
        return rec

    if len(frames) < 2:
        return fallback({"sigma2_px2": 0.0, "samples": 0, "pairs": 0, "frames": list(frames)}, "one frame, no phase estimate")
    prep = kernel.prepare(t, cal, white, hue_model=hue_model, min_saturation=calibration["min_saturation"],
                          shadow=shadow_mask(white, calibration["shadow_fraction"]), bit_depth=s.bit_depth,
                          predistortion=s.predistortion)
    plain, unit = [], []
    for n in frames:
        rgb = read(s.frames[n])
        for sigma2, out in ((0.0, plain), (1.0, unit)):
            m = kernel.frame_maps(prep, texture.correct(rgb, white, sigma2), denoise_radius=0, want_dphi=True)
            out.append(np.where(m.valid, m.dphi, np.nan))
    est = {**texture.blur_from_phases(plain, unit), "frames": [int(n) for n in frames]}
    if "rejected" in est:
        return fallback(est, "phase estimate refused (see rejected)")
    return {**est, "source": "auto: estimated from the object frames"}


def compensation(session: str, table: str, model: str, hue_model: str, calibration: Mapping[str, Any],
                 pattern: str, history: str, cross_section: str, residual_map: str, camera_json: str = "") -> None:
    """Pre-distorted projector pattern (paper Fig. 6) and the calibration QA figures (Fig. 7)."""
    from huefringe import compensation as calib
    from huefringe.io import write_png_rgb

    s = load_session(session)
    t = HueTable.load(table)
    cal = PlaneCalibration.load(model)
    comp = calibration["compensation"]
    image, steps = calib.compensate_pattern(
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
    calib.hue_cross_section_figure(hue[row], phase[row], truth[row], cross_section)
    calib.residual_map_figure(wrap(phase - truth), residual_map)
    qa = calib.qa_stats(hue, phase, true_phase=truth, table=t, raw_rgb=balanced)
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
    for i, (n, height, phase, hue, stats, u_map, support) in enumerate(results):
        path = s.frames[n]
        write_tiff(heights[i], height, pixel_pitch_mm=s.pixel_pitch_mm)
        if uncertainties:
            write_tiff(uncertainties[i], u_map, pixel_pitch_mm=s.pixel_pitch_mm)
        if supports:
            write_tiff(supports[i], np.rint(support).astype(np.uint16))
        if n in maps:
            write_tiff(maps[n][0], phase)
            write_tiff(maps[n][1], hue)
        write_json(qa[i], {"frame": n, "file": str(path), **stats})
        log.info("frame %04d: %.1f %% valid, median %.3f mm", n, 100 * stats["valid_fraction"],
                 stats["median_height_mm"] or float("nan"))


def frame_results(s: Session, t: HueTable, cal: PlaneCalibration, frames: Sequence[int], hue_model: str,
                  measurement: Mapping[str, Any], map_frames: set[int] | None = None, want_uncertainty: bool = True,
                  reader: CaptureReader | None = None):
    """Measure frames of a session one by one: yields ``(frame, height, phase, hue, stats, uncertainty, support)``.

    The loop of :func:`measure_frames` (which writes what it yields) and of :func:`huefringe.measure`
    (which keeps it): the fused kernel with ``measurement.kernel`` and reference-relative
    unwrapping, :func:`~huefringe.perframe.measure_frame` otherwise. ``phase`` and ``hue`` are
    those of the frames in ``map_frames`` (default: all; None from the kernel for the others).
    ``uncertainty`` is the height's standard uncertainty map (mm, :mod:`huefringe.uncertainty`;
    None from the kernel with ``want_uncertainty=False``), ``support`` the number of pixels the
    phase filter averaged into each height (float32, 0 where NaN; None alike).
    After either chain, ``measurement.edge_jump_mm`` > 0 invalidates the mixed pixels of step edges
    (``measurement.edge_test``: :func:`~huefringe.perframe.step_edge_mask`, or
    :func:`~huefringe.perframe.plane_edge_mask` with ``edge_plane_tol_mm``; ``stats["edge_fraction"]``),
    so the kernel and :func:`~huefringe.perframe.measure_frame` stay identical to each other; then the uncertainty
    gains the lateral term of the delivered heights (:func:`~huefringe.uncertainty.add_lateral`,
    ``measurement.lateral_uncertainty_px``; 0 = off).
    Each frame is refused (:class:`~huefringe.perframe.FrameError`, naming it) before it is yielded.
    The kernel's arrays are reused from frame to frame: copy what you keep.
    Every capture is read through ``reader`` (the camera corrections, :class:`~huefringe.camera.CaptureReader`:
    both chains read the same registered sensor codes); default: as stored.
    """
    maps = set(frames) if map_frames is None else set(map_frames)
    reader = reader or CaptureReader()
    white = reader.rgb(s.object_white)
    shadow = shadow_mask(white, measurement["shadow_fraction"])
    adaptive = noise_aware_adaptive(measurement.get("denoise_adaptive"), t)
    budget = None
    fast = bool(measurement["kernel"]) and measurement["unwrap"] == "reference"
    if fast:
        prep = kernel.prepare(t, cal, white, hue_model=hue_model, min_saturation=measurement["min_saturation"],
                              shadow=shadow, bit_depth=s.bit_depth, predistortion=s.predistortion,
                              own_noise=bool(measurement.get("own_noise", False)))
        table_invalid = float(np.mean(~t.valid))
        shadow_fraction = float(shadow.mean())
        del t  # the kernel's pixel-major copy replaces the band-major table
        buffers = (np.empty(prep.shape, np.float32), np.empty(prep.shape, bool))  # reused frame to frame
    blur2 = float(cal.texture_blur_px2 or 0.0)  # the plane calibration's (calibration.texture_blur_px2)
    # the texture term of u: the heights' change when the correction's blur moves by its uncertainty
    blur_u = (float(cal.texture_blur_u_px2 or 0.0)
              if want_uncertainty and measurement.get("texture_uncertainty", True) else 0.0)
    for n in frames:
        path = s.frames[n]
        # the texture-edge correction (huefringe.texture) once, before either chain: both read it
        rgb = None
        moved = None  # the capture corrected with the blur moved by its uncertainty (texture term)
        if blur2 > 0 or blur_u > 0:
            raw = reader.rgb(path)
            clip = clipped_mask(raw, s.bit_depth)
            if blur2 > 0:
                rgb = texture.correct(raw, white, blur2, clipped=clip)
            if blur_u > 0:
                moved = texture.correct(raw, white, blur2 + blur_u, clipped=clip)
        if rgb is None and reader.demixed:  # the demixed channels (camera.colour_demixing), to both chains
            rgb = reader.rgb(path)
        if fast:  # the kernel reads the sensor codes as read_rgb scales them
            if moved is not None:  # first, on buffers of its own (a copy: the pass below reuses the kernel's)
                moved_height = np.array(kernel.frame_maps(
                    prep, moved, denoise_radius=measurement["denoise_radius"], denoise_adaptive=adaptive,
                    want_maps=False, want_dphi=False, want_uncertainty=False).height)
            m = kernel.frame_maps(prep, reader.codes(path) if rgb is None else rgb, denoise_radius=measurement["denoise_radius"],
                                  denoise_adaptive=adaptive,
                                  want_maps=n in maps, want_dphi=True, want_uncertainty=want_uncertainty,
                                  out=buffers)
            px = m.valid.size  # frame_stats with unwrap's reference flags, in one compiled pass
            # the wrap flags on the pixels valid before the filter (measure_frame's unwrap call): the
            # kernel's dphi is NaN exactly where no phase was decoded; m.valid has lost the filter's rejects
            stats = reference_frame_stats(m.dphi, m.valid, m.height, clipped_fraction=m.counts["clipped"] / px,  # type: ignore[arg-type]
                                          hue_undefined_fraction=m.counts["hue_undefined"] / px,
                                          table_invalid_fraction=table_invalid, shadow_fraction=shadow_fraction,
                                          hue_model=hue_model, flag_valid=np.isfinite(m.dphi))
            height, phase, hue, u_map, support = m.height, m.phase, m.hue, m.uncertainty, m.support
            if moved is not None:
                tex_u = texture_term(height, moved_height)
        else:
            budget = pixel_budget(t, cal) if budget is None else budget

            def reference(image: NDArray[np.floating]):
                return measure_frame(image, white, t, cal, hue_model=hue_model, min_saturation=measurement["min_saturation"],
                                     shadow=shadow, unwrap_mode=measurement["unwrap"], bit_depth=s.bit_depth,
                                     denoise_radius=measurement["denoise_radius"], predistortion=s.predistortion,
                                     denoise_adaptive=adaptive, budget=budget,
                                     own_noise=bool(measurement.get("own_noise", False)))

            res = reference(reader.rgb(path) if rgb is None else rgb)
            height, phase, hue, stats, u_map = res.height, res.phase, res.hue, res.stats, res.uncertainty
            support = res.support
            if moved is not None:  # the same chain and budget (budget=None would rebuild it every frame)
                tex_u = texture_term(height, reference(moved).height)
        jump = float(measurement.get("edge_jump_mm", 0.0) or 0.0)
        if jump > 0:  # mixed pixels at step edges, after either chain (the kernel's buffers are not touched)
            height, (phase, u_map), (support,), changed = remove_step_edges(
                height, jump, nan_maps=(phase, u_map), zero_maps=(support,), test=str(measurement.get("edge_test", "plane")),
                tol_mm=float(measurement.get("edge_plane_tol_mm", 0.1)))
            stats = {**stats, **changed}
        if u_map is not None and moved is not None:  # the texture term, in quadrature (NaN where the height is)
            u_map = np.hypot(u_map, tex_u).astype(np.float32)
        lateral = float(measurement.get("lateral_uncertainty_px", LATERAL_PX))
        step = float(measurement.get("lateral_step_px", LATERAL_STEP_PX))
        if u_map is not None and (lateral > 0 or step > 0):  # the lateral term on the heights as delivered (after the edge mask)
            u_map = add_lateral(height, u_map, lateral_px=lateral, step_px=step)
        _refuse_bad_frame(path, stats, measurement)
        yield n, height, phase, hue, stats, u_map, support


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
    from huefringe.cloud import _check_colours, colour_bytes, write_height_cloud

    if not len(frames) == len(heights) == len(clouds):
        raise ValueError(f"cloud_frames: {len(frames)} frames, {len(heights)} height maps, {len(clouds)} clouds")
    s = load_session(session)
    model, reader = session_corrections(s, camera_json)
    white = reader.rgb(s.object_white)
    if uncertainties and len(uncertainties) != len(frames):
        raise ValueError(f"cloud_frames: {len(frames)} frames, {len(uncertainties)} uncertainty maps")
    rgb = colour_bytes(_check_colours(white, white.shape[:2]).reshape(-1, 3))  # once per batch
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
    from huefringe.settings import software_identity
    from huefringe.x3p import write_height_x3p

    if not len(frames) == len(heights) == len(x3p):
        raise ValueError(f"x3p_frames: {len(frames)} frames, {len(heights)} height maps, {len(x3p)} X3P files")
    s = load_session(session)
    software = software_identity()
    for n, height, out in zip(frames, heights, x3p, strict=True):
        t0 = time.perf_counter()
        write_height_x3p(out, read_tiff(height), s.pixel_pitch_mm, provenance=s.provenance, session_id=s.id,
                         frame=n, software=software)
        log.info("frame %04d: %s, %d bytes, %.3f s", n, out, Path(out).stat().st_size, time.perf_counter() - t0)


def _refuse_bad_frame(path: Path, stats: Mapping[str, Any], measurement: Mapping[str, Any]) -> None:
    if stats["clipped_fraction"] > measurement["max_clipped_fraction"]:
        raise FrameError(
            f"{path}: {100 * stats['clipped_fraction']:.1f} % of the pixels are clipped (sensor saturated), "
            f"above the limit of {100 * measurement['max_clipped_fraction']:.1f} %; reduce the exposure"
        )
    if stats["valid_fraction"] < measurement["min_valid_fraction"]:
        raise FrameError(
            f"{path}: only {100 * stats['valid_fraction']:.1f} % of the pixels carry a usable fringe "
            f"(limit {100 * measurement['min_valid_fraction']:.1f} %): lens cap, projector off or no fringe?"
        )


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
        from huefringe import uncertainty as unc

        errs, us, per = [], [], []
        for p, q, n in zip(heights, uncertainties, s.frame_ids, strict=True):
            e = (read_tiff(p).astype(np.float64) - read_tiff(s.ground_truth[n]))
            u = read_tiff(q).astype(np.float64)
            r = unc.reliability(e, u)
            per.append({"frame": n, "coverage_2u": r["coverage_2u"], "rms_u_mm": r.get("rms_u_mm")})
            errs.append(e.ravel())
            us.append(u.ravel())
        pooled = unc.reliability(np.concatenate(errs), np.concatenate(us))
        pooled["per_frame"] = per
        out["trapezoidal-hsi"]["uncertainty"] = pooled
        if reliability:
            from huefringe.render import reliability_figure

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
    from huefringe import mesh as meshing

    s = load_session(session)
    model, reader = session_corrections(s, camera_json)
    h = read_tiff(height)
    m = meshing.height_to_mesh(h, s.pixel_pitch_mm, colours=reader.rgb(s.object_white))
    m = meshing.clean_mesh(m, min_island_faces=mesh["min_island_faces"])
    if mesh["decimate_faces"]:
        m = meshing.decimate(m, mesh["decimate_faces"])
    if uncertainty is not None:
        meshing.attach_sigma(m, read_tiff(uncertainty), s.pixel_pitch_mm)
    if not model.plain:  # last: the steps above find pixels from u * pitch
        meshing.place_vertices(m, model.xy_at, s.pixel_pitch_mm)
    meshing.export_mesh(m, ply, stl)
    if meshing.stats_path(ply) != Path(stats):
        raise RuntimeError(f"mesh statistics went to {meshing.stats_path(ply)}, the workflow expects {stats}")


def render(session: str, mesh: str, height: str, phase: str, render: Mapping[str, Any], frame: str,
           top: str, oblique1: str, oblique2: str, height_map: str, phase_map: str,
           uncertainty: str = "", uncertainty_map: str = "", camera_json: str = "") -> None:
    """Off-screen renders (top and two oblique views) and the height and phase figures of one frame
    (and, given the frame's ``uncertainty`` TIFF, the uncertainty figure beside the height's)."""
    import trimesh

    from huefringe import render as rendering

    s = load_session(session)
    size = (int(render["width"]), int(render["height"]))
    clim = _height_limits(s)
    model = session_corrections(s, camera_json)[0]
    if model.plain:
        cams = rendering.camera_for_field((s.width - 1) * s.pixel_pitch_mm, (s.height - 1) * s.pixel_pitch_mm, clim,
                                          size=size)
    else:  # the lens model's field on the plate (the mesh's vertices are in its X, Y)
        x0, x1, y0, y1 = model.field_mm()
        cams = rendering.camera_for_field(x1 - x0, y1 - y0, clim, origin=(x0, y0), size=size)
    m = trimesh.load(mesh, process=False, force="mesh")
    out_dir = Path(top).parent
    written = rendering.render_views(m, out_dir, f"frame_{frame}", clim=clim, camera=cams, size=size,
                                     title=f"{s.id} frame {frame}")
    expected = {Path(top), Path(oblique1), Path(oblique2)}
    if not expected <= set(written):
        raise RuntimeError(f"render wrote {written}, expected {sorted(map(str, expected))}")
    rendering.height_map_figure(read_tiff(height), s.pixel_pitch_mm, height_map, clim=clim,
                                title=f"{s.id} frame {frame}: height (mm)")
    rendering.wrapped_phase_figure(read_tiff(phase), phase_map, pitch_mm=s.pixel_pitch_mm,
                                   title=f"{s.id} frame {frame}: corrected code phase")
    if uncertainty and uncertainty_map:
        rendering.uncertainty_map_figure(read_tiff(uncertainty), s.pixel_pitch_mm, uncertainty_map,
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
    import json as jsonlib

    from huefringe import metrology, report
    from huefringe import render as rendering

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
            return metrology.evaluate_session((read_tiff(p) for p in paths), spec, s.pixel_pitch_mm,
                                              range_mm=range_mm, edge_exclusion=edge, camera=lens, **kw)
        except metrology.MetrologyError as exc:
            where = paths[exc.frame] if exc.frame is not None and exc.frame < len(paths) else s.root / "session.yaml"
            raise metrology.MetrologyError(f"{where}: {exc} (specimen in {s.root / 'session.yaml'})") from exc

    method = evaluate(heights)
    if uncertainties:
        add_step_uncertainty(method, _TiffMaps(heights), _TiffMaps(uncertainties), spec, s.pixel_pitch_mm,
                             PlaneCalibration.load(model), HueTable.load(object_table), edge_exclusion=edge,
                             denoise_radius=int(config["measurement"]["denoise_radius"]),
                             supports=_TiffMaps(supports) if supports else None, workers=threads, camera=lens,
                             lateral_px=float(config["measurement"].get("lateral_uncertainty_px", LATERAL_PX)),
                             lateral_step_px=float(config["measurement"].get("lateral_step_px", LATERAL_STEP_PX)))
    base = evaluate(baseline, method="three-step-phase-shift") if baseline else None
    plane_stats = jsonlib.loads(Path(planes).read_text())
    table_stats = jsonlib.loads(Path(tables).read_text())
    provenance = report.collect_provenance(s.id, dict(config), s.input_files(), root=s.root)
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
    doc = report.build_report_json(s.id, spec, method, base, extras=extras)
    # a profile through the middle of the steps' ROIs (paper Fig. 9 d)
    rows = [(st["roi"][1] + st["roi"][3]) // 2 for st in spec["steps"]]
    rendering.profile_figure(read_tiff(heights[0]), int(np.median(rows)), s.pixel_pitch_mm, profile,
                             title=f"{s.id} frame {s.frame_ids[0]:04d}: cross-section")
    report.per_frame_figure(doc, per_frame)
    figures = {"profile": Path(profile), "height": Path(height_map), "render": Path(render),
               "per_frame": Path(per_frame), "calibration_qa": Path(cross_section)}
    write_json(json, doc)
    report.write_report_html(html, doc, figures, provenance, pixel_pitch_mm=s.pixel_pitch_mm,
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
    import json as jsonlib

    from huefringe import table1 as t1

    results = {}
    for period, path in zip(periods, reports, strict=True):
        doc = jsonlib.loads(Path(path).read_text())
        results[int(period)] = {"method": {"steps": doc["steps"]}}
        if doc.get("baseline"):
            results[int(period)]["baseline"] = doc["baseline"]
    rows = t1.table1_rows(results, step_name=step, nominal=nominal_mm)
    t1.write_table1(rows, markdown, csv, figure)
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
                         camera: CameraModel | None = None, lateral_px: float = LATERAL_PX,
                         lateral_step_px: float = LATERAL_STEP_PX) -> None:
    """Add ``u_mm``, ``U_mm`` (k = 2), ``conformance`` and ``uncertainty_budget`` to each step of an
    :func:`huefringe.metrology.evaluate_session` block, and ``verdict_with_uncertainty`` to the block.

    ``pass`` stays ``|error| <= tolerance`` (the contract); ``conformance`` is the ISO 14253-1
    decision with U: ``pass``, ``fail`` or ``undecided``. ``camera``: the lens model the steps were
    evaluated with (the budget's plane lever arms at each pixel's X, Y); ``lateral_px``: the
    ``measurement.lateral_uncertainty_px`` the maps were made with, ``lateral_step_px`` its
    ``measurement.lateral_step_px`` (the budget takes the lateral term out).
    """
    from huefringe import uncertainty as unc

    budgets = unc.step_budget(heights, uncertainties, specimen, pitch_mm, cal.a, cal.b, unc.pixel_budget(table, cal),
                              edge_exclusion=edge_exclusion, denoise_radius=denoise_radius, supports=supports,
                              workers=workers, camera=camera, lateral_px=lateral_px,
                              lateral_step_px=lateral_step_px)
    tol = float(method["tolerance_mm"])
    for step, bud in zip(method["steps"], budgets, strict=True):
        step["u_mm"] = bud["u_mm"]
        step["U_mm"] = bud["U_mm"]
        step["conformance"] = unc.conformance(step["error_mm"], tol, bud["U_mm"])
        step["uncertainty_budget"] = {k: v for k, v in bud.items() if k not in ("name", "u_mm", "U_mm")}
    zones = {st["conformance"] for st in method["steps"]}
    method["verdict_with_uncertainty"] = "FAIL" if "fail" in zones else ("UNDECIDED" if "undecided" in zones else "PASS")


def archive_session(session: str, results: str, config: Mapping[str, Any], archive: str) -> None:
    """Pack a session and its results with RO-Crate metadata, then read the archive back once."""
    from huefringe.archive import ArchiveError, verify_archive, write_archive

    write_archive(session, results, archive, config=dict(config))
    check = verify_archive(archive)
    if not check.ok:
        raise ArchiveError(check.summary())
    log.info("%s", check.summary())


def archive(archives: Sequence[str], index: str) -> None:
    """The run's archives in one index (``results/archives.json``): size and SHA-256 of each ZIP
    and its crate's summary (:func:`huefringe.archive.archive_index`)."""
    from huefringe.archive import archive_index

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
    camera_calibration(str(session), config.get("camera", {}), cal, record=cam)
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
    import inspect

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
    from huefringe.archive import ArchiveError
    from huefringe.metrology import MetrologyError
    from huefringe.session import SessionError
    from huefringe.x3p import X3PError

    logfile = smk.log[0] if len(smk.log) else None
    handlers: list[logging.Handler] = [logging.StreamHandler(sys.stderr)]
    if logfile:
        Path(logfile).parent.mkdir(parents=True, exist_ok=True)
        handlers.append(logging.FileHandler(logfile, mode="w"))
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s", handlers=handlers, force=True)
    from huefringe.io import remove_stale_parts

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
