"""Structured-light sessions written by the bench rig: calibration poses, object scenes, ground truth.

One YAML file (format ``huefringe-sl-bench/1``, schema ``sl_bench.schema.json`` beside this
module; presets ``rig-poses``, ``rig-gauge``, ``rig-board``, ``rig-oneshot``, ``rig-oneshot-vibrating``,
``rig-base-plane``, ``rig-oneshot-on-base``) describes a
``structured-light-session/1`` folder (``docs/spec/structured-light-session.md``):

* ``captures/0000.png ..``: the sequence on the scene (a flat board, or a tilted base plane with
  blocks and a ball: :class:`~huefringe.bench.rig.CompositeScene`), where the projector lights a
  point directly; a point in a projector shadow gets ambient light and noise only; a sequence
  with one-shot blocks (``hue_bands``, ``trapezoid``) is captured in colour, every frame, the
  blocks coated as ``scene.colours`` lists (:meth:`~huefringe.bench.rig.BenchRig.capture_rgb`);
* with ``poses``: ``poses/pose_NN/0000.png ..``, a printed board in each pose, and ``board:`` in
  session.yaml (a calibration session);
* with ``calibration_session``: ``calibration: {session: <relative path>}`` in session.yaml;
* with ``oneshot_reference``: ``oneshot: {reference: {session: <relative path>}}`` in session.yaml
  (the one-shot frames' order from another session's coded captures, e.g. the base plane alone);
* ``features.yaml``: camera-pixel boxes well inside each face of the scene's truth (eroded by
  ``features.margin_px``, clear of shadows), nominal values from the scene;
* ``ground_truth/x.tiff``, ``y.tiff`` (true projector coordinates) and ``xyz.tiff`` (true
  camera-frame points, mm), NaN where the projector does not light the pixel's point directly;
  of the scene where the first one-shot frame sees it (the still scene without ``vibration``);
* with ``vibration``: the scene moves along its base plane's normal while the one-shot frames are
  captured (each frame averaged over instants across its exposure); every other frame sees it
  still. Each one-shot frame's displacement: :func:`vibration_displacements`, its truth:
  :func:`scene_truth` of :func:`displaced_config`.

Public API
----------
load_sl_bench_config(ref) -> dict
    Read, validate and complete a YAML file or packaged preset.
validate_sl_bench_config(raw) -> dict
    The same for a mapping built in code.
bench_kind(ref) -> str
    The session format a bench YAML or preset writes (``capture-session/1`` or
    ``structured-light-session/1``), from its ``format`` key.
sl_session_plan(cfg) -> dict
    What the session will hold, without writing anything.
scene_truth(cfg) -> dict
    The scene's truth on the camera pixels (float64): points, projector coordinates, face labels, lit mask.
features_from_truth(truth, names, ...) -> dict
    ``features.yaml``'s content from the truth.
vibration_displacements(cfg) -> ndarray
    Each one-shot frame's displacements (mm, towards the camera) at the instants of its exposure.
displaced_config(cfg, d_mm) -> dict
    The configuration with its scene moved ``d_mm`` along the base plane's normal.
write_sl_session(cfg, out_dir) -> Path
    Write the session (atomically) and validate it with :func:`huefringe.session.load_sl_session`.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
import tempfile
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import jsonschema
import numpy as np
import yaml
from numpy.typing import NDArray

from .config import BenchConfigError, _fill_defaults, preset_path

__all__ = [
    "SL_BENCH_FORMAT",
    "bench_kind",
    "displaced_config",
    "features_from_truth",
    "largest_box",
    "load_sl_bench_config",
    "scene_truth",
    "sl_bench_schema",
    "sl_session_plan",
    "validate_sl_bench_config",
    "vibration_displacements",
    "write_sl_session",
]

SL_BENCH_FORMAT = "huefringe-sl-bench/1"
_SCHEMA = Path(__file__).resolve().parent / "sl_bench.schema.json"
F64 = NDArray[np.float64]


@cache
def sl_bench_schema() -> dict[str, Any]:
    """The JSON schema of the structured-light bench YAML (draft 2020-12)."""
    return json.loads(_SCHEMA.read_text(encoding="utf-8"))


def _resolve_ref(ref: str | os.PathLike[str]) -> Path:
    p = Path(ref)
    if p.is_file():
        return p
    if p.suffix not in (".yaml", ".yml") and p.parent == Path("."):
        return preset_path(str(ref))
    return p


def bench_kind(ref: str | os.PathLike[str]) -> str:
    """The session format a bench YAML (or preset name) writes.

    Returns
    -------
    str
        ``structured-light-session/1`` for ``format: huefringe-sl-bench/1``, else
        ``capture-session/1`` (the capture-session bench, :func:`huefringe.bench.write_session`).

    Raises
    ------
    BenchConfigError
        If the file cannot be read or parsed.
    FileNotFoundError
        For an unknown preset name.
    """
    p = _resolve_ref(ref)
    try:
        raw = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise BenchConfigError(p, f"cannot read the bench YAML ({exc})") from exc
    fmt = raw.get("format") if isinstance(raw, dict) else None
    return "structured-light-session/1" if fmt == SL_BENCH_FORMAT else "capture-session/1"


def load_sl_bench_config(ref: str | os.PathLike[str]) -> dict[str, Any]:
    """Read, validate and complete a structured-light bench YAML (a path, or a preset name such as
    ``rig-gauge``).

    Raises
    ------
    BenchConfigError
        Naming the file and the problem (unknown keys included).
    """
    p = _resolve_ref(ref)
    try:
        raw = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise BenchConfigError(p, f"cannot read the bench YAML ({exc})") from exc
    return validate_sl_bench_config(raw, source=p)


def validate_sl_bench_config(raw: Any, source: str | os.PathLike[str] = "<dict>") -> dict[str, Any]:
    """Validate a structured-light bench configuration and return a completed copy (idempotent).

    Raises
    ------
    BenchConfigError
        On a schema violation, a sequence :mod:`huefringe.codecs` cannot read, or a block or
        sphere of no size.
    """
    if not isinstance(raw, dict):
        raise BenchConfigError(source, "the bench configuration must be a YAML mapping")
    schema = sl_bench_schema()
    errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(raw), key=lambda e: list(map(str, e.absolute_path)))
    if errors:
        raise BenchConfigError(source, "; ".join(
            f"at {'.'.join(map(str, e.absolute_path)) or 'top level'}: {e.message}" for e in errors[:3]))
    cfg = copy.deepcopy(raw)
    _fill_defaults(cfg, schema, schema)
    kind = cfg["scene"]["kind"]
    _fill_defaults(cfg["scene"], schema["$defs"][f"scene_{kind}"], schema)
    if "poses" in cfg:
        _fill_defaults(cfg["poses"], schema["properties"]["poses"], schema)
    if "vibration" in cfg:
        _fill_defaults(cfg["vibration"], schema["properties"]["vibration"], schema)
    try:
        _spec(cfg)
    except Exception as exc:  # noqa: BLE001 - any sequence problem is the configuration's
        raise BenchConfigError(source, f"sequence: {exc}") from exc
    for i, b in enumerate(cfg["scene"].get("blocks", [])):
        if not (b[2] > b[0] and b[3] > b[1] and b[4] > 0):
            raise BenchConfigError(source, f"scene.blocks.{i}: x1 > x0, y1 > y0 and a positive height expected")
    for i, s in enumerate(cfg["scene"].get("spheres", [])):
        if not s[2] > 0:
            raise BenchConfigError(source, f"scene.spheres.{i}: a positive radius expected")
    if "vibration" in cfg and (kind != "composite" or _spec(cfg).oneshot_frames == 0):
        raise BenchConfigError(source, "vibration: moves a composite scene while its one-shot (trapezoid) frames are "
                                       f"captured; this one is a {kind} scene with {_spec(cfg).oneshot_frames} one-shot frames")
    if cfg.get("oneshot_reference") and _spec(cfg).oneshot_frames == 0:
        raise BenchConfigError(source, "oneshot_reference: the order reference of one-shot (trapezoid) frames; the "
                                       "sequence has none")
    colours = cfg["scene"].get("colours")
    if colours is not None and len(colours) != len(cfg["scene"]["blocks"]):
        raise BenchConfigError(source, f"scene.colours: {len(colours)} coatings for {len(cfg['scene']['blocks'])} blocks")
    return cfg


def sl_session_plan(cfg: dict[str, Any]) -> dict[str, Any]:
    """What :func:`write_sl_session` writes for ``cfg``, without writing (for a workflow planner).

    Returns
    -------
    dict
        ``id``; ``poses`` (bool: ``poses/`` and ``board:``); ``pose_names``; ``board`` (the
        board mapping or None); ``calibration_session`` (the relative path or None); ``features``
        (bool: ``features.yaml``); ``ground_truth`` (bool); ``frames`` (captures per sequence);
        ``format`` (``structured-light-session/1``); ``oneshot_frames``; ``oneshot_axis`` (the
        trapezoid blocks' axis or None); ``absolute_axes`` (``{"x": bool, "y": bool}``: the
        sequence decodes absolutely along the axis); ``hue_bands`` (``(n, repeats)`` of the
        sequence's hue-band block, or None).
    """
    from huefringe.codecs.sequence import HueBandsBlock, TrapezoidBlock, axis_is_absolute

    cfg = validate_sl_bench_config(cfg)
    poses = "poses" in cfg
    spec = _spec(cfg)
    return {
        "id": cfg["id"],
        "format": "structured-light-session/1",
        "poses": poses,
        "pose_names": [f"pose_{i:02d}" for i in range(cfg["poses"]["count"])] if poses else [],
        "board": dict(cfg["poses"]["board"]) if poses else None,
        "calibration_session": cfg.get("calibration_session"),
        "oneshot_reference": cfg.get("oneshot_reference"),
        "features": _writes_features(cfg),
        "ground_truth": bool(cfg["ground_truth"]),
        "frames": _spec(cfg).n_frames,
        "oneshot_frames": _oneshot_frames(_spec(cfg)),
        "oneshot_axis": next((b.axis for b in spec.blocks if isinstance(b, TrapezoidBlock)), None),
        "absolute_axes": {a: bool(axis_is_absolute(spec, a)) for a in ("x", "y")},
        "hue_bands": next(((b.n, b.repeats) for b in spec.blocks if isinstance(b, HueBandsBlock)), None),
    }


def _oneshot_frames(spec: Any) -> int:
    """The sequence's one-shot (trapezoid) frames: captured in colour when there are any."""
    return int(spec.oneshot_frames)


def _colour_patterns(spec: Any) -> list[NDArray[np.uint8]]:
    """The projector images of ``spec`` in colour (R, G, B), in capture order; a repeated hue band or
    trapezoid frame is the same array (one render each)."""
    from dataclasses import replace

    from huefringe.codecs import generate_rgb
    from huefringe.codecs.sequence import FlatBlock, HueBandsBlock, SequenceSpec, TrapezoidBlock

    w, h = spec.projector_width, spec.projector_height
    out: list[NDArray[np.uint8]] = []
    for b, _ in spec.slices():
        if isinstance(b, HueBandsBlock):
            distinct = generate_rgb(SequenceSpec((FlatBlock("white"), HueBandsBlock(b.n)), w, h))[1:]
            out += [distinct[i] for i in range(b.n) for _ in range(b.repeats)]
        elif isinstance(b, TrapezoidBlock):
            one = generate_rgb(SequenceSpec((FlatBlock("white"), HueBandsBlock(2), replace(b, frames=1)), w, h))[-1]
            out += [one] * b.frames
        else:
            out += list(generate_rgb(SequenceSpec((b,), w, h)))
    return out


def _writes_features(cfg: dict[str, Any]) -> bool:
    return bool(cfg["features"]["enabled"]) and "poses" not in cfg


def _spec(cfg: dict[str, Any]) -> Any:
    from huefringe.codecs.sequence import sequence_from_mapping

    doc = {**cfg["sequence"], "frames": "[0-9][0-9][0-9][0-9].png"}
    return sequence_from_mapping(doc, "<sequence>", ".")


def _scene(cfg: dict[str, Any]) -> Any:
    from .rig import CompositeScene, PlaneScene

    s = cfg["scene"]
    if s["kind"] == "board":
        return PlaneScene(point=tuple(s["point"]), tilt_deg=tuple(s["tilt_deg"]))
    return CompositeScene(tilt_deg=tuple(s["tilt_deg"]), origin=tuple(s["origin"]),
                          blocks=tuple(tuple(b) for b in s["blocks"]), spheres=tuple(tuple(b) for b in s["spheres"]))


def scene_truth(cfg: dict[str, Any]) -> dict[str, Any]:
    """The truth of ``cfg``'s scene on its rig's camera pixels, float64.

    Returns
    -------
    dict
        ``rig`` (:class:`~huefringe.bench.rig.BenchRig`), ``scene``, ``names`` (face label ->
        name), ``label`` (H, W) face labels (see :class:`~huefringe.bench.rig.CompositeScene`; 0
        everywhere on a board), ``seen`` (surface in view), ``shadow`` (seen but not lit directly:
        cast or attached shadow), ``lit`` (lit directly and inside the projector's image), ``u``,
        ``v`` (true projector coordinates, NaN where not ``lit``), ``xyz`` (H, W, 3) true points,
        NaN where not ``lit``.
    """
    from .rig import RIGS

    rig = RIGS[cfg["rig"]]
    scene = _scene(cfg)
    cast = scene.cast(rig.rays)
    xyz, seen = cast[0], cast[1]
    label = cast[2] if len(cast) > 2 and cast[2].dtype.kind == "i" else np.zeros(seen.shape, dtype=np.int64)
    lit = scene.lit(rig, xyz, seen)
    m = rig.coordinates(xyz, lit, np.random.default_rng(0), 0.0)
    valid = m["valid"]
    names = scene.names() if hasattr(scene, "names") else {0: "board"}
    return {"rig": rig, "scene": scene, "names": names, "label": label, "seen": seen, "shadow": seen & ~lit,
            "lit": valid, "u": m["u_true"], "v": m["v_true"], "xyz": np.where(valid[..., None], xyz, np.nan)}


def largest_box(mask: NDArray[np.bool_]) -> tuple[int, int, int, int] | None:
    """The largest axis-aligned rectangle of ``True`` pixels, ``(x0, y0, x1, y1)`` with columns
    ``x0 .. x1-1`` and rows ``y0 .. y1-1``; None for an empty mask."""
    h, w = mask.shape
    heights = np.zeros(w + 1, dtype=np.int64)
    best, box = 0, None
    for y in range(h):
        heights[:w] = np.where(mask[y], heights[:w] + 1, 0)
        stack: list[int] = []
        for x in range(w + 1):
            while stack and heights[stack[-1]] >= heights[x]:
                top = stack.pop()
                left = stack[-1] + 1 if stack else 0
                area = int(heights[top]) * (x - left)
                if area > best:
                    best, box = area, (left, y - int(heights[top]) + 1, x, y + 1)
            stack.append(x)
    return box


def _face_box(mask: NDArray[np.bool_], margin: int) -> tuple[int, int, int, int] | None:
    """The largest box in ``mask`` eroded by ``margin`` pixels (the image border counts as outside)."""
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return None
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    k = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    sub = np.zeros((y1 - y0 + 2, x1 - x0 + 2), np.uint8)
    sub[1:-1, 1:-1] = mask[y0:y1, x0:x1]
    full = np.zeros(mask.shape, np.uint8)
    full[y0:y1, x0:x1] = cv2.erode(sub, k, borderType=cv2.BORDER_CONSTANT, borderValue=0)[1:-1, 1:-1]
    full[:margin], full[-margin:], full[:, :margin], full[:, -margin:] = 0, 0, 0, 0
    b = largest_box(full[y0:y1, x0:x1].astype(bool))
    return None if b is None else (int(b[0] + x0), int(b[1] + y0), int(b[2] + x0), int(b[3] + y0))


def features_from_truth(truth: dict[str, Any], *, margin_px: int = 6, tolerance_mm: float = 0.05,
                        base_boxes: int = 3, min_side_px: int = 20) -> dict[str, Any]:
    """``features.yaml``'s content from :func:`scene_truth`: boxes inside each face (face label
    and direct light, eroded by ``margin_px``), nominal values from the scene.

    The base (label 0) gets up to ``base_boxes`` boxes, largest first, each at least
    ``min_side_px`` on a side; each block top a ``steps`` entry (``block-<h>``, nominal height),
    a ``planes`` entry (``top-<h>``, nominal flatness 0) and a ``distances`` entry to the base;
    each sphere a ``spheres`` entry (nominal radius). On a board the whole board is the base and
    one plane (``board``).
    """
    label, lit, names, scene = truth["label"], truth["lit"], truth["names"], truth["scene"]
    out: dict[str, Any] = {"tolerance_mm": float(tolerance_mm)}
    base_mask = (label == 0) & lit
    boxes: list[list[int]] = []
    free = base_mask.copy()
    for _ in range(base_boxes):
        b = _face_box(free, margin_px)
        if b is None or min(b[2] - b[0], b[3] - b[1]) < min_side_px:
            break
        boxes.append(list(b))
        free[max(b[1] - margin_px, 0):b[3] + margin_px, max(b[0] - margin_px, 0):b[2] + margin_px] = False
    if not boxes:
        raise ValueError("no box fits on the base plane")
    out["base"] = {"boxes": boxes}
    blocks = getattr(scene, "blocks", ())
    spheres = getattr(scene, "spheres", ())
    if not blocks and not spheres:
        out["planes"] = [{"name": names[0], "box": list(boxes[0]), "nominal_flatness_mm": 0.0}]
        return out
    steps, planes, distances, balls = [], [], [], []
    for k, (*_, h) in enumerate(blocks, start=1):
        b = _face_box((label == k) & lit, margin_px)
        if b is None:
            continue
        tag = names[k].removeprefix("block-")
        steps.append({"name": names[k], "box": list(b), "nominal_mm": float(h)})
        planes.append({"name": f"top-{tag}", "box": list(b), "nominal_flatness_mm": 0.0})
        distances.append({"name": f"top-{tag}-to-base", "planes": [f"top-{tag}", "base"], "nominal_mm": float(h)})
    for j, (*_, r) in enumerate(spheres, start=1):
        k = len(blocks) + j
        b = _face_box((label == k) & lit, margin_px)
        if b is not None:
            balls.append({"name": names[k], "box": list(b), "nominal_radius_mm": float(r)})
    for key, val in (("steps", steps), ("planes", planes), ("distances", distances), ("spheres", balls)):
        if val:
            out[key] = val
    return out


def vibration_displacements(cfg: dict[str, Any]) -> F64:
    """Displacement (mm, along the base plane's normal, towards the camera) of the scene at each
    instant of each one-shot frame's exposure, shape (one-shot frames, ``vibration.subframes``);
    zeros without ``vibration``.

    One-shot frame ``k`` is taken at ``t_k = k / frame_rate_hz``, its ``S`` instants spread evenly
    over the exposure centred on ``t_k`` (one instant: ``t_k``); the displacement is
    ``amplitude_mm sin(2 pi frequency_hz t + phase_rad)``.
    """
    cfg = validate_sl_bench_config(cfg)
    n = _spec(cfg).oneshot_frames
    v = cfg.get("vibration")
    if not v:
        return np.zeros((n, 1))
    s = int(v["subframes"])
    within = (np.arange(s) + 0.5) / s - 0.5 if s > 1 else np.zeros(1)
    t = np.arange(n)[:, None] / float(v["frame_rate_hz"]) + within[None, :] * float(v["exposure_ms"]) * 1e-3
    return float(v["amplitude_mm"]) * np.sin(2 * np.pi * float(v["frequency_hz"]) * t + float(v["phase_rad"]))


def displaced_config(cfg: dict[str, Any], d_mm: float) -> dict[str, Any]:
    """``cfg`` with its composite scene moved ``d_mm`` along the base plane's normal (towards the
    camera), blocks and spheres with it: the truth of a vibrating scene at one instant
    (:func:`scene_truth`)."""
    out = copy.deepcopy(cfg)
    R, o = _scene(cfg).frame()
    out["scene"]["origin"] = [float(x) for x in o + float(d_mm) * R[:, 2]]
    return out


def _albedo_map(cfg: dict[str, Any], label: NDArray[np.int64]) -> F64:
    """The camera's albedo on the base and balls, the blocks in ``scene.colours``, per pixel (R, G, B)."""
    from .scenes import BLOCK_COLOURS

    alb = np.empty((*label.shape, 3))
    alb[:] = cfg["camera"]["albedo"]
    for k, c in enumerate(cfg["scene"].get("colours") or [], start=1):
        alb[np.abs(label) == k] = BLOCK_COLOURS[c]
    return alb


def _write_colour_captures(cfg: dict[str, Any], spec: Any, truth: dict[str, Any], folder: Path,
                           rng: np.random.Generator) -> None:
    """Every capture of ``spec`` in colour (8-bit RGB PNG): the base and balls grey at the camera's
    albedo, the blocks in ``scene.colours``, through the bench camera's channel mixing; with
    ``vibration``, each one-shot frame of the moving scene averaged over its exposure's instants."""
    from huefringe.codecs.sequence import TrapezoidBlock

    from .oneshot import CROSSTALK

    cam = cfg["camera"]
    alb = _albedo_map(cfg, truth["label"])
    folder.mkdir(parents=True, exist_ok=True)
    pats = _colour_patterns(spec)
    moving: list[int] = []
    if cfg.get("vibration"):
        moving = [i for b, sl in spec.slices() if isinstance(b, TrapezoidBlock) for i in range(sl.start, sl.stop)]
    still = sorted(set(range(len(pats))) - set(moving))
    for j0 in range(0, len(still), 16):  # a few frames at a time: a session holds a hundred colour frames
        idx = still[j0:j0 + 16]
        frames = truth["rig"].capture_rgb([pats[i] for i in idx], truth["u"], truth["v"], truth["lit"], rng, albedo=alb,
                                          ambient=cam["ambient"], noise_dn=cam["noise_dn"], crosstalk=CROSSTALK)
        for k, f in zip(idx, frames, strict=True):
            cv2.imwrite(str(folder / f"{k:04d}.png"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    for k, ds in zip(moving, vibration_displacements(cfg) if moving else [], strict=True):
        signal = np.zeros((*truth["label"].shape, 3))
        for d in ds:   # the exposure's instants, each the scene where it then is
            t = scene_truth(displaced_config(cfg, float(d)))
            signal += t["rig"].capture_rgb([pats[k]], t["u"], t["v"], t["lit"], rng, albedo=_albedo_map(cfg, t["label"]),
                                           ambient=cam["ambient"], crosstalk=CROSSTALK, signal_only=True)[0]
        img = signal / len(ds) + rng.normal(0.0, cam["noise_dn"], signal.shape)
        f = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"{k:04d}.png"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))


def _write_tiff(path: Path, a: NDArray[np.floating]) -> None:
    import tifffile

    tifffile.imwrite(path, np.ascontiguousarray(a, dtype=np.float32), photometric="rgb" if a.ndim == 3 else "minisblack")


def write_sl_session(cfg: dict[str, Any], out_dir: str | os.PathLike[str]) -> Path:
    """Write the structured-light session of ``cfg`` at ``out_dir``.

    Everything is written into a temporary folder beside ``out_dir``, checked with
    ``load_sl_session(..., deep=True)`` and then moved into place (replacing a previous session
    there; a folder that is neither empty nor a session is refused).

    Parameters
    ----------
    cfg : dict
        A structured-light bench configuration (validated here again).
    out_dir : path
        The session folder.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    BenchConfigError
        On an invalid configuration.
    FileExistsError
        If ``out_dir`` exists and is neither empty nor a session.
    """
    from huefringe.codecs.sequence import sequence_to_mapping
    from huefringe.rig.calibrate import Board
    from huefringe.session import load_sl_session

    from .rig import write_captures, write_pose_folders
    from .writer import _prepare_target, _swap_into_place

    cfg = validate_sl_bench_config(cfg)
    out = Path(out_dir)
    _prepare_target(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    try:
        spec = _spec(cfg)
        truth = scene_truth(cfg)
        rig = truth["rig"]
        cam = cfg["camera"]
        rng = np.random.default_rng([cfg["seed"], 1])
        colour = _oneshot_frames(spec) > 0
        if colour:
            _write_colour_captures(cfg, spec, truth, tmp / "captures", rng)
        else:
            write_captures(rig, spec, tmp / "captures", truth["u"], truth["v"], truth["lit"], rng,
                           noise_dn=cam["noise_dn"], albedo=cam["albedo"], ambient=cam["ambient"], name="{:04d}.png")
        w, h = rig.camera_size
        meta: dict[str, Any] = {
            "format": "structured-light-session/1",
            "id": cfg["id"],
            "camera": {"width": w, "height": h, "bit_depth": 8, "channels": 3 if colour else 1},
            "projector": {"width": spec.projector_width, "height": spec.projector_height},
            "sequence": {"file": "sequence.yaml", "frames": spec.n_frames},
        }
        if "poses" in cfg:
            p = cfg["poses"]
            board = Board(p["board"]["cols"], p["board"]["rows"], float(p["board"]["pitch_mm"]), p["board"]["kind"])
            write_pose_folders(rig, board, spec, p["count"], p["seed"], tmp / "poses", corner_image=False,
                               printed=True, noise_dn=cam["noise_dn"], ambient=cam["ambient"],
                               folder_name="pose_{:02d}", frame_name="{:04d}.png")
            meta["poses"] = [f"pose_{i:02d}" for i in range(p["count"])]
            meta["board"] = {"cols": board.cols, "rows": board.rows, "pitch_mm": board.pitch_mm, "kind": board.kind}
        if cfg.get("calibration_session"):
            meta["calibration"] = {"session": cfg["calibration_session"]}
        if cfg.get("oneshot_reference"):
            meta["oneshot"] = {"reference": {"session": cfg["oneshot_reference"]}}
        notes = cfg.get("notes") or (f"huefringe bench rig {cfg['rig']}, scene {cfg['scene']['kind']}, "
                                     f"noise {cam['noise_dn']:g} DN, ambient {cam['ambient']:g}")
        if cfg.get("vibration") and not cfg.get("notes"):
            v = cfg["vibration"]
            notes += (f"; the scene vibrates {v['amplitude_mm']:g} mm at {v['frequency_hz']:g} Hz along its base's normal "
                      f"while the one-shot frames are captured ({v['frame_rate_hz']:g} frames/s, {v['exposure_ms']:g} ms "
                      "exposure); the other frames see it still; the ground truth is where the first one-shot frame "
                      "sees it")
        meta["provenance"] = {"instrument": f"huefringe virtual bench rig {cfg['rig']} "
                                            f"(camera {w} x {h}, projector {spec.projector_width} x {spec.projector_height})",
                              "simulated": True, "notes": notes}
        if cfg["ground_truth"]:
            (tmp / "ground_truth").mkdir()
            gt = truth if not cfg.get("vibration") else scene_truth(
                displaced_config(cfg, float(vibration_displacements(cfg)[0].mean())))   # where frame_0000 saw it
            for axis, key in (("x", "u"), ("y", "v")):
                if axis in spec.axes():    # the true coordinate of each coded axis
                    _write_tiff(tmp / "ground_truth" / f"{axis}.tiff", gt[key])
            _write_tiff(tmp / "ground_truth" / "xyz.tiff", gt["xyz"])
        if _writes_features(cfg):
            f = cfg["features"]
            feats = features_from_truth(truth, margin_px=f["margin_px"], tolerance_mm=f["tolerance_mm"],
                                        base_boxes=f["base_boxes"])
            (tmp / "features.yaml").write_text(yaml.safe_dump(feats, sort_keys=False, default_flow_style=None),
                                               encoding="utf-8")
        stored = {**sequence_to_mapping(spec), "frames": "[0-9][0-9][0-9][0-9].png"}
        (tmp / "sequence.yaml").write_text(yaml.safe_dump(stored, sort_keys=False, default_flow_style=None),
                                           encoding="utf-8")
        (tmp / "session.yaml").write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
        load_sl_session(tmp, deep=True)
        _swap_into_place(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
