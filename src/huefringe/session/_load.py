"""Loading a capture-session/1 folder: finding its images, collecting every problem at once, the :class:`Session`."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
import yaml
from ._images import IMAGE_SUFFIXES, image_info, read_rgb
from ._model import Problem, Session, SessionError, read_predistortion
from ._validate import _normalise_dates, _schema_problems, _semantic_problems


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
