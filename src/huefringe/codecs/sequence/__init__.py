"""A capture sequence described once: its projector images and its decoding.

A :class:`SequenceSpec` lists the projected images in capture order as blocks:
:class:`PhaseBlock` (N phase-shifted sinusoids of one period along one axis), :class:`GrayBlock`
(a Gray code along one axis, with or without inverse patterns) and :class:`FlatBlock` (a white or
black image). :func:`generate` writes the projector images; :func:`decode_sequence` turns the
camera's captures into one :class:`Decoded` per projector axis: the absolute projector coordinate
of every camera pixel with its standard uncertainty, the modulation (data quality) and a validity
mask.

Decoding an axis, coarse to fine: the Gray code (only its bits coarser than a quarter of the
first period it must resolve) or, without one, the beats of the axis' periods (heterodyne) give a
first absolute estimate; each stage fixes the next one's fringe order
(:func:`~huefringe.codecs.temporal.orders_from_reference`); with neither a Gray code nor a beat
covering the projector, the number-theoretic search over the periods decides. Every phase block
of the axis is then unwrapped against the finest stage and the results are averaged with
weights ``1 / u**2``: the coordinate's uncertainty is that of the weighted mean.

A complementary Gray code (``complementary: true``: one more pattern, the half-cell stripes of
the next Gray bit) beside a phase block of period ``cell_px`` takes each pixel's order from the
``bits``-bit code in the middle half of the period and from the ``bits + 1``-bit code in its
edge quarters (:class:`GrayBlock`).

A Gray code alone decodes to the centre of each pixel's cell (standard uncertainty
``cell_px / sqrt(12)``) where every bit is clear of its threshold. An axis with one period, or
periods that repeat within the projector (:func:`periods_cover`), is relative
(``Decoded.absolute`` False) and never triangulated.

A pixel is valid when every test of :class:`Reason` passes (the ``codecs`` block of the
configuration): direct projector light (no shadow), every phase block's modulation above
``min_modulation_dn`` and ``min_snr`` times its own noise, no saturated phase frame, a readable
Gray code, every order decision with a margin below ``order_tolerance`` (a fraction of the
period; 0.5 is a coin toss), the coordinate inside the projector. ``Decoded.reasons`` holds the
bits of the failed tests per pixel.

YAML form (:func:`load_sequence`), blocks in capture order::

    projector: {width: 1920, height: 1080, gamma: 1.0}
    frames: "pat*.png"          # the captures, sorted by the number in their names; or a list of
                                # file names in capture order: [img_03.bmp, img_04.bmp, ...]
    blocks:
      - phase: {axis: x, period_px: 66.6667, shifts_deg: [-120, 0, 120]}
      - phase: {axis: x, period_px: 100, steps: 4, encoding_gamma: 1.0, origin_px: 0}
      - gray: {axis: x, bits: 5, cell_px: 100, inverse: true}   # or cells: 20; inverse defaults to true
      - phase: {axis: y, period_px: 60, steps: 12, origin_px: 30}
      - gray: {axis: y, bits: 4, cell_px: 60, inverse: false, complementary: true}   # 5 patterns
      - hue_bands: {n: 64, repeats: 3}   # the paper's hue bands, for the per-pixel hue table
      - trapezoid: {axis: x, period_px: 36, origin_px: 0, frames: 10}   # one-shot colour frames
      - skip: 1                 # a frame captured but not used
      - white
      - black

``trapezoid`` and ``hue_bands`` (one-shot colour frames and the hue bands of their per-pixel
table, white-balanced against the ``white`` frame) are not decoded here: :mod:`huefringe.rig.oneshot`
decodes them, with the order taken from a reference's absolute coordinate.

or ``kamino410: {config: path/to/config.xml, program: phase_shifting | gamma_correction}``
for the layouts of github.com/kamino410/phase-shifting (:func:`kamino410_sequence`).
"""

from __future__ import annotations

from ._spec import (  # noqa: F401
    Axis,
    SequenceError,
    Reason,
    SkipBlock,
    TrapezoidBlock,
    HueBandsBlock,
    axis_is_absolute,
    periods_cover,
    PhaseBlock,
    GrayBlock,
    FlatBlock,
    Block,
    SequenceSpec,
    DecodeOptions,
    Decoded,
    opencv_gray_blocks,
    kamino410_sequence,
    _float,
    _phase_block,
    _gray_block,
    load_sequence,
    sequence_from_mapping,
    _check_spec,
    sequence_to_mapping,
)
from ._decode import (  # noqa: F401
    _NUM,
    _frame_key,
    capture_files,
    read_captures,
    generate,
    generate_rgb,
    _as_stack,
    _gray_reference,
    _gray_threshold,
    _direct_light,
    _stages,
    _decode_axis,
    decode_sequence,
)

__all__ = [
    "Decoded",
    "DecodeOptions",
    "FlatBlock",
    "GrayBlock",
    "HueBandsBlock",
    "PhaseBlock",
    "Reason",
    "SequenceError",
    "SequenceSpec",
    "SkipBlock",
    "TrapezoidBlock",
    "axis_is_absolute",
    "decode_sequence",
    "generate",
    "generate_rgb",
    "kamino410_sequence",
    "load_sequence",
    "opencv_gray_blocks",
    "capture_files",
    "read_captures",
    "sequence_from_mapping",
    "sequence_to_mapping",
]

# the classes are re-exported by huefringe.codecs too: named after this module, as they are
# imported, they have one canonical name in the API reference
for _cls in (SequenceError, Reason, PhaseBlock, GrayBlock, FlatBlock, SkipBlock, TrapezoidBlock, HueBandsBlock, SequenceSpec, DecodeOptions, Decoded):
    _cls.__module__ = __name__
del _cls
