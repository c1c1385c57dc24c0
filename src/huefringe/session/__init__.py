"""Session readers and validators: capture-session/1 (``../shared/spec/capture-session.md``) and
structured-light-session/1 (``docs/spec/structured-light-session.md``, :func:`load_sl_session`);
:func:`session_format` tells the two apart from ``session.yaml``.

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
from ._features import FEATURES_FILE, Feature, Features, Region, load_features  # noqa: F401
from ._structured import (  # noqa: F401
    SL_FORMAT,
    SLSession,
    assemble_sl_session,
    calibration_problems,
    load_sl_session,
    session_format,
)

__all__ = [
    "FORMAT",
    "FEATURES_FILE",
    "Feature",
    "Features",
    "Region",
    "SL_FORMAT",
    "SLSession",
    "load_features",
    "assemble_sl_session",
    "calibration_problems",
    "load_sl_session",
    "session_format",
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
