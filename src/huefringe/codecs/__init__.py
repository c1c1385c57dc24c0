"""The field's codecs: captures of coded projector patterns in, absolute projector coordinates out.

Each codec is a small module of array-to-array functions; :func:`decode_sequence` is the one
interface the pipeline calls, whichever way a session was captured:

``nstep``
    N-step phase shifting (N >= 3, any distinct shifts, 8 or 16 bit): wrapped phase, fringe
    modulation and the phase's standard uncertainty from a camera noise model (first-order GUM
    propagation through the arctangent, the encoding-gamma linearisation included).
``graycode``
    Binary-reflected Gray code, each pattern with its inverse or against a white/black mean;
    OpenCV ``structured_light::GrayCodePattern``'s layout (:func:`opencv_gray_blocks`).
``temporal``
    Absolute phase: fringe orders from a coarser estimate (Gray code, or the beat of two or three
    periods: heterodyne), or by the number-theoretic search over candidate orders.
``gamma``
    The projector's (display's) gamma estimated from the captures themselves.
``sequence``
    A declarative description of a capture sequence (:class:`SequenceSpec`), its projector
    images (:func:`generate`) and its decoding (:func:`decode_sequence`) into one
    :class:`Decoded` per projector axis.

Conventions
-----------
A phase frame is ``I_n = A + B cos(2 pi (u - origin) / P + delta_n)`` with ``u`` the projector
coordinate along the block's axis in projector pixels, pixel centres at integers (column ``x`` or
row ``y``), ``P`` the period and ``delta_n`` the frame's shift. The wrapped phase is therefore
``2 pi (u - origin) / P`` modulo ``2 pi``, and the decoded coordinate is ``u``.
"""

from __future__ import annotations

from huefringe.codecs.gamma import GammaEstimate, estimate_projector_gamma
from huefringe.codecs.graycode import (
    GrayDecoded,
    decode_gray,
    gray_to_index,
    index_to_gray,
    opencv_graycode_patterns,
)
from huefringe.codecs.nstep import NoiseModel, WrappedPhase, equal_shifts, profile_lut, wrapped_phase
from huefringe.codecs.sequence import (
    Decoded,
    DecodeOptions,
    FlatBlock,
    GrayBlock,
    PhaseBlock,
    Reason,
    SequenceError,
    SequenceSpec,
    SkipBlock,
    TrapezoidBlock,
    HueBandsBlock,
    axis_is_absolute,
    decode_sequence,
    generate,
    generate_rgb,
    kamino410_sequence,
    load_sequence,
    opencv_gray_blocks,
    capture_files,
    read_captures,
    sequence_from_mapping,
    sequence_to_mapping,
)
from huefringe.codecs.temporal import heterodyne, number_theoretic, orders_from_reference

__all__ = [
    "Decoded",
    "DecodeOptions",
    "FlatBlock",
    "GammaEstimate",
    "GrayBlock",
    "GrayDecoded",
    "NoiseModel",
    "PhaseBlock",
    "Reason",
    "SequenceError",
    "SequenceSpec",
    "SkipBlock",
    "TrapezoidBlock",
    "HueBandsBlock",
    "WrappedPhase",
    "axis_is_absolute",
    "decode_gray",
    "decode_sequence",
    "equal_shifts",
    "estimate_projector_gamma",
    "generate",
    "generate_rgb",
    "gray_to_index",
    "heterodyne",
    "index_to_gray",
    "kamino410_sequence",
    "load_sequence",
    "number_theoretic",
    "opencv_gray_blocks",
    "opencv_graycode_patterns",
    "orders_from_reference",
    "profile_lut",
    "capture_files",
    "read_captures",
    "sequence_from_mapping",
    "sequence_to_mapping",
    "wrapped_phase",
]
