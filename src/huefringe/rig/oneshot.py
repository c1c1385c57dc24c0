"""One-shot colour frames on a calibrated rig: the paper's trapezoid to absolute X, Y, Z.

Chen, Nguyen & Shu's method measures from one trapezoidal RGB fringe per instant: the captured,
white-balanced hue of a pixel goes through the pixel's own hue table (built from ``N`` uniform
hue bands, :mod:`huefringe.huetable`) back to the projected code phase, so the projector gamma,
the camera's crosstalk and the surface colour drop out pixel by pixel. The code phase gives the
projector coordinate within one period only. On a calibrated projector-camera rig
(:class:`~huefringe.rig.RigCalibration`) this module

1. decodes a trapezoid frame to the projector coordinate modulo the period with its standard
   uncertainty, with the capture-session route's own functions (white balance, hue, the table's
   inverse lookup and slope, :func:`huefringe.perframe.phase_sigma`): :func:`trapezoid_coordinate`;
2. fixes the fringe order from a reference captured once with an absolute coded sequence (Gray
   code + phase shifting on a plane, the board or the background, at calibration time):
   :func:`absolute_from_reference`, :func:`oneshot_reference`;
3. triangulates the absolute coordinate with the rig calibration to X, Y, Z in mm with its
   per-pixel uncertainty: :func:`measure_oneshot`.

Order from the reference (the reference-phase temporal method)
--------------------------------------------------------------
Each camera pixel's absolute projector coordinate on the reference, ``u_ref``, is decoded once
(Gray code + phase: :func:`~huefringe.codecs.decode_sequence`). A one-shot frame gives
``w = u mod P``; the order ``k`` is the one that puts ``u = w + k P`` nearest ``u_ref``. This is
the reference-plane (reference-phase) unwrapping of fringe projection profilometry: the object's
phase is unwrapped against a known absolute phase map of a reference captured beforehand, which
is exact while the object's phase stays within half a period (``pi``) of the reference's at every
pixel (Zuo et al., "Temporal phase unwrapping algorithms for fringe projection profilometry: a
comparative review", Opt. Lasers Eng. 85, 2016, sect. 2: the phase of a reference captured once
as the unwrapping guide; Takeda & Mutoh, Appl. Opt. 22, 1983, and Srinivasan, Liu & Halioua,
Appl. Opt. 23, 1984, measure against a reference plane's phase the same way; the plane-based
route of this project does it with ``phase.unwrap(mode="reference")``). The range is geometric:
along each camera ray, the depth change that moves the projector coordinate by ``P / 2`` either
way (:class:`OneShotReference` ``range_front_mm`` / ``range_back_mm``, from the calibration).

A decision is refused (:class:`~huefringe.codecs.Reason` ``ORDER``, never triangulated) where
``|u - u_ref|`` comes within ``order_sigmas`` standard uncertainties (of ``w`` and ``u_ref``
together) of ``P / 2``, and, with ``stands_on_reference`` (objects stand on or in front of the
reference, as on the plane route), where the point would lie more than ``behind_mm`` behind the
reference: a surface between half a period and a whole period in front of the reference wraps
to there, so it is flagged instead of measured at a wrong depth. A surface more than a whole
period (less ``behind_mm``) in front aliases undetectably: that is the method's limit, stated
with the range.

A declared working volume (the trapezoid block's ``travel_mm``: how far the surface may stand in
front of and behind the reference point along each ray) removes that limit's silence: the
volume's two ends on each ray are projected to the projector coordinate once
(:func:`oneshot_reference`), and a frame's order is the one candidate ``u = origin + w + k P``
inside that interval (:func:`absolute_from_reference`). A pixel with no candidate inside (its
surface outside the volume) or with two (the volume spans a period or more there and both
candidates are possible) is flagged ``ORDER``: while the surface stays in the declared volume no
pixel is measured at a wrong order.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from huefringe.codecs.sequence import Decoded, FlatBlock, HueBandsBlock, Reason, SequenceError, SequenceSpec, TrapezoidBlock
from huefringe.colour import hue as hue_of
from huefringe.colour import white_balance, white_gains
from huefringe.huetable import HueTable, band_smoothing_matrix, build_table
from huefringe.perframe import (WEIGHT_BLUR_PX, capture_noise, clipped_mask, frame_hue_noise, noise_ratio2, phase_sigma,
                                sensor_model, weight_noise_of)
from huefringe.rig.model import RigCalibration
from huefringe.rig.triangulation import project, triangulate

__all__ = ["CODED_GEOMETRY", "ONESHOT_GEOMETRY", "OneShotCaptures", "OneShotCoordinate", "OneShotPhase",
           "OneShotReference", "OneShotResult", "OneShotSession", "absolute_from_reference", "filter_against_reference",
           "hue_table_from_frames",
           "is_oneshot", "measure_oneshot", "measure_oneshot_session", "oneshot_captures", "oneshot_reference",
           "reference_decode",
           "table_phase_sigma", "trapezoid_coordinate"]

ONESHOT_GEOMETRY = "oneshot-trapezoid via rig calibration"
"""The geometry that measured a session whose sequence holds ``trapezoid`` blocks (its provenance)."""
CODED_GEOMETRY = "coded light"
"""The geometry that measured a session of coded blocks only."""

F64 = NDArray[np.float64]
TWO_PI = 2.0 * np.pi


@dataclass(frozen=True, eq=False)
class OneShotCaptures:
    """A sequence's one-shot captures in colour (R, G, B, float in [0, 1]).

    Attributes
    ----------
    white : ndarray, shape (H, W, 3)
    bands : ndarray, shape (n * repeats, H, W, 3)
        The ``hue_bands`` block's captures in capture order.
    frames : ndarray, shape (K, H, W, 3)
        Every ``trapezoid`` block's captures in capture order.
    bands_block : HueBandsBlock
    block : TrapezoidBlock
        The trapezoid blocks' pattern (axis, period, origin; ``frames`` their total).
    bit_depth : int
    """

    white: NDArray[np.float32]
    bands: NDArray[np.float32]
    frames: NDArray[np.float32]
    bands_block: HueBandsBlock
    block: TrapezoidBlock
    bit_depth: int


def oneshot_captures(paths: Sequence[str | os.PathLike[str]], spec: SequenceSpec) -> OneShotCaptures:
    """Read the white frame, the hue bands and the trapezoid frames of ``spec`` from its captures.

    Parameters
    ----------
    paths : sequence of paths
        Every capture of the sequence in capture order (e.g. a structured-light session's
        ``captures``); only the one-shot blocks' and the white frame are read, in colour.
    spec : SequenceSpec
        With a ``white`` frame, one ``hue_bands`` block and ``trapezoid`` blocks.

    Raises
    ------
    SequenceError
        Every problem at once, each naming its file: the wrong number of paths, no one-shot blocks,
        a grey or unreadable capture, mixed sizes or bit depths.
    """
    if len(paths) != spec.n_frames:
        raise SequenceError(f"{len(paths)} captures, the sequence has {spec.n_frames} frames")
    traps = [(b, sl) for b, sl in spec.slices() if isinstance(b, TrapezoidBlock)]
    bands = [(b, sl) for b, sl in spec.slices() if isinstance(b, HueBandsBlock)]
    white = [sl for b, sl in spec.slices() if isinstance(b, FlatBlock) and b.level == "white"]
    if not traps or not bands or not white:
        raise SequenceError("the sequence has no one-shot frames (a trapezoid block, a hue_bands block and a white frame)")
    want = [white[0].start, *range(bands[0][1].start, bands[0][1].stop),
            *[i for _, sl in traps for i in range(sl.start, sl.stop)]]
    problems: list[str] = []
    images: list[NDArray[np.float32]] = []
    ref: tuple[Path, tuple[int, ...], Any] | None = None
    for i in want:
        f = Path(paths[i])
        im = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        if im is None:
            problems.append(f"{f}: not an image OpenCV can read")
            continue
        if im.ndim != 3 or im.shape[2] < 3:
            problems.append(f"{f}: a grey capture; one-shot frames and hue bands need colour (R, G, B)")
            continue
        if im.dtype not in (np.uint8, np.uint16):
            problems.append(f"{f}: {im.dtype} pixels (8- or 16-bit integers expected)")
            continue
        if ref is None:
            ref = (f, im.shape[:2], im.dtype)
        elif (im.shape[:2], im.dtype) != ref[1:]:
            problems.append(f"{f}: {im.shape[:2]} {im.dtype}, {ref[0].name} is {ref[1]} {ref[2]}")
            continue
        images.append(cv2.cvtColor(im[..., :3], cv2.COLOR_BGR2RGB).astype(np.float32) / np.float32(np.iinfo(im.dtype).max))
    if problems:
        raise SequenceError("; ".join(problems))
    b0 = traps[0][0]
    nb = bands[0][0].n_frames
    return OneShotCaptures(images[0], np.stack(images[1 : 1 + nb]), np.stack(images[1 + nb :]), bands[0][0],
                           TrapezoidBlock(b0.axis, b0.period_px, b0.origin_px, spec.oneshot_frames, b0.travel_mm),
                           8 if ref is not None and ref[2] == np.uint8 else 16)


def hue_table_from_frames(white: NDArray[np.floating], bands: Sequence[NDArray[np.floating]] | NDArray[np.floating],
                          block: HueBandsBlock, **build_kw: Any) -> HueTable:
    """The per-pixel hue table of a ``hue_bands`` block's captures (:func:`huefringe.huetable.build_table`).

    Parameters
    ----------
    white : ndarray, shape (H, W, 3)
        The sequence's white frame, float in [0, 1].
    bands : sequence of ndarray, shape (n * repeats, H, W, 3)
        The block's captures in capture order (band-major: band ``i``, repeat ``r`` at
        ``i * repeats + r``), float in [0, 1].
    block : HueBandsBlock
    **build_kw
        Passed to :func:`~huefringe.huetable.build_table` (``model``, ``min_saturation``, ...).
    """
    if len(bands) != block.n_frames:
        raise ValueError(f"{len(bands)} hue-band captures, the block has {block.n} bands x {block.repeats} repeats")
    paths = [[bands[i * block.repeats + r] for r in range(block.repeats)] for i in range(block.n)]
    return build_table(paths, np.asarray(white, np.float32), read=lambda a: np.asarray(a, np.float32), **build_kw)


def table_phase_sigma(table: HueTable, slope: NDArray[np.floating], floor_slope: float = 0.05) -> F64:
    """Per-pixel standard uncertainty (rad) of the code phase the table itself contributes.

    The table's entries are band means (standard error ``noise_rad``) smoothed along the bands
    (:func:`~huefringe.huetable.band_smoothing_matrix`, RMS row gain), read at the pixel's slope:
    ``gain noise_rad / max(slope, floor_slope)``. A fixed error of the pixel (the same in every
    frame), added in quadrature to the capture's own noise (:func:`huefringe.perframe.phase_sigma`).
    """
    p = (table.stats or {}).get("params", {})
    window, order = int(p.get("smooth_window", 15)), int(p.get("smooth_order", 2))
    gain = 1.0
    if window > 1:
        m = band_smoothing_matrix(table.n_bands, window, order)
        gain = float(np.sqrt(np.mean(np.sum(m**2, axis=1))))
    noise = np.where(np.isfinite(table.noise_rad), table.noise_rad, np.nan).astype(np.float64)
    return gain * noise / np.maximum(np.where(np.isfinite(slope), slope, 1.0), floor_slope)


@dataclass(frozen=True, eq=False)
class OneShotPhase:
    """A trapezoid frame decoded to the projector coordinate within one period.

    Attributes
    ----------
    wrapped : ndarray of float64
        ``(u - origin_px) mod period_px`` in ``[0, period_px)`` (projector px); NaN where not valid.
    sigma : ndarray of float64
        Its standard uncertainty (projector px): the capture's hue noise (from the frame's own
        signal where the table has a sensor model) and the table's own, through the table's
        slope. NaN where not valid.
    valid : ndarray of bool
    reasons : ndarray of uint8
        :class:`~huefringe.codecs.Reason` bits: ``LOW_SIGNAL`` (table pixel masked, or the hue
        undefined), ``SATURATED`` (a clipped channel).
    code_phase : ndarray of float32
        The table's code phase (rad), NaN where not valid.
    sigma_weights : ndarray of float64, optional
        The same with the capture's noise read from the smoothed signal, which weights the phase
        filter (:func:`filter_against_reference`; the plane route's weights,
        :func:`huefringe.perframe.weight_noise`); None: ``sigma`` weights it.
    """

    wrapped: F64
    sigma: F64
    valid: NDArray[np.bool_]
    reasons: NDArray[np.uint8]
    code_phase: NDArray[np.float32]
    sigma_weights: F64 | None = None


def trapezoid_coordinate(rgb: NDArray[np.floating], white: NDArray[np.floating], table: HueTable,
                         block: TrapezoidBlock, *, bit_depth: int = 8, min_saturation: float | None = None,
                         floor_slope: float = 0.05, weight_blur_px: float = 0.0) -> OneShotPhase:
    """Decode one trapezoid frame: white balance, hue, the table's inverse and slope, sigma.

    The capture-session route's chain (:func:`huefringe.perframe.measure_frame`'s first steps):
    :func:`~huefringe.colour.white_balance` against the white frame,
    :func:`~huefringe.colour.hue` with the table's model,
    :meth:`~huefringe.huetable.HueTable.to_phase_and_slope`, and the phase noise
    :func:`~huefringe.perframe.phase_sigma` (capture) with :func:`table_phase_sigma` (table).
    The capture's hue noise is, as in the plane route's uncertainty, the table's pooled
    per-pixel figure scaled by the frame's own signal (``pooled sqrt(r)``, ``r``
    :func:`~huefringe.perframe.noise_ratio2` of :func:`~huefringe.perframe.frame_hue_noise`)
    where the table has a sensor model, else the pooled figure: a hue's noise follows its chroma
    and signal, which the pooled figure (one per pixel over all bands) does not.

    Parameters
    ----------
    rgb, white : ndarray, shape (H, W, 3)
        The frame and the white frame, float in [0, 1].
    table : HueTable
        Built from the sequence's hue bands on the same scene (:func:`hue_table_from_frames`).
    block : TrapezoidBlock
    bit_depth : int
        The captures' bit depth (a channel at its top code is clipped).
    min_saturation : float, optional
        Hue undefined at or below this white-balanced saturation; default the table's.
    floor_slope : float
        Smallest table slope the noise is divided by.
    weight_blur_px : float
        > 0 (with a sensor model): also the sigma that weights the phase filter, the capture's
        noise read from the signal through a Gaussian of this sigma
        (:func:`~huefringe.perframe.weight_noise`; :attr:`OneShotPhase.sigma_weights`).
    """
    p = (table.stats or {}).get("params", {})
    ms = float(p.get("min_saturation", 0.0)) if min_saturation is None else float(min_saturation)
    floor = p.get("floor", 1.0 / 255.0)
    bal = white_balance(rgb, white, floor=floor)
    h = hue_of(bal, table.model, min_saturation=ms)  # type: ignore[arg-type]
    phase, slope = table.to_phase_and_slope(h)
    noise = noise_w = None
    model = sensor_model(table)
    if model is not None:  # the capture's noise from its own signal
        gains = white_gains(white, floor=floor)
        pooled = capture_noise(table)
        own = frame_hue_noise(table, rgb, gains, table.model, pooled=pooled)
        noise = pooled * np.sqrt(noise_ratio2(own, pooled).astype(np.float64))
        if weight_blur_px > 0:
            noise_w = weight_noise_of(pooled, model, rgb, gains, table.model == "hsi", weight_blur_px)[0]
    s_tab = table_phase_sigma(table, slope, floor_slope)
    s_tab2 = np.where(np.isfinite(s_tab), s_tab, 0.0) ** 2
    s_rad = np.sqrt(phase_sigma(table, slope, floor_slope, noise=noise) ** 2 + s_tab2)
    reasons = np.zeros(phase.shape, np.uint8)
    reasons[~np.isfinite(phase)] |= np.uint8(Reason.LOW_SIGNAL)
    reasons[clipped_mask(rgb, bit_depth)] |= np.uint8(Reason.SATURATED)
    valid = reasons == 0
    scale = block.period_px / TWO_PI
    wrapped = np.where(valid, np.mod(phase.astype(np.float64) * scale, block.period_px), np.nan)
    s_w = None
    if noise_w is not None:
        s_w = np.where(valid, np.sqrt(phase_sigma(table, slope, floor_slope, noise=noise_w) ** 2 + s_tab2) * scale, np.nan)
    return OneShotPhase(wrapped, np.where(valid, s_rad * scale, np.nan), valid, reasons,
                        np.where(valid, phase, np.nan).astype(np.float32), s_w)


@dataclass(frozen=True, eq=False)
class OneShotReference:
    """The reference's absolute coordinate per camera pixel and the unambiguous range about it.

    Attributes
    ----------
    coord, sigma : ndarray of float64
        ``u_ref`` (projector px along the trapezoid's axis) and its standard uncertainty; NaN
        where the reference was not decoded.
    valid : ndarray of bool
    reasons : ndarray of uint8
        The reference decode's :class:`~huefringe.codecs.Reason` bits.
    period_px : float
    range_front_mm, range_back_mm : ndarray of float64
        Along each camera ray, how far in front of (towards the camera) and behind the reference
        a surface may stand before its coordinate moves by half a period: the unambiguous range.
    front_sign : ndarray of float64
        +1 where the coordinate grows towards the camera, -1 where it falls (NaN invalid).
    px_per_mm : ndarray of float64
        ``|du / d(depth)|`` at the reference (projector px per mm along the ray), from the same
        two triangulations.
    travel_mm : (float, float) or None
        The declared working volume (:attr:`TrapezoidBlock.travel_mm
        <huefringe.codecs.TrapezoidBlock.travel_mm>`): how far the surface may stand in front of
        and behind the reference point along each ray, mm; None when not declared.
    travel_coord : ndarray of float64, shape (H, W, 2), or None
        With ``travel_mm``: the projector coordinate of the volume's two ends on each ray (the
        reference point moved ``front`` mm towards the camera, and ``back`` mm away, projected),
        NaN where the reference is not valid.
    """

    coord: F64
    sigma: F64
    valid: NDArray[np.bool_]
    reasons: NDArray[np.uint8]
    period_px: float
    range_front_mm: F64
    range_back_mm: F64
    front_sign: F64
    px_per_mm: F64
    travel_mm: tuple[float, float] | None = None
    travel_coord: F64 | None = None

    def summary(self) -> dict[str, float]:
        """Median, 5th and 95th percentile of the range in front and behind over valid pixels (mm)."""
        out: dict[str, float] = {}
        for name, a in (("front", self.range_front_mm), ("back", self.range_back_mm)):
            v = a[np.isfinite(a)]
            if v.size:
                out |= {f"{name}_median_mm": float(np.median(v)), f"{name}_p05_mm": float(np.percentile(v, 5)),
                        f"{name}_p95_mm": float(np.percentile(v, 95))}
        return out

    def travel_summary(self) -> dict[str, Any] | None:
        """The declared working volume, its median span in projector px and the share of pixels where
        it spans a period or more (there a second candidate order may fall inside it, and a pixel
        whose does is flagged ``ORDER``), for the QA record; None when not declared."""
        if self.travel_mm is None or self.travel_coord is None:
            return None
        span = np.abs(self.travel_coord[..., 0] - self.travel_coord[..., 1])[self.valid]
        return {"front_mm": self.travel_mm[0], "back_mm": self.travel_mm[1],
                "span_px_median": float(np.median(span)) if span.size else None,
                "wider_than_period_fraction": float(np.mean(span >= self.period_px)) if span.size else None}


def oneshot_reference(decoded: Decoded, calib: RigCalibration, block: TrapezoidBlock) -> OneShotReference:
    """The order reference from an absolute decode of the reference scene (Gray code + phase).

    The range: the reference point (``u_ref`` triangulated) against the points at
    ``u_ref +- P / 2`` on the same camera ray; their distances along the ray are
    ``range_front_mm`` and ``range_back_mm`` (the one nearer the camera is the front).
    With the block's ``travel_mm`` the working volume's ends on each ray (the reference point
    moved ``front`` mm towards the camera and ``back`` mm away) are projected to the projector
    coordinate (``travel_coord``).

    Raises
    ------
    ValueError
        The decoded axis is not the trapezoid's, or is relative (no absolute order to carry).
    """
    if decoded.axis != block.axis:
        raise ValueError(f"the reference is decoded along {decoded.axis}, the trapezoid runs along {block.axis}")
    if not decoded.absolute:
        raise ValueError(f"the reference's axis {decoded.axis} is decoded within one period only (no Gray code or "
                         "second period): it cannot give the one-shot frames their order")
    valid = decoded.valid & np.isfinite(decoded.coord) & np.isfinite(decoded.sigma)
    coord = np.where(valid, decoded.coord, np.nan)
    mode = "u" if block.axis == "x" else "v"
    half = 0.5 * block.period_px

    def tri(c: F64) -> tuple[F64, F64]:
        t = triangulate(calib, **{mode: c}, valid=valid & np.isfinite(c), mode=mode)  # type: ignore[arg-type]
        return np.linalg.norm(t.xyz, axis=-1), t.xyz     # distance from the camera along the ray

    (r0, x0), (rp, _), (rm, _) = tri(coord), tri(coord + half), tri(coord - half)
    plus_front = (rp < r0)                              # +P/2 brings the point nearer the camera
    front = np.where(plus_front, r0 - rp, r0 - rm)
    back = np.where(plus_front, rm - r0, rp - r0)
    ok = valid & np.isfinite(front) & np.isfinite(back) & (front > 0) & (back > 0)
    sign = np.where(ok, np.where(plus_front, 1.0, -1.0), np.nan)
    px_per_mm = np.where(ok, 2.0 * half / (front + back), np.nan)
    reasons = decoded.reasons.copy() if decoded.reasons.size else np.zeros(coord.shape, np.uint8)
    reasons[valid & ~ok] |= np.uint8(Reason.ORDER)
    travel_coord = None
    if block.travel_mm is not None:
        travel_coord = np.full((*coord.shape, 2), np.nan)
        p0 = x0[ok]
        unit = p0 / r0[ok][:, None]
        axis = 0 if block.axis == "x" else 1
        for j, shift in enumerate((-block.travel_mm[0], block.travel_mm[1])):   # front: towards the camera
            travel_coord[ok, j] = project(p0 + shift * unit, calib.projector_matrix, calib.projector_distortion,
                                          calib.R, calib.T)[:, axis]
    return OneShotReference(np.where(ok, coord, np.nan), np.where(ok, decoded.sigma, np.nan), ok, reasons,
                            float(block.period_px), np.where(ok, front, np.nan), np.where(ok, back, np.nan), sign,
                            px_per_mm, block.travel_mm, travel_coord)


@dataclass(frozen=True, eq=False)
class OneShotCoordinate:
    """A one-shot frame's absolute projector coordinate.

    Attributes
    ----------
    coord, sigma : ndarray of float64
        ``u = origin + w + k P`` and its standard uncertainty (that of ``w``: the order is an
        integer decision); NaN where not valid.
    valid : ndarray of bool
    reasons : ndarray of uint8
        :class:`~huefringe.codecs.Reason` bits: the frame's, the reference's, ``ORDER`` (the
        decision within ``order_sigmas`` of half a period, or an alias behind the reference),
        ``OUTSIDE`` (off the projector).
    offset : ndarray of float64
        ``u - u_ref`` (projector px) wherever both are decoded, flagged or not.
    margin : ndarray of float64
        How far (projector px) the order decision is from going another way, wherever both are
        decoded: ``P / 2 - |u - u_ref|``; with a working volume the smallest distance of ``u``
        inside, or of ``u +- P`` outside, the volume's coordinate interval (negative: flagged).
    """

    coord: F64
    sigma: F64
    valid: NDArray[np.bool_]
    reasons: NDArray[np.uint8]
    offset: F64
    margin: F64 | None = None


def absolute_from_reference(phase: OneShotPhase, reference: OneShotReference, block: TrapezoidBlock, *,
                            order_sigmas: float = 3.0, stands_on_reference: bool = True, behind_mm: float = 0.25,
                            extent: int | None = None) -> OneShotCoordinate:
    """The order of every pixel from the reference: ``u = origin + w + k P`` nearest ``u_ref``.

    Parameters
    ----------
    phase : OneShotPhase
        :func:`trapezoid_coordinate`'s result.
    reference : OneShotReference
        :func:`oneshot_reference`'s result (same camera, same projector axis).
    block : TrapezoidBlock
    order_sigmas : float
        ``ORDER`` where ``|u - u_ref| > P / 2 - order_sigmas * sqrt(sigma_w^2 + sigma_ref^2)``:
        the decision could go either way.
    stands_on_reference : bool
        ``ORDER`` also where the point lies more than ``behind_mm`` behind the reference (the
        alias of a surface between half and one period in front of it).
    behind_mm : float
        How far behind the reference a surface may be and still count as on it.
    extent : int, optional
        Projector pixels along the axis: ``OUTSIDE`` beyond ``[-0.5, extent - 0.5]``.

    Notes
    -----
    With a declared working volume (``reference.travel_mm``, from the block's ``travel_mm``) the
    order is instead the one candidate ``u = origin + w + k P`` inside the volume's coordinate
    interval on the pixel's ray (``reference.travel_coord``, widened by ``order_sigmas`` standard
    uncertainties): a pixel with no candidate there (its surface outside the declared volume) or
    with more than one (the volume spans a period or more there: an alias could not be told from
    the surface) is flagged ``ORDER``. ``stands_on_reference`` and the half-period margin do not
    apply then: the volume replaces them. Without it a surface more than a period in front of or
    behind the reference aliases undetectably.
    """
    P = float(block.period_px)
    if not math.isclose(P, reference.period_px):
        raise ValueError(f"the reference was prepared for period {reference.period_px:g} px, the frame has {P:g}")
    reasons = phase.reasons | reference.reasons
    both = phase.valid & reference.valid
    w = np.where(both, phase.wrapped + block.origin_px, np.nan)
    margin = order_sigmas * np.sqrt(phase.sigma**2 + reference.sigma**2)
    if reference.travel_coord is not None:                   # the one candidate inside the working volume
        ends = reference.travel_coord
        with np.errstate(invalid="ignore"):
            lo = np.minimum(ends[..., 0], ends[..., 1]) - margin
            hi = np.maximum(ends[..., 0], ends[..., 1]) + margin
            k_lo, k_hi = np.ceil((lo - w) / P), np.floor((hi - w) / P)
            ambiguous = both & ~(k_hi == k_lo)
        k = k_lo
    else:
        k = np.rint((reference.coord - w) / P)
    u = w + k * P
    d = u - reference.coord
    if reference.travel_coord is not None:
        lo0, hi0 = lo + margin, hi - margin
        decision = np.minimum(np.minimum(u - lo0, hi0 - u), np.minimum(lo0 - (u - P), (u + P) - hi0))
    else:
        decision = 0.5 * P - np.abs(d)
    with np.errstate(invalid="ignore"):
        if reference.travel_coord is None:
            ambiguous = both & ~(np.abs(d) <= 0.5 * P - margin)
            if stands_on_reference:
                ambiguous |= both & (d * reference.front_sign < -behind_mm * reference.px_per_mm)
        reasons = reasons | np.where(ambiguous, np.uint8(Reason.ORDER), np.uint8(0))
        if extent is not None:
            outside = both & ~((u >= -0.5) & (u <= extent - 0.5))
            reasons = reasons | np.where(outside, np.uint8(Reason.OUTSIDE), np.uint8(0))
    reasons = reasons | np.where(~both & (reasons == 0), np.uint8(Reason.ORDER), np.uint8(0))  # no order without both
    reasons = reasons.astype(np.uint8)
    valid = (reasons == 0) & both
    return OneShotCoordinate(np.where(valid, u, np.nan), np.where(valid, phase.sigma, np.nan), valid, reasons,
                             np.where(both, d, np.nan), np.where(both, decision, np.nan))


def filter_against_reference(phase: OneShotPhase, reference: OneShotReference, block: TrapezoidBlock, *,
                             radius: int, adaptive: dict[str, Any] | None = None,
                             systematic_rad: NDArray[np.floating] | None = None) -> OneShotPhase:
    """The plane route's phase filter on a one-shot frame: its offset from the reference, filtered.

    The capture-session route filters the phase difference from its reference plane
    (:func:`huefringe.phase.denoise_phase`: inverse-variance weighted, a neighbour accepted only
    within ``k`` combined sigma, so a step is not blurred; ``adaptive`` grows the window where the
    filtered sigma stays above its target). Here the difference is the frame's coordinate less
    the reference's, ``2 pi (origin + w - u_ref) / P`` (wrapped: the filter takes differences
    modulo ``2 pi``), nearly flat where the plane route's is; it is filtered with the frame's own
    sigma and put back on the reference, ``u = u_ref + filtered offset``. Its standard uncertainty:
    ``1 / sqrt(sum w)`` (the capture's and the hue table's noise, independent between pixels,
    averaged; with :attr:`OneShotPhase.sigma_weights`, which then weights the filter,
    ``sqrt(sum w r) / sum w``, ``r`` the pixel's ``(sigma / sigma_weights)^2``), the reference's
    own sigma (which the offset carries and putting it back restores), and ``systematic_rad``, an
    error that neighbours share and averaging does not reduce (the table's interpolation between
    bands in the code-phase bin of the pixel's phase, from the curvature its noise does not
    explain, as the plane route adds it:
    :func:`huefringe.uncertainty.interpolation_bins` with ``noise_free``,
    :func:`huefringe.uncertainty.interpolation_at`), in quadrature.

    Parameters
    ----------
    phase : OneShotPhase
        :func:`trapezoid_coordinate`'s result.
    reference : OneShotReference
    block : TrapezoidBlock
    radius : int
        The filter's radius (``measurement.denoise_radius``); 0 returns ``phase`` unchanged.
    adaptive : dict, optional
        ``measurement.denoise_adaptive`` (:func:`huefringe.phase.adaptive_kwargs`); None: a fixed window.
    systematic_rad : ndarray, optional
        Per-pixel code-phase error (rad) that neighbours share.
    """
    from huefringe.phase import adaptive_kwargs, denoise_phase

    if radius <= 0:
        return phase
    P = float(block.period_px)
    both = phase.valid & reference.valid
    k = TWO_PI / P
    d = np.where(both, k * (phase.wrapped + block.origin_px - reference.coord), np.nan)
    d = np.angle(np.exp(1j * d))
    wsum = np.zeros(d.shape, np.float32)
    sw = phase.sigma if phase.sigma_weights is None else phase.sigma_weights
    ratio = rsum = None
    if phase.sigma_weights is not None:  # weighted by the smoothed signal's figure; u by the frame's own
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(both, (phase.sigma / phase.sigma_weights) ** 2, 1.0).astype(np.float32)
        rsum = np.zeros(d.shape, np.float32)
    f = denoise_phase(d, np.where(both, k * sw, np.nan), both, radius=radius, weight_sum=wsum, ratio=ratio,
                      ratio_sum=rsum, **adaptive_kwargs(adaptive))
    ok = both & np.isfinite(f) & (wsum > 0)
    wrapped = np.where(ok, np.mod(reference.coord + f.astype(np.float64) / k - block.origin_px, P), np.nan)
    sys2 = 0.0 if systematic_rad is None else np.nan_to_num(np.asarray(systematic_rad, np.float64)) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        w64 = np.where(ok, wsum, 1.0).astype(np.float64)
        filt = 1.0 / w64 if rsum is None else np.where(ok, rsum, 1.0).astype(np.float64) / w64**2
        var = filt + sys2 + (k * np.nan_to_num(reference.sigma)) ** 2
        sigma = np.where(ok, np.sqrt(var) / k, np.nan)
    reasons = phase.reasons.copy()
    reasons[both & ~ok] |= np.uint8(Reason.LOW_SIGNAL)   # rejected by the adaptive filter
    valid = phase.valid & (ok | ~reference.valid)
    return OneShotPhase(np.where(valid, np.where(ok, wrapped, phase.wrapped), np.nan),
                        np.where(valid, np.where(ok, sigma, phase.sigma), np.nan), valid, reasons, phase.code_phase)


@dataclass(frozen=True, eq=False)
class OneShotResult:
    """One one-shot frame triangulated.

    Attributes
    ----------
    xyz, sigma : ndarray, shape (H, W, 3)
        X, Y, Z (mm, camera frame) and their standard uncertainties from the one-shot
        coordinate's noise (capture and hue table); NaN where not valid.
    sigma_ray : ndarray, shape (H, W)
        The same along the camera ray.
    valid : ndarray of bool
    coordinate : OneShotCoordinate
    phase : OneShotPhase
    """

    xyz: F64
    sigma: F64
    sigma_ray: F64
    valid: NDArray[np.bool_]
    coordinate: OneShotCoordinate
    phase: OneShotPhase

    def reason_counts(self) -> dict[str, int]:
        """Pixels per :class:`~huefringe.codecs.Reason` bit (a pixel counts under every bit it has)."""
        r = self.coordinate.reasons
        return {m.name.lower(): int(np.count_nonzero(r & m.value)) for m in Reason}  # type: ignore[union-attr]


def measure_oneshot(rgb: NDArray[np.floating], white: NDArray[np.floating], table: HueTable, block: TrapezoidBlock,
                    calib: RigCalibration, reference: OneShotReference, *, bit_depth: int = 8,
                    order_sigmas: float = 3.0, stands_on_reference: bool = True, behind_mm: float = 0.25,
                    denoise_radius: int = 0, denoise_adaptive: dict[str, Any] | None = None,
                    interp_bins: NDArray[np.float32] | None = None,
                    weight_blur_px: float = WEIGHT_BLUR_PX) -> OneShotResult:
    """One trapezoid frame to X, Y, Z: :func:`trapezoid_coordinate`, :func:`absolute_from_reference`,
    :func:`~huefringe.rig.triangulate` (ray against the projector plane of the coordinate, ``sigma_u``
    the coordinate's). Pixels flagged by either step are never triangulated. ``denoise_radius`` > 0
    filters the frame's offset from the reference first, as the plane route filters its phase
    difference (:func:`filter_against_reference`, ``denoise_adaptive`` its adaptive support), its
    systematic term the table's interpolation error in the bin of each pixel's code phase
    (``interp_bins``: :func:`huefringe.uncertainty.interpolation_bins` of ``table`` with
    ``noise_free``, computed here when None; a session passes its own once), its weights the
    capture's noise read through a Gaussian of ``weight_blur_px`` (``measurement.weight_blur_px``;
    0: the frame's own figure as captured, which u reads either way)."""
    ph = trapezoid_coordinate(rgb, white, table, block, bit_depth=bit_depth,
                              weight_blur_px=weight_blur_px if denoise_radius > 0 else 0.0)
    if denoise_radius > 0:
        from huefringe.uncertainty import interpolation_at, interpolation_bins

        bins = interpolation_bins(table, noise_free=True) if interp_bins is None else interp_bins
        ph = filter_against_reference(ph, reference, block, radius=denoise_radius, adaptive=denoise_adaptive,
                                      systematic_rad=interpolation_at(bins, ph.code_phase))
    extent = calib.projector_size[0 if block.axis == "x" else 1] or None
    co = absolute_from_reference(ph, reference, block, order_sigmas=order_sigmas,
                                 stands_on_reference=stands_on_reference, behind_mm=behind_mm, extent=extent)
    mode = "u" if block.axis == "x" else "v"
    t = triangulate(calib, **{mode: co.coord, f"sigma_{mode}": co.sigma}, valid=co.valid, mode=mode)  # type: ignore[arg-type]
    return OneShotResult(t.xyz, t.sigma, t.sigma_ray, t.valid, co, ph)


def is_oneshot(spec: SequenceSpec) -> bool:
    """Whether a structured-light sequence holds one-shot frames (a ``trapezoid`` block)."""
    return spec.oneshot_frames > 0


@dataclass(frozen=True, eq=False)
class OneShotSession:
    """A structured-light session's one-shot frames measured (:func:`measure_oneshot_session`).

    Attributes
    ----------
    frames : list of RigFrame
        One per trapezoid frame in capture order: X, Y, Z, sigma, validity and the decoded maps
        (``u`` or ``v`` the absolute one-shot coordinate, ``decoded`` its
        :class:`~huefringe.codecs.Decoded` with the :class:`~huefringe.codecs.Reason` bits, ``mean``
        the frame's grey level), triangulated ``u`` (``v`` for a trapezoid along y).
    results : list of OneShotResult
    reference : OneShotReference
        The order reference: the session's own coded blocks decoded on its scene.
    table : HueTable
        The per-pixel hue table of the session's ``hue_bands`` block.
    block : TrapezoidBlock
    reference_session : Path or None
        The reference session the order came from (``oneshot: {reference: {session: PATH}}``),
        resolved; None: the session's own coded blocks.
    """

    frames: list[Any]
    results: list[OneShotResult]
    reference: OneShotReference
    table: HueTable
    block: TrapezoidBlock
    reference_session: Path | None = None

    def order_summary(self) -> dict[str, Any]:
        """The order reference and its unambiguous range, for the QA record."""
        if self.reference_session is not None:
            what = (f"the coded captures of the reference session {self.reference_session} (absolute coordinate along "
                    f"{self.block.axis}), a plane under the object: each one-shot frame's order is the one nearest it, "
                    "flagged where the point would lie behind the reference")
        else:
            what = ("the session's coded blocks decoded on its own scene (absolute coordinate along "
                    f"{self.block.axis}): each one-shot frame's order is the one nearest it")
        return {"reference": what,
                **({} if self.reference_session is None else {"reference_session": str(self.reference_session)}),
                "period_px": self.block.period_px, "reference_valid_fraction": float(self.reference.valid.mean()),
                "unambiguous_range_mm": self.reference.summary(),
                "what": "how far each pixel's surface may move along its camera ray towards the camera (front) or away "
                        "(back) from where the coded blocks saw it and keep its order; beyond, pixels are flagged order"
                        + ("" if self.reference_session is None else
                           " (in front of the reference plane up to the front range; behind it by at most 0.25 mm)"),
                **({} if self.reference.travel_mm is None else {"travel": self.reference.travel_summary(), "order":
                    "the one candidate inside the declared working volume (travel_mm); none or several: flagged order"})}


def measure_oneshot_session(session: Any, calib: RigCalibration, cfg: dict[str, Any], *,
                            order_sigmas: float = 3.0) -> OneShotSession:
    """Every one-shot frame of a structured-light session triangulated with the rig calibration.

    The session's sequence holds coded blocks (Gray code + phase along the trapezoid's axis), a
    white frame, one ``hue_bands`` block and ``trapezoid`` blocks, all captured on the same scene.
    The coded blocks are decoded once (:func:`huefringe.rig.measure.decode_frame`) as the order
    reference (:func:`oneshot_reference`); the hue table is built from the bands
    (:func:`hue_table_from_frames`, model ``cfg['hue_model']``); then each trapezoid frame in turn
    goes through :func:`measure_oneshot` with the order nearest the reference on either side
    (``stands_on_reference=False``: the reference is the scene itself, so a surface may move
    towards or away from the camera), flagged ``ORDER`` within ``order_sigmas`` of half a period;
    with the trapezoid block's ``travel_mm`` the one order inside that working volume, flagged
    ``ORDER`` where none or two are (:func:`absolute_from_reference`).

    A session naming a reference session (``session.oneshot_reference``, from
    ``oneshot: {reference: {session: PATH}}``) takes its order reference from that session's coded
    captures instead (:func:`reference_decode`: the same rig and calibration, a plane under the
    object captured once) and needs no coded blocks of its own; the order is then the one nearest
    the reference with ``stands_on_reference=True``, as on the plane route: a point more than
    0.25 mm behind the reference plane is flagged ``ORDER`` (the alias of a surface between half a
    period and a period in front of it). The hue table still comes from the session's own bands,
    captured on the object's scene (the table is per pixel of the surface it sees).

    ``cfg['rig']['oneshot_denoise_radius']`` > 0 filters each frame's offset from the reference
    with that radius, ``cfg['measurement']['denoise_adaptive']`` and ``weight_blur_px``
    (:func:`measure_oneshot`, :func:`filter_against_reference`); 0 or absent: unfiltered.

    Raises
    ------
    RigError
        No coded blocks along the trapezoid's axis and no reference session, or relative ones; a
        reference session missing, refused, of another camera, projector or calibration, or
        decoding too few pixels (:func:`reference_decode`); unreadable or grey one-shot captures;
        captures not of the calibration's camera size; fewer than 3 points in a frame.
    """
    from huefringe.codecs import Decoded
    from huefringe.rig.measure import RigError, RigFrame, decode_frame

    spec = session.spec
    where = session.root / "sequence.yaml"
    block = next(b for b in spec.blocks if isinstance(b, TrapezoidBlock))
    ref_root = getattr(session, "oneshot_reference", None)
    if ref_root is None and block.axis not in spec.axes():
        raise RigError(f"{where}: the trapezoid frames run along {block.axis}, the sequence has no coded blocks along "
                       f"{block.axis} to give them their order (Gray code + phase on the same scene), and "
                       f"{session.root / 'session.yaml'} names no reference session "
                       "(oneshot: {reference: {session: PATH}})")
    try:
        caps = oneshot_captures(session.captures, spec)
    except SequenceError as exc:
        raise RigError(str(exc)) from None
    h, w = caps.white.shape[:2]
    if calib.camera_size != (0, 0) and calib.camera_size != (w, h):
        raise RigError(f"{session.root / 'captures'}: {w} x {h} captures, the calibration's camera is "
                       f"{calib.camera_size[0]} x {calib.camera_size[1]}")
    if ref_root is None:
        try:
            decoded = decode_frame(session.read_captures(), spec, cfg)["decoded"][block.axis]
        except SequenceError as exc:
            raise RigError(str(exc)) from None
        ref_where = where
    else:
        decoded, ref_where = reference_decode(session, block, cfg, (w, h))
    try:
        ref = oneshot_reference(decoded, calib, block)
    except ValueError as exc:
        raise RigError(f"{ref_where}: {exc}") from None
    table = hue_table_from_frames(caps.white, caps.bands, caps.bands_block, model=cfg.get("hue_model", "hexcone"))
    radius = int((cfg.get("rig") or {}).get("oneshot_denoise_radius") or 0)
    adaptive = (cfg.get("measurement") or {}).get("denoise_adaptive") if radius > 0 else None
    blur = float((cfg.get("measurement") or {}).get("weight_blur_px", WEIGHT_BLUR_PX))
    bins = None
    if radius > 0:
        from huefringe.uncertainty import interpolation_bins

        bins = interpolation_bins(table, noise_free=True)
    key, other = ("u", "v") if block.axis == "x" else ("v", "u")
    frames, results = [], []
    for k in range(caps.frames.shape[0]):
        res = measure_oneshot(caps.frames[k], caps.white, table, caps.block, calib, ref, bit_depth=caps.bit_depth,
                              order_sigmas=order_sigmas, stands_on_reference=ref_root is not None,
                              denoise_radius=radius, denoise_adaptive=adaptive, interp_bins=bins,
                              weight_blur_px=blur)
        if int(res.valid.sum()) < 3:
            raise RigError(f"{session.root / 'captures'}: one-shot frame {k}: {int(res.valid.sum())} pixels decoded and "
                           "triangulated; nothing to measure")
        co = res.coordinate
        top = 255.0 if caps.bit_depth == 8 else 65535.0
        dec = Decoded(block.axis, co.coord, co.sigma, (caps.frames[k].mean(axis=-1) * top).astype(np.float32), co.valid,
                      np.where(co.valid, co.margin, np.nan).astype(np.float32), True,
                      co.reasons)
        maps = {key: co.coord, other: None, f"sigma_{key}": co.sigma, f"sigma_{other}": None, f"valid_{key}": co.valid,
                f"valid_{other}": None, "mean": caps.frames[k].mean(axis=-1).astype(np.float64) * top,
                "decoded": {block.axis: dec}}
        frames.append(RigFrame(res.xyz, res.sigma, res.valid, maps, key, res.sigma_ray))
        results.append(res)
    return OneShotSession(frames, results, ref, table, caps.block, ref_root)


def reference_decode(session: Any, block: TrapezoidBlock, cfg: dict[str, Any],
                     camera_size: tuple[int, int]) -> tuple[Decoded, Path]:
    """The absolute decode, along the trapezoid's axis, of the reference session a one-shot session
    names (``oneshot: {reference: {session: PATH}}``): its coded captures decoded once.

    Parameters
    ----------
    session : SLSession
        The one-shot session (``oneshot_reference`` set).
    block : TrapezoidBlock
        Its trapezoid blocks' pattern (the axis decoded).
    cfg : dict
        The run's configuration (``codecs``).
    camera_size : (int, int)
        The one-shot captures' width and height.

    Returns
    -------
    Decoded
        The reference's absolute decode along ``block.axis``.
    Path
        The reference's ``sequence.yaml`` (for messages).

    Raises
    ------
    RigError
        Every problem at once, each naming its file: the reference missing or not a valid
        structured-light session, not of the same camera, projector or calibration, its sequence
        not absolute along the trapezoid's axis, its captures of another size, or fewer decoded
        pixels than ``codecs.min_valid_fraction`` of the camera.
    """
    from huefringe.codecs.sequence import axis_is_absolute
    from huefringe.rig.measure import RigError, decode_frame
    from huefringe.session import SessionError, load_sl_session
    from huefringe.session._structured import oneshot_reference_problems

    root = Path(session.oneshot_reference)
    here = session.root / "session.yaml"
    if not (root / "session.yaml").is_file():
        raise RigError(f"{here}: oneshot/reference: {root} holds no session (session.yaml missing)")
    problems = [f"{p.path}: {p.message}" if p.path else p.message
                for p in oneshot_reference_problems(root, here, session.meta, block.axis, session.root)]
    try:
        ref = load_sl_session(root)
    except SessionError as exc:
        problems.append(f"{here}: oneshot/reference: {root} is refused: {exc}")
        ref = None
    if ref is not None and not axis_is_absolute(ref.spec, block.axis):   # type: ignore[arg-type]
        problems.append(f"{root / 'sequence.yaml'}: no absolute coordinate along {block.axis} (the trapezoid's axis)")
    if problems:
        raise RigError("; ".join(dict.fromkeys(problems)))
    assert ref is not None
    try:
        d = decode_frame(ref.read_captures(), ref.spec, cfg)
    except SequenceError as exc:
        raise RigError(f"{root / 'captures'}: {exc}") from None
    dec = d["decoded"][block.axis]
    hh, ww = d["mean"].shape
    if (ww, hh) != tuple(camera_size):
        raise RigError(f"{root / 'captures'}: {ww} x {hh} captures, the one-shot session's are "
                       f"{camera_size[0]} x {camera_size[1]}")
    least = float(cfg.get("codecs", {}).get("min_valid_fraction", 0.01))
    frac = float(np.mean(dec.valid))
    if frac < least:
        raise RigError(f"{root / 'captures'}: the reference decodes {frac:.1%} of the camera along {block.axis}, below "
                       f"codecs.min_valid_fraction {least:.1%}: no order reference for the one-shot frames")
    return dec, root / "sequence.yaml"
