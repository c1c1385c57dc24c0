"""A structured-light sequence's description: its phase, Gray and flat blocks, loading and writing it, the rigs' stock sequences."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal
from xml.etree import ElementTree

import numpy as np
import yaml
from numpy.typing import NDArray

from huefringe.codecs.graycode import bits_for
from huefringe.codecs.nstep import TWO_PI, NoiseModel, WrappedPhase, equal_shifts


Axis = Literal["x", "y"]


class SequenceError(ValueError):
    """A sequence description or a folder of captures that cannot be decoded (names the file)."""


class Reason(enum.IntFlag):
    """Why a decoded pixel is not valid: the bits of :attr:`Decoded.reasons` (0 = valid).

    ``SHADOW``
        No direct projector light: the white - black difference (without white/black frames:
        the Gray code's pattern - inverse difference, else twice the phase blocks' modulation)
        below ``min_direct_dn``, or, without white/black frames, a phase block's modulation below
        ``min_fringe_contrast`` times its mean.
    ``LOW_SIGNAL``
        A phase block's modulation below ``min_modulation_dn`` or below ``min_snr`` times its own
        standard uncertainty (from the pixel's noise: ``1 / sigma_phase``).
    ``SATURATED``
        A phase frame at or above ``saturation_dn``.
    ``GRAY``
        The Gray code unreadable: a bit closer to its threshold than ``min_gray_contrast_dn``
        (all bits but one with a phase block to absorb a one-cell miss, every bit without), or a
        cell beyond the code.
    ``ORDER``
        A fringe-order decision missed its integer by ``order_tolerance`` or more (an unwrapping
        failure), or the coordinate is not finite.
    ``OUTSIDE``
        The absolute coordinate lies outside the projector.
    ``RAY``
        Set after triangulation, where both projector axes are decoded: the camera ray and the
        projector ray of ``(u, v)`` do not meet. The decoded projector pixel lies farther from
        the camera pixel's epipolar line than ``max_ray_sigma`` times the distance's standard
        uncertainty from ``sigma_u, sigma_v``, and farther than ``ray_floor_px``
        (:func:`huefringe.rig.triangulation.epipolar_residual`).
    """

    SHADOW = 1
    LOW_SIGNAL = 2
    SATURATED = 4
    GRAY = 8
    ORDER = 16
    OUTSIDE = 32
    RAY = 64


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

    Projector pixel ``u`` lies in cell ``floor(u / cell_px)``. With ``inverse`` (the default)
    each pattern is followed by its inverse (OpenCV's layout); without, bits are read against the
    mean of the sequence's white and black frames, or, without those, against the mean of the
    same axis' phase-shift frames.

    ``complementary`` adds one pattern after the ``bits`` patterns (two with ``inverse``): the
    last bit of the ``bits + 1``-bit Gray code of cells ``cell_px / 2``, whose stripes are half as
    wide as the finest cell's (Zhang, Su et al., Opt. Lasers Eng. 50 (2012) 574, the complementary
    Gray code). It needs a phase block of period ``cell_px`` on the same axis: the fringe order
    is the ``bits``-bit cell ``k1`` in the middle half of each period and ``k2 = (V2 + 1) // 2``
    of the ``bits + 1``-bit code ``V2`` in the quarters at its edges (``k2 - 1`` in the last
    quarter), so that neither code is read near its own stripe edges.
    """

    axis: Axis
    bits: int
    cell_px: float
    inverse: bool = True
    complementary: bool = False

    @property
    def n_frames(self) -> int:
        return self.code_bits * (2 if self.inverse else 1)

    @property
    def code_bits(self) -> int:
        """Patterns of the block (without inverses): ``bits``, plus one when complementary."""
        return self.bits + int(self.complementary)

    @property
    def code_cell_px(self) -> float:
        """The finest stripe's width: ``cell_px``, halved when complementary."""
        return self.cell_px / 2.0 if self.complementary else self.cell_px


@dataclass(frozen=True)
class SkipBlock:
    """Frames captured but not used (a colour frame, hue bands, a rig's own extras): ``frames`` of them."""

    frames: int

    @property
    def n_frames(self) -> int:
        return self.frames


@dataclass(frozen=True)
class FlatBlock:
    """A uniform white or black projector image."""

    level: Literal["white", "black"]

    @property
    def n_frames(self) -> int:
        return 1


@dataclass(frozen=True)
class TrapezoidBlock:
    """One-shot colour frames: the paper's trapezoidal RGB fringe (eq. 3) of one period along one axis.

    Each of the ``frames`` captures (one per instant of a moving object) shows
    :func:`huefringe.patterns.trapezoid_rgb` at code phase ``2 pi (u - origin_px) / period_px``,
    ``u`` the projector column (axis ``x``) or row (axis ``y``). Decoded through the per-pixel hue
    table of the sequence's :class:`HueBandsBlock` and white frame
    (:mod:`huefringe.rig.oneshot`), never by :func:`decode_sequence`.
    """

    axis: Axis
    period_px: float
    origin_px: float = 0.0
    frames: int = 1
    travel_mm: tuple[float, float] | None = None
    """The working volume, when the sequence declares one: how far each pixel's surface may stand in
    front of (towards the camera) and behind the point where the order reference saw it, mm along
    the camera ray. With it the order is the one candidate inside that volume and a pixel with none
    or several is flagged (:func:`huefringe.rig.oneshot.absolute_from_reference`)."""

    @property
    def n_frames(self) -> int:
        return self.frames


@dataclass(frozen=True)
class HueBandsBlock:
    """The paper's hue bands (sect. 2.3): ``n`` uniform colours, band ``i`` the trapezoid of eq. 3 at
    code phase ``2 pi i / n``, each captured ``repeats`` times in a row (band-major: band ``i``,
    repeat ``r`` is frame ``i * repeats + r`` of the block). With the sequence's white frame they
    build the per-pixel hue table (:func:`huefringe.huetable.build_table`)."""

    n: int
    repeats: int = 1

    @property
    def n_frames(self) -> int:
        return self.n * self.repeats


Block = PhaseBlock | GrayBlock | FlatBlock | SkipBlock | TrapezoidBlock | HueBandsBlock


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
    frames : str or tuple of str
        Glob of the captures inside a folder, sorted by the last number in their names; or the
        file names in capture order, one per frame (a folder with other files, or names whose
        numbers do not give the order, used as it is).
    """

    blocks: tuple[Block, ...]
    projector_width: int
    projector_height: int
    projector_gamma: float = 1.0
    frames: str | tuple[str, ...] = "*.png"

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

    @property
    def oneshot_frames(self) -> int:
        """One-shot colour frames of the sequence: the ``trapezoid`` blocks' frames (0: a coded sequence)."""
        return sum(b.frames for b in self.blocks if isinstance(b, TrapezoidBlock))

    def axes(self) -> list[Axis]:
        """The projector axes the sequence encodes (``x`` before ``y``)."""
        have = {b.axis for b in self.blocks if isinstance(b, PhaseBlock | GrayBlock)}
        return [a for a in ("x", "y") if a in have]

    def extent(self, axis: Axis) -> int:
        """Projector pixels along ``axis``."""
        return self.projector_width if axis == "x" else self.projector_height


@dataclass(frozen=True)
class DecodeOptions:
    """Thresholds and the camera noise model of :func:`decode_sequence` (``codecs`` in the configuration).

    DN values are on an 8-bit scale (times 257 for 16-bit captures); :class:`Reason` says which
    test each threshold drives. ``min_valid_fraction`` is the smallest valid fraction of an axis
    with which ``huefringe decode`` ends OK.
    """

    min_modulation_dn: float
    min_gray_contrast_dn: float
    order_tolerance: float
    read_noise_dn: float
    full_well_e: float | None
    min_direct_dn: float = 0.0
    min_fringe_contrast: float = 0.0
    min_snr: float = 0.0
    saturation_dn: float = 255.0
    min_valid_fraction: float = 0.0

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
            min_direct_dn=float(c.get("min_direct_dn", 0.0)),
            min_fringe_contrast=float(c.get("min_fringe_contrast", 0.0)),
            min_snr=float(c.get("min_snr", 0.0)),
            saturation_dn=float(c.get("saturation_dn", 255.0)),
            min_valid_fraction=float(c.get("min_valid_fraction", 0.0)),
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
        A Gray-code-only axis gives the centre of the decoded cell with ``cell_px / sqrt(12)``
        (uniform quantisation).
    modulation : ndarray of float32
        Fringe amplitude (camera DN) of the axis' finest phase block: the data-quality map; on a
        Gray-code-only axis the code's contrast (smallest ``|pattern - reference|`` over its bits).
    valid : ndarray of bool
        ``reasons == 0``: every test of :class:`Reason` passed.
    order_margin : ndarray of float32
        Largest fraction of a period by which an order decision missed its integer (0 .. 0.5).
    absolute : bool
        False when the sequence carries nothing beyond one period (a lone phase block): such a
        coordinate is never triangulated (:func:`huefringe.rig.decoded.triangulation_inputs`).
    reasons : ndarray of uint8
        Per pixel, the :class:`Reason` bits of every test that failed (0 where valid).
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
    reasons: NDArray[np.uint8] = field(repr=False, default_factory=lambda: np.zeros((0, 0), np.uint8))
    phases: tuple[WrappedPhase, ...] = field(repr=False, default=())


def opencv_gray_blocks(width: int, height: int, cell_px: float = 1.0) -> tuple[GrayBlock, GrayBlock]:
    """The x and y blocks of OpenCV's ``GrayCodePattern.create(width, height)`` (cells, not px).

    Examples
    --------
    >>> opencv_gray_blocks(20, 11, 100)[0]
    GrayBlock(axis='x', bits=5, cell_px=100, inverse=True, complementary=False)
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
    if period is not None and not (np.isfinite(period) and period > 0):
        problems.append(f"{where}.period_px must be a finite number > 0, got {period}")
        period = None
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
    if eg is not None and not (np.isfinite(eg) and eg > 0):
        problems.append(f"{where}.encoding_gamma must be a finite number > 0, got {eg}")
        eg = None
    if origin is not None and not np.isfinite(origin):
        problems.append(f"{where}.origin_px must be finite, got {origin}")
        origin = None
    if axis not in ("x", "y") or period is None or shifts is None or eg is None or origin is None:
        return None
    return PhaseBlock(axis, period, shifts, eg, origin)


def _gray_block(d: Any, where: str, problems: list[str]) -> GrayBlock | None:
    if not isinstance(d, dict):
        problems.append(f"{where}: expected a mapping with axis, cells or bits, cell_px")
        return None
    unknown = set(d) - {"axis", "cells", "bits", "cell_px", "inverse", "complementary"}
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
    if cell is not None and not (np.isfinite(cell) and cell > 0):
        problems.append(f"{where}.cell_px must be a finite number > 0, got {cell}")
        cell = None
    inverse = d.get("inverse", True)
    if not isinstance(inverse, bool):
        problems.append(f"{where}.inverse must be true or false, got {inverse!r}")
    comp = d.get("complementary", False)
    if not isinstance(comp, bool):
        problems.append(f"{where}.complementary must be true or false, got {comp!r}")
    if axis not in ("x", "y") or bits is None or cell is None or not isinstance(inverse, bool) or not isinstance(comp, bool):
        return None
    return GrayBlock(axis, bits, cell, inverse, comp)


def _trapezoid_block(d: Any, where: str, problems: list[str]) -> TrapezoidBlock | None:
    if not isinstance(d, dict):
        problems.append(f"{where}: expected a mapping with axis, period_px (origin_px, frames)")
        return None
    unknown = set(d) - {"axis", "period_px", "origin_px", "frames", "travel_mm"}
    if unknown:
        problems.append(f"{where}: unknown keys {sorted(unknown)} (axis, period_px, origin_px, frames, travel_mm)")
    axis = d.get("axis")
    if axis not in ("x", "y"):
        problems.append(f"{where}: axis must be x (projector columns) or y (rows), got {axis!r}")
    period = _float(d.get("period_px"), f"{where}.period_px", problems)
    if period is not None and not (np.isfinite(period) and period >= 6):
        problems.append(f"{where}.period_px must be a finite number >= 6 (six sextants of eq. 3), got {period}")
        period = None
    origin = _float(d.get("origin_px", 0.0), f"{where}.origin_px", problems)
    if origin is not None and not np.isfinite(origin):
        problems.append(f"{where}.origin_px must be finite, got {origin}")
        origin = None
    n = d.get("frames", 1)
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        problems.append(f"{where}.frames: the number of one-shot frames, an integer >= 1, got {n!r}")
        n = None
    travel: tuple[float, float] | None = None
    if "travel_mm" in d:
        t = d["travel_mm"]
        f = _float(t.get("front"), f"{where}.travel_mm.front", problems) if isinstance(t, dict) else None
        b = _float(t.get("back"), f"{where}.travel_mm.back", problems) if isinstance(t, dict) else None
        if not isinstance(t, dict) or set(t) != {"front", "back"}:
            problems.append(f"{where}.travel_mm: expected {{front: mm, back: mm}} (how far the surface may stand in "
                            f"front of and behind the order reference along each camera ray), got {t!r}")
        elif f is not None and b is not None:
            if not (np.isfinite(f) and np.isfinite(b) and f >= 0 and b >= 0 and f + b > 0):
                problems.append(f"{where}.travel_mm: front and back must be finite, >= 0 and not both 0, got {f}, {b}")
            else:
                travel = (float(f), float(b))
        if travel is None:
            return None
    if axis not in ("x", "y") or period is None or origin is None or n is None:
        return None
    return TrapezoidBlock(axis, period, origin, n, travel)


def _hue_bands_block(d: Any, where: str, problems: list[str]) -> HueBandsBlock | None:
    if not isinstance(d, dict):
        problems.append(f"{where}: expected a mapping with n (and repeats)")
        return None
    unknown = set(d) - {"n", "repeats"}
    if unknown:
        problems.append(f"{where}: unknown keys {sorted(unknown)} (n, repeats)")
    n, r = d.get("n"), d.get("repeats", 1)
    ok = True
    if not isinstance(n, int) or isinstance(n, bool) or n < 12:
        problems.append(f"{where}.n: the number of hue bands, an integer >= 12 (two per sextant), got {n!r}")
        ok = False
    if not isinstance(r, int) or isinstance(r, bool) or r < 1:
        problems.append(f"{where}.repeats: captures of each band, an integer >= 1, got {r!r}")
        ok = False
    return HueBandsBlock(n, r) if ok else None


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
    return sequence_from_mapping(doc, path, base)


def sequence_from_mapping(doc: Any, path: str | Path, base: str | Path) -> SequenceSpec:
    """A :class:`SequenceSpec` from the parsed YAML form (module docstring) read from ``path``.

    Parameters
    ----------
    doc : mapping
        The parsed YAML document.
    path : path
        The file it came from (named in every refusal).
    base : path
        The folder a kamino410 ``config`` path is relative to.
    """
    path, base = Path(path), Path(base)
    if not isinstance(doc, dict):
        raise SequenceError(f"{path}: expected a mapping with projector and blocks (or kamino410)")
    if "kamino410" in doc:
        k = doc["kamino410"]
        if not isinstance(k, dict) or set(k) != {"config", "program"}:
            raise SequenceError(f"{path}: kamino410 needs exactly config and program")
        spec = kamino410_sequence(base / str(k["config"]), k["program"])
        if "frames" in doc:
            kp: list[str] = []
            spec = replace(spec, frames=_frames(doc["frames"], spec.n_frames, kp))
            if kp:
                raise SequenceError(f"{path}: " + "; ".join(kp))
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
    raw = doc.get("blocks")
    blocks: list[Block] = []
    if not isinstance(raw, list) or not raw:
        problems.append("blocks: expected a non-empty list of phase, gray, trapezoid, hue_bands, skip, white, black")
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
        elif isinstance(item, dict) and len(item) == 1 and "trapezoid" in item:
            b = _trapezoid_block(item["trapezoid"], f"{where}.trapezoid", problems)
            blocks.append(b) if b else None
        elif isinstance(item, dict) and len(item) == 1 and "hue_bands" in item:
            b = _hue_bands_block(item["hue_bands"], f"{where}.hue_bands", problems)
            blocks.append(b) if b else None
        elif isinstance(item, dict) and len(item) == 1 and "skip" in item:
            n = item["skip"]
            if not isinstance(n, int) or isinstance(n, bool) or n < 1:
                problems.append(f"{where}.skip: the number of frames to skip, an integer >= 1, got {n!r}")
            else:
                blocks.append(SkipBlock(n))
        else:
            problems.append(f"{where}: expected phase: {{...}}, gray: {{...}}, trapezoid: {{...}}, hue_bands: {{...}}, "
                            f"skip: N, white or black, got {item!r}")
    if not problems and not any(isinstance(b, PhaseBlock | GrayBlock | TrapezoidBlock) for b in blocks):
        problems.append("blocks: no phase, gray or trapezoid block: nothing to decode")
    frames = _frames(frames, None if problems else sum(b.n_frames for b in blocks), problems)
    if problems:
        raise SequenceError(f"{path}: " + "; ".join(problems))
    spec = SequenceSpec(tuple(blocks), int(w), int(h), float(gamma), frames)
    try:
        _check_spec(spec)
    except SequenceError as exc:
        raise SequenceError(f"{path}: {exc}") from None
    return spec


def _frames(v: Any, n_frames: int | None, problems: list[str]) -> str | tuple[str, ...]:
    """``frames``: a glob, or a list of file names in capture order (no duplicates, one per frame)."""
    if isinstance(v, str) and v:
        return v
    if not isinstance(v, list) or not v:
        problems.append(f"frames: expected a glob such as 'pat*.png' or a list of file names in capture order, got {v!r}")
        return "*.png"
    bad = [f for f in v if not isinstance(f, str) or not f or "/" in f or "\\" in f]
    if bad:
        problems.append(f"frames: file names inside the captures' folder expected, got {', '.join(map(repr, bad))}")
    names = [f for f in v if isinstance(f, str)]
    dup = sorted({f for f in names if names.count(f) > 1})
    if dup:
        problems.append(f"frames: {', '.join(dup)} listed more than once")
    if n_frames is not None and len(v) != n_frames:
        problems.append(f"frames: {len(v)} file names, the blocks have {n_frames} frames")
    return tuple(names)


def _check_spec(spec: SequenceSpec) -> None:
    """Refuse a spec that cannot be decoded (all problems at once)."""
    problems = []
    flats = {b.level for b in spec.blocks if isinstance(b, FlatBlock)}
    for axis in spec.axes():
        grays = [b for b in spec.blocks if isinstance(b, GrayBlock) and b.axis == axis]
        has_phase = any(isinstance(b, PhaseBlock) and b.axis == axis for b in spec.blocks)
        if len(grays) > 1:
            problems.append(f"axis {axis}: more than one Gray block")
        if any(not g.inverse for g in grays) and not {"white", "black"} <= flats and not has_phase:
            problems.append(f"axis {axis}: a Gray code without inverses is read against the white and black "
                            "frames' mean or the same axis' phase frames' mean; the sequence has neither")
        periods = [b.period_px for b in spec.blocks if isinstance(b, PhaseBlock) and b.axis == axis]
        for g in grays:
            if g.complementary and not any(np.isclose(p, g.cell_px, rtol=1e-9, atol=1e-9) for p in periods):
                have = ", ".join(f"{p:g}" for p in periods) or "none"
                problems.append(f"axis {axis}: a complementary Gray code needs a phase block of period_px equal to "
                                f"its cell_px {g.cell_px:g} on the same axis (the edge quarters of each period choose "
                                f"its extra bit); phase periods on axis {axis}: {have}")
    problems += _oneshot_problems(spec)
    if problems:
        raise SequenceError("; ".join(problems))


def _oneshot_problems(spec: SequenceSpec) -> list[str]:
    """What the one-shot blocks need: a trapezoid frame is decoded through the hue table of one
    ``hue_bands`` block and the white frame (the white balance of the bands and of every frame)."""
    traps = [b for b in spec.blocks if isinstance(b, TrapezoidBlock)]
    bands = [b for b in spec.blocks if isinstance(b, HueBandsBlock)]
    white = any(isinstance(b, FlatBlock) and b.level == "white" for b in spec.blocks)
    out = []
    if len(bands) > 1:
        out.append("more than one hue_bands block (one per-pixel hue table per sequence)")
    if (traps or bands) and not white:
        out.append("hue_bands and trapezoid frames are white-balanced against the sequence's white frame; "
                   "the sequence has none")
    if traps and not bands:
        out.append("a trapezoid block is decoded through the per-pixel hue table of a hue_bands block; "
                   "the sequence has none")
    if len({(b.axis, b.period_px, b.origin_px) for b in traps}) > 1:
        out.append("trapezoid blocks of different axes, periods or origins (one hue table decodes one pattern)")
    if len({b.travel_mm for b in traps}) > 1:
        out.append("trapezoid blocks with different travel_mm (one working volume per scene)")
    return out


def axis_is_absolute(spec: SequenceSpec, axis: Axis) -> bool:
    """Whether ``spec`` decodes an absolute coordinate along ``axis`` (a Gray code, a period or beat
    covering the projector, or two distinct periods), as :func:`decode_sequence` does.

    Examples
    --------
    >>> d = tuple(equal_shifts(4))
    >>> axis_is_absolute(SequenceSpec((PhaseBlock("x", 16.0, d),), 64, 8), "x")
    False
    >>> axis_is_absolute(SequenceSpec((PhaseBlock("x", 16.0, d), PhaseBlock("x", 20.0, d)), 64, 8), "x")
    True
    """
    if any(isinstance(b, GrayBlock) and b.axis == axis for b in spec.blocks):
        return True
    periods = sorted({b.period_px for b in spec.blocks if isinstance(b, PhaseBlock) and b.axis == axis}, reverse=True)
    if not periods:
        return False
    if periods[0] >= spec.extent(axis):
        return True
    if len(periods) >= 2:
        from huefringe.codecs.sequence._decode import _stages

        return _stages(periods)[0][0] >= spec.extent(axis) or periods_cover(periods, spec.extent(axis))
    return False


def periods_cover(periods: list[float], extent: float, separation: float = 0.05) -> bool:
    """Whether several periods tell every coordinate in ``[0, extent)`` from every other.

    Two coordinates ``D`` apart (``D`` a multiple of the finest period, up to ``extent`` less half
    that period) look alike to the number-theoretic search unless some period sees them at least
    ``separation`` of itself apart; 18 and 20 px, for instance, repeat every 180 px.

    Examples
    --------
    >>> periods_cover([18.0, 20.0], 1024), periods_cover([20.0, 23.0, 29.0], 1024)
    (False, True)
    """
    p0 = min(periods)
    k = 1
    while (d := k * p0) <= extent - 0.5 * p0:
        k += 1
        worst = max(abs(d / p - np.round(d / p)) for p in periods)
        if worst < separation:
            return False
    return True


def sequence_to_mapping(spec: SequenceSpec) -> dict[str, Any]:
    """The explicit YAML form of ``spec`` (``projector``, ``frames``, ``blocks``), read back by
    :func:`sequence_from_mapping` into an equivalent spec (shifts in degrees to 12 significant digits).

    Examples
    --------
    >>> spec = SequenceSpec((PhaseBlock("x", 16.0, tuple(equal_shifts(4))), FlatBlock("white")), 64, 8)
    >>> sequence_to_mapping(spec)["blocks"][1]
    'white'
    """
    blocks: list[Any] = []
    for b in spec.blocks:
        if isinstance(b, FlatBlock):
            blocks.append(b.level)
        elif isinstance(b, SkipBlock):
            blocks.append({"skip": int(b.frames)})
        elif isinstance(b, TrapezoidBlock):
            trap: dict[str, Any] = {"axis": b.axis, "period_px": float(b.period_px), "origin_px": float(b.origin_px),
                                    "frames": int(b.frames)}
            if b.travel_mm is not None:
                trap["travel_mm"] = {"front": float(b.travel_mm[0]), "back": float(b.travel_mm[1])}
            blocks.append({"trapezoid": trap})
        elif isinstance(b, HueBandsBlock):
            blocks.append({"hue_bands": {"n": int(b.n), "repeats": int(b.repeats)}})
        elif isinstance(b, PhaseBlock):
            blocks.append({"phase": {"axis": b.axis, "period_px": float(b.period_px),
                                     "shifts_deg": [float(f"{np.degrees(d):.12g}") for d in b.shifts_rad],
                                     "encoding_gamma": float(b.encoding_gamma), "origin_px": float(b.origin_px)}})
        else:
            gray = {"axis": b.axis, "bits": int(b.bits), "cell_px": float(b.cell_px), "inverse": bool(b.inverse)}
            if b.complementary:
                gray["complementary"] = True
            blocks.append({"gray": gray})
    return {"projector": {"width": int(spec.projector_width), "height": int(spec.projector_height),
                          "gamma": float(spec.projector_gamma)},
            "frames": spec.frames if isinstance(spec.frames, str) else list(spec.frames), "blocks": blocks}
