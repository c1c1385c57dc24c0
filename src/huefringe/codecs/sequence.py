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

A pixel is valid when every phase block's modulation reaches ``min_modulation_dn``, every decoded
Gray bit differs from its reference by ``min_gray_contrast_dn`` and every order decision kept a
margin below ``order_tolerance`` (a fraction of the period; 0.5 is a coin toss).

YAML form (:func:`load_sequence`), blocks in capture order::

    projector: {width: 1920, height: 1080, gamma: 1.0}
    frames: "pat*.png"          # the captures, sorted by the number in their names
    blocks:
      - phase: {axis: x, period_px: 66.6667, shifts_deg: [-120, 0, 120]}
      - phase: {axis: x, period_px: 100, steps: 4, encoding_gamma: 1.0, origin_px: 0}
      - gray: {axis: x, cells: 20, cell_px: 100, inverse: true}
      - white
      - black

or ``kamino410: {config: path/to/config.xml, program: phase_shifting | gamma_correction}``
for the layouts of github.com/kamino410/phase-shifting (:func:`kamino410_sequence`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal
from xml.etree import ElementTree

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from huefringe.codecs.graycode import bits_for, decode_gray, index_to_gray
from huefringe.codecs.nstep import TWO_PI, NoiseModel, WrappedPhase, equal_shifts, wrapped_phase
from huefringe.codecs.temporal import heterodyne, number_theoretic, orders_from_reference

Axis = Literal["x", "y"]

__all__ = [
    "Decoded",
    "DecodeOptions",
    "FlatBlock",
    "GrayBlock",
    "PhaseBlock",
    "SequenceError",
    "SequenceSpec",
    "decode_sequence",
    "generate",
    "kamino410_sequence",
    "load_sequence",
    "opencv_gray_blocks",
    "read_captures",
]


class SequenceError(ValueError):
    """A sequence description or a folder of captures that cannot be decoded (names the file)."""


@dataclass(frozen=True)
class PhaseBlock:
    """N phase-shifted sinusoids of one period along one projector axis.

    Frame ``n`` shows ``(0.5 + 0.5 cos(2 pi (u - origin_px) / period_px + shifts_rad[n]))**encoding_gamma``
    times full scale, ``u`` the projector column (axis ``x``) or row (axis ``y``).
    """

    axis: Axis
    period_px: float
    shifts_rad: tuple[float, ...]
    encoding_gamma: float = 1.0
    origin_px: float = 0.0

    @property
    def n_frames(self) -> int:
        return len(self.shifts_rad)


@dataclass(frozen=True)
class GrayBlock:
    """A Gray code along one axis: ``bits`` patterns, MSB first, cells ``cell_px`` wide.

    Projector pixel ``u`` lies in cell ``floor(u / cell_px)``. With ``inverse`` each pattern is
    followed by its inverse (OpenCV's layout); without, bits are read against the mean of the
    sequence's white and black frames.
    """

    axis: Axis
    bits: int
    cell_px: float
    inverse: bool = True

    @property
    def n_frames(self) -> int:
        return self.bits * (2 if self.inverse else 1)


@dataclass(frozen=True)
class FlatBlock:
    """A uniform white or black projector image."""

    level: Literal["white", "black"]

    @property
    def n_frames(self) -> int:
        return 1


Block = PhaseBlock | GrayBlock | FlatBlock


@dataclass(frozen=True)
class SequenceSpec:
    """A capture sequence: blocks in capture order and the projector they were shown on.

    Attributes
    ----------
    blocks : tuple of blocks
        In capture order; each consumes ``n_frames`` captures.
    projector_width, projector_height : int
        The projector's (display's) size in pixels.
    projector_gamma : float
        The display's response exponent; with each block's ``encoding_gamma`` it makes the
        exponent :func:`~huefringe.codecs.nstep.linearise` undoes (1 = linear).
    frames : str
        Glob of the captures inside a folder, sorted by the last number in their names.
    """

    blocks: tuple[Block, ...]
    projector_width: int
    projector_height: int
    projector_gamma: float = 1.0
    frames: str = "*.png"

    @property
    def n_frames(self) -> int:
        return sum(b.n_frames for b in self.blocks)

    def slices(self) -> list[tuple[Block, slice]]:
        """Each block with the slice of the capture list it consumes."""
        out, i = [], 0
        for b in self.blocks:
            out.append((b, slice(i, i + b.n_frames)))
            i += b.n_frames
        return out

    def axes(self) -> list[Axis]:
        """The projector axes the sequence encodes (``x`` before ``y``)."""
        have = {b.axis for b in self.blocks if isinstance(b, PhaseBlock | GrayBlock)}
        return [a for a in ("x", "y") if a in have]

    def extent(self, axis: Axis) -> int:
        """Projector pixels along ``axis``."""
        return self.projector_width if axis == "x" else self.projector_height


@dataclass(frozen=True)
class DecodeOptions:
    """Thresholds and the camera noise model of :func:`decode_sequence` (``codecs`` in the configuration)."""

    min_modulation_dn: float
    min_gray_contrast_dn: float
    order_tolerance: float
    read_noise_dn: float
    full_well_e: float | None

    @classmethod
    def from_config(cls, cfg: dict[str, Any] | None = None) -> DecodeOptions:
        """From a configuration's ``codecs`` block (the packaged defaults when ``cfg`` is None)."""
        if cfg is None:
            from huefringe.settings import load_config

            cfg = load_config()
        c = cfg["codecs"]
        return cls(
            min_modulation_dn=float(c["min_modulation_dn"]),
            min_gray_contrast_dn=float(c["min_gray_contrast_dn"]),
            order_tolerance=float(c["order_tolerance"]),
            read_noise_dn=float(c["noise"]["read_dn"]),
            full_well_e=None if c["noise"]["full_well_e"] is None else float(c["noise"]["full_well_e"]),
        )

    def noise(self, full_scale_dn: float) -> NoiseModel:
        """The noise model for captures of this full scale (255, 65535)."""
        return NoiseModel(self.read_noise_dn, self.full_well_e, full_scale_dn)


@dataclass(frozen=True)
class Decoded:
    """One projector axis decoded, per camera pixel.

    Attributes
    ----------
    axis : "x" or "y"
        Projector column (``x``) or row (``y``).
    coord : ndarray of float64
        Absolute projector coordinate (px, pixel centres at integers); NaN where not valid.
        Relative to the block's origin within one period where ``absolute`` is False.
    sigma : ndarray of float64
        Its standard uncertainty (projector px) from the frames' noise; NaN where not valid.
    modulation : ndarray of float32
        Fringe amplitude (camera DN) of the axis' finest phase block: the data-quality map.
    valid : ndarray of bool
        Modulation, Gray contrast and order margins all passed.
    order_margin : ndarray of float32
        Largest fraction of a period by which an order decision missed its integer (0 .. 0.5).
    absolute : bool
        False when the sequence carries nothing beyond one period (a lone phase block).
    phases : tuple of WrappedPhase
        Each phase block of the axis, in capture order.
    """

    axis: Axis
    coord: NDArray[np.float64]
    sigma: NDArray[np.float64]
    modulation: NDArray[np.float32]
    valid: NDArray[np.bool_]
    order_margin: NDArray[np.float32]
    absolute: bool
    phases: tuple[WrappedPhase, ...] = field(repr=False, default=())


def opencv_gray_blocks(width: int, height: int, cell_px: float = 1.0) -> tuple[GrayBlock, GrayBlock]:
    """The x and y blocks of OpenCV's ``GrayCodePattern.create(width, height)`` (cells, not px).

    Examples
    --------
    >>> opencv_gray_blocks(20, 11, 100)[0]
    GrayBlock(axis='x', bits=5, cell_px=100, inverse=True)
    """
    return GrayBlock("x", bits_for(width), cell_px, True), GrayBlock("y", bits_for(height), cell_px, True)


def kamino410_sequence(config_xml: str | Path, program: Literal["phase_shifting", "gamma_correction"]) -> SequenceSpec:
    """The sequence written by github.com/kamino410/phase-shifting's ``generate`` from its config.xml.

    ``phase_shifting``: three-step sinusoids (shifts -120, 0, +120 deg) of periods ``step/3`` and
    ``step/2`` along x then y, OpenCV Gray code of ``step/2`` cells, white, black.
    ``gamma_correction``: two three-step sets of period ``disp_width/8`` along x then y, encoded
    with exponents ``1/gamma_p1`` and ``1/gamma_p2``, OpenCV Gray code of ``step`` cells, white,
    black.
    """
    path = Path(config_xml)
    try:
        root = ElementTree.parse(path).getroot()
        vals = {c.tag: float(c.text) for c in root}
        w, h, step = int(vals["disp_width"]), int(vals["disp_height"]), int(vals["step"])
    except (OSError, ElementTree.ParseError, KeyError, TypeError, ValueError) as exc:
        raise SequenceError(f"{path}: not a kamino410 config.xml with disp_width, disp_height, step ({exc})") from None
    d3 = tuple(float(v) for v in equal_shifts(3, -TWO_PI / 3))
    if program == "phase_shifting":
        gc = step // 2
        phase = [PhaseBlock(a, p, d3) for a in ("x", "y") for p in (step / 3, step / 2)]
        gx, gy = opencv_gray_blocks((w - 1) // gc + 1, (h - 1) // gc + 1, gc)
    elif program == "gamma_correction":
        if "gamma_p1" not in vals or "gamma_p2" not in vals:
            raise SequenceError(f"{path}: gamma_correction needs gamma_p1 and gamma_p2")
        period = float(w // 8)
        g = (1.0 / vals["gamma_p1"], 1.0 / vals["gamma_p2"])
        phase = [PhaseBlock(a, period, d3, encoding_gamma=gi) for a in ("x", "y") for gi in g]
        gx, gy = opencv_gray_blocks((w - 1) // step + 1, (h - 1) // step + 1, step)
    else:
        raise SequenceError(f"{path}: unknown kamino410 program {program!r} (phase_shifting, gamma_correction)")
    blocks = (*phase, gx, gy, FlatBlock("white"), FlatBlock("black"))
    return SequenceSpec(blocks=blocks, projector_width=w, projector_height=h, frames="pat*.png")


def load_sequence(path: str | Path) -> SequenceSpec:
    """Read a sequence YAML (module docstring); every problem in one :class:`SequenceError`."""
    raise NotImplementedError


def read_captures(folder: str | Path, spec: SequenceSpec) -> list[NDArray[np.number]]:
    """The captures of ``spec.frames`` in ``folder``, grayscale, sorted by the number in their names.

    Raises
    ------
    SequenceError
        Naming the folder or file: a wrong count, an unreadable file, mixed sizes or dtypes.
    """
    raise NotImplementedError


def generate(spec: SequenceSpec, dtype: type[np.integer] = np.uint8) -> NDArray[np.integer]:
    """The projector images of ``spec`` in capture order, shape (n_frames, height, width)."""
    raise NotImplementedError


def decode_sequence(
    images: list[NDArray[np.number]] | NDArray[np.number],
    spec: SequenceSpec,
    options: DecodeOptions | None = None,
) -> dict[Axis, Decoded]:
    """Decode captures of ``spec`` into the absolute projector coordinate of each axis.

    Parameters
    ----------
    images : list of ndarray or ndarray, shape (n_frames, H, W)
        Grayscale captures in capture order (8- or 16-bit integers, or floats on a 0..255 scale).
    spec : SequenceSpec
    options : DecodeOptions, optional
        Thresholds and noise model; default the configuration's ``codecs`` block.

    Returns
    -------
    dict
        ``{"x": Decoded, "y": Decoded}`` for the axes the sequence encodes.
    """
    raise NotImplementedError
