"""The images a real rig projects for one capture session, and the manifest of capture order.

:func:`write_patterns` writes into a new folder ``OUT`` (contract: ``RIG_MANIFEST``, summarised in
``docs/guide.md``, "Images to project"):

- ``NNNN_<name>.png``: every distinct projector image once, numbered in the order of its first
  capture: ``white`` (full white), ``band_III`` (the uniform colour of hue band ``III``, code phase
  ``2 pi i / N``), ``trapezoid`` (paper eq. 3, code phase ``2 pi x / T`` at column ``x``) and, with
  phase shifting, ``shift_s0..s2`` (grey ``0.5 + 0.5 cos(2 pi x / T + delta_s)``). RGB PNG at the
  projector's resolution, 8- or 16-bit codes rounded to the nearest step.
- ``manifest.csv``: ``order,image,session_path``, one row per capture in capture order, naming the
  image to show and where that capture goes in a capture-session/1 folder.
- ``patterns.yaml``: what was asked (resolution, bit depth, projector period, N, R, planes, frames).
- with ``compensated=CALIB`` (paper Fig. 6): ``trapezoid`` pre-distorted from the plate's hue
  table ``CALIB/table_reference.json`` (:func:`huefringe.compensation.plate_transfer`,
  :func:`~huefringe.compensation.predistortion`) at the projector's resolution and period, and
  ``predistortion.csv`` (the session extension of docs/design.md), which ``huefringe session``
  copies into the session so that it decodes. With phase shifting, the three sinusoids are
  pre-compensated for the projector's response, read off the same table
  (:func:`huefringe.compensation.projector_gamma` of its transfer: per-channel gamma from the hue bands' ramps):
  channel ``k`` of ``shift_sN`` drives ``I ** (1 / gamma_k)`` so that the captured intensity is
  the sinusoid ``I`` again, and ``phase_shift_levels.csv`` records the drive levels applied
  (:func:`phase_shift_levels_csv`). Bands and white stay plain.

The folder is written into a hidden temporary folder beside ``OUT`` and renamed onto ``OUT`` at the
end, so an interrupted run leaves nothing that looks complete. Arguments are checked before anything
is written; a bad one raises :class:`PatternsError` naming it.
"""

from __future__ import annotations

import contextlib
import csv
import io as _stdio
import math
import os
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from .compensation import GammaFit, GammaFitError, emitted_columns, linearised_levels, plate_transfer, \
    predistortion, projector_gamma
from .huetable import HueTable
from .io import atomic_path, write_png_rgb
from .patterns import MANIFEST_HEADER, TWO_PI, band_rgb, phase_shift_intensity, projector_image, quantise
from .session import SessionError, format_predistortion, read_predistortion

#: The hue table of the reference plate that ``--compensated`` reads from a calibration folder.
CALIB_TABLE = "table_reference.json"

#: What ``--compensated`` writes beside the manifest when the phase-shift sinusoids are pre-compensated.
PHASE_SHIFT_LEVELS = "phase_shift_levels.csv"

#: Rows of ``phase_shift_levels.csv``: wanted grey level ``j / PHASE_SHIFT_LEVEL_STEPS``.
PHASE_SHIFT_LEVEL_STEPS = 256

#: Smallest projector period accepted: below 6 px the six linear pieces of eq. 3 get < 1 px each.
MIN_PERIOD_PX = 6.0

#: Fewest fringe periods across the projector's width (``huefringe session`` measures the period from them).
MIN_PERIODS = 2

#: Largest projector side accepted (8K projectors are 8192 px wide).
MAX_SIDE_PX = 16384

#: Smallest projector height accepted.
MIN_HEIGHT_PX = 2

_UMASK = os.umask(0)
os.umask(_UMASK)


class PatternsError(ValueError):
    """A bad argument of :func:`write_patterns`: ``argument`` names it, ``problem`` says why."""

    def __init__(self, argument: str, problem: str) -> None:
        self.argument = argument
        self.problem = problem
        super().__init__(f"{argument}: {problem}")


def projector_period(camera_period_px: float, magnification: float) -> float:
    """Projector period giving a wanted camera period: ``camera_period_px / magnification``.

    ``magnification`` is the lateral scale of the rig on the reference plane, in **camera pixels per
    projector pixel** (e.g. a projector column pattern of period 40 px seen with a period of 60
    camera px: magnification 1.5).
    """
    return float(camera_period_px) / float(magnification)


def _check(
    out_dir: Path, *, width: int, height: int, period_px: float | None, hue_bands: int, repeats: int,
    planes_mm: Sequence[float], frames: int, bit_depth: int, camera_period_px: float | None,
    magnification: float | None,
) -> tuple[float, list[float]]:
    def positive_int(name: str, value: object, lo: int = 1, hi: int | None = None) -> None:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise PatternsError(name, f"must be an integer, got {value!r}")
        if value < lo or (hi is not None and value > hi):
            raise PatternsError(name, f"must be in {lo}..{hi if hi is not None else 'inf'}, got {value}")

    positive_int("width", width, 1, MAX_SIDE_PX)
    positive_int("height", height, MIN_HEIGHT_PX, MAX_SIDE_PX)
    positive_int("hue_bands", hue_bands, 6, 999)  # capture-session/1: pattern.hue_bands 6..999
    positive_int("repeats", repeats, 1, 99)  # pattern.repeats 1..99
    positive_int("frames", frames, 1, 10000)  # frame_NNNN: four digits
    if bit_depth not in (8, 16):
        raise PatternsError("bit_depth", f"must be 8 or 16, got {bit_depth!r}")
    if period_px is not None and (camera_period_px is not None or magnification is not None):
        raise PatternsError("period_px", "give the projector period or camera_period_px with magnification, not both")
    if period_px is None:
        if camera_period_px is None or magnification is None:
            raise PatternsError("period_px", "give the projector period, or camera_period_px and magnification")
        for name, v in (("camera_period_px", camera_period_px), ("magnification", magnification)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise PatternsError(name, f"must be a positive number, got {v!r}")
        period = projector_period(camera_period_px, magnification)
        where = f"camera_period_px / magnification = {camera_period_px:g} / {magnification:g} = {period:g} px"
        name = "camera_period_px"
    else:
        if not (isinstance(period_px, (int, float)) and math.isfinite(period_px)):
            raise PatternsError("period_px", f"must be a number, got {period_px!r}")
        period, where, name = float(period_px), f"{float(period_px):g} px", "period_px"
    if period < MIN_PERIOD_PX:
        raise PatternsError(name, f"the projector period must be at least {MIN_PERIOD_PX:g} px, got {where}")
    if width < MIN_PERIODS * period:
        raise PatternsError("width" if width < MIN_PERIODS * MIN_PERIOD_PX else name,
                            f"the fringe must repeat at least {MIN_PERIODS} times across the projector's {width} px "
                            f"(the period is measured from the repeats), got a period of {where}: "
                            f"a projector of at least {math.ceil(MIN_PERIODS * period)} px, or a shorter period")
    need = _peak_bytes(width, height, bit_depth)
    if (avail := _available_memory()) is not None and need > avail:
        raise PatternsError("width", f"one {width} x {height} image needs about {need / 2**30:.1f} GiB of memory "
                                     f"while it is written, and {avail / 2**30:.1f} GiB are available")
    try:
        planes = [float(z) for z in planes_mm]
    except (TypeError, ValueError) as exc:
        raise PatternsError("planes_mm", f"must be a list of numbers in mm ({exc})") from exc
    if not all(math.isfinite(z) for z in planes):
        raise PatternsError("planes_mm", f"must be finite numbers, got {planes}")
    keys = [f"{z:.3f}" for z in planes]  # session file names z_<mm with 3 decimals>
    if len(planes) < 2:
        raise PatternsError("planes_mm", f"needs at least two planes (0.0 and one more), got {planes}")
    if len(set(keys)) != len(keys):
        raise PatternsError("planes_mm", f"has repeated planes (to 3 decimals): {planes}")
    if "0.000" not in keys and "-0.000" not in keys:
        raise PatternsError("planes_mm", f"must contain the reference plane 0.0, got {planes}")
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise PatternsError("out_dir", f"{out_dir} already exists and is not an empty folder")
    return period, planes


def _peak_bytes(width: int, height: int, bit_depth: int) -> int:
    """Memory one image takes while written: the RGB codes, the BGR copy for OpenCV and the PNG buffer."""
    return 3 * int(width) * int(height) * 3 * (1 if bit_depth == 8 else 2)


def _available_memory() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` in bytes, None where the system does not say."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        return None
    return None


def _check_disk(out: Path, n_images: int, width: int, height: int, bit_depth: int) -> None:
    """Refuse before writing when even the compressed images would not fit (uniform images
    compress to almost nothing; the trapezoid and the sinusoids to about a third)."""
    parent = out.parent if not out.exists() else out
    while not parent.exists():
        parent = parent.parent
    need = 4 * width * height * 3 * (1 if bit_depth == 8 else 2) // 3 + n_images * 4096
    free = shutil.disk_usage(parent).free
    if need > free:
        raise PatternsError("out_dir", f"the images need about {need / 2**30:.1f} GiB, {parent} has "
                                       f"{free / 2**30:.1f} GiB free")


def capture_plan(hue_bands: int, repeats: int, planes_mm: Sequence[float], frames: int,
                 phase_shift: bool) -> list[tuple[str, str]]:
    """``(image name, session path)`` of every capture in capture order (image names without number).

    Order: reference white, reference bands (band-major: ``band_000_r0, band_000_r1, ...``),
    reference planes in the given order, object white, object bands, object frames ``0..F-1``,
    then the phase-shift triple of frame 0000 when ``phase_shift``.
    """
    plan: list[tuple[str, str]] = []
    for part in ("reference", "object"):
        plan.append(("white", f"{part}/white.png"))
        plan += [(f"band_{i:03d}", f"{part}/hue/band_{i:03d}_r{r}.png")
                 for i in range(hue_bands) for r in range(repeats)]
        if part == "reference":
            plan += [("trapezoid", f"reference/planes/z_{z:.3f}.png") for z in planes_mm]
    plan += [("trapezoid", f"object/frames/frame_{f:04d}.png") for f in range(frames)]
    if phase_shift:
        plan += [(f"shift_s{s}", f"object/phase_shift/frame_0000_s{s}.png") for s in range(3)]
    return plan


@dataclass(frozen=True)
class Compensation:
    """The pre-distortion of paper Fig. 6 computed from a calibration folder's plate hue table."""

    calib: Path
    code: np.ndarray
    """Code phases ``c`` (``2 pi k / M``)."""
    emitted: np.ndarray
    """Phase ``p(c)`` the trapezoid emits for code ``c``."""
    history: list[dict[str, float]]
    """The loop's predicted residual per iteration (:func:`huefringe.compensation.predistortion`)."""
    gamma: GammaFit | None = None
    """The projector's per-channel response the phase-shift sinusoids are pre-compensated with
    (None: no phase shifting)."""


def load_compensation(calib: str | os.PathLike[str], *, threshold_rad: float = 2e-3, max_iter: int = 50,
                      gain: float = 0.8, phase_shift: bool = False) -> Compensation:
    """The pre-distortion from ``calib/table_reference.json`` (a run's ``results/<id>/calib``).

    With ``phase_shift`` also the projector's per-channel gamma from the same table
    (:func:`huefringe.compensation.projector_gamma` of the same plate transfer), for pre-compensated
    phase-shift sinusoids.

    Raises
    ------
    PatternsError
        (``compensated``) the folder or the table's files are missing or unreadable, or (with
        ``phase_shift``) the table cannot give the projector's response, naming the file and why.
    """
    folder = Path(calib)
    if not folder.is_dir():
        raise PatternsError("compensated", f"{folder} is not a folder (give a run's results/<id>/calib)")
    base = folder / CALIB_TABLE
    for name in (CALIB_TABLE, CALIB_TABLE.replace(".json", ".npy"), CALIB_TABLE.replace(".json", ".maps.npz")):
        if not (folder / name).is_file():
            raise PatternsError("compensated", f"{folder / name} is missing: the calibration folder must hold the "
                                               f"plate's hue table {CALIB_TABLE} with its .npy and .maps.npz (the "
                                               "workflow's rule hue_table writes them to results/<id>/calib)")
    try:
        table = HueTable.load(base)
        code, dist = plate_transfer(table)
    except (OSError, ValueError, KeyError) as exc:
        raise PatternsError("compensated", f"{base}: cannot use the hue table ({exc})") from exc
    c, p, history = predistortion(code, dist, threshold_rad=threshold_rad, max_iter=max_iter, gain=gain)
    if np.any(np.diff(p) <= 0) or p[-1] >= p[0] + TWO_PI or np.any(np.abs(p - c) >= np.pi):
        raise PatternsError("compensated", f"{base}: the plate's transfer function gives a pre-distortion that is "
                                           "not invertible (emitted phase not rising by less than one turn)")
    fit = None
    if phase_shift:
        try:
            fit = projector_gamma(code, code + dist, model=table.model)  # the transfer read once, above
        except GammaFitError as exc:
            raise PatternsError("compensated", f"{base}: cannot read the projector's response for the phase-shift "
                                               f"images off the plate's hue table: {exc} (or write them with "
                                               "--no-phase-shift)") from exc
    return Compensation(folder, c, p, history, fit)


def predistortion_csv(comp: Compensation) -> str:
    """``predistortion.csv`` text (huefringe extension of capture-session/1, docs/design.md)."""
    return format_predistortion(comp.code, comp.emitted,
                                source=f"huefringe patterns --compensated from {comp.calib / CALIB_TABLE}")


def phase_shift_levels_csv(comp: Compensation) -> str:
    """``phase_shift_levels.csv`` text: the drive levels of the pre-compensated phase-shift images.

    Comment lines ``#`` (the fitted gammas, the fit's residual and the source table), a header
    ``level,r,g,b``, then one row per wanted grey level ``j / 256``: the drive level (0..1, before
    rounding to the image's codes) each channel is given for it, ``level ** (1 / gamma_k)``
    (:func:`huefringe.compensation.linearised_levels`).
    """
    fit = comp.gamma
    assert fit is not None
    level = np.arange(PHASE_SHIFT_LEVEL_STEPS + 1) / PHASE_SHIFT_LEVEL_STEPS
    drive = linearised_levels(level, fit.gamma)
    g = fit.gamma
    lines = ["# huefringe phase-shift-levels/1: the grey phase-shift sinusoids I = 0.5 + 0.5 cos(2 pi x / T + delta_s)",
             "# were projected with channel k driven at level ** (1 / gamma_k), so that the captured intensity is I",
             f"# gamma R, G, B = {g[0]:.4f}, {g[1]:.4f}, {g[2]:.4f} (normalised response v ** gamma_k), fitted to the",
             f"# captured hue of the plate's {fit.n_bands} hue bands: "
             f"residual RMS {fit.residual_rms_rad:.4f} rad, max {fit.residual_max_rad:.4f} rad",
             f"# written by huefringe patterns --compensated from {comp.calib / CALIB_TABLE}",
             "level,r,g,b"]
    lines += [f"{lv:.6f},{r:.6f},{gg:.6f},{b:.6f}" for lv, (r, gg, b) in zip(level, drive, strict=True)]
    return "\n".join(lines) + "\n"


def _image(name: str, *, width: int, height: int, period: float, hue_bands: int, bit_depth: int,
           compensation: Compensation | None = None) -> np.ndarray:
    if name == "trapezoid" and compensation is not None:
        emit = emitted_columns(compensation.code, compensation.emitted, width, period)
        return projector_image(width, height, period, phase_map=emit, bit_depth=bit_depth)
    if name == "white":
        return np.full((height, width, 3), 2**bit_depth - 1, dtype=np.uint8 if bit_depth == 8 else np.uint16)
    if name == "trapezoid":
        return projector_image(width, height, period, bit_depth=bit_depth)
    if name.startswith("band_"):
        colour = quantise(band_rgb(int(name[5:]), hue_bands), bit_depth)
        return np.broadcast_to(colour, (height, width, 3)).copy()
    if name.startswith("shift_s") and compensation is not None and compensation.gamma is not None:
        level = phase_shift_intensity(TWO_PI * np.arange(width) / period, int(name[7:]))
        row = quantise(linearised_levels(level, compensation.gamma.gamma), bit_depth)
        return np.broadcast_to(row[None, :, :], (height, width, 3)).copy()
    if name.startswith("shift_s"):
        row = quantise(phase_shift_intensity(TWO_PI * np.arange(width) / period, int(name[7:])), bit_depth)
        return np.broadcast_to(row[None, :, None], (height, width, 3)).copy()
    raise ValueError(f"unknown projector image {name!r}")


def write_patterns(
    out_dir: str | os.PathLike[str],
    *,
    width: int,
    height: int,
    period_px: float | None = None,
    hue_bands: int = 256,
    repeats: int = 3,
    planes_mm: Sequence[float] = (0.0, 2.0, 4.0),
    frames: int = 1,
    phase_shift: bool = True,
    bit_depth: int = 8,
    camera_period_px: float | None = None,
    magnification: float | None = None,
    compensated: str | os.PathLike[str] | None = None,
    threshold_rad: float = 2e-3,
    max_iter: int = 50,
    gain: float = 0.8,
) -> Path:
    """Write every projector image of one session, ``manifest.csv`` and ``patterns.yaml`` into ``out_dir``.

    Parameters
    ----------
    out_dir : path
        New folder to create (an existing empty folder is accepted; a non-empty one is refused).
    width, height : int
        Projector resolution in pixels.
    period_px : float, optional
        Fringe period in **projector** pixels (at least 6). Give it, or ``camera_period_px`` with
        ``magnification``.
    hue_bands, repeats : int
        N uniform hue bands (6..999) captured R times each (1..99), as capture-session/1 requires.
    planes_mm : sequence of float
        Heights of the calibration planes in capture order; at least two, distinct to 3 decimals,
        one of them 0.0.
    frames : int
        Object frames (1..10000); each shows the trapezoid.
    phase_shift : bool
        Also write and list the three-step phase-shift sinusoids for frame 0000.
    bit_depth : {8, 16}
        PNG code depth.
    camera_period_px : float, optional
        Wanted fringe period on the reference plane in camera pixels (the session's
        ``pattern.period_px``).
    magnification : float, optional
        Measured lateral scale on the reference plane in camera pixels per projector pixel; the
        projector period is then ``camera_period_px / magnification`` (:func:`projector_period`).
    compensated : path, optional
        A calibration folder (a run's ``results/<id>/calib``) holding the plate's hue table
        ``table_reference.json``: the trapezoid is then pre-distorted (paper Fig. 6) and
        ``predistortion.csv`` is written beside the manifest (:func:`load_compensation`); with
        ``phase_shift`` the sinusoids are pre-compensated for the projector's per-channel gamma
        fitted to the same table, recorded in ``phase_shift_levels.csv`` and ``patterns.yaml``.
    threshold_rad, max_iter, gain
        The compensation loop's (:func:`huefringe.compensation.predistortion`).

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    PatternsError
        Bad argument (named in ``.argument``), before anything is written.
    """
    out = Path(out_dir)
    period, planes = _check(out, width=width, height=height, period_px=period_px, hue_bands=hue_bands,
                            repeats=repeats, planes_mm=planes_mm, frames=frames, bit_depth=bit_depth,
                            camera_period_px=camera_period_px, magnification=magnification)
    comp = None if compensated is None else load_compensation(compensated, threshold_rad=threshold_rad,
                                                                  max_iter=max_iter, gain=gain,
                                                                  phase_shift=phase_shift)
    plan = capture_plan(hue_bands, repeats, planes, frames, phase_shift)
    files: dict[str, str] = {}
    for name, _ in plan:
        files.setdefault(name, f"{len(files):04d}_{name}.png")
    _check_disk(out, len(files), width, height, bit_depth)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent))
    try:
        for name, file in files.items():
            write_png_rgb(tmp / file, _image(name, width=width, height=height, period=period,
                                              hue_bands=hue_bands, bit_depth=bit_depth, compensation=comp))
        if comp is not None:
            with atomic_path(tmp / "predistortion.csv") as p:
                p.write_text(predistortion_csv(comp), encoding="utf-8")
            try:
                read_predistortion(tmp / "predistortion.csv")
            except SessionError as exc:  # pragma: no cover - load_compensation checks the same
                raise PatternsError("compensated", str(exc)) from exc
            if comp.gamma is not None:
                with atomic_path(tmp / PHASE_SHIFT_LEVELS) as p:
                    p.write_text(phase_shift_levels_csv(comp), encoding="utf-8")
        text = _stdio.StringIO()
        w = csv.writer(text, lineterminator="\n")
        w.writerow(MANIFEST_HEADER)
        w.writerows((k, files[name], path) for k, (name, path) in enumerate(plan))
        with atomic_path(tmp / "manifest.csv") as p:
            p.write_text(text.getvalue(), encoding="utf-8")
        asked = {
            "format": "huefringe-patterns/1",
            "width": int(width), "height": int(height), "bit_depth": int(bit_depth),
            "period_px": period, "camera_period_px": None if camera_period_px is None else float(camera_period_px),
            "magnification": None if magnification is None else float(magnification),
            "hue_bands": int(hue_bands), "repeats": int(repeats), "planes_mm": planes,
            "frames": int(frames), "phase_shift": bool(phase_shift),
            "images": len(files), "captures": len(plan),
        }
        if comp is not None:
            asked["compensated"] = {"calibration": str(comp.calib), "table": CALIB_TABLE,
                                    "threshold_rad": float(threshold_rad), "max_iter": int(max_iter),
                                    "gain": float(gain), "samples": int(comp.code.size),
                                    "predicted_residual_rad": {"before": comp.history[0]["std_rad"],
                                                               "after": comp.history[-1]["std_rad"]},
                                    "iterations": int(comp.history[-1]["iteration"])}
            if comp.gamma is not None:
                fit = comp.gamma
                asked["compensated"]["phase_shift"] = {
                    "levels": PHASE_SHIFT_LEVELS, "model": "drive = level ** (1 / gamma), per channel R, G, B",
                    "gamma": [float(g) for g in fit.gamma],
                    "fit_residual_rad": {"rms": fit.residual_rms_rad, "max": fit.residual_max_rad},
                    "hue_bands": fit.n_bands, "ramp_bands": list(fit.ramp_bands)}
        with atomic_path(tmp / "patterns.yaml") as p:
            p.write_text(yaml.safe_dump(asked, sort_keys=False), encoding="utf-8")
        os.chmod(tmp, 0o777 & ~_UMASK)  # mkdtemp creates 0700
        os.replace(tmp, out)  # POSIX: atomic, also onto an existing empty folder
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            shutil.rmtree(tmp)
        raise
    return out

