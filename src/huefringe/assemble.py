"""Assemble a checked capture-session/1 folder from a flat folder of camera captures.

A real rig shows the projector images of a patterns folder (``manifest.csv`` + ``patterns.yaml``,
written by ``huefringe patterns``, contract in docs/guide.md) one after another and saves one
camera file per image. :func:`assemble_session` matches capture ``k`` (natural order of file
name) to manifest row ``k``, converts it (Bayer demosaic, 12-bit scaling) and writes the session
folder with its ``session.yaml``, after checking everything it can before writing anything, in
one reading pass that reports every problem together: counts, unreadable files, sizes and bit
depths (against the majority), copies (:mod:`huefringe.capture_checks`: same or near-identical
pixel values, named as copies), the Bayer pattern against the mosaic's statistics (the four
patterns compared), the spec YAML, the content (the white capture is the brightest, fringe
captures show a fringe, uniform captures do not, each hue band's hue rises with its band
number, and the fringe period on the reference plane agrees with the declared ``period_px``
within 5 %), and the free disk.

Layer: above :mod:`huefringe.session`, :mod:`huefringe.camera` and :mod:`huefringe.capture_checks`.
"""

from __future__ import annotations

import csv
import hashlib
import os
import re
import shutil
import tempfile
from collections import Counter
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
from huefringe.capture_checks import NEAR_IDENTICAL_FRACTION, band_order_problems, bayer_fit, duplicate_groups, \
    site_means
from huefringe.io import atomic_path, publish_dir
from huefringe.patterns import MANIFEST_HEADER
from huefringe.session import Problem, Session, SessionError, decode_image, load_session, read_predistortion

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


def _count_problem(files: list[Path], rows: list[_Row], captures_dir: Path,
                   duplicates: list[tuple[list[int], bool]] = ()) -> SessionError | None:
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
    n_extra = len(files) - len(rows)
    n_copies = sum(len(g) - 1 for g, _ in duplicates)
    if n_copies:
        why = (f"{n_copies} of the captures {'is a copy' if n_copies == 1 else 'are copies'} of another "
               "(named below): remove the copies" + ("" if n_copies == n_extra else
                                                     f", then {n_extra - n_copies:+d} capture(s) remain extra"))
        return SessionError.at(captures_dir, f"{len(files)} captures for {len(rows)} manifest rows: "
                                             f"{n_extra} extra; {why}")
    gaps = _numbering_gaps(files)
    extra = files[len(rows):]
    names = ", ".join(p.name for p in extra[:10]) + (f" and {len(extra) - 10} more" if len(extra) > 10 else "")
    where = (f"the numbering breaks at {', '.join(gaps[:5])}" if gaps else
             f"the last in name order are {names}, but the extra capture may be anywhere: check the "
             "captures against manifest.csv")
    return SessionError.at(captures_dir, f"{len(files)} captures for {len(rows)} manifest rows: "
                                         f"{n_extra} extra; no two captures have the same content; {where}")


def _duplicate_problems(files: list[Path], duplicates: list[tuple[list[int], bool]]) -> list[Problem]:
    out = []
    for group, identical in duplicates:
        # the original: the plainest name (a copy gets " (1)", " copy", ...), else the first in order
        first = min(group, key=lambda k: (len(files[k].name), natural_key(files[k].name)))
        copies = [k for k in group if k != first]
        for k in copies:
            how = ("has the same pixel values as" if identical else
                   f"is near-identical to (at most {100 * NEAR_IDENTICAL_FRACTION:g} % of the pixels differ, by one code)")
            out.append(Problem(files[k], f"{how} {files[first].name}: a copy, not a second capture (two exposures "
                                         "never agree that well); remove the copy"))
    return out


@dataclass
class _Scan:
    """What the one reading pass of a captures folder keeps: problems, shapes, fingerprints, profiles."""

    problems: list[Problem]
    shape: tuple[int, ...] | None
    dtype: np.dtype | None
    duplicates: list[tuple[list[int], bool]]
    profiles: dict[str, NDArray[np.float64]]
    sites: dict[str, NDArray[np.float64]]


def _scan(files: list[Path], rows: list[_Row], *, bayer: str | None, bit_in: int | None) -> _Scan:
    """Read every capture once: every file's problems (unreadable, size, bit depth, channels,
    12-bit range), content digests and signatures for duplicates, and, when the count matches the
    manifest, column profiles (and Bayer photosite means of the reference white and bands)."""
    paths = [r.session_path for r in rows] if len(files) == len(rows) else [None] * len(files)
    problems: list[Problem] = []
    shapes: list[tuple[tuple[int, ...], np.dtype] | None] = []
    digests: list[bytes | None] = []
    sigs = np.zeros((len(files), 32))
    profiles: dict[str, NDArray[np.float64]] = {}
    sites: dict[str, NDArray[np.float64]] = {}
    per_file: dict[int, str] = {}
    for k, (p, key) in enumerate(zip(files, paths)):
        try:
            r = read_capture(p)
        except SessionError as exc:
            problems += exc.problems
            shapes.append(None)
            digests.append(None)
            continue
        shapes.append((r.shape, r.dtype))
        digests.append(hashlib.sha256(repr((r.shape, r.dtype.str)).encode() + r.tobytes()).digest())
        file_bits = 8 if r.dtype == np.uint8 else (bit_in or 16)
        raw_profile = r.mean(axis=0, dtype=np.float64)  # (W,) or (W, C): the column means as stored
        col = raw_profile.reshape(r.shape[1], -1).mean(axis=1)
        sigs[k] = [b.mean() for b in np.array_split(col, 32)] if col.size >= 32 else np.resize(col, 32)
        if bayer and (why := bayer_problem(r.shape, r.dtype)):
            per_file[k] = f"does not fit Bayer pattern {bayer}: {why}"
        elif not bayer and (r.ndim != 3 or r.shape[2] != 3):
            per_file[k] = (f"not an RGB image (array shape {r.shape}); a raw Bayer mosaic needs "
                           "--bayer or bayer: in the spec")
        elif file_bits == 12 and int(r.max()) > 4095:
            per_file[k] = f"value {int(r.max())} exceeds 4095, not 12-bit data (bit_depth_in: 12)"
        elif key is not None:
            # without a demosaic or a 12-bit scaling the stored values are the session's: reuse their profile
            profiles[key] = (raw_profile if not bayer and file_bits != 12 else
                             column_profile(convert_capture(r, bayer=bayer, bit_depth_in=file_bits)))
            if bayer and key.startswith("reference/") and ("/hue/" in key or key.endswith("white.png")):
                sites[key] = site_means(r)
    seen = [s for s in shapes if s is not None]
    shape = dtype = None
    if seen:
        (shape, dtype), _ = Counter(seen).most_common(1)[0]
        n_like = sum(1 for s in seen if s == (shape, dtype))
        ref = next(files[k] for k, s in enumerate(shapes) if s == (shape, dtype))
        for k, s in enumerate(shapes):
            if s is not None and s != (shape, dtype):
                problems.append(Problem(files[k], f"{_describe_shape(*s)} differs from {n_like} of the "
                                                  f"{len(seen)} captures ({_describe_shape(shape, dtype)}, e.g. "
                                                  f"{ref.name})"))
                per_file.pop(k, None)
                if paths[k] is not None:
                    profiles.pop(paths[k], None)
    problems += [Problem(files[k], msg) for k, msg in sorted(per_file.items())]
    step = 1.0 if dtype == np.uint8 or dtype is None else (16.0 if bit_in == 12 else 1.0)

    def differ(i: int, j: int) -> float:
        a, b = read_capture(files[i]).astype(np.int64), read_capture(files[j]).astype(np.int64)
        if a.shape != b.shape:
            return 1.0
        d = np.abs(a - b)
        return 1.0 if d.max() > step else float(np.count_nonzero(d) / d.size)

    dups = duplicate_groups(digests, sigs, step, differ)
    return _Scan(sorted(problems, key=lambda q: natural_key(q.path.name)), shape, dtype, dups, profiles, sites)


def _describe_shape(shape: tuple[int, ...], dtype: np.dtype) -> str:
    chans = 1 if len(shape) == 2 else shape[2]
    return f"{shape[1]} x {shape[0]} px, {chans} channel(s), {np.dtype(dtype).itemsize * 8}-bit"


def _band_index(session_path: str) -> int:
    return int(session_path.rsplit("/band_", 1)[1][:3])


def _bayer_problems(scan: _Scan, bayer: str, rows: list[_Row], files: list[Path], hue_bands: int) -> list[Problem]:
    white = scan.sites.get("reference/white.png")
    keys = [r.session_path for r in rows if r.session_path.startswith("reference/hue/") and r.session_path in scan.sites]
    if white is None or len(keys) < 6:
        return []
    fit = bayer_fit(white, np.stack([scan.sites[k] for k in keys]), [_band_index(k) for k in keys], hue_bands)
    if fit.fits(bayer):
        return []
    where = {r.session_path: p for r, p in zip(rows, files)}
    return [Problem(where["reference/white.png"].parent,
                    f"the Bayer pattern {bayer} does not fit these mosaics: read as {bayer}, the reference hue "
                    f"bands' hue departs from their code phase by {fit.rms_rad[bayer]:.2f} rad RMS; the four patterns "
                    f"compared ({fit.describe()}) point to {fit.best}: give --bayer {fit.best} (or bayer: "
                    f"{fit.best} in the spec)")]


def _band_problems(profiles: dict[str, NDArray[np.float64]], where: dict[str, Path], hue_bands: int) -> list[Problem]:
    out = []
    for part in ("reference", "object"):
        white = profiles.get(f"{part}/white.png")
        keys = [k for k in where if k.startswith(f"{part}/hue/") and k in profiles]
        if white is None or not keys:
            continue
        w = np.maximum(white, 1e-9)
        rgb = np.stack([(profiles[k] / w).mean(axis=0) for k in keys])
        bands = [_band_index(k) for k in keys]
        found = band_order_problems(rgb, bands, hue_bands)
        for m in found:
            key = keys[m.index]
            rep = key.rsplit("_r", 1)[1]  # the same repeat of the other band first
            partner = sorted((keys[o.index] for o in found if o.band == m.fits and o.fits == m.band),
                             key=lambda k: k.rsplit("_r", 1)[1] != rep)
            swap = f"; swapped with {where[partner[0]].name}?" if partner else ""
            out.append(Problem(where[key], f"goes to {key} (hue band {m.band:03d}) but its hue, {m.hue_rad:.3f} rad, is "
                                           f"that of band {m.fits:03d}: the captured hue must rise with the band "
                                           f"number; hue band captured out of order{swap}"))
    return out


def _check_space(files: list[Path], out: Path, *, bayer: str | None) -> None:
    """Refuse before writing when the session would not fit on the disk of ``out``."""
    need = int(sum(p.stat().st_size for p in files) * (3.0 if bayer else 1.0) * 1.2)
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    free = shutil.disk_usage(parent).free
    if need > free:
        raise SessionError.at(out, f"needs about {need / 1e9:.1f} GB, {parent} has {free / 1e9:.1f} GB free")


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
        Before anything is written, naming each file, all problems of the folder at once: count
        mismatch, copies, unreadable files, size/bit depth/Bayer problems, a bad spec or patterns
        folder, content or hue bands out of order, a period disagreeing by more than 5 %, too
        little disk, or an existing non-empty ``out_dir``.
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
    planes_mm = [float(z) for z in patterns["planes_mm"]]
    scan = _scan(files, rows, bayer=bayer, bit_in=bit_in)
    problems: list[Problem] = []
    if (err := _count_problem(files, rows, captures, scan.duplicates)) is not None:
        problems += err.problems
    problems += _duplicate_problems(files, scan.duplicates)
    problems += scan.problems
    if scan.dtype is not None and bit_in is not None and (bit_in == 8) != (scan.dtype == np.uint8):
        problems.append(Problem(Path(spec_yaml), f"bit_depth_in {bit_in} does not fit {scan.dtype.itemsize * 8}-bit "
                                                 f"capture files ({files[0].name})"))
    if len(files) == len(rows):  # the rows' meaning is known: check the content of every readable capture
        where = {row.session_path: p for row, p in zip(rows, files)}
        if bayer and (bp := _bayer_problems(scan, bayer, rows, files, int(patterns["hue_bands"]))):
            problems += bp  # the content checks would only repeat it, capture by capture
        else:
            problems += _content_problems(scan.profiles, where, float(spec["period_px"]), planes_mm)
            problems += _band_problems(scan.profiles, where, int(patterns["hue_bands"]))
    if problems:
        raise SessionError(problems)
    if bit_in is None:
        bit_in = 8 if scan.dtype == np.uint8 else 16
    first_shape = scan.shape
    assert first_shape is not None
    _check_space(files, out, bayer=bayer)

    height, width = first_shape[:2]
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


def session_band_problems(session: Session) -> list[Problem]:
    """Hue-band images of a written session whose hue is another band's (``huefringe check --deep``).

    The check :func:`assemble_session` makes at assembly (:func:`huefringe.capture_checks.band_order_problems`),
    on each band image's mean colour over its white's, for a session however it was written.
    """
    out = []
    for part, white, bands in (("reference", session.reference_white, session.reference_bands),
                               ("object", session.object_white, session.object_bands)):
        paths = [(i, p) for i, reps in enumerate(bands) for p in reps]
        w = decode_image(white).mean(axis=(0, 1), dtype=np.float64)
        rgb = np.stack([decode_image(p).mean(axis=(0, 1), dtype=np.float64) for _, p in paths]) / np.maximum(w, 1e-9)
        for m in band_order_problems(rgb, [i for i, _ in paths], session.hue_bands):
            out.append(Problem(paths[m.index][1], f"{part} hue band {m.band:03d}, but its hue ({m.hue_rad:.3f} rad) "
                                                  f"is that of band {m.fits:03d}: the captured hue must rise with the "
                                                  "band number; bands out of order"))
    return out
