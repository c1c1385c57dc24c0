"""Assemble a checked capture-session/1 folder from a flat folder of camera captures.

A real rig shows the projector images of a patterns folder (``manifest.csv`` + ``patterns.yaml``,
written by ``huefringe patterns``, contract in docs/guide.md) one after another and saves one
camera file per image. :func:`assemble_session` matches capture ``k`` (natural order of file
name) to manifest row ``k``, converts it (Bayer demosaic, 12-bit scaling) and writes the session
folder with its ``session.yaml``, after checking everything it can before writing anything:
counts, sizes, bit depths, the Bayer pattern, the spec YAML, and the content (the white
capture is the brightest, fringe captures show a fringe, uniform captures do not, and the
fringe period on the reference plane agrees with the declared ``period_px`` within 5 %).

Layer: above :mod:`huefringe.session` and :mod:`huefringe.camera`.
"""

from __future__ import annotations

import csv
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import cv2
import jsonschema
import numpy as np
import yaml
from numpy.typing import NDArray

from huefringe.camera import BAYER_PATTERNS, bayer_problem, demosaic
from huefringe.io import atomic_path, publish_dir
from huefringe.patterns import MANIFEST_HEADER
from huefringe.session import Problem, SessionError, decode_image, load_session, read_predistortion

CAPTURE_SUFFIXES = (".png", ".tif", ".tiff")
PREDISTORTION = "predistortion.csv"
"""A patterns folder's pre-distortion (``huefringe patterns --compensated``), copied into the session."""
PERIOD_TOLERANCE = 0.05
"""Largest relative disagreement between the declared and the measured reference-plane period."""
FRINGE_LEVEL = 0.1
"""Fringe amplitude (fraction of the white capture's level) above which a capture shows a fringe."""
_SESSION_PATH = re.compile(r"^((reference|object)/white|(reference|object)/hue/band_\d{3}_r\d+|reference/planes/z_-?\d+\.\d{3}"
                           r"|object/frames/frame_\d{4}|object/phase_shift/frame_\d{4}_s[0-2])\.png$")
_FRINGE_PATHS = re.compile(r"^(reference/planes/|object/frames/|object/phase_shift/)")


@dataclass(frozen=True)
class _Row:
    order: int
    image: str
    session_path: str


def natural_key(name: str) -> list[Any]:
    """Sort key putting ``img2`` before ``img10`` (digit runs compare as numbers)."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def capture_files(captures_dir: str | os.PathLike[str]) -> list[Path]:
    """The PNG/TIFF files of ``captures_dir`` in natural order of file name (hidden files skipped)."""
    folder = Path(captures_dir)
    files = [p for p in folder.iterdir()
             if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in CAPTURE_SUFFIXES]
    return sorted(files, key=lambda p: natural_key(p.name))


def read_capture(path: Path) -> NDArray:
    """A camera file as stored: ``(H, W)`` (raw/mono) or ``(H, W, 3)`` in R, G, B order."""
    data = decode_image(path)
    if data.dtype not in (np.uint8, np.uint16):
        raise SessionError.at(path, f"unsupported pixel type {data.dtype} (8- or 16-bit expected)")
    return np.ascontiguousarray(data)


def _spec_schema() -> dict[str, Any]:
    text = resources.files("huefringe").joinpath("schemas/session-spec.schema.yaml").read_text()
    return yaml.safe_load(text)


def read_spec(spec_yaml: str | os.PathLike[str]) -> dict[str, Any]:
    """Read and schema-check the spec YAML (``schemas/session-spec.schema.yaml``)."""
    path = Path(spec_yaml)
    try:
        spec = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise SessionError.at(path, f"cannot read the spec YAML ({exc})") from exc
    if isinstance(spec, dict) and isinstance(spec.get("provenance"), dict):
        prov = spec["provenance"]
        if "captured_at" in prov and not isinstance(prov["captured_at"], str):
            prov["captured_at"] = prov["captured_at"].isoformat().replace("+00:00", "Z")
    validator = jsonschema.Draft202012Validator(_spec_schema())
    problems = []
    for err in sorted(validator.iter_errors(spec), key=lambda e: list(map(str, e.absolute_path))):
        where = "/".join(str(p) for p in err.absolute_path) or "(top level)"
        problems.append(Problem(path, f"at {where}: {err.message}"))
    if problems:
        raise SessionError(problems)
    return spec


def read_patterns(patterns_dir: str | os.PathLike[str]) -> tuple[dict[str, Any], list[_Row]]:
    """``patterns.yaml`` and the rows of ``manifest.csv`` of a patterns folder, checked."""
    folder = Path(patterns_dir)
    pyaml, mcsv = folder / "patterns.yaml", folder / "manifest.csv"
    try:
        meta = yaml.safe_load(pyaml.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise SessionError.at(pyaml, f"cannot read patterns.yaml ({exc})") from exc
    if not isinstance(meta, dict):
        raise SessionError.at(pyaml, "not a mapping")
    for key in ("hue_bands", "repeats", "planes_mm"):
        if key not in meta:
            raise SessionError.at(pyaml, f"missing key {key!r}")
    try:
        with open(mcsv, newline="", encoding="utf-8") as fh:
            lines = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError) as exc:
        raise SessionError.at(mcsv, f"cannot read the manifest ({exc})") from exc
    if not lines or tuple(lines[0]) != MANIFEST_HEADER:
        raise SessionError.at(mcsv, f"header must be exactly {','.join(MANIFEST_HEADER)}")
    rows = []
    for k, line in enumerate(lines[1:]):
        if len(line) != 3 or line[0] != str(k) or not line[2].endswith(".png") or line[2].startswith("/") \
                or ".." in Path(line[2]).parts:
            raise SessionError.at(mcsv, f"line {k + 2} ({','.join(line)}): expected order {k}, an image and a "
                                        "relative session_path ending in .png")
        if not _SESSION_PATH.match(line[2]):
            raise SessionError.at(mcsv, f"line {k + 2} (order {k}): session_path {line[2]!r} is not a capture-session/1 image path")
        rows.append(_Row(k, line[1], line[2]))
    if len({r.session_path for r in rows}) != len(rows):
        raise SessionError.at(mcsv, "a session_path appears twice")
    return meta, rows


def _count_problem(files: list[Path], rows: list[_Row], captures_dir: Path) -> SessionError | None:
    if len(files) == len(rows):
        return None
    if len(files) < len(rows):
        missing = rows[len(files):]
        names = ", ".join(f"row {r.order} ({r.session_path})" for r in missing[:10])
        more = f" and {len(missing) - 10} more" if len(missing) > 10 else ""
        gaps = _numbering_gaps(files)
        where = (f"; the file numbering has gaps: {', '.join(gaps[:10])}" if gaps else
                 f"; if the last captures are missing, {names}{more}")
        return SessionError.at(captures_dir, f"{len(files)} captures for {len(rows)} manifest rows: "
                                             f"{len(missing)} missing{where}")
    extra = files[len(rows):]
    names = ", ".join(p.name for p in extra[:10]) + (f" and {len(extra) - 10} more" if len(extra) > 10 else "")
    return SessionError.at(captures_dir, f"{len(files)} captures for {len(rows)} manifest rows: "
                                         f"{len(extra)} extra: {names}")


def _numbering_gaps(files: list[Path]) -> list[str]:
    """Numbers absent from the last digit run of the file stems (``cap_6``, ``cap_8``: 7), as text."""
    nums = []
    for p in files:
        runs = re.findall(r"\d+", p.stem)
        if not runs:
            return []
        nums.append(int(runs[-1]))
    out = []
    for (a, pa), (b, pb) in zip(zip(nums, files), zip(nums[1:], files[1:])):
        if b - a > 1:
            span = f"{a + 1}" if b - a == 2 else f"{a + 1}-{b - 1}"
            out.append(f"no file numbered {span} between {pa.name} and {pb.name}")
    return out


def convert_capture(raw: NDArray, *, bayer: str | None, bit_depth_in: int) -> NDArray:
    """A capture as the session stores it: RGB uint8 (8-bit input) or uint16 (12/16-bit input).

    12-bit values (0..4095 in a 16-bit container) are multiplied by 16 (4095 -> 65520, i.e.
    0.99977 of full scale) before a Bayer mosaic is demosaiced with
    :func:`huefringe.camera.demosaic` (OpenCV edge-aware).
    """
    data = raw
    if bit_depth_in == 12:
        data = (raw.astype(np.uint16) << np.uint16(4)).astype(np.uint16)
    if bayer:
        data = demosaic(data, bayer)
    return np.ascontiguousarray(data)


def column_profile(rgb: NDArray) -> NDArray[np.float64]:
    """Mean over rows of each column and channel, ``(W, 3)`` float64."""
    return rgb.mean(axis=0, dtype=np.float64)


def fringe_profile(rgb: NDArray, white: NDArray) -> NDArray[np.float64]:
    """Row means of ``rgb`` over row means of ``white`` per channel, ``(W, 3)``: the fringe along
    columns in fractions of the white capture's level (shading and albedo divide out)."""
    return _ratio(column_profile(rgb), column_profile(white))


def _ratio(profile: NDArray[np.float64], white: NDArray[np.float64]) -> NDArray[np.float64]:
    return profile / np.maximum(white, 1e-9)


def fringe_spectrum(profile: NDArray[np.float64], *, pad: int = 16) -> tuple[float, float]:
    """Dominant fringe of a ``(W, 3)`` profile: ``(amplitude, period_px)``.

    Hann-windowed FFT of each channel's profile along columns, zero-padded ``pad`` times; the
    largest peak above 1.5 cycles per image (below that is shading, not fringe) gives the
    period ``W / k``; amplitude is the sinusoid amplitude of that peak (window gain removed).
    """
    width = profile.shape[0]
    win = np.hanning(width)
    centred = (profile - profile.mean(axis=0)) * win[:, None]
    spec = np.abs(np.fft.rfft(centred, n=pad * width, axis=0))
    k = np.arange(spec.shape[0]) / pad  # cycles per image
    spec[k < 1.5] = 0.0
    i, c = np.unravel_index(int(np.argmax(spec)), spec.shape)
    amplitude = 2.0 * spec[i, c] / win.sum()
    return float(amplitude), float(width / k[i]) if k[i] > 0 else float("inf")


def _content_problems(profiles: dict[str, NDArray[np.float64]], files: dict[str, Path], period_px: float,
                      planes_mm: list[float]) -> list[Problem]:
    problems = []
    for part in ("reference", "object"):
        wkey = f"{part}/white.png"
        if wkey not in profiles:
            continue
        white = profiles[wkey]
        wmean = float(white.mean())
        for key, img in profiles.items():
            if not key.startswith(part + "/") or key == wkey:
                continue
            if float(img.mean()) >= wmean:
                problems.append(Problem(files[key], f"is as bright as or brighter than the white capture "
                                                    f"{files[wkey].name} (mean {img.mean():.4g} >= {wmean:.4g}), "
                                                    f"but goes to {key}: likely out of order"))
                continue
            amp, period = fringe_spectrum(_ratio(img, white))
            fringe = bool(_FRINGE_PATHS.match(key))
            if fringe and amp < FRINGE_LEVEL:
                problems.append(Problem(files[key], f"shows no fringe (amplitude {amp:.3f} of white < {FRINGE_LEVEL}) "
                                                    f"but goes to {key}: likely out of order"))
            elif not fringe and amp >= FRINGE_LEVEL:
                problems.append(Problem(files[key], f"shows a fringe (amplitude {amp:.3f} of white, period "
                                                    f"{period:.1f} px) but goes to {key}, a uniform capture: "
                                                    "likely out of order"))
            elif key == f"reference/planes/z_{0.0:.3f}.png" or (
                    key.startswith("reference/planes/") and 0.0 not in planes_mm
                    and key == f"reference/planes/z_{planes_mm[0]:.3f}.png"):
                if abs(period - period_px) > PERIOD_TOLERANCE * period_px:
                    problems.append(Problem(files[key], f"the fringe period measured on this reference-plane "
                                                        f"capture is {period:.2f} px, the spec declares period_px "
                                                        f"{period_px:g} (differs by "
                                                        f"{100 * abs(period - period_px) / period_px:.1f} % > "
                                                        f"{100 * PERIOD_TOLERANCE:g} %)"))
    return problems


def assemble_session(captures_dir: str | os.PathLike[str], patterns_dir: str | os.PathLike[str],
                     spec_yaml: str | os.PathLike[str], out_dir: str | os.PathLike[str], *,
                     bayer: str | None = None) -> Path:
    """Write a checked capture-session/1 folder at ``out_dir`` from a folder of camera captures.

    Parameters
    ----------
    captures_dir : path
        One camera file per manifest row (PNG or TIFF, 8/12/16 bit; RGB, or single-channel raw
        Bayer mosaics with ``bayer``), matched to the rows in natural order of file name.
    patterns_dir : path
        The patterns folder: ``manifest.csv`` (``order,image,session_path``) and
        ``patterns.yaml`` (``hue_bands``, ``repeats``, ``planes_mm`` are read), and, if the
        trapezoid was pre-distorted (``huefringe patterns --compensated``), ``predistortion.csv``,
        checked and copied to the session's root.
    spec_yaml : path
        ``id``, ``pixel_pitch_mm``, ``period_px`` (camera px on the reference plane), optional
        ``specimen``, ``provenance``, ``camera`` (extra keys copied), ``bayer``, ``bit_depth_in``
        (schema: ``schemas/session-spec.schema.yaml``).
    out_dir : path
        The session folder to write; must not exist or be empty.
    bayer : {'RGGB', 'BGGR', 'GRBG', 'GBRG'}, optional
        Overrides the spec's ``bayer``.

    Returns
    -------
    Path
        ``out_dir``, validated with ``load_session(out_dir, deep=True)``.

    Raises
    ------
    SessionError
        Before anything is written, naming the file: count mismatch, size/bit depth/Bayer
        problems, a bad spec or patterns folder, content out of order, a period disagreeing by
        more than 5 %, or an existing non-empty ``out_dir``.
    """
    captures, out = Path(captures_dir), Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise SessionError.at(out, "already exists and is not empty; give a new folder")
    if not captures.is_dir():
        raise SessionError.at(captures, "not a folder of captures")
    if out.resolve().is_relative_to(captures.resolve()):
        raise SessionError.at(out, f"lies inside the captures folder {captures}, which is never modified")
    spec = read_spec(spec_yaml)
    bayer = bayer or spec.get("bayer")
    if bayer is not None and bayer not in BAYER_PATTERNS:
        raise SessionError.at(spec_yaml, f"unknown Bayer pattern {bayer!r}; use one of {', '.join(BAYER_PATTERNS)}")
    bit_in = spec.get("bit_depth_in")
    patterns, rows = read_patterns(patterns_dir)
    predistortion = Path(patterns_dir) / PREDISTORTION
    if predistortion.exists():  # huefringe patterns --compensated: the session must carry it to decode
        read_predistortion(predistortion)
    elif patterns.get("compensated"):
        raise SessionError.at(predistortion, "missing: patterns.yaml says the trapezoid was pre-distorted "
                                             "(compensated), and the session cannot decode without this file")
    files = capture_files(captures)
    if (err := _count_problem(files, rows, captures)) is not None:
        raise err

    # pass 1: every file read once, checked, and reduced to its column profile (memory O(width));
    # pass 2, after every check passed: read again, converted and written.
    first = read_capture(files[0])
    container = 8 if first.dtype == np.uint8 else 16
    bit_in = container if bit_in is None else bit_in
    if (bit_in == 8) != (container == 8):
        raise SessionError.at(spec_yaml, f"bit_depth_in {bit_in} does not fit {container}-bit capture files "
                                         f"({files[0].name})")
    problems = []
    profiles: dict[str, NDArray[np.float64]] = {}
    for row, p in zip(rows, files):
        r = first if p == files[0] else read_capture(p)
        if r.shape != first.shape or r.dtype != first.dtype:
            problems.append(Problem(p, f"{_describe(r)} differs from the first capture {files[0].name} "
                                       f"({_describe(first)})"))
        elif bayer and (why := bayer_problem(r.shape, r.dtype)):
            problems.append(Problem(p, f"does not fit Bayer pattern {bayer}: {why}"))
        elif not bayer and (r.ndim != 3 or r.shape[2] != 3):
            problems.append(Problem(p, f"not an RGB image (array shape {r.shape}); a raw Bayer mosaic needs "
                                       "--bayer or bayer: in the spec"))
        elif bit_in == 12 and int(r.max()) > 4095:
            problems.append(Problem(p, f"value {int(r.max())} exceeds 4095, not 12-bit data (bit_depth_in: 12)"))
        else:
            profiles[row.session_path] = column_profile(convert_capture(r, bayer=bayer, bit_depth_in=bit_in))
    if problems:
        raise SessionError(problems)
    where = {row.session_path: p for row, p in zip(rows, files)}
    planes_mm = [float(z) for z in patterns["planes_mm"]]
    if problems := _content_problems(profiles, where, float(spec["period_px"]), planes_mm):
        raise SessionError(problems)

    height, width = first.shape[:2]
    camera = {"width": int(width), "height": int(height), "bit_depth": 8 if bit_in == 8 else 16,
              "pixel_pitch_mm": spec["pixel_pitch_mm"], **spec.get("camera", {})}
    if bayer:  # the pattern the images were demosaiced from: the method re-demosaics them (config camera.demosaic)
        camera["bayer"] = bayer
    meta: dict[str, Any] = {
        "format": "capture-session/1", "id": spec["id"], "camera": camera,
        "pattern": {"period_px": spec["period_px"], "hue_bands": int(patterns["hue_bands"]),
                    "repeats": int(patterns["repeats"])},
        "planes_mm": planes_mm,
    }
    for key in ("specimen", "provenance"):
        if key in spec:
            meta[key] = spec[key]

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent))
    try:
        for row, p in zip(rows, files):
            img = convert_capture(read_capture(p), bayer=bayer, bit_depth_in=bit_in)
            target = tmp / row.session_path
            target.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(target) as t:
                if not cv2.imwrite(str(t), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
                    raise SessionError.at(target, "OpenCV could not write the PNG")
        if predistortion.exists():
            with atomic_path(tmp / PREDISTORTION) as t:
                shutil.copyfile(predistortion, t)
        with atomic_path(tmp / "session.yaml") as t:
            t.write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
        try:
            load_session(tmp, deep=True)
        except SessionError as exc:  # name the files as they would be in OUT, not in the temp folder
            raise SessionError([Problem(out / p.path.relative_to(tmp) if p.path.is_relative_to(tmp) else p.path,
                                        f"{p.message} (nothing written)") for p in exc.problems]) from exc
        publish_dir(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _describe(a: NDArray) -> str:
    chans = 1 if a.ndim == 2 else a.shape[2]
    return f"{a.shape[1]} x {a.shape[0]} px, {chans} channel(s), {a.dtype.itemsize * 8}-bit"


