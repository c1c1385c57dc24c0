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

A pixel is valid when every phase block's modulation reaches ``min_modulation_dn`` and none of
its frames is clipped at full scale, the decoded Gray bits (all but one, next to a cell edge)
differ from their reference by ``min_gray_contrast_dn`` and every order decision kept a margin
below ``order_tolerance`` (a fraction of the period; 0.5 is a coin toss).

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
        The display's response exponent; times each block's ``encoding_gamma`` it is the fringe
        profile's exponent :func:`~huefringe.codecs.nstep.profile_lut` undoes (1 = linear).
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
        Modulation, no clipped frame, Gray contrast and order margins all passed.
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


def _float(v: Any, what: str, problems: list[str]) -> float | None:
    try:
        return float(v)
    except (TypeError, ValueError):
        problems.append(f"{what}: expected a number, got {v!r}")
        return None


def _phase_block(d: Any, where: str, problems: list[str]) -> PhaseBlock | None:
    if not isinstance(d, dict):
        problems.append(f"{where}: expected a mapping with axis, period_px and steps or shifts_deg")
        return None
    unknown = set(d) - {"axis", "period_px", "steps", "shifts_deg", "encoding_gamma", "origin_px"}
    if unknown:
        problems.append(f"{where}: unknown keys {sorted(unknown)}")
    axis = d.get("axis")
    if axis not in ("x", "y"):
        problems.append(f"{where}: axis must be x (projector columns) or y (rows), got {axis!r}")
    period = _float(d.get("period_px"), f"{where}.period_px", problems)
    if period is not None and period <= 0:
        problems.append(f"{where}.period_px must be > 0, got {period}")
    if ("steps" in d) == ("shifts_deg" in d):
        problems.append(f"{where}: give exactly one of steps (equal shifts 2 pi n / N) or shifts_deg")
        shifts = None
    elif "steps" in d:
        n = d["steps"]
        if not isinstance(n, int) or n < 3:
            problems.append(f"{where}.steps must be an integer >= 3, got {n!r}")
            shifts = None
        else:
            shifts = tuple(float(v) for v in equal_shifts(n))
    else:
        sd = d["shifts_deg"]
        vals = [_float(v, f"{where}.shifts_deg", problems) for v in (sd if isinstance(sd, list) else [None])]
        shifts = None if None in vals else tuple(float(np.radians(v)) for v in vals)
        if shifts is not None:
            from huefringe.codecs.nstep import shift_matrix

            try:
                shift_matrix(shifts)
            except ValueError as exc:
                problems.append(f"{where}.shifts_deg: {exc}")
    eg = _float(d.get("encoding_gamma", 1.0), f"{where}.encoding_gamma", problems)
    origin = _float(d.get("origin_px", 0.0), f"{where}.origin_px", problems)
    if eg is not None and eg <= 0:
        problems.append(f"{where}.encoding_gamma must be > 0, got {eg}")
    if axis not in ("x", "y") or period is None or shifts is None or eg is None or origin is None:
        return None
    return PhaseBlock(axis, period, shifts, eg, origin)


def _gray_block(d: Any, where: str, problems: list[str]) -> GrayBlock | None:
    if not isinstance(d, dict):
        problems.append(f"{where}: expected a mapping with axis, cells or bits, cell_px")
        return None
    unknown = set(d) - {"axis", "cells", "bits", "cell_px", "inverse"}
    if unknown:
        problems.append(f"{where}: unknown keys {sorted(unknown)}")
    axis = d.get("axis")
    if axis not in ("x", "y"):
        problems.append(f"{where}: axis must be x or y, got {axis!r}")
    if ("cells" in d) == ("bits" in d):
        problems.append(f"{where}: give exactly one of cells (OpenCV: bits = ceil(log2(cells))) or bits")
        bits = None
    else:
        v = d.get("cells", d.get("bits"))
        if not isinstance(v, int) or v < (2 if "cells" in d else 1):
            problems.append(f"{where}: cells/bits must be a positive integer, got {v!r}")
            bits = None
        else:
            bits = bits_for(v) if "cells" in d else v
    cell = _float(d.get("cell_px", 1.0), f"{where}.cell_px", problems)
    inverse = d.get("inverse", True)
    if not isinstance(inverse, bool):
        problems.append(f"{where}.inverse must be true or false, got {inverse!r}")
    if axis not in ("x", "y") or bits is None or cell is None or not isinstance(inverse, bool):
        return None
    return GrayBlock(axis, bits, cell, inverse)


def load_sequence(path: str | Path, captures: str | Path | None = None) -> SequenceSpec:
    """Read a sequence YAML (module docstring); every problem in one :class:`SequenceError`.

    Parameters
    ----------
    path : path
        The YAML file.
    captures : path, optional
        The captures' folder: relative paths in the YAML (a kamino410 ``config``) are resolved
        against it, else against the YAML's folder.
    """
    path = Path(path)
    base = Path(captures) if captures is not None else path.parent
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise SequenceError(f"{path}: cannot read the sequence ({exc})") from None
    if not isinstance(doc, dict):
        raise SequenceError(f"{path}: expected a mapping with projector and blocks (or kamino410)")
    if "kamino410" in doc:
        k = doc["kamino410"]
        if not isinstance(k, dict) or set(k) != {"config", "program"}:
            raise SequenceError(f"{path}: kamino410 needs exactly config and program")
        spec = kamino410_sequence(base / str(k["config"]), k["program"])
        if "frames" in doc:
            spec = replace(spec, frames=str(doc["frames"]))
        if "projector" in doc and isinstance(doc["projector"], dict) and "gamma" in doc["projector"]:
            spec = replace(spec, projector_gamma=float(doc["projector"]["gamma"]))
        return spec
    problems: list[str] = []
    unknown = set(doc) - {"projector", "frames", "blocks"}
    if unknown:
        problems.append(f"unknown keys {sorted(unknown)} (projector, frames, blocks; or kamino410)")
    proj = doc.get("projector")
    w = h = None
    gamma = 1.0
    if not isinstance(proj, dict):
        problems.append("projector: expected a mapping with width, height (and gamma)")
    else:
        w, h = proj.get("width"), proj.get("height")
        if not isinstance(w, int) or not isinstance(h, int) or w < 2 or h < 2:
            problems.append(f"projector: width and height must be integers >= 2, got {w!r} x {h!r}")
        g = _float(proj.get("gamma", 1.0), "projector.gamma", problems)
        if g is not None and g <= 0:
            problems.append(f"projector.gamma must be > 0, got {g}")
        gamma = g if g else 1.0
    frames = doc.get("frames", "*.png")
    if not isinstance(frames, str) or not frames:
        problems.append(f"frames: expected a glob such as 'pat*.png', got {frames!r}")
    raw = doc.get("blocks")
    blocks: list[Block] = []
    if not isinstance(raw, list) or not raw:
        problems.append("blocks: expected a non-empty list of phase, gray, white, black")
        raw = []
    for i, item in enumerate(raw):
        where = f"blocks[{i}]"
        if item in ("white", "black"):
            blocks.append(FlatBlock(item))
        elif isinstance(item, dict) and len(item) == 1 and "phase" in item:
            b = _phase_block(item["phase"], f"{where}.phase", problems)
            blocks.append(b) if b else None
        elif isinstance(item, dict) and len(item) == 1 and "gray" in item:
            b = _gray_block(item["gray"], f"{where}.gray", problems)
            blocks.append(b) if b else None
        else:
            problems.append(f"{where}: expected phase: {{...}}, gray: {{...}}, white or black, got {item!r}")
    if not problems and not any(isinstance(b, PhaseBlock | GrayBlock) for b in blocks):
        problems.append("blocks: no phase or gray block: nothing to decode")
    if problems:
        raise SequenceError(f"{path}: " + "; ".join(problems))
    spec = SequenceSpec(tuple(blocks), int(w), int(h), float(gamma), str(frames))
    try:
        _check_spec(spec)
    except SequenceError as exc:
        raise SequenceError(f"{path}: {exc}") from None
    return spec


def _check_spec(spec: SequenceSpec) -> None:
    """Refuse a spec that cannot be decoded (all problems at once)."""
    problems = []
    flats = [b.level for b in spec.blocks if isinstance(b, FlatBlock)]
    needs_flats = any(isinstance(b, GrayBlock) and not b.inverse for b in spec.blocks)
    if needs_flats and not ({"white", "black"} <= set(flats)):
        problems.append("a Gray code without inverses needs a white and a black frame")
    for axis in spec.axes():
        if not any(isinstance(b, PhaseBlock) and b.axis == axis for b in spec.blocks):
            problems.append(f"axis {axis}: a Gray code without a phase block (decode it with decode_gray)")
        if sum(isinstance(b, GrayBlock) and b.axis == axis for b in spec.blocks) > 1:
            problems.append(f"axis {axis}: more than one Gray block")
    if problems:
        raise SequenceError("; ".join(problems))


_NUM = re.compile(r"(\d+)")


def _frame_key(p: Path) -> tuple[int, str]:
    nums = _NUM.findall(p.stem)
    return (int(nums[-1]) if nums else -1, p.name)


def read_captures(folder: str | Path, spec: SequenceSpec) -> list[NDArray[np.number]]:
    """The captures of ``spec.frames`` in ``folder``, grayscale, sorted by the last number in their names.

    Colour captures are converted to grayscale (OpenCV's BGR -> gray weights).

    Raises
    ------
    SequenceError
        Naming the folder or file: a wrong count, an unreadable file, mixed sizes or dtypes.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SequenceError(f"{folder}: not a folder of captures")
    files = sorted(folder.glob(spec.frames), key=_frame_key)
    if len(files) != spec.n_frames:
        raise SequenceError(
            f"{folder}: {len(files)} files match {spec.frames!r}, the sequence has {spec.n_frames} frames "
            f"({', '.join(type(b).__name__ + '[' + str(b.n_frames) + ']' for b in spec.blocks)})"
        )
    problems, images = [], []
    for f in files:
        im = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        if im is None:
            problems.append(f"{f}: not an image OpenCV can read")
            continue
        if im.ndim == 3:
            im = cv2.cvtColor(im[..., :3], cv2.COLOR_BGR2GRAY)
        if im.dtype not in (np.uint8, np.uint16):
            problems.append(f"{f}: {im.dtype} pixels (8- or 16-bit integers expected)")
            continue
        images.append((f, im))
    if images:
        f0, ref = images[0]
        for f, im in images[1:]:
            if im.shape != ref.shape or im.dtype != ref.dtype:
                problems.append(f"{f}: {im.shape} {im.dtype}, {f0.name} is {ref.shape} {ref.dtype}")
    if problems:
        raise SequenceError("; ".join(problems))
    return [im for _, im in images]


def generate(spec: SequenceSpec, dtype: type[np.integer] = np.uint8) -> NDArray[np.integer]:
    """The projector images of ``spec`` in capture order, shape (n_frames, height, width).

    Examples
    --------
    >>> spec = SequenceSpec((PhaseBlock("x", 16.0, tuple(equal_shifts(4))), FlatBlock("white")), 64, 8)
    >>> generate(spec).shape, int(generate(spec)[0, 0, 0]), int(generate(spec)[2, 0, 0])
    ((5, 8, 64), 255, 0)
    """
    full = float(np.iinfo(dtype).max)
    h, w = spec.projector_height, spec.projector_width
    out = np.empty((spec.n_frames, h, w), dtype)
    coords = {"x": np.arange(w, dtype=np.float64)[None, :], "y": np.arange(h, dtype=np.float64)[:, None]}
    for b, sl in spec.slices():
        if isinstance(b, FlatBlock):
            out[sl] = full if b.level == "white" else 0
        elif isinstance(b, PhaseBlock):
            u = coords[b.axis]
            for i, d in zip(range(sl.start, sl.stop), b.shifts_rad, strict=True):
                v = (0.5 + 0.5 * np.cos(TWO_PI * (u - b.origin_px) / b.period_px + d)) ** b.encoding_gamma
                out[i] = np.broadcast_to(np.round(v * full), (h, w))
        else:
            g = index_to_gray(np.floor(coords[b.axis] / b.cell_px).astype(np.int64))
            i = sl.start
            for k in range(b.bits - 1, -1, -1):
                bit = np.broadcast_to(((g >> k) & 1).astype(bool), (h, w))
                out[i] = np.where(bit, full, 0)
                i += 1
                if b.inverse:
                    out[i] = np.where(bit, 0, full)
                    i += 1
    return out


def _as_stack(images: list[NDArray[np.number]] | NDArray[np.number], spec: SequenceSpec) -> tuple[NDArray, float]:
    if isinstance(images, np.ndarray):
        stack = images
    else:
        shapes = {np.shape(im) for im in images}
        if len(shapes) != 1:
            raise SequenceError(f"captures of different shapes {sorted(shapes)}")
        stack = np.stack(images)
    if stack.ndim != 3:
        raise SequenceError(f"expected grayscale captures (n_frames, H, W), got shape {stack.shape}")
    if stack.shape[0] != spec.n_frames:
        raise SequenceError(f"{stack.shape[0]} captures, the sequence has {spec.n_frames} frames")
    full = 65535.0 if stack.dtype == np.uint16 else 255.0
    return stack, full


def _gray_reference(
    stack: NDArray, block: GrayBlock, sl: slice, flats: dict[str, NDArray], longest: float, cells: int, opts: DecodeOptions, scale: float
) -> tuple[NDArray[np.float64], NDArray[np.bool_], float]:
    """The Gray code's cell-centre coordinate, decoded to the bits a period ``longest`` needs."""
    drop = 0
    while drop < block.bits - 1 and block.cell_px * 2 ** (drop + 1) <= longest / 3.0:
        drop += 1
    use = block.bits - drop
    frames = stack[sl]
    if block.inverse:
        dec = decode_gray(frames[0::2], opts.min_gray_contrast_dn * scale, inverse=frames[1::2], use_bits=use)
    else:
        ref = 0.5 * (flats["white"].astype(np.float32) + flats["black"].astype(np.float32))
        dec = decode_gray(frames, opts.min_gray_contrast_dn * scale, reference=ref, use_bits=use)
    cell = block.cell_px * 2**drop
    n_eff = -(-cells // 2**drop)
    centre = dec.index * cell + 0.5 * (cell - 1.0) if cell >= 1 else (dec.index + 0.5) * cell
    return centre.astype(np.float64), dec.valid & (dec.index < n_eff), cell


def _stages(periods: list[float]) -> list[tuple[float, tuple[int, ...]]]:
    """Coarse-to-fine stages: the distinct periods and their heterodyne beats (index tuples)."""
    q = sorted(set(periods), reverse=True)
    st: list[tuple[float, tuple[int, ...]]] = [(p, (periods.index(p),)) for p in q]
    if len(q) >= 2:
        beats = []
        for a, b in zip(q[:-1], q[1:], strict=True):
            pb = a * b / (a - b)
            beats.append(pb)
            st.append((pb, (periods.index(a), periods.index(b))))
        if len(beats) == 2 and beats[0] != beats[1]:
            st.append((beats[0] * beats[1] / abs(beats[0] - beats[1]), ()))
    return sorted(st, key=lambda s: -s[0])


def _decode_axis(
    stack: NDArray, spec: SequenceSpec, axis: Axis, flats: dict[str, NDArray], noise: NoiseModel, opts: DecodeOptions, full: float
) -> Decoded:
    scale = full / 255.0
    blocks = [(b, sl) for b, sl in spec.slices() if isinstance(b, PhaseBlock) and b.axis == axis]
    phases = [wrapped_phase(stack[sl], b.shifts_rad, noise, gamma=b.encoding_gamma * spec.projector_gamma) for b, sl in blocks]
    periods = [b.period_px for b, _ in blocks]
    # wrapped coordinates u mod P (origins folded in) and their standard uncertainties (px)
    wraps = [np.mod(b.origin_px + p.phase * (b.period_px / TWO_PI), b.period_px) for (b, _), p in zip(blocks, phases, strict=True)]
    sig = [p.sigma.astype(np.float64) * (b.period_px / TWO_PI) for (b, _), p in zip(blocks, phases, strict=True)]
    valid = np.ones(stack.shape[1:], bool)
    for p in phases:
        valid &= p.modulation >= opts.min_modulation_dn * scale
    for _, sl in blocks:  # a clipped frame is no sinusoid
        valid &= stack[sl].max(axis=0) < full
    margin = np.zeros(stack.shape[1:], np.float64)
    extent = spec.extent(axis)

    stages = _stages(periods)
    beat_w: dict[tuple[int, ...], NDArray[np.float64]] = {}

    def stage_wrap(pst: float, idx: tuple[int, ...]) -> NDArray[np.float64]:
        if len(idx) == 1:
            return wraps[idx[0]]
        if len(idx) == 2:
            w, _ = heterodyne(wraps[idx[0]], periods[idx[0]], wraps[idx[1]], periods[idx[1]])
            beat_w[idx] = w
            return w
        two = [(p, i) for p, i in stages if len(i) == 2]
        for _, i in two:
            if i not in beat_w:
                stage_wrap(0.0, i)
        w, _ = heterodyne(beat_w[two[0][1]], two[0][0], beat_w[two[1][1]], two[1][0])
        return w

    gray = [(b, sl) for b, sl in spec.slices() if isinstance(b, GrayBlock) and b.axis == axis]
    absolute = True
    ref: NDArray[np.float64] | None = None
    if gray:
        gb, gsl = gray[0]
        cells = int(np.ceil(extent / gb.cell_px))
        full_cell = gb.cell_px
        # start at the finest stage the full Gray code resolves with room to spare, else the coarsest
        start = next((i for i in range(len(stages) - 1, -1, -1) if stages[i][0] >= 3.0 * full_cell), 0)
        ref, gvalid, _ = _gray_reference(stack, gb, gsl, flats, stages[start][0], cells, opts, scale)
        valid &= gvalid
        chain = stages[start:]
    elif stages[0][0] >= extent:
        ref = stage_wrap(*stages[0])
        chain = stages[1:]
    elif len(set(periods)) >= 2:
        uniq = sorted(set(periods))
        idx = [periods.index(p) for p in uniq]
        ref, m = number_theoretic([wraps[i] for i in idx], uniq, [sig[i] for i in idx], extent)
        margin = np.maximum(margin, m)
        chain = []
    else:
        absolute = False
        chain = []
    if ref is not None:
        for pst, idx in chain:
            ref, m = orders_from_reference(stage_wrap(pst, idx), pst, ref)
            margin = np.maximum(margin, m)
        coords = []
        for w, pp in zip(wraps, periods, strict=True):
            c, m = orders_from_reference(w, pp, ref)
            margin = np.maximum(margin, m)
            coords.append(c)
    else:
        finest = int(np.argmin(periods))
        coords = [wraps[finest]]
        sig = [sig[finest]]
    inv = [1.0 / np.maximum(s, 1e-12) ** 2 for s in sig]
    wsum = np.sum(inv, axis=0)
    coord = np.sum([c * i for c, i in zip(coords, inv, strict=True)], axis=0) / wsum
    sigma = 1.0 / np.sqrt(wsum)
    valid &= margin < opts.order_tolerance
    valid &= np.isfinite(coord) & np.isfinite(sigma)
    coord = np.where(valid, coord, np.nan)
    sigma = np.where(valid, sigma, np.nan)
    finest = int(np.argmin(periods))
    return Decoded(
        axis=axis,
        coord=coord,
        sigma=sigma,
        modulation=phases[finest].modulation,
        valid=valid,
        order_margin=margin.astype(np.float32),
        absolute=absolute,
        phases=tuple(phases),
    )


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
        Thresholds and noise model; default the configuration's ``codecs`` block. Thresholds and
        read noise are on an 8-bit scale, multiplied by 257 for 16-bit captures.

    Returns
    -------
    dict
        ``{"x": Decoded, "y": Decoded}`` for the axes the sequence encodes.

    Raises
    ------
    SequenceError
        A wrong number or shape of captures, or a spec that cannot be decoded.
    """
    opts = options if options is not None else DecodeOptions.from_config()
    _check_spec(spec)
    stack, full = _as_stack(images, spec)
    scale = full / 255.0
    noise = opts.noise(full)
    noise = NoiseModel(noise.read_dn * scale, noise.full_well_e, full)
    flats: dict[str, NDArray] = {}
    for b, sl in spec.slices():
        if isinstance(b, FlatBlock) and b.level not in flats:
            flats[b.level] = stack[sl.start]
    return {axis: _decode_axis(stack, spec, axis, flats, noise, opts, full) for axis in spec.axes()}
