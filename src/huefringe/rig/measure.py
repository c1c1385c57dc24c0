"""Structured-light sessions measured: the rig route's decode and geometry steps.

Decode (:mod:`huefringe.codecs`) gives each camera pixel its projector coordinate with its
standard uncertainty; the geometry (:func:`huefringe.rig.triangulate` with a
:class:`~huefringe.rig.RigCalibration`) turns it into X, Y, Z in mm in the camera frame with its
uncertainty, on the camera grid (:class:`RigFrame`). The calibration comes from a session's board
poses (:func:`calibrate_sl_session`) together with its leave-one-pose-out calibrations, whose
spread is the calibration's term in every reported uncertainty (:func:`huefringe.metrology.jackknife_u`). Heights
are distances from a datum plane (:func:`height_over_plane`), on the camera grid and resampled on
the plane's own square grid for height maps, meshes and X3P (:func:`plane_grid`).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from huefringe.codecs import DecodeOptions, Reason, SequenceError, decode_sequence, load_sequence, read_captures
from huefringe.io import atomic_path
from huefringe.metrology import flatness_u, sigma_along
from huefringe.rig.calibrate import (
    Board,
    CalibrationReport,
    PoseObservation,
    calibrate_rig,
    detect_corners,
    projector_corners,
    refine_corners_fronto_parallel,
)
from huefringe.rig.decoded import RelativeCoordinateError, TriangulationInputs, relative_axes_problems, triangulation_inputs
from huefringe.rig.filestorage import write_calibration
from huefringe.rig.model import RigCalibration
from huefringe.rig.triangulation import epipolar_residual, triangulate

__all__ = [
    "RigCalibrationRun",
    "RigError",
    "RigFrame",
    "board_from",
    "calibrate_folders",
    "calibrate_poses",
    "calibrate_sl_session",
    "calibration_spread",
    "decode_frame",
    "height_over_plane",
    "measure_sl_frame",
    "plane_grid",
    "ray_test",
    "read_jackknife",
    "triangulate_frame",
    "write_rig_calibration",
]

F64 = NDArray[np.float64]


class RigError(ValueError):
    """Inputs the rig route refuses (every problem, each naming its file or folder)."""


# ------------------------------------------------------------------------------------ calibration


@dataclass(frozen=True, eq=False)
class RigCalibrationRun:
    """A rig calibrated from board poses, with its leave-one-pose-out calibrations.

    Attributes
    ----------
    calibration : RigCalibration
    report : CalibrationReport
        Per-pose RMS (``camera_rms_px``: the camera alone; ``projector_rms_px``: the projector
        against the joint model), the poses left out, and the fit's RMS.
    jackknife : tuple of (str, RigCalibration)
        The rig calibrated again without each used pose in turn (named by the pose left out).
    board : Board
    """

    calibration: RigCalibration
    report: CalibrationReport
    jackknife: tuple[tuple[str, RigCalibration], ...]
    board: Board


def board_from(block: dict[str, Any] | None, where: str | os.PathLike[str]) -> Board:
    """The :class:`Board` of a session's ``board`` block; refused (naming ``where``) when absent."""
    if not block:
        raise RigError(f"{where}: no board: a calibration session says which target its poses show "
                       "(board: {cols, rows, pitch_mm, kind})")
    return Board(int(block["cols"]), int(block["rows"]), float(block["pitch_mm"]), block.get("kind", "chessboard"))


def decode_frame(images: list[NDArray[np.number]], spec: Any, cfg: dict[str, Any]) -> dict[str, Any]:
    """Decode one capture sequence into ``u``, ``v`` (NaN where not valid), their sigmas, validity,
    modulation and absoluteness per axis, and the mean frame (for corners and colour)."""
    dec = decode_sequence(images, spec, DecodeOptions.from_config(cfg))
    out: dict[str, Any] = {"mean": np.mean(np.asarray(images, dtype=np.float64), axis=0), "decoded": dec}
    for axis, key in (("x", "u"), ("y", "v")):
        d = dec.get(axis)
        out[key] = None if d is None else np.where(d.valid, d.coord, np.nan)
        out["sigma_" + key] = None if d is None else d.sigma
        out["valid_" + key] = None if d is None else d.valid
        out["modulation_" + key] = None if d is None else d.modulation
        out["absolute_" + key] = None if d is None else bool(d.absolute)
    return out


def _observe(name: str, where: Path, d: dict[str, Any], image: Any, board: Board, rc: dict[str, Any],
             problems: list[str], corners: F64 | None = None) -> PoseObservation | None:
    corners = detect_corners(image, board) if corners is None else corners
    if corners is None:
        problems.append(f"{where}: the {board.cols} x {board.rows} {board.kind} was not found")
        return None
    valid = d["valid_u"] & d["valid_v"]
    pc, ok = projector_corners(corners, d["u"], d["v"], valid, rc["half_window_px"], rc["min_window_pixels"],
                               sigma_u=d["sigma_u"], sigma_v=d["sigma_v"])
    if not ok.all():
        problems.append(f"{where}: {int((~ok).sum())} of {len(ok)} corners without {rc['min_window_pixels']} decoded pixels around them")
        return None
    return PoseObservation(name, corners, pc)


PoseLoader = Callable[[], tuple[dict[str, Any], Any]]
"""Decodes one pose: :func:`decode_frame`'s maps and the image its corners are found in."""


def calibrate_poses(poses: list[tuple[str, Path, PoseLoader]], spec: Any, board: Board, cfg: dict[str, Any],
                    where: Path) -> RigCalibrationRun:
    """Calibrate the rig from board poses, each ``(name, folder, loader)``; then once more without each
    used pose in turn (the leave-one-pose-out calibrations of the calibration's uncertainty term).

    Raises
    ------
    RigError
        A sequence without both projector axes, or either axis relative (no Gray code or second
        period), poses whose board or corners were not found, too few usable poses; every
        problem at once.
    """
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # OpenCV's threaded corner search and calibration differ in the last digits from run to run
    try:
        return _calibrate_poses(poses, spec, board, cfg, where)
    finally:
        cv2.setNumThreads(threads)


def _calibrate_poses(poses: list[tuple[str, Path, PoseLoader]], spec: Any, board: Board, cfg: dict[str, Any],
                     where: Path) -> RigCalibrationRun:
    rc = cfg["rig"]
    problems: list[str] = []
    decoded: dict[str, dict[str, Any]] = {}
    missing = [a for a in ("x", "y") if a not in spec.axes()]
    if missing:
        raise RigError(f"{where}: calibration needs both projector axes (x and y) in the sequence; it codes "
                       f"{', '.join(spec.axes()) or 'none'}")
    obs = []
    images: dict[str, Any] = {}
    size = None
    for name, folder, load in poses:
        try:
            d, image = load()
        except SequenceError as exc:
            problems.append(str(exc))
            continue
        relative = [axis for axis, key in (("x", "u"), ("y", "v")) if d["absolute_" + key] is False]
        problems += [f"{where}: axis {axis} is decoded relative to one fringe period only (no Gray code or second "
                     "period): a calibration needs absolute projector coordinates" for axis in relative]
        if relative:
            continue
        o = _observe(name, folder, d, image, board, rc, problems)
        if o is not None:
            obs.append(o)
            decoded[name] = d
            images[name] = image
            size = (d["mean"].shape[1], d["mean"].shape[0])
    if len(obs) < rc["min_poses"]:
        problems.append(f"{where}: {len(obs)} usable poses; a calibration needs at least {rc['min_poses']}")
    if problems:
        raise RigError("; ".join(dict.fromkeys(problems)))
    assert size is not None
    kw = {"fix_k3": rc["fix_k3"], "min_poses": rc["min_poses"]}
    proj = (spec.projector_width, spec.projector_height)
    calib, report = calibrate_rig(obs, board, size, proj, outlier_factor=rc["outlier_factor"], **kw)
    rounds = int(rc["corner_refinement_rounds"])
    if rounds > 0:
        refinement: dict[str, Any] = {
            "method": "fronto-parallel views (Datta, Kim & Kanade 2009): corners found again on the board's plane "
                      "resampled with the calibration, carried back; projector corners and calibration again",
            "rounds": rounds, "not_refined": [], "mean_shift_px": []}
        for _ in range(rounds):
            again, shifts, kept = [], [], []
            for o in obs:
                c = refine_corners_fronto_parallel(images[o.name], o.camera, board, calib.camera_matrix,
                                                   calib.camera_distortion)
                r = None if c is None else _observe(o.name, where, decoded[o.name], None, board, rc, [], corners=c)
                if r is None:
                    kept.append(o.name)
                    again.append(o)
                    continue
                shifts.append(float(np.linalg.norm(r.camera - o.camera, axis=1).mean()))
                again.append(r)
            obs = again
            refinement["not_refined"] = kept
            refinement["mean_shift_px"].append(round(float(np.mean(shifts)), 4) if shifts else None)
            calib, report = calibrate_rig(obs, board, size, proj, outlier_factor=rc["outlier_factor"], **kw)
        report.corner_refinement = refinement
    used = [o for o in obs if o.name not in report.rejected]
    jack = []
    if len(used) > rc["min_poses"]:
        for o in used:
            # no second rejection round: each leave-one-out fit sees the final fit's poses, less one
            c, _ = calibrate_rig([p for p in used if p is not o], board, size, proj, outlier_factor=np.inf, **kw)
            jack.append((o.name, c))
    report.form_floor = _board_form(calib, used, decoded, cfg)
    return RigCalibrationRun(calib, report, tuple(jack), board)


def _board_form(calib: RigCalibration, poses: list[PoseObservation], decoded: dict[str, dict[str, Any]],
                cfg: dict[str, Any]) -> dict[str, Any]:
    """The instrument's form floor: the flatness (noise removed) of each calibration board, measured
    with the final calibration inside its corners' hull; a flat board shows the short-range errors
    that the decoded noise does not (the RMS over the poses is the floor)."""
    per = {}
    for o in poses:
        d = decoded[o.name]
        hull = cv2.convexHull(o.camera.astype(np.float32).reshape(-1, 1, 2))
        mask = np.zeros(d["mean"].shape, dtype=np.uint8)
        cv2.fillConvexPoly(mask, np.round(hull).astype(np.int32), 1)
        frame = triangulate_frame(d, calib, cfg, where=o.name)
        m = frame.valid & mask.astype(bool)
        if m.sum() < 100:
            continue
        p, sg = frame.xyz[m], frame.sigma[m]
        per[o.name] = flatness_u(p, sg, draws=16)["rms_form_mm"]
    floor = float(np.sqrt(np.mean(np.square(list(per.values()))))) if per else None
    return {"rms_form_mm": floor, "per_pose_mm": per,
            "what": "flatness FLTq (noise removed) of each calibration board with the final calibration, and their RMS: "
                    "the form floor every flatness and sphere form figure carries as an uncertainty term"}


def calibrate_sl_session(session: Any, cfg: dict[str, Any], board: Board | None = None) -> RigCalibrationRun:
    """Calibrate the rig from a structured-light session's ``poses/`` (corners in each pose's mean frame).

    Parameters
    ----------
    session : SLSession
        A loaded session (:func:`huefringe.session.load_sl_session`) with poses.
    cfg : dict
        The configuration (``codecs`` and ``rig`` blocks).
    board : Board, optional
        Overrides the session's ``board`` block.

    Raises
    ------
    RigError
        No poses or board, and every refusal of :func:`calibrate_poses`.
    """
    where = session.root / "session.yaml"
    if not session.poses:
        raise RigError(f"{where}: no calibration poses (poses: and poses/<name>/ folders)")
    board = board or board_from(session.board, where)

    def load(name: str) -> tuple[dict[str, Any], Any]:
        d = decode_frame(session.read_captures(name), session.spec, cfg)
        return d, d["mean"]

    poses = [(name, session.root / "poses" / name, lambda n=name: load(n)) for name in sorted(session.poses)]
    return calibrate_poses(poses, session.spec, board, cfg, session.root / "sequence.yaml")


def calibrate_folders(poses_dir: str | os.PathLike[str], sequence: str | os.PathLike[str], board: Board,
                      cfg: dict[str, Any]) -> RigCalibrationRun:
    """Calibrate from a folder of pose folders, each holding the sequence's captures (corners in their
    mean frame, or in ``board.png`` when the folder has one)."""
    poses_dir = Path(poses_dir)
    try:
        spec = load_sequence(sequence)
    except SequenceError as exc:
        raise RigError(str(exc)) from None
    folders = sorted(p for p in poses_dir.iterdir() if p.is_dir()) if poses_dir.is_dir() else []
    if not folders:
        raise RigError(f"{poses_dir}: no pose folders")

    def load(f: Path) -> tuple[dict[str, Any], Any]:
        d = decode_frame(read_captures(f, spec), spec, cfg)
        img = cv2.imread(str(f / "board.png"), cv2.IMREAD_GRAYSCALE) if (f / "board.png").exists() else d["mean"]
        return d, img

    return calibrate_poses([(f.name, f, lambda f=f: load(f)) for f in folders], spec, board, cfg, Path(sequence))


def _calib_doc(c: RigCalibration) -> dict[str, Any]:
    return {"camera_matrix": c.camera_matrix.tolist(), "camera_distortion": c.camera_distortion.tolist(),
            "projector_matrix": c.projector_matrix.tolist(), "projector_distortion": c.projector_distortion.tolist(),
            "R": c.R.tolist(), "T": c.T.tolist(), "camera_size": list(c.camera_size), "projector_size": list(c.projector_size)}


def write_rig_calibration(run: RigCalibrationRun, path: str | os.PathLike[str]) -> dict[str, Path]:
    """Write ``path`` (OpenCV FileStorage), ``<stem>.report.json`` (per-pose errors, poses left out,
    both RMS definitions) and ``<stem>.jackknife.json`` (the leave-one-pose-out calibrations)."""
    path = Path(path)
    write_calibration(path, run.calibration)
    report = {
        "board": {"cols": run.board.cols, "rows": run.board.rows, "pitch_mm": run.board.pitch_mm, "kind": run.board.kind},
        **run.report.to_dict(),
        "rms_definitions": {
            "camera": "camera alone: RMS reprojection error of every corner of the used poses (cv2.calibrateCamera)",
            "projector": "projector alone: RMS reprojection error of the projector corners (cv2.calibrateCamera on them)",
            "stereo": "joint model: RMS over camera and projector corners after the stereo refinement (cv2.stereoCalibrate)",
            "poses[].camera_rms_px / projector_rms_px": "per pose, against the final joint model (the board pose from the camera)",
        },
        "baseline_mm": run.calibration.baseline_mm,
        "jackknife_poses": [name for name, _ in run.jackknife],
    }
    files = {"calibration": path, "report": path.with_suffix(".report.json"), "jackknife": path.with_suffix(".jackknife.json")}
    _write_json(files["report"], report)
    _write_json(files["jackknife"], {"left_out": {name: _calib_doc(c) for name, c in run.jackknife}})
    return files


def read_jackknife(path: str | os.PathLike[str]) -> list[tuple[str, RigCalibration]]:
    """The leave-one-pose-out calibrations :func:`write_rig_calibration` wrote (empty when the file is absent)."""
    p = Path(path)
    if not p.is_file():
        return []
    doc = json.loads(p.read_text(encoding="utf-8"))
    return [(name, RigCalibration(**{k: (tuple(v) if k.endswith("_size") else np.asarray(v)) for k, v in c.items()}))
            for name, c in doc["left_out"].items()]


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=2, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)) + "\n")


# ------------------------------------------------------------------------------------ geometry


@dataclass(frozen=True, eq=False)
class RigFrame:
    """One triangulated frame on the camera grid.

    Attributes
    ----------
    xyz, sigma : ndarray, shape (H, W, 3)
        X, Y, Z in mm (camera frame) and their standard uncertainties from the decoded
        coordinates; NaN where not valid.
    valid : ndarray of bool, shape (H, W)
    decoded : dict
        :func:`decode_frame`'s maps (``u``, ``v``, sigmas, validity, modulation, ``mean``).
    mode : str
        The triangulation: ``u``, ``v`` (ray against a projector plane) or ``both`` (ray-ray).
    sigma_ray : ndarray, shape (H, W)
        The decoded coordinates' noise along each point's camera ray, mm.
    ray_residual : ndarray, shape (H, W) or None
        With both axes (``mode == 'both'``): how far the camera and projector rays miss, in
        projector pixels (:func:`~huefringe.rig.triangulation.epipolar_residual`), at every pixel
        that passed the decoding's tests (NaN elsewhere); pixels that failed the ray test are
        flagged :attr:`~huefringe.codecs.Reason.RAY` in ``decoded``. None with one axis.
    """

    xyz: F64
    sigma: F64
    valid: NDArray[np.bool_]
    decoded: dict[str, Any]
    mode: str
    sigma_ray: F64
    ray_residual: F64 | None = None


def ray_test(d: dict[str, Any], ti: TriangulationInputs, calib: RigCalibration, cfg: dict[str, Any]
             ) -> tuple[dict[str, Any], TriangulationInputs, F64 | None]:
    """Drop the pixels whose camera ray and projector ray miss each other (both axes decoded).

    A pixel fails when its decoded projector pixel lies farther from the camera pixel's epipolar
    line than ``codecs.max_ray_sigma`` times the distance's standard uncertainty from the decoded
    coordinates' sigmas and farther than ``codecs.ray_floor_px`` (the calibration's own epipolar
    error, which the decoded sigmas do not hold). Such a pixel carries a wrong fringe order or
    Gray cell the decoding's own tests missed, or light that did not come straight from the
    projector (interreflection, a blurred edge).

    Returns
    -------
    d : dict
        :func:`decode_frame`'s maps with the failing pixels not valid (``u``, ``v`` NaN) and
        flagged :attr:`~huefringe.codecs.Reason.RAY` in both axes' ``reasons``; ``d`` itself
        when the test does not apply (one axis) or drops nothing.
    inputs : TriangulationInputs
        ``ti`` without the failing pixels.
    residual : ndarray or None
        The miss in projector pixels at every pixel of ``ti.valid`` (NaN elsewhere); None with one axis.
    """
    if ti.mode != "both" or ti.u is None or ti.v is None:
        return d, ti, None
    c = cfg["codecs"]
    k, floor = float(c["max_ray_sigma"]), float(c["ray_floor_px"])
    r, s = epipolar_residual(calib, ti.u, ti.v, sigma_u=ti.sigma_u, sigma_v=ti.sigma_v)
    with np.errstate(invalid="ignore"):
        bad = ti.valid & (np.abs(r) > np.maximum(k * s, floor))
    if not bad.any():
        return d, ti, r
    keep = ti.valid & ~bad
    dec = dict(d["decoded"])
    out = dict(d)
    for axis, key in (("x", "u"), ("y", "v")):
        a = dec[axis]
        reasons = a.reasons.copy()
        if reasons.size:           # a Decoded built without reason codes keeps none
            reasons[bad] |= np.uint8(Reason.RAY)
        valid = a.valid & ~bad
        dec[axis] = replace(a, coord=np.where(valid, a.coord, np.nan), sigma=np.where(valid, a.sigma, np.nan),
                            valid=valid, reasons=reasons)
        out[key] = np.where(valid, d[key], np.nan)
        out["valid_" + key] = valid
        out["sigma_" + key] = dec[axis].sigma
    out["decoded"] = dec
    nan = np.where(keep, 0.0, np.nan)
    ti = replace(ti, u=ti.u + nan, v=ti.v + nan, sigma_u=None if ti.sigma_u is None else ti.sigma_u + nan,
                 sigma_v=None if ti.sigma_v is None else ti.sigma_v + nan, valid=keep)
    return out, ti, r


def triangulate_frame(d: dict[str, Any], calib: RigCalibration, cfg: dict[str, Any], *, where: str,
                      spec: Any = None) -> RigFrame:
    """Triangulate decoded maps ``d`` with ``calib``; refuse what cannot be absolute X, Y, Z.

    Only pixels whose every validity test passed are triangulated
    (:func:`huefringe.rig.decoded.triangulation_inputs`); with both axes, only those whose
    camera and projector rays meet (:func:`ray_test`).

    Raises
    ------
    RigError
        An axis the triangulation needs is missing or decoded relative to one period only (no
        Gray code or second period: a relative projector coordinate triangulates to a wrong,
        plausible-looking surface), the captures are not the calibration's camera size, or
        fewer than 3 points.
    """
    h, w = d["mean"].shape
    if calib.camera_size != (0, 0) and calib.camera_size != (w, h):
        raise RigError(f"{where}: {w} x {h} captures, the calibration's camera is {calib.camera_size[0]} x {calib.camera_size[1]}")
    try:
        ti = triangulation_inputs(d["decoded"], spec, cfg["rig"]["triangulation"])
    except RelativeCoordinateError as exc:
        raise RigError(f"{where}: {exc}") from None
    d, ti, residual = ray_test(d, ti, calib, cfg)
    t = triangulate(calib, ti.u, ti.v, sigma_u=ti.sigma_u, sigma_v=ti.sigma_v, valid=ti.valid, mode=ti.mode)
    if int(t.valid.sum()) < 3:
        raise RigError(f"{where}: {int(t.valid.sum())} pixels decoded and triangulated; nothing to measure")
    return RigFrame(t.xyz, t.sigma, t.valid, d, ti.mode, t.sigma_ray, residual)


def measure_sl_frame(session: Any, calib: RigCalibration, cfg: dict[str, Any]) -> RigFrame:
    """Decode a structured-light session's ``captures/`` and triangulate them with ``calib``
    (a sequence that cannot give absolute coordinates is refused before anything is decoded)."""
    problems = relative_axes_problems(session.spec, cfg["rig"]["triangulation"])
    if problems:
        raise RigError("; ".join(f"{session.root / 'sequence.yaml'}: {p}" for p in problems))
    try:
        d = decode_frame(session.read_captures(), session.spec, cfg)
    except SequenceError as exc:
        raise RigError(str(exc)) from None
    return triangulate_frame(d, calib, cfg, where=str(session.root / "captures"), spec=session.spec)


CALIBRATION_SPREAD_STRIDE = 4
"""The calibration's per-pixel term is computed every this many camera pixels along both axes and
interpolated between them (it varies with the calibration's smooth errors, not from pixel to pixel)."""


def calibration_spread(frame: RigFrame, jackknife: list[tuple[str, RigCalibration]],
                       stride: int = CALIBRATION_SPREAD_STRIDE) -> tuple[F64, F64]:
    """The calibration's standard uncertainty of every point: the jackknife spread of the point
    triangulated again with each leave-one-pose-out calibration.

    The points are triangulated again on every ``stride``-th pixel of each axis; the spread is
    interpolated bilinearly between them (weights normalised over the valid samples, so a sample
    across an invalid region does not count).

    Returns
    -------
    u_axes : ndarray, shape (H, W, 3)
        Per axis, ``sqrt((J - 1) / J * sum_j (p_j - mean)^2) * sqrt((J - 1) / (J - 3))``: the
        jackknife standard error as the standard deviation of the t-distribution with ``J - 1``
        degrees of freedom (JCGM 101, :func:`huefringe.metrology.jackknife_u`); zero without
        leave-one-out calibrations.
    u_ray : ndarray, shape (H, W)
        The same along the point's camera ray (where a triangulated point's error lies).

    Every valid pixel gets a term: one without a valid sample within ``stride`` pixels gets its own,
    and one that a leave-one-out calibration cannot triangulate (behind a device) gets an
    infinite term (the calibrations do not agree that the point exists).
    """
    if not jackknife:
        return np.where(frame.valid[..., None], np.zeros(3), np.nan), np.where(frame.valid, 0.0, np.nan)
    n = len(jackknife)
    if n < 4:
        raise RigError(f"{n} leave-one-pose-out calibrations; the calibration's term needs at least 4")
    h, w = frame.valid.shape
    sample = np.zeros_like(frame.valid)
    sample[::stride, ::stride] = True
    sample &= frame.valid
    scale = (n - 1) / n * (n - 1) / (n - 3)
    vals, got = _jackknife_at(frame, jackknife, sample, scale)
    coarse = np.zeros(((h + stride - 1) // stride, (w + stride - 1) // stride, 5), dtype=np.float32)
    rows, cols = np.nonzero(sample)
    coarse[rows[got] // stride, cols[got] // stride] = vals[got]
    # bilinear between the samples (pixel i*stride of the full grid is sample i), weights normalised
    yy = np.arange(h) / stride
    xx = np.arange(w) / stride
    fine = cv2.remap(coarse, *np.meshgrid(xx.astype(np.float32), yy.astype(np.float32)), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
    with np.errstate(invalid="ignore", divide="ignore"):
        est = fine[..., :4] / fine[..., 4:5]
    both = np.full((h, w, 4), np.nan)  # the axes' terms and the ray's, NaN where not valid
    np.copyto(both, est, where=frame.valid[..., None])
    u_axes, u_ray = both[..., :3], both[..., 3]
    # a valid pixel with no sample around it (a small island, the edge of a region): its own term
    alone = frame.valid & ~np.isfinite(u_ray)
    if alone.any():
        vals, got = _jackknife_at(frame, jackknife, alone, scale)
        a_axes, a_ray = np.full((int(alone.sum()), 3), np.inf), np.full(int(alone.sum()), np.inf)
        a_axes[got], a_ray[got] = vals[got, :3], vals[got, 3]
        u_axes[alone], u_ray[alone] = a_axes, a_ray
    return u_axes, u_ray


def _jackknife_at(frame: RigFrame, jackknife: list[tuple[str, RigCalibration]], where: NDArray[np.bool_],
                  scale: float) -> tuple[F64, NDArray[np.bool_]]:
    """The jackknife spread (per axis, along the ray, and a weight of one) of the points at ``where``
    and whether every leave-one-out calibration triangulated them."""
    d = frame.decoded
    use = {"u": frame.mode in ("u", "both"), "v": frame.mode in ("v", "both")}
    # a sparse set as pixel vectors (the rays triangulate's grid path takes for it, without the
    # full camera maps), a dense one as maps masked to it (its cached grid rays)
    sparse = 4 * int(where.sum()) < where.size
    coords = {k: (np.asarray(d[k], np.float64)[where] if sparse else d[k]) if use[k] else None for k in use}
    if sparse:
        rows, cols = np.nonzero(where)
        at: dict[str, Any] = {"pixels": np.column_stack([cols, rows]).astype(np.float64)}
    else:
        at = {"valid": where}
    pts = []
    for _, c in jackknife:
        t = triangulate(c, coords["u"], coords["v"], mode=frame.mode, **at)  # type: ignore[arg-type]
        pts.append(t.xyz if sparse else t.xyz[where])
    p = np.stack(pts)
    dev = p - p.mean(axis=0)
    ray = frame.xyz[where] / np.linalg.norm(frame.xyz[where], axis=-1, keepdims=True)
    got = np.isfinite(dev).all(axis=(0, 2))
    vals = np.column_stack([np.sqrt(scale * np.sum(dev**2, axis=0)),
                            np.sqrt(scale * np.sum(np.einsum("jik,ik->ji", dev, ray) ** 2, axis=0)), np.ones(len(ray))])
    return vals, got


def height_over_plane(frame: RigFrame, centroid: F64, normal: F64) -> tuple[F64, F64]:
    """Signed distance of every valid point from the plane (``normal`` towards the camera) and its
    standard uncertainty, on the camera grid (NaN where not valid)."""
    h = np.where(frame.valid, (frame.xyz - centroid) @ normal, np.nan)
    u = np.where(frame.valid, sigma_along(frame.xyz, frame.sigma, normal), np.nan)
    return h, u


def plane_grid(frame: RigFrame, height: F64, u: F64, centroid: F64, normal: F64) -> dict[str, Any]:
    """Height and its uncertainty resampled on a square grid in the plane's own axes.

    The grid's pitch is the median distance between neighbouring camera pixels' points; each node
    takes the inverse-distance mean of the 4 nearest points within 1.5 pitch (NaN beyond). Axes:
    ``a`` = normal x camera X (unit), ``b`` = normal x a; the node ``(i, j)`` lies at
    ``centroid + (s0 + j pitch) a + (q0 + i pitch) b``.
    """
    a = np.cross(normal, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    pts = frame.xyz[frame.valid]
    s, q = (pts - centroid) @ a, (pts - centroid) @ b
    pitch = float(np.nanmedian(np.linalg.norm(np.diff(frame.xyz, axis=1), axis=2)))
    gs = np.arange(s.min(), s.max(), pitch)
    gq = np.arange(q.min(), q.max(), pitch)
    S, Q = np.meshgrid(gs, gq)
    dist, idx = cKDTree(np.column_stack([s, q])).query(np.column_stack([S.ravel(), Q.ravel()]), k=4,
                                                        distance_upper_bound=1.5 * pitch)
    ok = np.isfinite(dist)
    wgt = np.where(ok, 1.0 / np.maximum(dist, 1e-6 * pitch), 0.0)
    safe = np.minimum(idx, len(pts) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        hz = (wgt * np.where(ok, height[frame.valid][safe], 0.0)).sum(axis=1) / wgt.sum(axis=1)
        # the mean of up to 4 points: u of one point kept (neighbours' errors are not averaged
        # away for a surface, and the mean does not make a pixel more certain than its points)
        uz = (wgt * np.where(ok, u[frame.valid][safe], 0.0)).sum(axis=1) / wgt.sum(axis=1)
    return {"height": hz.reshape(S.shape).astype(np.float32), "uncertainty": uz.reshape(S.shape).astype(np.float32),
            "pitch_mm": pitch, "origin_mm": (centroid + gs[0] * a + gq[0] * b).tolist(),
            "axes": {"a": a.tolist(), "b": b.tolist(), "normal": normal.tolist()}}
