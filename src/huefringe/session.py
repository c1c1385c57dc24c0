"""Capture-session reader and validator (``../shared/spec/capture-session.md``, version 1).

A session is refused *before any work starts* when it breaks the format: :func:`load_session`
checks session.yaml against a JSON schema (unknown keys refused), every expected file, and the
header of every image (size, bit depth, RGB, PNG/TIFF not truncated), and raises one
:class:`SessionError` listing each problem with the file it concerns. Decoding every pixel is
left to :func:`read_rgb` (which raises the same error type) or to ``deep=True``.
"""

from __future__ import annotations

import datetime as dt
import json
import re
import struct
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import cv2
import jsonschema
import numpy as np
import tifffile
import yaml

FORMAT = "capture-session/1"
IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a session: the file it concerns and what is wrong."""

    path: Path
    message: str

    def __str__(self) -> str:
        return f"{self.path}: {self.message}"


class SessionError(ValueError):
    """A capture session (or one of its files) breaks the capture-session format.

    ``problems`` lists every problem found; ``str()`` names each file and what is wrong.
    """

    def __init__(self, problems: list[Problem] | Problem):
        self.problems = [problems] if isinstance(problems, Problem) else list(problems)
        lines = [str(p) for p in self.problems[:20]]
        if len(self.problems) > 20:
            lines.append(f"... and {len(self.problems) - 20} more problems")
        super().__init__("\n".join(lines))

    @classmethod
    def at(cls, path: str | Path, message: str) -> SessionError:
        return cls(Problem(Path(path), message))


@dataclass(frozen=True)
class Session:
    """A validated capture session: its metadata and the paths of all its files."""

    root: Path
    meta: dict[str, Any]
    reference_white: Path
    reference_bands: tuple[tuple[Path, ...], ...]
    planes: dict[float, Path]
    object_white: Path
    object_bands: tuple[tuple[Path, ...], ...]
    frames: dict[int, Path]
    phase_shift: dict[int, tuple[Path, Path, Path]] = field(default_factory=dict)
    ground_truth: dict[int, Path] = field(default_factory=dict)
    predistortion: Predistortion | None = None
    """Extension: the pre-distortion the planes and frames were projected with (``predistortion.csv``)."""
    ground_truth_xy: dict[int, Path] = field(default_factory=dict)
    """Extension (bench sessions): the true X, Y of each pixel, ``ground_truth/xy/frame_NNNN.tiff``,
    float32 (H, W, 2) in mm, NaN where unseen."""

    @property
    def id(self) -> str:
        return str(self.meta["id"])

    @property
    def width(self) -> int:
        return int(self.meta["camera"]["width"])

    @property
    def height(self) -> int:
        return int(self.meta["camera"]["height"])

    @property
    def bit_depth(self) -> int:
        return int(self.meta["camera"]["bit_depth"])

    @property
    def pixel_pitch_mm(self) -> float:
        return float(self.meta["camera"]["pixel_pitch_mm"])

    @property
    def period_px(self) -> float:
        return float(self.meta["pattern"]["period_px"])

    @property
    def hue_bands(self) -> int:
        return int(self.meta["pattern"]["hue_bands"])

    @property
    def repeats(self) -> int:
        return int(self.meta["pattern"]["repeats"])

    @property
    def planes_mm(self) -> list[float]:
        return [float(z) for z in self.meta["planes_mm"]]

    @property
    def specimen(self) -> dict[str, Any] | None:
        return self.meta.get("specimen")

    @property
    def provenance(self) -> dict[str, Any]:
        """The optional ``provenance`` block (``captured_at`` as an ISO 8601 string); ``{}`` if absent."""
        return dict(self.meta.get("provenance") or {})

    @property
    def frame_ids(self) -> list[int]:
        return sorted(self.frames)

    def all_images(self) -> list[Path]:
        """Every image path of the session (ground truth excluded)."""
        out = [self.reference_white, self.object_white, *self.planes.values(), *self.frames.values()]
        for bands in (self.reference_bands, self.object_bands):
            out.extend(p for reps in bands for p in reps)
        for triple in self.phase_shift.values():
            out.extend(triple)
        return out

    def input_files(self) -> list[Path]:
        """Every file of the session, session.yaml and ground truth included, sorted."""
        extra = [self.predistortion.path] if self.predistortion is not None else []
        return sorted([self.root / "session.yaml", *self.all_images(), *self.ground_truth.values(),
                       *self.ground_truth_xy.values(), *extra])


@dataclass(frozen=True)
class Predistortion:
    """A pre-distorted trapezoid (paper Fig. 6): code phase ``c`` was projected as phase ``p(c)``.

    huefringe extension of capture-session/1: an optional ``predistortion.csv`` at the session
    root (comment lines ``#``, a header ``code_phase_rad,emitted_phase_rad``, then rows with
    ``c`` ascending over [0, 2 pi) and ``p`` strictly increasing, ``p(c) - c`` periodic). It
    applies to the reference planes and the object frames; hue bands, white images and
    phase-shift captures are never pre-distorted. Readers of plain capture-session/1 ignore it.
    """

    path: Path
    code: np.ndarray
    emitted: np.ndarray

    def decode(self, emitted_phase: np.ndarray) -> np.ndarray:
        """Invert ``p``: the code phase (position) whose pre-distorted trapezoid was captured."""
        two_pi = 2.0 * np.pi
        e = np.concatenate([self.emitted - two_pi, self.emitted, self.emitted + two_pi])
        c = np.concatenate([self.code - two_pi, self.code, self.code + two_pi])
        x = np.mod(np.asarray(emitted_phase, np.float64) - self.emitted[0], two_pi) + self.emitted[0]
        return np.mod(np.interp(x, e, c), two_pi).astype(np.float32)

    def decode_slope(self, emitted_phase: np.ndarray) -> np.ndarray:
        """``d decode / d emitted`` at each emitted phase: the slope of the piecewise-linear
        segment :meth:`decode` interpolates on (scales phase uncertainties)."""
        two_pi = 2.0 * np.pi
        e = np.concatenate([self.emitted - two_pi, self.emitted, self.emitted + two_pi])
        c = np.concatenate([self.code - two_pi, self.code, self.code + two_pi])
        x = np.mod(np.asarray(emitted_phase, np.float64) - self.emitted[0], two_pi) + self.emitted[0]
        j = np.clip(np.searchsorted(e, x, side="right") - 1, 0, e.size - 2)
        slopes = (c[1:] - c[:-1]) / (e[1:] - e[:-1])
        return np.where(np.isfinite(x), slopes[j], np.nan)


def format_predistortion(code: np.ndarray, emitted: np.ndarray, *, source: str | None = None) -> str:
    """The text of a ``predistortion.csv`` (:class:`Predistortion`, read by :func:`read_predistortion`):
    the header comments, ``# written by ...`` when ``source`` is given, the column header and one
    row per code phase, 9 decimals."""
    lines = ["# huefringe predistortion/1: the trapezoidal planes and frames of this session were projected",
             "# with code phase c emitting the trapezoid of phase p(c) (paper Fig. 6); uniform bands were not."]
    if source is not None:
        lines.append(f"# written by {source}")
    lines.append("code_phase_rad,emitted_phase_rad")
    lines += [f"{c:.9f},{e:.9f}" for c, e in zip(code, emitted, strict=True)]
    return "\n".join(lines) + "\n"


def read_predistortion(path: str | Path) -> Predistortion:
    """Read and check ``predistortion.csv``; raise :class:`SessionError` naming the file."""
    path = Path(path)
    try:
        lines = [ln.strip() for ln in path.read_text(encoding="utf-8").splitlines()]
    except (OSError, UnicodeDecodeError) as exc:
        raise SessionError.at(path, f"cannot read ({exc})") from exc
    rows = [ln for ln in lines if ln and not ln.startswith("#")]
    if not rows or rows[0].replace(" ", "") != "code_phase_rad,emitted_phase_rad":
        raise SessionError.at(path, "header 'code_phase_rad,emitted_phase_rad' expected")
    try:
        data = np.array([[float(v) for v in r.split(",")] for r in rows[1:]], dtype=np.float64)
    except ValueError as exc:
        raise SessionError.at(path, f"not numeric ({exc})") from exc
    if data.ndim != 2 or data.shape[1] != 2 or data.shape[0] < 16:
        raise SessionError.at(path, "at least 16 rows of two numbers are needed")
    code, emitted = data[:, 0], data[:, 1]
    two_pi = 2.0 * np.pi
    if not np.all(np.isfinite(data)) or code[0] < 0 or code[-1] >= two_pi or np.any(np.diff(code) <= 0):
        raise SessionError.at(path, "code_phase_rad must rise strictly within [0, 2 pi)")
    if np.any(np.diff(emitted) <= 0) or emitted[-1] >= emitted[0] + two_pi:
        raise SessionError.at(path, "emitted_phase_rad must rise strictly by less than one turn (invertible)")
    if np.any(np.abs(emitted - code) >= np.pi):
        raise SessionError.at(path, "emitted_phase_rad departs from code_phase_rad by pi or more")
    return Predistortion(path, code, emitted)


# --------------------------------------------------------------------------- schema


def _schema() -> dict[str, Any]:
    text = resources.files("huefringe").joinpath("schemas/capture-session.schema.json").read_text()
    return json.loads(text)


def _schema_problems(meta: Any, yaml_path: Path) -> list[Problem]:
    validator = jsonschema.Draft202012Validator(_schema())
    problems = []
    for err in sorted(validator.iter_errors(meta), key=lambda e: list(map(str, e.absolute_path))):
        where = "/".join(str(p) for p in err.absolute_path) or "(top level)"
        msg = err.message
        if err.validator == "additionalProperties":
            msg = f"unknown key(s): {msg.split('(')[-1].rstrip(')')}" if "(" in msg else msg
        problems.append(Problem(yaml_path, f"at {where}: {msg}"))
    return problems


def _normalise_dates(meta: Any) -> Any:
    """YAML reads an unquoted ``captured_at: 2026-11-30T14:05:00Z`` as a datetime: make it ISO text.

    Returns a copy of ``meta`` with ``provenance.captured_at`` as a string (UTC written ``Z``);
    anything else is left for the schema to judge.
    """
    if not isinstance(meta, dict) or not isinstance(meta.get("provenance"), dict):
        return meta
    when = meta["provenance"].get("captured_at")
    if isinstance(when, (dt.datetime, dt.date)):
        text = when.isoformat()
        if isinstance(when, dt.datetime) and when.utcoffset() == dt.timedelta(0):
            text = when.replace(tzinfo=None).isoformat() + "Z"
        meta = {**meta, "provenance": {**meta["provenance"], "captured_at": text}}
    return meta


def parse_captured_at(text: str) -> dt.datetime | dt.date:
    """Parse ``provenance.captured_at``: an ISO 8601 date (``2026-11-30``) or date-time
    (``2026-11-30T14:05:00Z``, ``2026-11-30T15:05:00+01:00``, seconds optional).

    Raises
    ------
    ValueError
        When the text is neither.
    """
    if re.fullmatch(r"\d{4}-\d{2}-\d{2}", text):
        return dt.date.fromisoformat(text)
    if not re.fullmatch(r"\d{4}-\d{2}-\d{2}T\d{2}:\d{2}(:\d{2}(\.\d+)?)?(Z|[+-]\d{2}:\d{2})?", text):
        raise ValueError(text)
    return dt.datetime.fromisoformat(text)


def _semantic_problems(meta: dict[str, Any], yaml_path: Path) -> list[Problem]:
    problems = []
    when = (meta.get("provenance") or {}).get("captured_at")
    if when is not None:
        try:
            parse_captured_at(when)
        except ValueError:
            problems.append(Problem(yaml_path, f"at provenance/captured_at: {when!r} is not an ISO 8601 date or "
                                               "date-time (e.g. 2026-11-30 or 2026-11-30T14:05:00Z)"))
    w, h = meta["camera"]["width"], meta["camera"]["height"]
    problems += _camera_problems(meta["camera"], yaml_path)
    planes = [float(z) for z in meta["planes_mm"]]
    keys = [f"{z:.3f}" for z in planes]
    if len(set(keys)) != len(keys):
        problems.append(Problem(yaml_path, f"planes_mm has repeated planes (to 3 decimals): {planes}"))
    if "0.000" not in keys:
        problems.append(Problem(yaml_path, "planes_mm must contain the reference plane 0.0"))
    nonzero = [abs(z) for z in planes if f"{z:.3f}" != "0.000"]
    if not nonzero:
        problems.append(Problem(yaml_path, "planes_mm needs at least one plane besides 0.0"))
    spec = meta.get("specimen")
    if spec:
        boxes = [("base_roi", b) for b in spec["base_roi"]] + [
            (f"steps/{s['name']}/roi", s["roi"]) for s in spec["steps"]
        ]
        for where, (u0, v0, u1, v1) in boxes:
            if not (0 <= u0 < u1 <= w and 0 <= v0 < v1 <= h):
                problems.append(
                    Problem(
                        yaml_path,
                        f"specimen {where} [{u0}, {v0}, {u1}, {v1}) is empty or outside the "
                        f"{w} x {h} image",
                    )
                )
        names = [s["name"] for s in spec["steps"]]
        if len(set(names)) != len(names):
            problems.append(Problem(yaml_path, f"specimen step names repeat: {names}"))
    return problems


def _camera_problems(cam: dict[str, Any], yaml_path: Path) -> list[Problem]:
    """The lens block of the ``camera`` extension (docs/design.md, "the camera block"): what the
    schema cannot say (finite values, the matrix's last row, the distortion's length, what a
    pinhole camera needs)."""
    problems = []
    kind = cam.get("model", "telecentric")

    def bad(key: str, text: str) -> None:
        problems.append(Problem(yaml_path, f"at camera/{key}: {text}"))

    for key in ("pixel_pitch_mm", "matrix", "distortion", "plate_pose"):
        val = cam.get(key)
        if val is None:
            continue
        vals = [val] if key == "pixel_pitch_mm" else (
            [*val["rvec"], *val["tvec"]] if key == "plate_pose" else np.ravel(np.asarray(val, np.float64)).tolist())
        if not all(np.isfinite(float(x)) for x in vals):
            bad(key, "holds a value that is not finite (nan or inf)")
    k = cam.get("matrix")
    if k is not None:
        m = np.asarray(k, np.float64)
        if m.shape != (3, 3):
            bad("matrix", f"must be 3 x 3 (OpenCV camera matrix), got shape {m.shape}")
        elif np.all(np.isfinite(m)):
            if not np.array_equal(m[2], [0.0, 0.0, 1.0]):
                bad("matrix", f"last row must be [0, 0, 1], got {m[2].tolist()}")
            if not (m[0, 0] > 0 and m[1, 1] > 0):
                bad("matrix", f"focal lengths fx = {m[0, 0]:g}, fy = {m[1, 1]:g} px must be positive")
            if m[1, 0] != 0:
                bad("matrix", "must be upper triangular [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    d = cam.get("distortion")
    if d is not None and len(d) not in (4, 5, 8, 12, 14):
        bad("distortion", f"OpenCV distortion coefficients come as 4, 5, 8, 12 or 14 values "
                          f"(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]]), got {len(d)}")
    if kind == "pinhole":
        for key, what in (("matrix", "the camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (cv2.calibrateCamera)"),
                          ("plate_pose", "the plate's pose {rvec: [..], tvec: [..]} in camera coordinates, mm "
                                         "(cv2.solvePnP of a board lying on the plate)")):
            if cam.get(key) is None:
                bad(key, f"missing: a pinhole camera (camera/model: pinhole) needs {what}")
        pose = cam.get("plate_pose")
        if pose is not None and not problems and float(np.linalg.norm(pose["tvec"])) == 0.0:
            bad("plate_pose", "tvec is zero: the plate cannot pass through the camera centre")
    elif cam.get("plate_pose") is not None:
        bad("plate_pose", "only a pinhole camera (camera/model: pinhole) has a plate pose")
    if cam.get("bayer") is not None and (int(cam["width"]) % 2 or int(cam["height"]) % 2):
        bad("bayer", f"a Bayer sensor has whole 2 x 2 blocks: width and height must be even, got "
                     f"{cam['width']} x {cam['height']}")
    return problems


# --------------------------------------------------------------------------- image headers


@dataclass(frozen=True)
class ImageInfo:
    width: int
    height: int
    bit_depth: int
    channels: int


def image_info(path: Path) -> ImageInfo:
    """Read size, bit depth and channel count from an image header without decoding pixels.

    Raises :class:`SessionError` for an unreadable, truncated or unsupported file.
    """
    suffix = path.suffix.lower()
    try:
        if suffix == ".png":
            return _png_info(path)
        if suffix in (".tif", ".tiff"):
            return _tiff_info(path)
    except SessionError:
        raise
    except Exception as exc:  # any parser failure is a bad file, reported as such
        raise SessionError.at(path, f"cannot read image header ({exc.__class__.__name__}: {exc})") from exc
    raise SessionError.at(path, f"unsupported image type {suffix!r} (PNG or TIFF expected)")


def _png_info(path: Path) -> ImageInfo:
    with open(path, "rb") as f:
        head = f.read(33)
        if len(head) < 33 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
            raise SessionError.at(path, "not a PNG file (bad signature or header)")
        f.seek(0, 2)
        size = f.tell()
        f.seek(max(0, size - 12))
        if f.read(12) != _PNG_IEND:
            raise SessionError.at(path, "truncated PNG (no IEND chunk at the end of the file)")
    width, height, depth, colour_type = struct.unpack(">IIBB", head[16:26])
    channels = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}.get(colour_type, 0)
    if colour_type == 3:
        raise SessionError.at(path, "palette PNG; an RGB image is expected")
    return ImageInfo(width, height, depth, channels)


def _tiff_info(path: Path) -> ImageInfo:
    size = path.stat().st_size
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        end = max((o + c for o, c in zip(page.dataoffsets, page.databytecounts, strict=False)), default=0)
        if end > size:
            raise SessionError.at(path, f"truncated TIFF (image data ends at byte {end}, file has {size})")
        shape = page.shape
        channels = int(page.samplesperpixel)
        height, width = (shape[0], shape[1])
        depth = int(page.bitspersample)
        if page.dtype is not None and np.dtype(page.dtype).kind == "f":
            depth = -depth  # float data: marks "not an integer image"
    return ImageInfo(width, height, depth, channels)


def decode_image(path: Path) -> np.ndarray:
    """A PNG or TIFF as stored, 3-channel images in R, G, B order (no check of shape or type).

    Raises
    ------
    SessionError
        If the file cannot be decoded, naming it.
    """
    try:
        if path.suffix.lower() in (".tif", ".tiff"):
            data = tifffile.imread(path)
        else:
            data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if data is not None and data.ndim == 3 and data.shape[2] == 3:
                data = cv2.cvtColor(data, cv2.COLOR_BGR2RGB)
    except Exception as exc:
        raise SessionError.at(path, f"cannot decode image ({exc.__class__.__name__}: {exc})") from exc
    if data is None:
        raise SessionError.at(path, "cannot decode image (corrupt or truncated)")
    return data


def read_rgb_codes(path: str | Path) -> np.ndarray:
    """Read an 8/16-bit RGB PNG or TIFF as its sensor codes: C-contiguous ``uint8``/``uint16``
    ``(H, W, 3)`` in R, G, B order (what :func:`read_rgb` scales to [0, 1]).

    Raises
    ------
    SessionError
        If the file cannot be decoded or is not a 3-channel 8/16-bit image.
    """
    path = Path(path)
    data = decode_image(path)
    if data.ndim != 3 or data.shape[2] != 3:
        raise SessionError.at(path, f"not an RGB image (array shape {data.shape})")
    if data.dtype not in (np.uint8, np.uint16):
        raise SessionError.at(path, f"unsupported pixel type {data.dtype} (8- or 16-bit expected)")
    return np.ascontiguousarray(data)


def read_rgb(path: str | Path) -> np.ndarray:
    """Read an 8/16-bit RGB PNG or TIFF as ``float32 (H, W, 3)`` scaled to [0, 1].

    Raises
    ------
    SessionError
        If the file cannot be decoded or is not a 3-channel 8/16-bit image.
    """
    data = read_rgb_codes(path)
    scale = 255.0 if data.dtype == np.uint8 else 65535.0
    return data.astype(np.float32) * np.float32(1.0 / scale)


# --------------------------------------------------------------------------- layout


_BAND_RE = re.compile(r"^band_(\d{3})_r(\d+)$")
_FRAME_RE = re.compile(r"^frame_(\d{4})$")
_PS_RE = re.compile(r"^frame_(\d{4})_s([0-2])$")
_PLANE_RE = re.compile(r"^z_(-?\d+\.\d{3})$")


def _images_in(folder: Path, problems: list[Problem]) -> dict[str, Path]:
    """Map stem -> path for the images in ``folder``; report a stem stored twice."""
    out: dict[str, Path] = {}
    if not folder.is_dir():
        return out
    for p in sorted(folder.iterdir()):
        if p.name.startswith(".") or p.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        if p.stem in out:
            problems.append(Problem(p, f"the same image is stored twice ({out[p.stem].name} and {p.name})"))
            continue
        out[p.stem] = p
    return out


def _single_image(folder: Path, stem: str, problems: list[Problem]) -> Path | None:
    found = [folder / f"{stem}{s}" for s in IMAGE_SUFFIXES if (folder / f"{stem}{s}").is_file()]
    if not found:
        problems.append(Problem(folder / f"{stem}.png", "missing file"))
        return None
    if len(found) > 1:
        problems.append(Problem(found[0], f"the same image is stored twice: {[p.name for p in found]}"))
    return found[0]


def _bands(folder: Path, n: int, repeats: int, problems: list[Problem]) -> tuple[tuple[Path, ...], ...]:
    if not folder.is_dir():
        problems.append(Problem(folder, "missing folder of hue bands"))
        return ()
    images = _images_in(folder, problems)
    out = []
    for i in range(n):
        row = []
        for r in range(repeats):
            p = images.get(f"band_{i:03d}_r{r}")
            if p is None:
                problems.append(Problem(folder / f"band_{i:03d}_r{r}.png", "missing file"))
            else:
                row.append(p)
        out.append(tuple(row))
    for stem, p in images.items():
        m = _BAND_RE.match(stem)
        if not m:
            problems.append(Problem(p, "unexpected file name (band_III_rR expected)"))
        elif int(m.group(1)) >= n or int(m.group(2)) >= repeats:
            problems.append(
                Problem(p, f"band or repeat outside pattern.hue_bands={n}, pattern.repeats={repeats}")
            )
    return tuple(out)


def _collect(root: Path, meta: dict[str, Any], problems: list[Problem]) -> Session | None:
    n, repeats = int(meta["pattern"]["hue_bands"]), int(meta["pattern"]["repeats"])
    ref, obj = root / "reference", root / "object"
    for folder in (ref, obj):
        if not folder.is_dir():
            problems.append(Problem(folder, "missing folder"))
    if problems:
        return None
    ref_white = _single_image(ref, "white", problems)
    obj_white = _single_image(obj, "white", problems)
    ref_bands = _bands(ref / "hue", n, repeats, problems)
    obj_bands = _bands(obj / "hue", n, repeats, problems)

    planes: dict[float, Path] = {}
    plane_images = _images_in(ref / "planes", problems)
    if not (ref / "planes").is_dir():
        problems.append(Problem(ref / "planes", "missing folder of calibration planes"))
    by_key = {f"{float(z):.3f}": float(z) for z in meta["planes_mm"]}
    for stem, p in plane_images.items():
        m = _PLANE_RE.match(stem)
        if not m:
            problems.append(Problem(p, "unexpected file name (z_<mm with 3 decimals> expected)"))
        elif f"{float(m.group(1)):.3f}" not in by_key:
            problems.append(Problem(p, f"plane z={m.group(1)} mm is not listed in planes_mm {list(by_key.values())}"))
        else:
            planes[by_key[f"{float(m.group(1)):.3f}"]] = p
    for key, z in by_key.items():
        if z not in planes and (ref / "planes").is_dir():
            problems.append(Problem(ref / "planes" / f"z_{key}.png", f"missing file for plane {z} mm listed in planes_mm"))

    frames: dict[int, Path] = {}
    frames_dir = obj / "frames"
    if not frames_dir.is_dir():
        problems.append(Problem(frames_dir, "missing folder of frames"))
    else:
        for stem, p in _images_in(frames_dir, problems).items():
            m = _FRAME_RE.match(stem)
            if m:
                frames[int(m.group(1))] = p
            else:
                problems.append(Problem(p, "unexpected file name (frame_NNNN expected)"))
        if not frames:
            problems.append(Problem(frames_dir, "no frames: the folder holds no frame_NNNN image"))

    phase_shift: dict[int, tuple[Path, Path, Path]] = {}
    ps_dir = obj / "phase_shift"
    if ps_dir.is_dir():
        parts: dict[int, dict[int, Path]] = {}
        for stem, p in _images_in(ps_dir, problems).items():
            m = _PS_RE.match(stem)
            if not m:
                problems.append(Problem(p, "unexpected file name (frame_NNNN_sS expected, S in 0..2)"))
                continue
            parts.setdefault(int(m.group(1)), {})[int(m.group(2))] = p
        for idx, got in sorted(parts.items()):
            if idx not in frames:
                problems.append(Problem(ps_dir / f"frame_{idx:04d}_s0.png", f"phase-shift captures for instant {idx:04d}, which has no frame"))
            missing = [s for s in range(3) if s not in got]
            if missing:
                problems.append(Problem(ps_dir / f"frame_{idx:04d}_s{missing[0]}.png", "missing file (all three phase-shift captures are needed)"))
            else:
                phase_shift[idx] = (got[0], got[1], got[2])

    ground_truth: dict[int, Path] = {}
    gt_dir = root / "ground_truth" / "frames"
    if gt_dir.is_dir():
        for p in sorted(gt_dir.iterdir()):
            if p.name.startswith(".") or p.suffix.lower() not in (".tif", ".tiff"):
                continue
            m = _FRAME_RE.match(p.stem)
            if not m or int(m.group(1)) not in frames:
                problems.append(Problem(p, "ground truth for no frame of the session"))
            else:
                ground_truth[int(m.group(1))] = p
    ground_truth_xy: dict[int, Path] = {}
    xy_dir = root / "ground_truth" / "xy"
    if xy_dir.is_dir():
        for p in sorted(xy_dir.iterdir()):
            if p.name.startswith(".") or p.suffix.lower() not in (".tif", ".tiff"):
                continue
            m = _FRAME_RE.match(p.stem)
            if not m or int(m.group(1)) not in frames:
                problems.append(Problem(p, "X/Y ground truth for no frame of the session"))
            else:
                ground_truth_xy[int(m.group(1))] = p
    predistortion = None
    if (root / "predistortion.csv").exists():
        try:
            predistortion = read_predistortion(root / "predistortion.csv")
        except SessionError as exc:
            problems.extend(exc.problems)
    if problems or ref_white is None or obj_white is None:
        return None
    return Session(
        root=root,
        meta=meta,
        reference_white=ref_white,
        reference_bands=ref_bands,
        planes=dict(sorted(planes.items())),
        object_white=obj_white,
        object_bands=obj_bands,
        frames=dict(sorted(frames.items())),
        phase_shift=phase_shift,
        ground_truth=ground_truth,
        predistortion=predistortion,
        ground_truth_xy=ground_truth_xy,
    )


def _image_problems(session: Session, deep: bool) -> list[Problem]:
    problems: list[Problem] = []
    w, h, depth = session.width, session.height, session.bit_depth
    for p in session.all_images():
        try:
            info = image_info(p)
        except SessionError as exc:
            problems.extend(exc.problems)
            continue
        before = len(problems)
        if info.channels != 3:
            kind = {1: "greyscale", 2: "grey+alpha", 4: "RGBA"}.get(info.channels, f"{info.channels}-channel")
            problems.append(Problem(p, f"{kind} image; an RGB image is expected"))
        if (info.width, info.height) != (w, h):
            problems.append(Problem(p, f"image is {info.width} x {info.height}, session.yaml declares {w} x {h}"))
        if info.bit_depth != depth:
            problems.append(Problem(p, f"image is {abs(info.bit_depth)}-bit{' float' if info.bit_depth < 0 else ''}, session.yaml declares {depth}-bit"))
        if deep and len(problems) == before:
            try:
                read_rgb(p)
            except SessionError as exc:
                problems.extend(exc.problems)
    for idx, p in session.ground_truth.items():
        try:
            with tifffile.TiffFile(p) as tif:
                page = tif.pages[0]
                shape, dtype = page.shape, page.dtype
        except Exception as exc:
            problems.append(Problem(p, f"cannot read ground truth TIFF ({exc})"))
            continue
        if tuple(shape) != (h, w) or np.dtype(dtype) != np.float32:
            problems.append(Problem(p, f"ground truth must be float32 {h} x {w}, got {dtype} {tuple(shape)}"))
    for idx, p in session.ground_truth_xy.items():
        try:
            with tifffile.TiffFile(p) as tif:
                shape, dtype = tif.series[0].shape, tif.series[0].dtype
        except Exception as exc:
            problems.append(Problem(p, f"cannot read X/Y ground truth TIFF ({exc})"))
            continue
        if tuple(shape) != (h, w, 2) or np.dtype(dtype) != np.float32:
            problems.append(Problem(p, f"X/Y ground truth must be float32 {h} x {w} x 2, got {dtype} {tuple(shape)}"))
    return problems


def read_meta(root: str | Path) -> dict[str, Any]:
    """Read and schema-check ``session.yaml`` only (no file checks)."""
    root = Path(root)
    yaml_path = root / "session.yaml"
    if not root.is_dir():
        raise SessionError.at(root, "session folder does not exist")
    if not yaml_path.is_file():
        raise SessionError.at(yaml_path, "missing file")
    try:
        meta = yaml.safe_load(yaml_path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise SessionError.at(yaml_path, f"not valid YAML ({exc})") from exc
    if meta is None:
        raise SessionError.at(yaml_path, "is empty; expected a mapping with the keys format, id, camera, pattern "
                                         "and planes_mm (capture-session/1)")
    if not isinstance(meta, dict):
        raise SessionError.at(yaml_path, f"must be a mapping of keys (format, id, camera, pattern, planes_mm, ...), "
                                         f"got a {type(meta).__name__}: {str(meta)[:60]!r}")
    meta = _normalise_dates(meta)
    problems = _schema_problems(meta, yaml_path)
    if problems:
        raise SessionError(problems)
    problems = _semantic_problems(meta, yaml_path)
    if problems:
        raise SessionError(problems)
    return meta


def load_session(root: str | Path, *, deep: bool = False) -> Session:
    """Read and validate a capture session.

    Parameters
    ----------
    root : path
        The session folder (holding ``session.yaml``).
    deep : bool
        Also decode every image (slower; catches corruption inside otherwise well-formed files).

    Raises
    ------
    SessionError
        Listing every problem, each with the file concerned.
    """
    root = Path(root)
    meta = read_meta(root)
    problems: list[Problem] = []
    session = _collect(root, meta, problems)
    if session is None:
        raise SessionError(problems)
    problems = _image_problems(session, deep)
    if problems:
        raise SessionError(problems)
    return session
