"""Folders in, files out: calibrate a rig from board-pose capture folders; measure a capture folder.

``POSES_DIR`` holds one sub-folder per board pose, each with the captures of the coded sequence
(``SEQUENCE.yaml``, :mod:`huefringe.codecs`); the board's corners are found in the mean of the
pose's frames (the board evenly lit) or in ``board.png`` when the folder has one. A measurement
folder holds the captures of the same sequence on the object. Everything is checked before any
output is written, and each output file appears whole or not at all.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from huefringe.codecs import DecodeOptions, SequenceError, decode_sequence, load_sequence, read_captures
from huefringe.rig.calibrate import Board, CalibrationReport, PoseObservation, calibrate_rig, detect_corners, projector_corners
from huefringe.rig.filestorage import read_calibration, write_calibration
from huefringe.rig.forms import fit_plane, form_deviation
from huefringe.rig.model import RigCalibration
from huefringe.rig.triangulation import triangulate
from huefringe.settings import defaults

__all__ = ["RigError", "calibrate_folders", "calibrate_session", "decode_folder_uv", "measure_folder", "measure_session"]

F64 = NDArray[np.float64]


class RigError(ValueError):
    """Inputs a rig command refuses (every problem, each naming its file or folder)."""


def _decode_uv(images: Any, spec: Any) -> dict[str, Any]:
    """Decode one sequence of captures: ``u``, ``v``, their sigmas, validity, the mean frame."""
    dec = decode_sequence(images, spec, DecodeOptions.from_config())
    out: dict[str, Any] = {"mean": np.mean(np.asarray(images, dtype=np.float64), axis=0)}
    for axis, key in (("x", "u"), ("y", "v")):
        d = dec.get(axis)
        out[key] = None if d is None else np.where(d.valid, d.coord, np.nan)
        out["sigma_" + key] = None if d is None else d.sigma
        out["valid_" + key] = None if d is None else d.valid
    return out


def decode_folder_uv(folder: Path, spec: Any) -> dict[str, Any]:
    """Decode one capture folder: ``u``, ``v``, their sigmas, validity, the mean frame."""
    return _decode_uv(read_captures(folder, spec), spec)


def _load_session(session: str | os.PathLike[str]) -> Any:
    from huefringe.session import SessionError
    from huefringe.session import load_sl_session

    try:
        return load_sl_session(session)
    except SessionError as exc:
        raise RigError("; ".join(str(p) for p in exc.problems)) from None


def _both_axes(spec: Any, where: Any) -> None:
    axes = {b.axis for b in spec.blocks if hasattr(b, "axis")}
    if not {"x", "y"} <= axes:
        raise RigError(f"{where}: calibration needs both projector axes (x and y) in the sequence")


def calibrate_folders(poses_dir: str | os.PathLike[str], sequence: str | os.PathLike[str], out: str | os.PathLike[str],
                      board: Board, cfg: dict[str, Any] | None = None) -> tuple[RigCalibration, CalibrationReport]:
    """Calibrate from ``poses_dir``'s pose folders; write ``out`` (FileStorage) and ``out``.report.json."""
    poses_dir = Path(poses_dir)
    try:
        spec = load_sequence(sequence)
    except SequenceError as exc:
        raise RigError(str(exc)) from None
    _both_axes(spec, sequence)
    folders = sorted(p for p in poses_dir.iterdir() if p.is_dir()) if poses_dir.is_dir() else []
    if not folders:
        raise RigError(f"{poses_dir}: no pose folders")

    def load(f: Path) -> tuple[dict[str, Any], Any]:
        d = decode_folder_uv(f, spec)
        img = cv2.imread(str(f / "board.png"), cv2.IMREAD_GRAYSCALE) if (f / "board.png").exists() else d["mean"]
        return d, img

    return _calibrate([(f.name, f, lambda f=f: load(f)) for f in folders], poses_dir, spec, Path(out), board, cfg)


def calibrate_session(session: str | os.PathLike[str], out: str | os.PathLike[str], board: Board,
                      cfg: dict[str, Any] | None = None) -> tuple[RigCalibration, CalibrationReport]:
    """Calibrate from a structured-light session's ``poses/`` (corners in each pose's mean frame);
    write ``out`` (FileStorage) and ``out``.report.json."""
    s = _load_session(session)
    _both_axes(s.spec, s.root / "sequence.yaml")
    if not s.poses:
        raise RigError(f"{s.root / 'session.yaml'}: no calibration poses (poses: and poses/<name>/ folders)")

    def load(name: str) -> tuple[dict[str, Any], Any]:
        d = _decode_uv(s.read_captures(name), s.spec)
        return d, d["mean"]

    pose_list = [(name, s.root / "poses" / name, lambda n=name: load(n)) for name in sorted(s.poses)]
    return _calibrate(pose_list, s.root / "poses", s.spec, Path(out), board, cfg)


def _calibrate(poses: list[tuple[str, Path, Any]], where: Path, spec: Any, out: Path, board: Board,
               cfg: dict[str, Any] | None) -> tuple[RigCalibration, CalibrationReport]:
    rc = (cfg or defaults())["rig"]
    problems, obs = [], []
    size = None
    for name, f, load in poses:
        try:
            d, img = load()
        except SequenceError as exc:
            problems.append(str(exc))
            continue
        corners = detect_corners(img, board)
        if corners is None:
            problems.append(f"{f}: the {board.cols} x {board.rows} {board.kind} was not found")
            continue
        valid = d["valid_u"] & d["valid_v"]
        pc, ok = projector_corners(corners, d["u"], d["v"], valid, rc["half_window_px"], rc["min_window_pixels"],
                                   sigma_u=d["sigma_u"], sigma_v=d["sigma_v"])
        if not ok.all():
            problems.append(f"{f}: {int((~ok).sum())} of {len(ok)} corners without {rc['min_window_pixels']} decoded pixels around them")
            continue
        size = (img.shape[1], img.shape[0])
        obs.append(PoseObservation(name, corners, pc))
    if len(obs) < rc["min_poses"]:
        problems.append(f"{where}: {len(obs)} usable poses; a calibration needs at least {rc['min_poses']}")
    if problems:
        raise RigError("; ".join(problems))
    assert size is not None
    calib, report = calibrate_rig(obs, board, size, (spec.projector_width, spec.projector_height), outlier_factor=rc["outlier_factor"],
                                  fix_k3=rc["fix_k3"], min_poses=rc["min_poses"])
    write_calibration(out, calib)
    _write_json(out.with_suffix(".report.json"), {"calibration": str(out), "board": board.__dict__, **report.to_dict()})
    return calib, report


def _resample(s: F64, q: F64, z: F64, S: F64, Q: F64, pitch: float) -> NDArray[np.float32]:
    """Inverse-distance mean of the 4 nearest points within 1.5 pitch of each grid node (NaN beyond)."""
    dist, idx = cKDTree(np.column_stack([s, q])).query(np.column_stack([S.ravel(), Q.ravel()]), k=4,
                                                        distance_upper_bound=1.5 * pitch)
    ok = np.isfinite(dist)
    w = np.where(ok, 1.0 / np.maximum(dist, 1e-6 * pitch), 0.0)
    zz = np.where(ok, z[np.minimum(idx, len(z) - 1)], 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (w * zz).sum(axis=1) / w.sum(axis=1)
    return out.reshape(S.shape).astype(np.float32)


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=2, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    os.replace(tmp, path)


def measure_folder(captures: str | os.PathLike[str], sequence: str | os.PathLike[str],
                   calibration: list[str | os.PathLike[str]], outdir: str | os.PathLike[str],
                   boxes: dict[str, tuple[int, int, int, int]] | None = None,
                   cfg: dict[str, Any] | None = None, base: list[tuple[int, int, int, int]] | None = None) -> dict[str, Any]:
    """Decode, triangulate and write cloud, mesh, height map, X3P, figures and a JSON report into ``outdir``.

    The height map is the points' distance from their fitted plane, resampled on a square grid
    of the plane's own axes (pitch: the median camera-pixel footprint; inverse-distance mean of
    the 4 nearest points within 1.5 pitch). ``boxes`` (camera pixels
    ``x0, y0, x1, y1``: columns ``x0 .. x1 - 1``, rows ``y0 .. y1 - 1``) report each box's mean
    height above the plane (a step height). The plane is fitted to every point, or with ``base``
    (boxes of the same form) to the points in those boxes only: the surface the heights are
    measured from, without the object's own faces tilting it.
    """
    problems = []
    try:
        spec = load_sequence(sequence)
    except SequenceError as exc:
        problems.append(str(exc))
    try:
        calib = read_calibration(*calibration)
    except ValueError as exc:
        problems.append(str(exc))
    if problems:
        raise RigError("; ".join(problems))
    try:
        d = decode_folder_uv(Path(captures), spec)
    except SequenceError as exc:
        raise RigError(str(exc)) from None
    return _measure(d, calib, Path(outdir), boxes, base, cfg, where=str(captures), sequence=str(sequence),
                    inputs={"captures": str(captures), "calibration": [str(c) for c in calibration]},
                    title=Path(captures).name)


def measure_session(session: str | os.PathLike[str], outdir: str | os.PathLike[str],
                    boxes: dict[str, tuple[int, int, int, int]] | None = None,
                    calibration: list[str | os.PathLike[str]] | None = None,
                    cfg: dict[str, Any] | None = None, base: list[tuple[int, int, int, int]] | None = None) -> dict[str, Any]:
    """:func:`measure_folder` on a structured-light session: its ``captures/`` with its
    ``calibration/`` (or the ``calibration`` files given, e.g. one made from its ``poses/``)."""
    s = _load_session(session)
    files = [Path(c) for c in calibration] if calibration else ([s.calibration] if s.calibration else [])
    if not files:
        raise RigError(f"{s.root / 'session.yaml'}: no calibration in the session; give one "
                       "(huefringe rig-measure SESSION OUTDIR --calibration FILE)")
    try:
        calib = read_calibration(*files)
    except ValueError as exc:
        raise RigError(str(exc)) from None
    d = _decode_uv(s.read_captures(), s.spec)
    return _measure(d, calib, Path(outdir), boxes, base, cfg, where=str(s.root / "captures"),
                    sequence=str(s.root / "sequence.yaml"),
                    inputs={"session": str(s.root), "session_id": s.id, "calibration": [str(c) for c in files]},
                    title=s.id)


def _measure(d: dict[str, Any], calib: RigCalibration, out: Path, boxes: dict[str, tuple[int, int, int, int]] | None,
             base: list[tuple[int, int, int, int]] | None, cfg: dict[str, Any] | None, *, where: str, sequence: str,
             inputs: dict[str, Any], title: str) -> dict[str, Any]:
    """Triangulate decoded ``d`` with ``calib``; write every output into ``out`` and return the report."""
    import trimesh

    from huefringe.cloud import write_points
    from huefringe.io import write_tiff
    from huefringe.mesh import export_mesh, height_to_mesh
    from huefringe.render import camera_for_field, height_map_figure, render_views
    from huefringe.x3p import write_height_x3p

    conf = cfg or defaults()
    rc = conf["rig"]
    h, w = d["mean"].shape
    if calib.camera_size != (0, 0) and calib.camera_size != (w, h):
        raise RigError(f"{where}: {w} x {h} captures, the calibration's camera is {calib.camera_size[0]} x {calib.camera_size[1]}")
    mode = rc["triangulation"]
    if mode == "auto":
        mode = "both" if (d["u"] is not None and d["v"] is not None) else ("u" if d["u"] is not None else "v")
    valid = np.ones((h, w), dtype=bool)
    for k in ("u", "v") if mode == "both" else (mode,):
        if d[k] is None:
            raise RigError(f"{sequence}: triangulation {mode!r} needs the projector {'x' if k == 'u' else 'y'} axis")
        valid &= d["valid_" + k]
    for name, (x0, y0, x1, y1) in [*(boxes or {}).items(), *((f"base{i}", b) for i, b in enumerate(base or []))]:
        if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
            raise RigError(f"--box {x0},{y0},{x1},{y1} ({name}): x0 < x1 <= {w} and y0 < y1 <= {h} camera pixels expected")
    t = triangulate(calib, d["u"] if mode in ("u", "both") else None, d["v"] if mode in ("v", "both") else None,
                    sigma_u=d["sigma_u"], sigma_v=d["sigma_v"], valid=valid, mode=mode)
    pts = t.xyz[t.valid]
    if len(pts) < 3:
        raise RigError(f"{where}: {len(pts)} pixels decoded on both the camera and the projector; nothing to measure")
    on_base = np.zeros((h, w), dtype=bool)
    for x0, y0, x1, y1 in base or []:
        on_base[y0:y1, x0:x1] = True
    ref = pts if not base else t.xyz[t.valid & on_base]
    if len(ref) < 3:
        raise RigError(f"{where}: {len(ref)} measured points in the --base boxes; a plane needs 3")
    plane = fit_plane(ref)
    dist = np.full((h, w), np.nan)
    dist[t.valid] = plane.distance(pts)
    a = np.cross(plane.normal, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(plane.normal, a)
    s, q = (pts - plane.centroid) @ a, (pts - plane.centroid) @ b
    spacing = np.nanmedian(np.linalg.norm(np.diff(t.xyz, axis=1), axis=2))
    pitch = float(spacing)
    gs = np.arange(s.min(), s.max(), pitch)
    gq = np.arange(q.min(), q.max(), pitch)
    S, Q = np.meshgrid(gs, gq)
    height = _resample(s, q, dist[t.valid], S, Q, pitch)
    out.mkdir(parents=True, exist_ok=True)
    sig = t.sigma[t.valid]
    write_points(out / "cloud.ply", pts, scalars={"sigma_x": sig[:, 0], "sigma_y": sig[:, 1], "sigma_z": sig[:, 2]})
    write_tiff(out / "height.tiff", height, pixel_pitch_mm=pitch)
    write_height_x3p(out / "height.x3p", height, pitch)
    mesh = height_to_mesh(height, pitch)
    stats = export_mesh(mesh, out / "mesh.ply")
    # figures: the height map and the mesh rendered off-screen, as the capture-session route draws them
    finite = height[np.isfinite(height)]
    clim = (float(np.percentile(finite, 0.5)), float(np.percentile(finite, 99.5))) if finite.size else (-1.0, 1.0)
    height_map_figure(height, pitch, out / "height.png", clim=clim, title=f"{title}: height above the fitted plane (mm)")
    size = (int(conf["render"]["width"]), int(conf["render"]["height"]))
    cams = camera_for_field((height.shape[1] - 1) * pitch, (height.shape[0] - 1) * pitch, clim, size=size)
    renders = render_views(trimesh.load(out / "mesh.ply", process=False, force="mesh"), out, "mesh", clim=clim,
                           camera=cams, size=size, title=title)
    report: dict[str, Any] = {
        **inputs, "triangulation": mode,
        "points": int(len(pts)), "coverage": float(t.valid.mean()),
        "plane": {"normal": plane.normal.tolist(), "centroid_mm": plane.centroid.tolist(),
                  "rms_mm": plane.rms_mm, "form_deviation_mm": form_deviation(plane, ref),
                  "fitted_to": [list(b) for b in base] if base else "all points"},
        "median_sigma_mm": np.nanmedian(sig, axis=0).tolist(), "height_pitch_mm": pitch,
        "mesh": {k: v for k, v in stats.items() if isinstance(v, int | float)},
        "boxes": {},
        "files": sorted(["cloud.ply", "height.tiff", "height.x3p", "mesh.ply", "height.png", "report.json",
                         *(Path(r).name for r in renders)]),
    }
    for name, (x0, y0, x1, y1) in (boxes or {}).items():
        box = dist[y0:y1, x0:x1]
        report["boxes"][name] = {"mean_height_mm": float(np.nanmean(box)), "n": int(np.isfinite(box).sum())}
    _write_json(out / "report.json", report)
    return report
