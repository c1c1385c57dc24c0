"""Running the stages: a whole session without Snakemake, and the adapter a Snakemake script calls."""

from __future__ import annotations

import inspect
import logging
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from huefringe.io import remove_stale_parts
from huefringe.session import load_session, load_sl_session

log = logging.getLogger("huefringe")


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
    from ._calibration import camera_calibration, hue_table, plane_calibration
    from ._measurement import baseline_frames, cloud_frames, measure_frames

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


RIG_MEASURE: dict[str, str] = {
    "xyz": "xyz/frame_0000.tiff", "xyz_sigma": "xyz/frame_0000_sigma.tiff", "xyz_u": "xyz/frame_0000_u.tiff",
    "decoded": "decode/frame_0000.tiff", "cloud": "cloud/frame_0000.ply", "height": "height/frame_0000.tiff",
    "uncertainty": "uncertainty/frame_0000.tiff", "x3p": "x3p/frame_0000.x3p", "qa": "qa/frames/frame_0000.json",
    "quality": "qa/frame_0000_decode.png",
}
RIG_SURFACES: dict[str, str] = {
    "ply": "mesh/frame_0000.ply", "stl": "mesh/frame_0000.stl", "stats": "mesh/frame_0000.stats.json",
    "top": "renders/frame_0000_top.png", "oblique1": "renders/frame_0000_oblique1.png",
    "oblique2": "renders/frame_0000_oblique2.png", "height_map": "renders/frame_0000_height.png",
    "uncertainty_map": "renders/frame_0000_uncertainty.png",
}
RIG_REPORT: dict[str, str] = {"json": "metrology/report.json", "html": "metrology/report.html"}
RIG_OUTPUTS: dict[str, str] = {**RIG_MEASURE, **RIG_SURFACES, **RIG_REPORT, "accuracy": "accuracy.json"}
"""The files of a structured-light session under its results folder (``workflow/rules/rig.smk``),
by the stage that writes them (``rig_measure``, ``rig_surfaces``, ``rig_metrology``, ``rig_accuracy``)."""


def calibrate_rig_session(session: str | Path, out: str | Path, config: Mapping[str, Any], board: Any = None) -> dict[str, Path]:
    """The workflow's ``rig_calibrate`` without Snakemake: ``out`` (FileStorage), its report and the
    leave-one-pose-out calibrations beside it; ``board`` overrides the session's."""
    from ._rig import rig_calibrate

    out = Path(out)
    files = {"calibration": out, "report": out.with_suffix(".report.json"), "jackknife": out.with_suffix(".jackknife.json")}
    rig_calibrate(str(session), config, str(out), str(files["report"]), str(files["jackknife"]), board)
    return files


def measure_rig_session(session: str | Path, out: str | Path, config: Mapping[str, Any], *,
                        calibration: str | Path | None = None, surfaces: bool = True) -> dict[str, Path]:
    """A structured-light session measured without Snakemake: the workflow's ``rig_measure`` (or
    ``rig_oneshot`` for a session with one-shot frames, every frame's files),
    ``rig_surfaces``, ``rig_metrology`` (with ``features.yaml``) and ``rig_accuracy`` (with
    ``ground_truth/xyz.tiff``) in that order, into ``out`` in the results layout
    (:data:`RIG_OUTPUTS`).

    ``calibration`` (default: the session's own ``calibration/`` file, or the session that
    ``calibration: {session: PATH}`` names, calibrated first into ``out/calib/rig.yml``) may be a
    calibration that :func:`calibrate_rig_session` wrote: its report and leave-one-pose-out
    calibrations beside it are then used as the workflow uses them. Returns the paths written.
    """
    from huefringe.rig.measure import RigError
    from huefringe.rig.oneshot import is_oneshot

    from ._rig import rig_accuracy, rig_measure, rig_metrology, rig_oneshot, rig_surfaces

    s = load_sl_session(session)
    out = Path(out)
    if calibration is None and s.calibration is not None:
        calibration = s.calibration
    elif calibration is None and s.calibration_session is not None:
        if not (s.calibration_session / "session.yaml").is_file():
            raise RigError(f"{s.root / 'session.yaml'}: calibration/session: {s.calibration_session} holds no session")
        calibration = calibrate_rig_session(s.calibration_session, out / "calib" / "rig.yml", config)["calibration"]
    elif calibration is None:
        raise RigError(f"{s.root / 'session.yaml'}: no calibration in the session; give one "
                       "(huefringe rig-measure SESSION OUTDIR --calibration FILE)")
    calibration = Path(calibration)
    beside = {k: calibration.with_suffix(f".{k}.json") for k in ("jackknife", "report")}
    beside = {k: str(v) if v.is_file() else "" for k, v in beside.items()}
    p = {k: out / v for k, v in RIG_OUTPUTS.items()}
    keep = [*RIG_MEASURE, *(RIG_SURFACES if surfaces else ()), *(RIG_REPORT if s.features is not None else ()),
            *(("accuracy",) if "xyz" in s.ground_truth else ())]
    for k in keep:
        p[k].parent.mkdir(parents=True, exist_ok=True)
    frames: dict[str, list[str]] = {}
    if is_oneshot(s.spec):   # every one-shot frame, frame_0000 .. (the surfaces of the first, the report of all)
        n = s.spec.oneshot_frames
        frames = {k: [str(p[k]).replace("frame_0000", f"frame_{i:04d}") for i in range(n)] for k in RIG_MEASURE}
        for k in RIG_MEASURE:
            p[k].parent.mkdir(parents=True, exist_ok=True)
        rig_oneshot(str(s.root), config, str(calibration), **frames, jackknife=beside["jackknife"])
    else:
        rig_measure(str(s.root), config, str(calibration), **{k: str(p[k]) for k in RIG_MEASURE},
                    jackknife=beside["jackknife"])
    if surfaces:
        rig_surfaces(str(s.root), str(p["height"]), str(p["uncertainty"]), config["mesh"], config["render"],
                     **{k: str(p[k]) for k in RIG_SURFACES})
    if s.features is not None:   # a one-shot session's report: of every one-shot frame
        each = {k: frames.get(k) or str(p[k]) for k in ("xyz", "xyz_sigma", "decoded", "qa")}
        rig_metrology(str(s.root), config, str(calibration), each["xyz"], each["xyz_sigma"], each["decoded"],
                      each["qa"], str(p["top"]) if surfaces else "", str(p["height_map"]) if surfaces else "",
                      str(p["quality"]), str(p["json"]), str(p["html"]), jackknife=beside["jackknife"],
                      calibration_report=beside["report"])
    if "xyz" in s.ground_truth:
        rig_accuracy(str(s.root), str(calibration), str(p["xyz"]), str(p["xyz_sigma"]), str(p["xyz_u"]), str(p["accuracy"]))
    return {k: p[k] for k in keep}


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


def process_age() -> float | None:
    """Seconds since this process started (Linux ``/proc``), or None where that cannot be read."""
    try:
        start_ticks = float(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        uptime = float(Path("/proc/uptime").read_text().split()[0])
        return uptime - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def input_errors() -> tuple[type[Exception], ...]:
    """The exceptions that name a bad input file and its cause (a one-paragraph message, no
    traceback, in a job's log); imported when asked, so a job loads only its own stage's modules."""
    from huefringe.archive import ArchiveError
    from huefringe.height import PlaneCalibrationError
    from huefringe.huetable import HueTableError
    from huefringe.metrology import MetrologyError
    from huefringe.perframe import FrameError
    from huefringe.rig.measure import RigError
    from huefringe.session import SessionError
    from huefringe.x3p import X3PError

    return (SessionError, FrameError, HueTableError, PlaneCalibrationError, MetrologyError, ArchiveError, X3PError,
            RigError)


def run_from_snakemake(smk: Any, func: Callable[..., None], **extra: Any) -> None:
    """Call ``func`` with the job's named inputs, outputs and params as keyword arguments.

    Logging goes to the job's log file, which starts with the job's start-up (the seconds from
    the process's start to the stage's call: Python, Snakemake's script preamble, the imports).
    numba's parallel passes and OpenCV's threaded filters use the job's ``threads``, no more
    (left to itself OpenCV starts a thread per core in every job: jobs that each hold one core
    would contend for each other's). Known
    input problems end the job with a one-paragraph
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
    import numba  # the compiled passes' rows run on the job's threads (rule ``threads``), no more

    from huefringe import _threads  # noqa: F401  (the threading layer, before set_num_threads starts it)

    import cv2

    threads = max(1, min(int(getattr(smk, "threads", 1) or 1), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(threads)
    cv2.setNumThreads(threads)
    age = process_age()
    if age is not None:
        log.info("%s: job started %.2f s ago (Python, the script's preamble, imports), %d thread(s)", func.__name__, age,
                 threads)
    t0 = time.perf_counter()
    try:
        func(**kwargs)
    except Exception as exc:
        if not isinstance(exc, input_errors()):
            raise
        log.error("%s", exc)
        sys.stderr.write(f"\nhuefringe: {exc}\n")
        sys.exit(1)
    log.info("%s done in %.2f s", func.__name__, time.perf_counter() - t0)
