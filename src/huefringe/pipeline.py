"""The measuring pipeline in memory: prepare a session once, then measure one frame at a time.

:func:`prepare_session` runs what the workflow's calibration jobs run (the camera corrections,
both hue tables, the plane calibration with its phase-error table and texture blur);
:func:`prepare_frames` readies the per-frame chain (the object's white image, shadow, the fused
kernel or the NumPy reference chain) and :func:`measure_one` turns one capture into one
:class:`FrameResult`, the only shape a frame's result has. :func:`huefringe.measure` and the
workflow's stages (:mod:`huefringe.stages`, which read files, call these and write files) share
them, so both give the same numbers. The chains themselves are :mod:`huefringe.kernel` and
:mod:`huefringe.perframe`; their own result records are converted here.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe import kernel, patterns, phase_error, row_banding, texture
from huefringe.camera import CameraModel, CaptureReader, bayer_resampling, camera_record, corrections, mixing_band_pairs
from huefringe.colour import hue as hue_of
from huefringe.colour import balanced_hue, white_balance, white_gains
from huefringe.height import PlaneCalibration, PlaneCalibrationError, calibrate_planes
from huefringe.huetable import HueTable, HueTableError, build_table, white_balance_floor
from huefringe.perframe import (FrameError, clipped_mask, measure_frame, reference_frame_stats, remove_step_edges,
                                shadow_mask, shadow_masks)
from huefringe.session import Session
from huefringe.uncertainty import (PixelBudget, add_lateral, common_interpolation, noise_correlation,
                                   phase_error_residual_rad, pixel_budget)

__all__ = ["Calibrated", "FramePipeline", "FrameResult", "bayer_noise_correlation", "frame_results", "measure_one",
           "noise_aware_adaptive", "prepare_frames", "prepare_session", "session_camera_record",
           "session_corrections", "session_hue_table", "session_plane_calibration", "session_texture_blur",
           "session_texture_phases"]

_log = logging.getLogger("huefringe")


@dataclass
class FrameResult:
    """One frame measured: what :func:`measure_one` returns, for the workflow and :func:`huefringe.measure` alike."""

    frame: int
    """The frame number (``session.yaml``)."""
    height: NDArray[np.float32]
    """Height (mm) above the reference plane, NaN where invalid."""
    stats: dict[str, Any] = field(default_factory=dict)
    """The frame's QA figures (``qa/frames/frame_NNNN.json``)."""
    phase: NDArray[np.float32] | None = None
    """Corrected code phase, wrapped to [0, 2 pi), NaN where invalid (None where maps were not asked for)."""
    hue: NDArray[np.float32] | None = None
    """White-balanced captured hue, NaN where undefined (None alike)."""
    uncertainty: NDArray[np.float32] | None = None
    """Standard uncertainty of the height (mm), NaN where the height is NaN (:mod:`huefringe.uncertainty`);
    None without ``want_uncertainty``."""
    support: NDArray[np.float32] | None = None
    """Pixels the phase filter averaged into each height, 0 where NaN (None alike)."""

    @property
    def valid(self) -> NDArray[np.bool_]:
        """Pixels with a height."""
        return np.isfinite(self.height)


def session_camera_record(s: Session, camera: Mapping[str, Any], calibration: Mapping[str, Any]) -> dict[str, Any]:
    """The ``calib/camera.json`` record of a session in memory (:func:`camera_calibration` writes it)."""
    read = CaptureReader(bayer=bayer_resampling(s.meta, camera["demosaic"])).rgb
    white = read(s.reference_white)
    mode = camera["chromatic_registration"]
    planes = [] if mode is False or mode == "false" else [read(p) for p in s.planes.values()]
    demix = camera["colour_demixing"]
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
    record = json.loads(Path(camera_json).read_text()) if camera_json else None
    return corrections(record, s.meta)


def _calibration_opts(calibration: Mapping[str, Any]) -> dict[str, Any]:
    return {"min_saturation": calibration["min_saturation"], "min_intensity": calibration["min_intensity"]}

#: A hue table usable for fewer pixels than this is refused: the bands are not what they claim.
MIN_TABLE_VALID_FRACTION = 0.2

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


def session_hue_table(s: Session, which: str, hue_model: str, calibration: Mapping[str, Any], *,
                      reader: CaptureReader | None = None) -> HueTable:
    """The hue table of a session's reference plate or object, in memory (:func:`hue_table` writes it);
    the captures read through ``reader`` (the camera corrections; default: as stored). The
    reference table's ``stats["colour_flicker_means"]`` carries the image-mean hues of the
    colour-flicker QA's bands (:func:`reference_colour_flicker`), taken from the table's own
    white-balanced hue as it builds.

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
    limit = float(calibration["max_white_clipped_fraction"])
    if clipped > limit:
        raise HueTableError(
            f"{white_path}: {100 * clipped:.1f} % of the pixels are clipped (sensor saturated; limit "
            f"{100 * limit:g} %, calibration.max_white_clipped_fraction): white balance needs the unclipped level; "
            "reduce the exposure"
        )
    flicker = _FlickerMeans(len(bands), len(bands[0]), hue_model, calibration) if which == "reference" else None
    built = build_table(bands, white, model=hue_model, progress=False, read=reader.rgb,
                        on_hue=None if flicker is None else flicker.add, **_calibration_opts(calibration))
    _refuse_bad_table(s.root / which / "hue", built.stats)
    if flicker is not None:
        built.stats["colour_flicker_means"] = flicker.record()
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
    decoded = phases  # as decoded: the phase-error table learned from these planes would fit part of their banding
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
    if lut is not None:  # the plate's shared chord error goes with the table (the interpolation term's bins)
        smoothing = float(lut.stats["smooth_bins"]) * 2.0 * np.pi / float(lut.stats["bins"])
        cal.budget = {**(cal.budget or {}), **common_interpolation(t, smoothing)}
    blur = calibration["texture_blur_px2"]
    if blur == "auto" or float(blur or 0.0) > 0:  # the light without fringe the correction takes out first
        cal.projector_off = session_projector_off(s, calibration, reader)
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
        cal.stats.setdefault("uncertainty", {})["phase_error_residual_u_rad"] = phase_error_residual_rad(lut.stats)
    cal.stats["row_banding"] = plane_row_banding(s, decoded, valid, cal,
                                                 threshold_rad=float(calibration["row_banding_max_rad"]))
    cal.stats["colour_flicker"] = reference_colour_flicker(s, hue_model, calibration, reader, table=t)
    return cal


#: reference hue bands (evenly spaced, every repeat) the colour-flicker QA reads
FLICKER_BANDS = 16


def flicker_bands(n: int) -> list[int]:
    """The reference bands (of ``n``) the colour-flicker QA looks at: up to :data:`FLICKER_BANDS`, evenly spaced."""
    return sorted({int(round(i * n / min(n, FLICKER_BANDS))) % n for i in range(min(n, FLICKER_BANDS))})


def _flicker_floor(calibration: Mapping[str, Any]) -> float:
    """The white-balance floor of the colour-flicker QA's hue: the reference table's own."""
    return white_balance_floor(float(calibration["min_intensity"]))


class _FlickerMeans:
    """The colour-flicker QA's image-mean hues (:func:`huefringe.row_banding.mean_hue`) of
    :func:`flicker_bands`, taken from the white-balanced hue the hue table computes as it builds
    (``build_table(on_hue=...)``: its floor, :func:`_flicker_floor`, and minimum saturation)."""

    def __init__(self, n_bands: int, repeats: int, hue_model: str, calibration: Mapping[str, Any]) -> None:
        self.bands = flicker_bands(n_bands) if repeats >= 2 else []
        self.means: dict[int, list[float | None]] = {i: [None] * repeats for i in self.bands}
        self.hue_model = hue_model
        self.min_saturation = float(calibration["min_saturation"])
        self.floor = _flicker_floor(calibration)

    def add(self, i: int, r: int, hue: NDArray[np.floating]) -> None:
        if i in self.means:
            self.means[i][r] = row_banding.mean_hue(hue)

    def record(self) -> dict[str, Any]:
        return {"hue_model": self.hue_model, "min_saturation": self.min_saturation, "floor": self.floor,
                "bands": self.bands, "mean_hue_rad": [self.means[i] for i in self.bands]}


def _flicker_means_of(table: HueTable | None, n: int, hue_model: str, calibration: Mapping[str, Any]
                      ) -> list[list[float | None]] | None:
    """The image-mean hues a reference table carries for the colour-flicker QA, when they were taken
    with this hue model, minimum saturation, white-balance floor and band choice; else None."""
    rec = (table.stats or {}).get("colour_flicker_means") if table is not None else None
    if (not rec or rec.get("hue_model") != hue_model or rec.get("bands") != flicker_bands(n)
            or rec.get("min_saturation") != float(calibration["min_saturation"])
            or rec.get("floor") != _flicker_floor(calibration)):
        return None
    return [list(m) for m in rec["mean_hue_rad"]]


def reference_colour_flicker(s: Session, hue_model: str, calibration: Mapping[str, Any],
                             reader: CaptureReader | None = None, table: HueTable | None = None) -> dict[str, Any]:
    """The reference bands' colour flicker (:func:`huefringe.row_banding.repeat_hue_flicker`):
    whether a uniform band's white-balanced hue changes between its repeats (a colour-sequential
    projector with an exposure that is not a whole number of its colour cycles, a flickering
    light, auto white balance). Looks at up to :data:`FLICKER_BANDS` bands, every repeat: their
    image-mean hues from the reference ``table``'s ``stats["colour_flicker_means"]`` (the table's own
    hue, taken as it was built, :func:`session_hue_table`) when it carries them for this hue model,
    minimum saturation and white-balance floor, else read again through ``reader`` and white
    balanced as the table does (:func:`huefringe.huetable.white_balance_floor` of ``min_intensity``). QA only.

    Returns the record kept in ``calib/planes.json`` (``colour_flicker``): the
    :class:`~huefringe.row_banding.ColourFlicker` fields (``amplitude_rad`` None with one repeat);
    a suspected flicker is also logged as a warning.
    """
    if s.repeats < 2:
        return row_banding.ColourFlicker(None, None, 0, s.repeats, False,
                                         float(calibration["colour_flicker_max_rad"])).to_dict()
    n = len(s.reference_bands)
    means = _flicker_means_of(table, n, hue_model, calibration)
    if means is None:
        read = (reader or CaptureReader()).rgb
        gains = white_gains(read(s.reference_white), _flicker_floor(calibration))
        means = [[row_banding.mean_hue(balanced_hue(read(p), gains, hue_model,
                                                    min_saturation=float(calibration["min_saturation"])))
                  for p in s.reference_bands[i]] for i in flicker_bands(n)]
    fl = row_banding.flicker_from_means(means, threshold_rad=float(calibration["colour_flicker_max_rad"]))
    if fl.suspected:
        _log.warning("%s: the repeats of a uniform hue band differ in hue by %.4f rad (standard deviation over %d "
                     "bands): the colour balance changes from image to image (a colour-sequential projector filmed "
                     "with an exposure that is not a whole number of its colour cycles, flickering light, auto white "
                     "balance?). See docs/capture.md, 'Colour-sequential projectors'",
                     s.root / "reference" / "hue", fl.amplitude_rad, fl.bands)
    return fl.to_dict()



def plane_row_banding(s: Session, phases: Mapping[float, NDArray[np.floating]],
                      valid: Mapping[float, NDArray[np.bool_]], cal: PlaneCalibration,
                      threshold_rad: float = row_banding.THRESHOLD_RAD) -> dict[str, Any]:
    """The calibration planes' row banding (:func:`huefringe.row_banding.row_banding`): a
    colour-sequential projector filmed with an exposure that is not a whole number of its colour
    cycles (docs/capture.md). QA only: nothing measured depends on it. ``phases``: as decoded,
    before the phase-error table (learned from the same planes, it would take part of their own
    banding, which the object frames, each with its own, do not share).

    Returns the record kept in ``calib/planes.json`` (``row_banding``): per plane (key: height in
    mm, ``%.3f``) the :class:`~huefringe.row_banding.RowBanding` fields or ``{"error": why}``;
    ``amplitude_rad``, ``amplitude_px`` and ``period_rows`` of the plane with the largest
    amplitude, ``amplitude_mm`` (that phase through the reference's median phase-to-height slope
    ``1 / a``), ``suspected`` (any plane's) and ``threshold_rad``. A suspected banding is also
    logged as a warning.
    """
    planes: dict[str, Any] = {}
    worst: row_banding.RowBanding | None = None
    for z in sorted(phases):
        try:
            rb = row_banding.row_banding(phases[z], valid[z], period_px=s.period_px, threshold_rad=threshold_rad)
        except PlaneCalibrationError as exc:
            planes[f"{z:.3f}"] = {"error": str(exc)}
            continue
        planes[f"{z:.3f}"] = rb.to_dict()
        if worst is None or rb.amplitude_rad > worst.amplitude_rad:
            worst = rb
    out: dict[str, Any] = {"planes": planes, "threshold_rad": threshold_rad}
    if worst is None:
        out.update(amplitude_rad=None, amplitude_px=None, amplitude_mm=None, period_rows=None, suspected=False)
        return out
    a = np.abs(np.asarray(cal.a, np.float64))
    a = a[np.isfinite(a) & (a > 0)]
    mm_per_rad = float(1.0 / np.median(a)) if a.size else None
    out.update(amplitude_rad=worst.amplitude_rad, amplitude_px=worst.amplitude_px,
               amplitude_mm=None if mm_per_rad is None else worst.amplitude_rad * mm_per_rad,
               period_rows=worst.period_rows,
               suspected=any(bool(p.get("suspected")) for p in planes.values()))
    if out["suspected"]:
        _log.warning("%s: the calibration planes' phase bands along the rows (%.3f rad RMS = %.2f px of the fringe, "
                     "about %s mm of height, every %s rows): a colour-sequential (single-chip DLP) projector "
                     "filmed with an exposure that is not a whole number of its colour cycles? See docs/capture.md, "
                     "'Colour-sequential projectors'", s.root / "reference" / "planes", worst.amplitude_rad,
                     worst.amplitude_px, "?" if out["amplitude_mm"] is None else f"{out['amplitude_mm']:.4f}",
                     "?" if worst.period_rows is None else f"{worst.period_rows:.0f}")
    return out


#: object frames the texture-blur estimate reads (pairs of them)
TEXTURE_BLUR_FRAMES = 4


#: object hue bands per channel (every repeat) the light without fringe is averaged over
PROJECTOR_OFF_BANDS = 8


def session_projector_off(s: Session, calibration: Mapping[str, Any],
                          reader: CaptureReader | None = None) -> NDArray[np.float32] | None:
    """The light the object sends the camera with the projector's code at 0 (ambient light
    reflected, stray light, the projector's black level), per pixel and channel: each channel's mean
    over object hue bands (every repeat) whose code is 0 in that channel, up to
    :data:`PROJECTOR_OFF_BANDS` of them spread over its third of the bands
    (:func:`huefringe.texture.projector_off_light`, ``patterns.band_rgb``), read through ``reader``
    as the frames are. None when ``calibration.texture_offset`` is off."""
    if not calibration.get("texture_offset", True):
        return None
    read = (reader or CaptureReader()).rgb
    n = len(s.object_bands)
    codes = [patterns.band_rgb(i, n) for i in range(n)]
    chosen: set[int] = set()
    for c in range(3):
        zero = [i for i in range(n) if codes[i][c] == 0.0]
        take = min(len(zero), PROJECTOR_OFF_BANDS)
        chosen.update(zero[int(k * len(zero) / take)] for k in range(take))
    return texture.projector_off_light((read(p), codes[i]) for i in sorted(chosen) for p in s.object_bands[i])


def session_texture_phases(s: Session, t: HueTable, cal: PlaneCalibration, hue_model: str,
                           calibration: Mapping[str, Any], white: NDArray[np.floating], *,
                           reader: CaptureReader | None = None, offset: NDArray[np.floating] | None = None,
                           ) -> tuple[list[NDArray[np.float64]], list[NDArray[np.float64]]]:
    """The raw phase differences (the kernel, no phase filter; NaN where not valid) of the session's
    first object frames (up to :data:`TEXTURE_BLUR_FRAMES`) as captured and after
    :func:`huefringe.texture.correct` with ``sigma^2 = 1`` (with ``offset`` taken out first; the
    blur estimate's own are without it): the inputs of :func:`huefringe.texture.blur_from_phases`.
    ``white``: the object white image as ``reader`` reads it."""
    read = (reader or CaptureReader()).rgb  # the frames as the chains read them (re-demosaic, registration)
    prep = kernel.prepare(t, cal, white, hue_model=hue_model, min_saturation=calibration["min_saturation"],
                          shadow=shadow_mask(white, calibration["shadow_fraction"]), bit_depth=s.bit_depth,
                          predistortion=s.predistortion)
    plain: list[NDArray[np.float64]] = []
    unit: list[NDArray[np.float64]] = []
    for n in s.frame_ids[:TEXTURE_BLUR_FRAMES]:
        rgb = read(s.frames[n])
        for sigma2, out in ((0.0, plain), (1.0, unit)):
            m = kernel.frame_maps(prep, texture.correct(rgb, white, sigma2, offset=offset), denoise_radius=0,
                                  want_dphi=True)
            out.append(np.where(m.valid, m.dphi, np.nan))
    return plain, unit


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
    plain, unit = session_texture_phases(s, t, cal, hue_model, calibration, white, reader=reader)
    est = {**texture.blur_from_phases(plain, unit), "frames": [int(n) for n in frames]}
    if "rejected" in est:
        return fallback(est, "phase estimate refused (see rejected)")
    return {**est, "source": "auto: estimated from the object frames"}


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



@dataclass
class Calibrated:
    """A session prepared once (:func:`prepare_session`): its corrections, hue tables and plane calibration."""

    session: Session
    camera_record: dict[str, Any]
    """What ``calib/camera.json`` holds: the X, Y model and the channel registration."""
    camera: CameraModel
    reader: CaptureReader
    """Reads every capture through the camera corrections."""
    tables: dict[str, HueTable]
    """The hue tables of the ``"reference"`` plate and of the ``"object"``."""
    calibration: PlaneCalibration
    """The plane calibration, with its phase-error table and texture blur."""


def prepare_session(s: Session, config: Mapping[str, Any]) -> Calibrated:
    """Prepare a session once, in memory: camera corrections, both hue tables, plane calibration.

    ``config`` is a full configuration (packaged defaults with overrides:
    :func:`huefringe.settings.load_config`); ``hue_model``, ``calibration`` and ``camera`` are read.
    The workflow's ``camera_calibration``, ``hue_table`` and ``plane_calibration`` jobs compute the
    same, one file each.
    """
    hue_model, calibration = config["hue_model"], config["calibration"]
    record = session_camera_record(s, config["camera"], calibration)
    model, reader = corrections(record, s.meta)
    tables = {w: session_hue_table(s, w, hue_model, calibration, reader=reader) for w in ("reference", "object")}
    cal = session_plane_calibration(s, tables["reference"], hue_model, calibration, reader=reader,
                                    object_table=tables["object"])
    return Calibrated(session=s, camera_record=record, camera=model, reader=reader, tables=tables, calibration=cal)


@dataclass
class FramePipeline:
    """The per-frame chain of a session, ready to measure frames (:func:`prepare_frames`)."""

    session: Session
    calibration: PlaneCalibration
    hue_model: str
    measurement: Mapping[str, Any]
    reader: CaptureReader
    white: NDArray[np.floating]
    shadow: NDArray[np.bool_]
    adaptive: Mapping[str, Any] | None
    want_uncertainty: bool
    blur2: float
    """The texture-edge correction's blur variance (px^2, ``calibration.texture_blur_px2``)."""
    blur_u: float
    """Its uncertainty (px^2) when the texture term of u is on, else 0."""
    offset: NDArray[np.float64] | None = None
    """The light without fringe the texture-edge correction takes out (``calibration.projector_off``,
    float64 once for every frame), or None."""
    table: HueTable | None = None
    """The object's hue table (the NumPy chain; None with the kernel, whose pixel-major copy replaces it)."""
    prep: kernel.Prepared | None = None
    """The fused kernel's prepared tables (None: the NumPy reference chain)."""
    buffers: tuple[NDArray[np.float32], NDArray[np.bool_]] | None = None
    table_invalid: float = 0.0
    shadow_fraction: float = 0.0
    budget: PixelBudget | None = None
    spill: NDArray[np.bool_] | None = None
    """Pixels lit by the white image as read whose centre lies on a shadow's side of its edge
    (``measurement.shadow_own_light``, :func:`~huefringe.perframe.shadow_side`): invalidated after
    the step-edge test, which still holds their neighbours against them; None when there are none."""
    spill_fraction: float = 0.0
    """The share of the frame's pixels in :attr:`spill`."""

    @property
    def fast(self) -> bool:
        """Frames go through the fused kernel."""
        return self.prep is not None


def prepare_frames(s: Session, t: HueTable, cal: PlaneCalibration, hue_model: str, measurement: Mapping[str, Any], *,
                   want_uncertainty: bool = True, reader: CaptureReader | None = None) -> FramePipeline:
    """Ready the per-frame chain of a session: the fused kernel with ``measurement.kernel`` and
    reference-relative unwrapping (prepared once), :func:`~huefringe.perframe.measure_frame` otherwise.

    Every capture is read through ``reader`` (the camera corrections, :class:`~huefringe.camera.CaptureReader`:
    both chains read the same registered sensor codes); default: as stored.
    """
    reader = reader or CaptureReader()
    white = reader.rgb(s.object_white)
    shadow, spill = (shadow_masks(white, measurement["shadow_fraction"]) if measurement["shadow_own_light"]
                     else (shadow_mask(white, measurement["shadow_fraction"]), None))
    blur_u = float(cal.texture_blur_u_px2 or 0.0) if want_uncertainty and measurement["texture_uncertainty"] else 0.0
    fp = FramePipeline(session=s, calibration=cal, hue_model=hue_model, measurement=measurement, reader=reader,
                       white=white, shadow=shadow, adaptive=noise_aware_adaptive(measurement["denoise_adaptive"], t),
                       want_uncertainty=want_uncertainty, blur2=float(cal.texture_blur_px2 or 0.0), blur_u=blur_u,
                       offset=None if cal.projector_off is None else np.ascontiguousarray(cal.projector_off, np.float64),
                       spill=spill if spill is not None and spill.any() else None,
                       spill_fraction=float(spill.mean()) if spill is not None else 0.0)
    if bool(measurement["kernel"]) and measurement["unwrap"] == "reference":
        fp.prep = kernel.prepare(t, cal, white, hue_model=hue_model, min_saturation=measurement["min_saturation"],
                                 shadow=shadow, bit_depth=s.bit_depth, predistortion=s.predistortion,
                                 own_noise=bool(measurement["own_noise"]),
                                 weight_blur_px=float(measurement["weight_blur_px"]),
                                 weight_blur_shape=str(measurement["weight_blur_shape"]),
                                 phase_error_frequency=bool(measurement["phase_error_frequency"]))
        fp.table_invalid = float(np.mean(~t.valid))
        fp.shadow_fraction = float(shadow.mean())
        fp.buffers = (np.empty(fp.prep.shape, np.float32), np.empty(fp.prep.shape, bool))  # reused frame to frame
    else:
        fp.table = t
    return fp


def _reference(fp: FramePipeline, image: NDArray[np.floating], texture_rgb: NDArray[np.floating] | None = None):
    """The NumPy reference chain on one image (:func:`~huefringe.perframe.measure_frame`; the texture
    term from ``texture_rgb``)."""
    m, s = fp.measurement, fp.session
    if fp.budget is None:  # once per session, not per frame
        fp.budget = pixel_budget(fp.table, fp.calibration)
    return measure_frame(image, fp.white, fp.table, fp.calibration, hue_model=fp.hue_model,
                         min_saturation=m["min_saturation"], shadow=fp.shadow, unwrap_mode=m["unwrap"],
                         bit_depth=s.bit_depth, denoise_radius=m["denoise_radius"], predistortion=s.predistortion,
                         denoise_adaptive=fp.adaptive, budget=fp.budget, own_noise=bool(m["own_noise"]),
                         texture_rgb=texture_rgb, weight_blur_px=float(m["weight_blur_px"]),
                         weight_blur_shape=str(m["weight_blur_shape"]),
                         phase_error_frequency=bool(m["phase_error_frequency"]))


def measure_one(fp: FramePipeline, n: int, *, want_maps: bool = True) -> FrameResult:
    """Measure frame ``n`` of the session into a :class:`FrameResult`.

    The texture-edge correction (:mod:`huefringe.texture`) once, before either chain; then the
    fused kernel or :func:`~huefringe.perframe.measure_frame` (``phase`` and ``hue`` with
    ``want_maps``; the reference chain always gives them). After either chain,
    ``measurement.edge_jump_mm`` > 0 invalidates the mixed pixels of step edges
    (``measurement.edge_test``: :func:`~huefringe.perframe.step_edge_mask`, or
    :func:`~huefringe.perframe.plane_edge_mask` with ``edge_plane_tol_mm``; ``stats["edge_fraction"]``;
    a jump within ``edge_noise_k`` of the heights' own noise, :func:`~huefringe.perframe.height_noise`, is kept),
    so the kernel and :func:`~huefringe.perframe.measure_frame` stay identical to each other; the
    uncertainty then gains the texture term in quadrature (the heights' change when the blur moves
    by its uncertainty, carried through the frame's own filter: :func:`~huefringe.uncertainty.texture_term_phase`)
    and the lateral term of the
    delivered heights (:func:`~huefringe.uncertainty.add_lateral`, ``measurement.lateral_uncertainty_px``,
    ``lateral_step_px``; 0 = off).

    The kernel's arrays are reused from frame to frame: copy what you keep.

    Raises
    ------
    FrameError
        Naming the capture: too many clipped pixels or too few valid ones.
    """
    s, m, reader = fp.session, fp.measurement, fp.reader
    path = s.frames[n]
    rgb = None
    moved = None  # the capture corrected with the blur moved by its uncertainty (texture term)
    if fp.blur2 > 0 or fp.blur_u > 0:
        raw = reader.rgb(path)
        clip = clipped_mask(raw, s.bit_depth)
        rgb, moved = texture.correct_pair(raw, fp.white, fp.blur2, fp.blur2 + fp.blur_u if fp.blur_u > 0 else None,
                                          clipped=clip, offset=fp.offset)
        rgb = rgb if fp.blur2 > 0 else None
    if rgb is None and reader.demixed:  # the demixed channels (camera.colour_demixing), to both chains
        rgb = reader.rgb(path)
    jump = float(m["edge_jump_mm"] or 0.0)
    # a jump the heights' own noise explains is no step edge (measurement.edge_noise_k; the noise map needs the u pass)
    noise_k = float(m["edge_noise_k"]) if jump > 0 else 0.0
    if fp.prep is not None:  # the kernel reads the sensor codes as read_rgb scales them
        k = kernel.frame_maps(fp.prep, reader.codes(path) if rgb is None else rgb, denoise_radius=m["denoise_radius"],
                              denoise_adaptive=fp.adaptive, want_maps=want_maps, want_dphi=True,
                              want_uncertainty=fp.want_uncertainty or noise_k > 0, out=fp.buffers,
                              texture_rgb=moved)
        px = k.valid.size  # frame_stats with unwrap's reference flags, in one compiled pass
        # the wrap flags on the pixels valid before the filter (measure_frame's unwrap call): the
        # kernel's dphi is NaN exactly where no phase was decoded; k.valid has lost the filter's rejects
        stats = reference_frame_stats(k.dphi, k.valid, k.height, clipped_fraction=k.counts["clipped"] / px,  # type: ignore[arg-type]
                                      hue_undefined_fraction=k.counts["hue_undefined"] / px,
                                      table_invalid_fraction=fp.table_invalid, shadow_fraction=fp.shadow_fraction,
                                      hue_model=fp.hue_model, flag_valid=np.isfinite(k.dphi))
        height, phase, hue, u_map, support, noise_h = k.height, k.phase, k.hue, k.uncertainty, k.support, k.noise
        tex_u, weight, grown = k.texture_u, k.weight, k.bias2
        if not fp.want_uncertainty:
            u_map = support = None
    else:
        res = _reference(fp, reader.rgb(path) if rgb is None else rgb, texture_rgb=moved)
        height, phase, hue, stats, u_map, support = res.height, res.phase, res.hue, res.stats, res.uncertainty, res.support
        tex_u, weight, grown = res.texture_u, res.weight, res.bias2
        noise_h = res.noise
    if jump > 0 or fp.spill is not None:  # mixed pixels at step edges, after either chain (the kernel's buffers are
        # not touched); then the shadow-side pixels (fp.spill), which the edge test holds their neighbours against
        height, (phase, u_map), (support,), changed = remove_step_edges(
            height, jump, nan_maps=(phase, u_map), zero_maps=(support,), test=str(m["edge_test"]),
            tol_mm=float(m["edge_plane_tol_mm"]), noise=noise_h, noise_k=noise_k, drop=fp.spill)
        if fp.spill is not None:  # the session's shadow: the white image's and its shadow-side pixels
            changed["shadow_fraction"] = float(stats["shadow_fraction"]) + fp.spill_fraction
        if jump <= 0:
            del changed["edge_fraction"]
        stats = {**stats, **changed}
    if u_map is not None and moved is not None:  # the texture term, in quadrature (NaN where the height is)
        u_map = np.hypot(u_map, tex_u).astype(np.float32)
    lateral, step = float(m["lateral_uncertainty_px"]), float(m["lateral_step_px"])
    if u_map is not None and (lateral > 0 or step > 0):  # the lateral term on the heights as delivered (after the edge mask)
        u_map = add_lateral(height, u_map, lateral_px=lateral, step_px=step, weight=weight,
                            filter_radius=int(m["denoise_radius"] or 0), grown=grown)
    _refuse_bad_frame(path, stats, m)
    return FrameResult(frame=n, height=height, stats=stats, phase=phase, hue=hue, uncertainty=u_map, support=support)


def frame_results(s: Session, t: HueTable, cal: PlaneCalibration, frames: Sequence[int], hue_model: str,
                  measurement: Mapping[str, Any], map_frames: set[int] | None = None, want_uncertainty: bool = True,
                  reader: CaptureReader | None = None) -> Iterator[FrameResult]:
    """Measure frames of a session one by one (:func:`prepare_frames`, then :func:`measure_one` each).

    ``phase`` and ``hue`` are asked for the frames in ``map_frames`` (default: all). Each frame is
    refused (:class:`~huefringe.perframe.FrameError`, naming it) before it is yielded. The kernel's
    arrays are reused from frame to frame: copy what you keep.
    """
    maps = set(frames) if map_frames is None else set(map_frames)
    t0 = time.perf_counter()
    fp = prepare_frames(s, t, cal, hue_model, measurement, want_uncertainty=want_uncertainty, reader=reader)
    _log.info("frames of %s ready to measure in %.2f s (white image, shadow mask, %s)", s.id, time.perf_counter() - t0,
              "the kernel's per-pixel tables" if fp.prep is not None else "the reference chain")
    del t  # with the kernel, its pixel-major copy replaces the band-major table
    for n in frames:
        yield measure_one(fp, n, want_maps=n in maps)
