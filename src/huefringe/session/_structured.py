"""Structured-light sessions (``docs/spec/structured-light-session.md``, structured-light-session/1).

A structured-light session is a folder holding one coded capture sequence (N-step phase shifting,
Gray code, several periods, white/black frames: anything :mod:`huefringe.codecs` describes with a
:class:`~huefringe.codecs.SequenceSpec`), the captures in sequence order, and optionally the rig's
calibration (an OpenCV FileStorage file), the captures of calibration poses and ground truth.
It sits beside capture-session/1 (:mod:`huefringe.session`), whose format and validation it does
not touch: ``session.yaml``'s ``format`` tells the two apart (:func:`session_format`).

:func:`load_sl_session` validates a folder and raises one :class:`~huefringe.session.SessionError`
listing every problem with the file it concerns; :func:`assemble_sl_session` writes a new session
from a folder of captures and a sequence YAML, refusing before anything is written.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import cv2
import jsonschema
import numpy as np
import tifffile
import yaml
from numpy.typing import NDArray

from huefringe.codecs.sequence import (
    GrayBlock,
    TrapezoidBlock,
    PhaseBlock,
    SequenceError,
    SequenceSpec,
    capture_files,
    sequence_from_mapping,
    sequence_to_mapping,
)
from ._features import FEATURES_FILE, Features, load_features
from ._images import IMAGE_SUFFIXES, ImageInfo, image_info
from ._model import Problem, SessionError, SessionMeta
from ._validate import _normalise_dates

__all__ = [
    "SL_FORMAT",
    "SLSession",
    "assemble_sl_session",
    "calibration_problems",
    "load_sl_session",
    "session_format",
]

SL_FORMAT = "structured-light-session/1"
SEQUENCE_FILE = "sequence.yaml"
CAPTURES = "captures"
POSES = "poses"
CALIBRATION = "calibration"
GROUND_TRUTH = "ground_truth"
ASSEMBLY_KEYS = ("id", "calibration", "calibration_session", "oneshot_reference", "poses", "board", "features",
                 "provenance")
"""Keys of an assembly YAML that describe the session; every other key is the sequence's."""

SL_IMAGE_SUFFIXES = (*IMAGE_SUFFIXES, ".bmp")
"""Capture files of a structured-light session: PNG, TIFF and the BMP that SLStudio and SLMaster write."""

_CAPTURE_RE = re.compile(r"^(\d{4})$")
_NUM = re.compile(r"(\d+)")


@dataclass(frozen=True)
class SLSession(SessionMeta):
    """A validated structured-light session: metadata, its sequence and the paths of its files."""

    root: Path
    meta: dict[str, Any]
    spec: SequenceSpec
    captures: tuple[Path, ...]
    calibration: Path | None = None
    poses: dict[str, tuple[Path, ...]] = field(default_factory=dict)
    ground_truth: dict[str, Path] = field(default_factory=dict)
    """Axis (``x``, ``y``) -> ``ground_truth/<axis>.tiff``: float32 (H, W) projector coordinate, NaN where
    unseen; ``xyz`` -> ``ground_truth/xyz.tiff``: float32 (H, W, 3) camera-frame X, Y, Z in mm of the
    directly lit surface, NaN elsewhere."""
    calibration_session: Path | None = None
    """The session whose ``poses/`` calibrate this one (``calibration: {session: PATH}``), resolved."""
    features: Features | None = None
    """``features.yaml``: what to measure."""
    oneshot_reference: Path | None = None
    """The session whose coded captures give the one-shot frames their fringe order
    (``oneshot: {reference: {session: PATH}}``), resolved; None: the sequence's own coded blocks."""

    @property
    def board(self) -> dict[str, Any] | None:
        """The ``board`` block (``cols``, ``rows``, ``pitch_mm``, ``kind``), or None."""
        return self.meta.get("board")

    def read_captures(self, pose: str | None = None) -> list[NDArray[np.number]]:
        """The captures (of ``pose``, else the measurement) as grey arrays in sequence order,
        ready for :func:`huefringe.codecs.decode_sequence`."""
        out = []
        for p in self.captures if pose is None else self.poses[pose]:
            im = _decode(p)
            out.append(cv2.cvtColor(im[..., :3], cv2.COLOR_BGR2GRAY) if im.ndim == 3 else im)
        return out

    def input_files(self) -> list[Path]:
        """Every file of the session, sorted."""
        files = [self.root / "session.yaml", self.root / SEQUENCE_FILE, *self.captures, *self.ground_truth.values()]
        files += [p for ps in self.poses.values() for p in ps]
        if self.calibration is not None:
            files.append(self.calibration)
        if self.features is not None:
            files.append(self.features.path)
            files += [r.mask_file for r in self.features.regions().values() if r.mask_file is not None]
        return sorted(set(files))


def session_format(root: str | Path) -> str | None:
    """The ``format`` of ``root/session.yaml``, or None when it cannot be read or has none."""
    try:
        meta = yaml.safe_load((Path(root) / "session.yaml").read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError):
        return None
    return meta.get("format") if isinstance(meta, dict) and isinstance(meta.get("format"), str) else None


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _decode(path: Path) -> NDArray[np.number]:
    try:  # OpenCV for PNG, TIFF and BMP alike: colour comes as B, G, R, as codecs.read_captures reads it
        im = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except Exception as exc:
        raise SessionError.at(path, f"cannot decode image ({exc.__class__.__name__}: {exc})") from None
    if im is None:
        raise SessionError.at(path, "cannot decode image (corrupt or truncated)")
    return im


# --------------------------------------------------------------------------- checks


def sequence_problems(spec: SequenceSpec, where: Path) -> list[Problem]:
    """Sequence keys out of range for its projector: a Gray code that does not cover the projector or
    has non-positive cells, a fringe period below two projector pixels, a non-finite origin."""
    problems = []
    for i, b in enumerate(spec.blocks):
        if isinstance(b, GrayBlock):
            extent = spec.extent(b.axis)
            if not b.cell_px > 0:
                problems.append(Problem(where, f"blocks[{i}].gray.cell_px must be > 0, got {b.cell_px:g}"))
            elif 2**b.bits * b.cell_px < extent:
                problems.append(Problem(where, f"blocks[{i}].gray: {b.bits} bits of {b.cell_px:g} px cells cover "
                                               f"{2**b.bits * b.cell_px:g} px, the projector has {extent} along {b.axis}"))
        elif isinstance(b, PhaseBlock):
            if not b.period_px >= 2:
                problems.append(Problem(where, f"blocks[{i}].phase.period_px {b.period_px:g} is below 2 projector px "
                                               "(no projector can show it)"))
            if not np.isfinite(b.origin_px):
                problems.append(Problem(where, f"blocks[{i}].phase.origin_px must be finite, got {b.origin_px}"))
    return problems


def calibration_problems(path: str | Path, width: int, height: int) -> list[Problem]:
    """A calibration file that :func:`huefringe.rig.filestorage.read_calibration` does not read as a
    projector-camera calibration (the full model: both devices' matrices and distortion, R, T, in
    one of its layouts), or that belongs to another camera: its camera size, when the file states
    one, other than ``width`` x ``height``, or its principal point outside the image."""
    from huefringe.rig.filestorage import CalibrationFileError, read_calibration

    path = Path(path)
    if not path.is_file():
        return [Problem(path, "missing calibration file")]
    try:
        calib = read_calibration(path)
    except CalibrationFileError as exc:
        return [Problem(path, str(exc).removeprefix(f"{path}: "))]
    problems = []
    if calib.camera_size != (0, 0) and calib.camera_size != (width, height):
        cw, ch = calib.camera_size
        problems.append(Problem(path, f"calibrated for a {cw} x {ch} camera, the captures are {width} x {height}"))
    cx, cy = calib.camera_matrix[0, 2], calib.camera_matrix[1, 2]
    if not (0 < cx < width and 0 < cy < height):
        problems.append(Problem(path, f"principal point ({cx:g}, {cy:g}) px lies outside the {width} x {height} "
                                      "captures: a calibration of another camera size"))
    return problems


def _capture_problems(files: list[Path], expect: ImageInfo | None, deep: bool) -> tuple[list[Problem], ImageInfo | None]:
    """Headers (and with ``deep`` the pixels) of ``files`` against ``expect`` (else the first file)."""
    problems: list[Problem] = []
    ref, ref_path = expect, None
    for p in files:
        try:
            info = image_info(p)
        except SessionError as exc:
            problems.extend(exc.problems)
            continue
        if info.channels not in (1, 3) or info.bit_depth not in (8, 16):
            problems.append(Problem(p, f"{info.channels}-channel {abs(info.bit_depth)}-bit image; 8- or 16-bit grey or RGB expected"))
            continue
        if ref is None:
            ref, ref_path = info, p
            continue
        against = "session.yaml declares" if ref_path is None else f"{ref_path.name} is"
        if (info.width, info.height) != (ref.width, ref.height):
            problems.append(Problem(p, f"image is {info.width} x {info.height}, {against} {ref.width} x {ref.height}"))
        if info.bit_depth != ref.bit_depth:
            problems.append(Problem(p, f"image is {info.bit_depth}-bit, {against} {ref.bit_depth}-bit"))
        if info.channels != ref.channels:
            problems.append(Problem(p, f"image has {info.channels} channel(s), {against} {ref.channels}"))
    if deep and not problems:
        for p in files:
            try:
                im = _decode(p)
            except SessionError as exc:
                problems.extend(exc.problems)
                continue
            if ref is not None and im.shape[:2] != (ref.height, ref.width):
                problems.append(Problem(p, f"decodes to {im.shape[1]} x {im.shape[0]}, its header says {ref.width} x {ref.height}"))
    return problems, ref


def _numbered(folder: Path, n: int, problems: list[Problem]) -> list[Path]:
    """``folder/0000.* .. (n-1)``; a missing, extra, duplicated or misnamed image is a problem."""
    if not folder.is_dir():
        problems.append(Problem(folder, f"missing folder of captures ({n} expected, 0000 .. {n - 1:04d})"))
        return []
    found: dict[int, Path] = {}
    for p in sorted(folder.iterdir()):
        if p.name.startswith("."):
            continue
        m = _CAPTURE_RE.match(p.stem)
        if p.suffix.lower() not in SL_IMAGE_SUFFIXES or not m:
            problems.append(Problem(p, "unexpected file (NNNN.png, NNNN.tiff or NNNN.bmp captures expected)"))
        elif int(m.group(1)) in found:
            problems.append(Problem(p, f"the same capture is stored twice ({found[int(m.group(1))].name} and {p.name})"))
        elif int(m.group(1)) >= n:
            problems.append(Problem(p, f"capture beyond the sequence's {n} frames (0000 .. {n - 1:04d})"))
        else:
            found[int(m.group(1))] = p
    for i in range(n):
        if i not in found:
            problems.append(Problem(folder / f"{i:04d}.png", f"missing capture {i} of the sequence's {n} frames"))
    return [found[i] for i in sorted(found)]


def _schema_problems(meta: Any, yaml_path: Path) -> list[Problem]:
    schema = json.loads(resources.files("huefringe").joinpath("schemas/structured-light-session.schema.json").read_text())
    out = []
    for err in sorted(jsonschema.Draft202012Validator(schema).iter_errors(meta), key=lambda e: list(map(str, e.absolute_path))):
        where = "/".join(str(p) for p in err.absolute_path) or "(top level)"
        msg = err.message
        if err.validator == "additionalProperties" and "(" in msg:
            msg = f"unknown key(s): {msg.split('(')[-1].rstrip(')')}"
        out.append(Problem(yaml_path, f"at {where}: {msg}"))
    return out


def load_sl_session(root: str | Path, *, deep: bool = False) -> SLSession:
    """Read and validate a structured-light session.

    Parameters
    ----------
    root : path
        The session folder (holding ``session.yaml`` with ``format: structured-light-session/1``).
    deep : bool
        Also decode every image (catches corruption inside well-formed files).

    Raises
    ------
    SessionError
        Listing every problem, each with the file concerned: session.yaml against its schema, the
        sequence (unreadable, keys out of range, projector or frame count disagreeing with
        session.yaml), missing / extra / misnamed captures, sizes, bit depths or channels other
        than declared, truncated images, a calibration file that is missing, altered (sha256),
        unparsable or of another camera size, pose folders and ground truth.
    """
    root = Path(root)
    yaml_path = root / "session.yaml"
    if not yaml_path.is_file():
        raise SessionError.at(yaml_path, "missing file")
    try:
        meta = yaml.safe_load(yaml_path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise SessionError.at(yaml_path, f"not valid YAML ({exc})") from None
    meta = _normalise_dates(meta)
    problems = _schema_problems(meta, yaml_path)
    if problems:
        raise SessionError(problems)
    seq_path = root / SEQUENCE_FILE
    spec = None
    try:
        doc = yaml.safe_load(seq_path.read_text(encoding="utf-8"))
        spec = sequence_from_mapping(doc, seq_path, root)
    except FileNotFoundError:
        problems.append(Problem(seq_path, "missing file (the sequence the captures follow)"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        problems.append(Problem(seq_path, f"cannot read the sequence ({exc})"))
    except SequenceError as exc:
        problems.append(Problem(seq_path, str(exc).removeprefix(f"{seq_path}: ")))
    n = int(meta["sequence"]["frames"])
    if spec is not None:
        problems += sequence_problems(spec, seq_path)
        pw, ph = meta["projector"]["width"], meta["projector"]["height"]
        if (spec.projector_width, spec.projector_height) != (pw, ph):
            problems.append(Problem(seq_path, f"projector {spec.projector_width} x {spec.projector_height}, "
                                              f"session.yaml declares {pw} x {ph}"))
        if spec.n_frames != n:
            problems.append(Problem(seq_path, f"{spec.n_frames} frames, session.yaml declares sequence/frames {n}"))
    cam = meta["camera"]
    expect = ImageInfo(cam["width"], cam["height"], cam["bit_depth"], cam.get("channels", 1))
    captures = _numbered(root / CAPTURES, n, problems)
    img_problems, _ = _capture_problems(captures, expect, deep)
    problems += img_problems
    poses: dict[str, tuple[Path, ...]] = {}
    for name in meta.get("poses", []):
        files = _numbered(root / POSES / name, n, problems)
        problems += _capture_problems(files, expect, deep)[0]
        poses[name] = tuple(files)
    if (root / POSES).is_dir():
        for d in sorted((root / POSES).iterdir()):
            if d.name not in poses and not d.name.startswith("."):
                problems.append(Problem(d, "pose folder not listed in session.yaml poses"))
    calib = calib_session = None
    if "file" in meta.get("calibration", {}):
        calib = root / meta["calibration"]["file"]
        if calib.is_file() and _sha256(calib) != meta["calibration"]["sha256"]:
            problems.append(Problem(calib, "sha256 differs from session.yaml calibration/sha256: the file was altered"))
        problems += calibration_problems(calib, cam["width"], cam["height"])
    elif "session" in meta.get("calibration", {}):
        calib_session = (root / meta["calibration"]["session"]).resolve()
        if (calib_session / "session.yaml").exists():  # an absent one is refused where it is needed (plan, rig-measure)
            problems += calibration_session_problems(calib_session, yaml_path, meta)
    oneshot_ref = None
    if "oneshot" in meta:
        oneshot_ref = (root / meta["oneshot"]["reference"]["session"]).resolve()
        trap = None if spec is None else next((b for b in spec.blocks if isinstance(b, TrapezoidBlock)), None)
        if spec is not None and trap is None:
            problems.append(Problem(yaml_path, "oneshot/reference: the sequence has no trapezoid blocks (one-shot frames) "
                                               "to give an order reference"))
        elif oneshot_ref == root.resolve():
            problems.append(Problem(yaml_path, "oneshot/reference: names this session itself; without oneshot the "
                                               "sequence's own coded blocks are the reference"))
        elif trap is not None and (oneshot_ref / "session.yaml").exists():  # an absent one: refused where needed
            problems += oneshot_reference_problems(oneshot_ref, yaml_path, meta, trap.axis, root)
    features = None
    if (root / FEATURES_FILE).exists():
        features, fp = load_features(root / FEATURES_FILE, cam["width"], cam["height"])
        problems += fp
    gt: dict[str, Path] = {}
    gt_dir = root / GROUND_TRUTH
    if gt_dir.is_dir():
        axes = spec.axes() if spec is not None else ["x", "y"]
        for p in sorted(gt_dir.iterdir()):
            if p.name.startswith("."):
                continue
            if p.suffix.lower() not in (".tif", ".tiff") or p.stem not in (*axes, "xyz"):
                problems.append(Problem(p, f"unexpected ground truth ({', '.join(a + '.tiff' for a in axes)} or xyz.tiff expected)"))
                continue
            try:
                with tifffile.TiffFile(p) as tif:
                    shape, dtype = tif.series[0].shape, tif.series[0].dtype
            except Exception as exc:
                problems.append(Problem(p, f"cannot read ground truth TIFF ({exc})"))
                continue
            want = (cam["height"], cam["width"], 3) if p.stem == "xyz" else (cam["height"], cam["width"])
            if tuple(shape) != want or np.dtype(dtype) != np.float32:
                problems.append(Problem(p, f"ground truth must be float32 {' x '.join(map(str, want))}, got {dtype} {tuple(shape)}"))
            gt[p.stem] = p
    if problems or spec is None:
        raise SessionError(problems)
    return SLSession(root, meta, spec, tuple(captures), calib, poses, gt, calib_session, features, oneshot_ref)


def _other_session(other: Path, where: Path, key: str) -> tuple[Path, dict[str, Any], list[Problem]]:
    """Another session's ``session.yaml`` named by ``key`` of ``where``: its path, its document, and
    the problem (unreadable, or not a structured-light session) when there is one."""
    doc_path = other / "session.yaml"
    try:
        doc = yaml.safe_load(doc_path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError):
        return doc_path, {}, [Problem(where, f"{key}: {other} holds no readable session.yaml")]
    if not isinstance(doc, dict) or doc.get("format") != SL_FORMAT:
        return doc_path, {}, [Problem(where, f"{key}: {doc_path} is not a {SL_FORMAT} session")]
    return doc_path, doc, []


def calibration_session_problems(other: Path, where: Path, meta: dict[str, Any]) -> list[Problem]:
    """A ``calibration: {session: PATH}`` that does not name a structured-light session with poses and a
    board, of the same camera and projector (read from its ``session.yaml`` only)."""
    doc_path, doc, bad = _other_session(other, where, "calibration/session")
    if bad:
        return bad
    out = []
    if not doc.get("poses") or "board" not in doc:
        out.append(Problem(where, f"calibration/session: {doc_path} has no poses and board to calibrate from"))
    for key in ("width", "height"):
        if doc.get("camera", {}).get(key) != meta["camera"][key] or doc.get("projector", {}).get(key) != meta["projector"][key]:
            out.append(Problem(where, f"calibration/session: {doc_path} has another camera or projector {key}"))
    return out


def _calibration_identity(meta: dict[str, Any], root: Path) -> tuple[str, str] | None:
    """What calibrates a session: ``("file", sha256)``, ``("session", resolved folder)`` (its own when
    its poses and board calibrate it), or None when it names no calibration."""
    cal = meta.get("calibration") or {}
    if "sha256" in cal:
        return ("file", str(cal["sha256"]))
    if "session" in cal:
        return ("session", str((root / str(cal["session"])).resolve()))
    if meta.get("poses") and "board" in meta:
        return ("session", str(root.resolve()))
    return None


def oneshot_reference_problems(other: Path, where: Path, meta: dict[str, Any], axis: str, root: Path) -> list[Problem]:
    """An ``oneshot: {reference: {session: PATH}}`` that does not name a structured-light session of
    the same camera and projector, whose sequence decodes absolutely along the trapezoid's
    ``axis`` (Gray code + phase, or two periods) and whose calibration, when it names one, is this
    session's (read from its ``session.yaml`` and ``sequence.yaml`` only; its captures are checked
    when it is loaded to be decoded)."""
    from huefringe.codecs.sequence import axis_is_absolute

    doc_path, doc, bad = _other_session(other, where, "oneshot/reference")
    if bad:
        return bad
    out = []
    for dev in ("camera", "projector"):
        mine, theirs = meta[dev], doc.get(dev) if isinstance(doc.get(dev), dict) else {}
        if (theirs.get("width"), theirs.get("height")) != (mine["width"], mine["height"]):
            out.append(Problem(where, f"oneshot/reference: {doc_path} has a {theirs.get('width')} x {theirs.get('height')} "
                                      f"{dev}, this session's is {mine['width']} x {mine['height']}"))
    seq_path = other / SEQUENCE_FILE
    try:
        spec = sequence_from_mapping(yaml.safe_load(seq_path.read_text(encoding="utf-8")), seq_path, other)
    except (OSError, yaml.YAMLError, UnicodeDecodeError, SequenceError) as exc:
        out.append(Problem(where, f"oneshot/reference: {seq_path} cannot be read ({exc})"))
    else:
        if not axis_is_absolute(spec, axis):  # type: ignore[arg-type]
            what = (f"does not encode axis {axis}" if axis not in spec.axes()
                    else f"decodes axis {axis} only within one period")
            out.append(Problem(where, f"oneshot/reference: {seq_path} {what} (the trapezoid's axis): no absolute "
                                      f"coordinate to give the one-shot frames their order (Gray code + phase, or two "
                                      f"periods, along {axis})"))
    mine_cal, theirs_cal = _calibration_identity(meta, root), _calibration_identity(doc, other)
    if theirs_cal is not None and theirs_cal != mine_cal:
        out.append(Problem(where, f"oneshot/reference: {doc_path} is calibrated by {theirs_cal[0]} {theirs_cal[1]}, this "
                                  f"session by {'nothing' if mine_cal is None else ' '.join(mine_cal)}: the reference "
                                  "must be captured on the same rig with the same calibration"))
    return out


# --------------------------------------------------------------------------- assembly


def _frame_key(p: Path) -> tuple[int, str]:
    nums = _NUM.findall(p.stem)
    return (int(nums[-1]) if nums else -1, p.name)


def _sequence_files(folder: Path, spec: SequenceSpec, where: Path, problems: list[Problem]) -> list[Path]:
    """The captures of ``spec.frames`` in ``folder``: a glob's matches sorted by the last number in
    their names, or the listed files in their order."""
    if not isinstance(spec.frames, str):
        files, found = capture_files(folder, spec)
        problems += [Problem(p, msg) for p, msg in found]
        files = [p for p in files if p.is_file()]
        problems += [Problem(p, "not a PNG, TIFF or BMP capture") for p in files if p.suffix.lower() not in SL_IMAGE_SUFFIXES]
        return files
    if not folder.is_dir():
        problems.append(Problem(folder, "not a folder of captures"))
        return []
    files = sorted((p for p in folder.glob(spec.frames) if p.is_file()), key=_frame_key)
    if len(files) != spec.n_frames:
        problems.append(Problem(folder, f"{len(files)} files match {spec.frames!r}, the sequence {where} has "
                                        f"{spec.n_frames} frames"))
    bad = [p for p in files if p.suffix.lower() not in SL_IMAGE_SUFFIXES]
    problems += [Problem(p, "not a PNG, TIFF or BMP capture") for p in bad]
    for a, b in zip(files, files[1:], strict=False):
        if _frame_key(a)[0] == _frame_key(b)[0]:
            problems.append(Problem(b, f"has the same frame number as {a.name}: the order is ambiguous"))
    return files


def _check_calibration(calib: Path | None, info: ImageInfo | None, problems: list[Problem]) -> None:
    """The calibration an assembly stores: a FileStorage file of this camera (size from ``info``)."""
    if calib is None:
        return
    if calib.suffix.lower() not in (".yml", ".yaml", ".xml", ".json"):
        problems.append(Problem(calib, "an OpenCV FileStorage file (.yml, .yaml, .xml or .json) expected"))
    elif info is not None:
        problems += calibration_problems(calib, info.width, info.height)
    elif not calib.is_file():
        problems.append(Problem(calib, "missing calibration file"))
    else:
        from huefringe.rig.filestorage import CalibrationFileError, read_calibration

        try:
            read_calibration(calib)
        except CalibrationFileError as exc:
            problems.append(Problem(calib, str(exc).removeprefix(f"{calib}: ")))


def _slug(name: str) -> str:
    return re.sub(r"[^a-z0-9-]+", "-", name.lower()).strip("-") or "session"


def assemble_sl_session(
    captures_dir: str | os.PathLike[str],
    sequence_yaml: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    calibration: str | os.PathLike[str] | None = None,
    poses: str | os.PathLike[str] | None = None,
    session_id: str | None = None,
    board: dict[str, Any] | None = None,
    features: str | os.PathLike[str] | None = None,
    calibration_session: str | os.PathLike[str] | None = None,
) -> Path:
    """Write a checked structured-light session at ``out_dir`` from a folder of captures.

    Parameters
    ----------
    captures_dir : path
        The captures of one sequence, matched by the sequence's ``frames`` glob and ordered by the
        last number in their names (PNG or TIFF, 8 or 16 bit, grey or RGB). Never modified.
    sequence_yaml : path
        The sequence in :func:`huefringe.codecs.load_sequence`'s YAML form (explicit ``blocks``
        or ``kamino410``, whose ``config`` is relative to ``captures_dir``), plus optional session
        keys :data:`ASSEMBLY_KEYS`: ``id``; ``calibration`` (a FileStorage file),
        ``calibration_session`` (the session whose poses calibrate this one), ``oneshot_reference``
        (the session whose coded captures are the one-shot frames' order reference), ``poses`` (a folder
        of pose folders) and ``features`` (a features YAML), paths relative to the YAML's folder;
        ``board`` (the target the poses show) and ``provenance``.
    out_dir : path
        The session folder to write; must not exist or be empty.
    calibration, poses : path, optional
        Override the YAML's: an OpenCV FileStorage calibration (copied to ``calibration/``), a
        folder of pose folders each holding one full sequence (copied to ``poses/<name>/``).
    session_id : str, optional
        Overrides the YAML's ``id``; default the output folder's name in ``[a-z0-9-]``.
    board, features, calibration_session : optional
        Override the YAML's: the board the poses show (``cols``, ``rows``, ``pitch_mm``,
        ``kind``), a features YAML (copied to ``features.yaml``), the session whose poses
        calibrate this one (written as a path relative to ``out_dir``).

    Returns
    -------
    Path
        ``out_dir``, validated by :func:`load_sl_session`.

    Raises
    ------
    SessionError
        Before anything is written, every problem naming its file.
    """
    captures, seq_yaml, out = Path(captures_dir), Path(sequence_yaml), Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise SessionError.at(out, "already exists and is not empty; give a new folder")
    if captures.is_dir() and out.resolve().is_relative_to(captures.resolve()):
        raise SessionError.at(out, f"lies inside the captures folder {captures}, which is never modified")
    try:
        doc = yaml.safe_load(seq_yaml.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise SessionError.at(seq_yaml, f"cannot read the sequence ({exc})") from None
    if not isinstance(doc, dict):
        raise SessionError.at(seq_yaml, "expected a mapping with projector and blocks (or kamino410)")
    extra = {k: doc.pop(k) for k in ASSEMBLY_KEYS if k in doc}
    problems: list[Problem] = []
    try:
        spec: SequenceSpec | None = sequence_from_mapping(doc, seq_yaml, captures)
    except SequenceError as exc:
        problems.append(Problem(seq_yaml, str(exc).removeprefix(f"{seq_yaml}: ")))
        spec = None
    if spec is not None:
        problems += sequence_problems(spec, seq_yaml)
    sid = session_id or extra.get("id") or _slug(out.name)
    if not isinstance(sid, str) or not re.fullmatch(r"[a-z0-9-]{1,120}", sid):
        problems.append(Problem(seq_yaml, f"id {sid!r} must match [a-z0-9-]+"))
    provenance = extra.get("provenance")
    if provenance is not None and not isinstance(provenance, dict):
        problems.append(Problem(seq_yaml, "provenance must be a mapping (captured_at, operator, instrument, source, license, notes)"))
    calib = Path(calibration) if calibration else (seq_yaml.parent / str(extra["calibration"]) if extra.get("calibration") else None)
    poses_dir = Path(poses) if poses else (seq_yaml.parent / str(extra["poses"]) if extra.get("poses") else None)
    calib_session = (Path(calibration_session) if calibration_session else
                     seq_yaml.parent / str(extra["calibration_session"]) if extra.get("calibration_session") else None)
    if board:
        extra["board"] = board
    if calib_session is not None and calib is not None:
        problems.append(Problem(seq_yaml, "calibration and calibration_session both given: name one"))
    features = Path(features) if features else (seq_yaml.parent / str(extra["features"]) if extra.get("features") else None)

    if spec is None:  # the sequence is refused: the calibration is still checked, against the first capture
        listed = doc.get("frames") if isinstance(doc.get("frames"), list) else None
        glob = doc.get("frames") if isinstance(doc.get("frames"), str) and doc.get("frames") else "*.png"
        if listed is not None:
            first = [captures / str(f) for f in listed if isinstance(f, str) and (captures / f).is_file()][:1]
        else:
            first = sorted((p for p in captures.glob(glob) if p.suffix.lower() in SL_IMAGE_SUFFIXES), key=_frame_key)[:1] \
                if captures.is_dir() else []
        files, info = [], None
        if first:
            try:
                info = image_info(first[0])
            except SessionError:
                info = None
        _check_calibration(calib, info, problems)
        raise SessionError(problems)
    files = _sequence_files(captures, spec, seq_yaml, problems)
    img_problems, info = _capture_problems(files, None, deep=True)
    problems += img_problems
    suffixes = {".tiff" if p.suffix.lower() in (".tif", ".tiff") else p.suffix.lower() for p in files}
    if len(suffixes) > 1:
        problems.append(Problem(captures, f"captures of several file types {sorted(suffixes)}: one type per session"))
    pose_files: dict[str, list[Path]] = {}
    if poses_dir is not None:
        if not poses_dir.is_dir():
            problems.append(Problem(poses_dir, "not a folder of pose folders"))
        else:
            for d in sorted(p for p in poses_dir.iterdir() if p.is_dir() and not p.name.startswith(".")):
                if not re.fullmatch(r"[A-Za-z0-9_-]+", d.name):
                    problems.append(Problem(d, "pose folder names are letters, digits, _ and - only"))
                    continue
                fs = _sequence_files(d, spec, seq_yaml, problems)
                problems += _capture_problems(fs, info, deep=True)[0]
                pose_files[d.name] = fs
            if not pose_files:
                problems.append(Problem(poses_dir, "holds no pose folder"))
    _check_calibration(calib, info, problems)
    if features is not None and info is not None:
        problems += load_features(features, info.width, info.height)[1]
    if problems or info is None:
        raise SessionError(problems or [Problem(captures, "no captures")])

    suffix = suffixes.pop()
    meta: dict[str, Any] = {
        "format": SL_FORMAT,
        "id": sid,
        "camera": {"width": info.width, "height": info.height, "bit_depth": info.bit_depth, "channels": info.channels},
        "projector": {"width": spec.projector_width, "height": spec.projector_height},
        "sequence": {"file": SEQUENCE_FILE, "frames": spec.n_frames},
    }
    stored = {**sequence_to_mapping(spec), "frames": "[0-9][0-9][0-9][0-9]" + suffix}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    try:
        for folder, fs in [(tmp / CAPTURES, files), *((tmp / POSES / k, v) for k, v in pose_files.items())]:
            folder.mkdir(parents=True)
            for i, src in enumerate(fs):
                shutil.copyfile(src, folder / f"{i:04d}{suffix}")
        if pose_files:
            meta["poses"] = sorted(pose_files)
        if calib is not None:
            (tmp / CALIBRATION).mkdir()
            dst = tmp / CALIBRATION / f"rig{calib.suffix.lower()}"
            shutil.copyfile(calib, dst)
            meta["calibration"] = {"file": f"{CALIBRATION}/{dst.name}", "sha256": _sha256(dst)}
        if calib_session is not None:
            meta["calibration"] = {"session": os.path.relpath(calib_session.resolve(), out.resolve())}
        if extra.get("oneshot_reference"):
            ref = (seq_yaml.parent / str(extra["oneshot_reference"])).resolve()
            meta["oneshot"] = {"reference": {"session": os.path.relpath(ref, out.resolve())}}
        if extra.get("board"):
            meta["board"] = extra["board"]
        if features is not None:
            shutil.copyfile(features, tmp / FEATURES_FILE)
        if provenance:
            meta["provenance"] = provenance
        (tmp / SEQUENCE_FILE).write_text(yaml.safe_dump(stored, sort_keys=False, default_flow_style=None), encoding="utf-8")
        (tmp / "session.yaml").write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
        load_sl_session(tmp)
        if out.exists():
            out.rmdir()
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
