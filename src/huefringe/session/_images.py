"""Reading the session's images: header info, decoding, sensor codes and float RGB."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import tifffile
from ._model import SessionError


IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"


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
        if suffix == ".bmp":
            return _bmp_info(path)
    except SessionError:
        raise
    except Exception as exc:  # any parser failure is a bad file, reported as such
        raise SessionError.at(path, f"cannot read image header ({exc.__class__.__name__}: {exc})") from exc
    raise SessionError.at(path, f"unsupported image type {suffix!r} (PNG, TIFF or BMP expected)")


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


def _bmp_info(path: Path) -> ImageInfo:
    """A Windows bitmap's header (SLStudio, SLMaster write them): 8-bit palette (grey when every
    palette entry is grey, else colour), 24-bit colour or 32-bit with alpha; uncompressed."""
    with open(path, "rb") as f:
        head = f.read(54)
        if len(head) < 54 or head[:2] != b"BM":
            raise SessionError.at(path, "not a BMP file (bad signature or header)")
        offset, dib = struct.unpack("<II", head[10:18])
        width, height, _, bpp, compression = struct.unpack("<iiHHI", head[18:34])
        if compression not in (0, 3):
            raise SessionError.at(path, f"compressed BMP (compression {compression}); an uncompressed bitmap is expected")
        channels = {24: 3, 32: 4}.get(bpp, 0)
        if bpp == 8:
            used = struct.unpack("<I", head[46:50])[0] or 256
            f.seek(14 + dib)
            pal = np.frombuffer(f.read(4 * used), np.uint8).reshape(-1, 4)
            channels = 1 if (pal[:, 0] == pal[:, 1]).all() and (pal[:, 1] == pal[:, 2]).all() else 3
        elif channels == 0:
            raise SessionError.at(path, f"{bpp}-bit BMP; 8-bit grey or 24-bit colour expected")
        f.seek(0, 2)
        size = f.tell()
    end = offset + ((bpp * width + 31) // 32) * 4 * abs(height)
    if end > size:
        raise SessionError.at(path, f"truncated BMP (pixel data ends at byte {end}, file has {size})")
    return ImageInfo(width, abs(height), 8, channels)


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
