"""Small file helpers: atomic writes, TIFF/JSON/PNG output.

Every output of the workflow goes through :func:`atomic_path`, so a killed job never leaves a
complete-looking but truncated file: data goes to a temporary file in the same folder and is
moved into place with :func:`os.replace`, which is atomic on POSIX file systems.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import tifffile


_UMASK = os.umask(0)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; move it onto ``target`` on success.

    The temporary file keeps the target's suffix so that libraries choosing a format by
    extension (Open3D, trimesh, OpenCV) behave as for the target.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".part{target.suffix}", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_UMASK)  # mkstemp creates 0600; give the usual permissions
        os.replace(tmp_path, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def publish_dir(tmp: str | os.PathLike[str], out: str | os.PathLike[str]) -> Path:
    """Rename a finished temporary folder ``tmp`` onto ``out`` (absent or an empty folder), with
    the permissions of a folder made under the current umask (``mkdtemp`` makes 0700). POSIX
    rename: a reader sees either nothing or the whole folder."""
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o777 & ~mask)
    out = Path(out)
    if out.exists():
        out.rmdir()
    os.replace(tmp, out)
    return out


def remove_stale_parts(target: str | os.PathLike[str]) -> list[Path]:
    """Delete temporary files that a killed writer of ``target`` left beside it.

    :func:`atomic_path` cleans up after exceptions, but not after SIGKILL; a rerun calls this.
    """
    target = Path(target)
    if not target.parent.is_dir():
        return []
    stale = sorted(target.parent.glob(f".{target.stem}.*.part{target.suffix}"))
    for p in stale:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
    return stale


def source_date_epoch() -> dt.datetime | None:
    """``SOURCE_DATE_EPOCH`` (the reproducible-builds convention) as a UTC time, or None if unset.

    Files that must carry a date but be byte-identical for the same inputs (archives, X3P)
    use it when the session gives no capture date, instead of the clock.

    Raises
    ------
    ValueError
        If the variable is set but is not a Unix time in whole seconds (the message names it).
    """
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if not epoch:
        return None
    try:
        return dt.datetime.fromtimestamp(int(epoch), tz=dt.UTC)
    except (ValueError, OverflowError, OSError) as exc:
        raise ValueError(f"SOURCE_DATE_EPOCH={epoch!r} is not a Unix time in seconds") from exc


def sha256_file(path: str | os.PathLike[str], chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()


def write_tiff(path: str | os.PathLike[str], data: np.ndarray, *, pixel_pitch_mm: float | None = None) -> None:
    """Write an array as an uncompressed TIFF, atomically and byte-reproducibly.

    With ``pixel_pitch_mm`` the lateral scale goes into the TIFF resolution tags
    (``XResolution`` = ``YResolution`` = ``10 / pixel_pitch_mm`` pixels per centimetre,
    ``ResolutionUnit`` centimetre), which image tools (Fiji/ImageJ, Gwyddion, GIMP) read as the
    pixel size; :func:`tiff_pixel_pitch_mm` reads it back.
    """
    extra: dict[str, Any] = {}
    if pixel_pitch_mm is not None:
        per_cm = 10.0 / float(pixel_pitch_mm)
        extra = {"resolution": (per_cm, per_cm), "resolutionunit": "CENTIMETER"}
    with atomic_path(path) as tmp:
        tifffile.imwrite(tmp, data, photometric="minisblack" if data.ndim == 2 else "rgb", software=False, **extra)


def tiff_pixel_pitch_mm(path: str | os.PathLike[str]) -> float | None:
    """The pixel pitch in mm of a TIFF's resolution tags (centimetre or inch units), or None without them."""
    with tifffile.TiffFile(path) as tif:
        tags = tif.pages[0].tags
        if "XResolution" not in tags or "ResolutionUnit" not in tags:
            return None
        num, den = tags["XResolution"].value
        unit = int(tags["ResolutionUnit"].value)
    if not num or unit not in (2, 3):
        return None
    return (25.4 if unit == 2 else 10.0) * den / num


def read_tiff(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a TIFF into a NumPy array."""
    return tifffile.imread(path)


def write_json(path: str | os.PathLike[str], obj: Any) -> None:
    """Write JSON (sorted keys, 2-space indent, NaN refused), atomically."""
    text = json.dumps(obj, indent=2, sort_keys=True, allow_nan=False, default=json_default)
    with atomic_path(path) as tmp:
        tmp.write_text(text + "\n", encoding="utf-8")


def json_default(o: Any) -> Any:
    """``json.dumps`` fallback for NumPy scalars and arrays and paths."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_figure_png(fig: Any, path: str | os.PathLike[str], dpi: float | None = None) -> Path:
    """Save a Matplotlib figure as PNG, atomically and without the library-version metadata
    (so the same figure gives the same bytes across Matplotlib releases)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi if dpi is not None else "figure", metadata={"Software": None})
    return path


def write_png_rgb(path: str | os.PathLike[str], rgb: np.ndarray) -> None:
    """Write an RGB ``uint8``/``uint16`` array as PNG (OpenCV stores BGR), atomically."""
    if rgb.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"PNG needs uint8 or uint16 data, got {rgb.dtype}")
    with atomic_path(path) as tmp:
        data = rgb[..., ::-1] if rgb.ndim == 3 else rgb
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(data)):
            raise OSError(f"{path}: OpenCV could not write the PNG")
