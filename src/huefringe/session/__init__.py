"""Capture-session reader and validator (``../shared/spec/capture-session.md``, version 1).

A session is refused *before any work starts* when it breaks the format: :func:`load_session`
checks session.yaml against a JSON schema (unknown keys refused), every expected file, and the
header of every image (size, bit depth, RGB, PNG/TIFF not truncated), and raises one
:class:`SessionError` listing each problem with the file it concerns. Decoding every pixel is
left to :func:`read_rgb` (which raises the same error type) or to ``deep=True``.
"""

from __future__ import annotations

from ._model import (  # noqa: F401
    FORMAT,
    Problem,
    SessionError,
    Session,
    Predistortion,
    format_predistortion,
    read_predistortion,
)
from ._validate import (  # noqa: F401
    _schema,
    _schema_problems,
    _normalise_dates,
    parse_captured_at,
    _semantic_problems,
    _camera_problems,
)
from ._images import (  # noqa: F401
    IMAGE_SUFFIXES,
    _PNG_SIGNATURE,
    _PNG_IEND,
    ImageInfo,
    image_info,
    _png_info,
    _tiff_info,
    decode_image,
    read_rgb_codes,
    read_rgb,
)
from ._load import (  # noqa: F401
    _BAND_RE,
    _FRAME_RE,
    _PS_RE,
    _PLANE_RE,
    _images_in,
    _single_image,
    _bands,
    _collect,
    _image_problems,
    read_meta,
    load_session,
)

__all__ = [
    "FORMAT",
    "IMAGE_SUFFIXES",
    "ImageInfo",
    "Predistortion",
    "Problem",
    "Session",
    "SessionError",
    "decode_image",
    "format_predistortion",
    "image_info",
    "load_session",
    "parse_captured_at",
    "read_meta",
    "read_predistortion",
    "read_rgb",
    "read_rgb_codes",
]
