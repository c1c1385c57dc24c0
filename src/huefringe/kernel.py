"""Fast per-frame kernel: one RGB frame to a height map, with the calibration prepared once.

:func:`prepare` lays out, once per session, everything a frame needs (white-balance gains of the
object white, the object's hue table, the pixel mask, the reference phase and the per-pixel
height model); :func:`frame_to_height` then takes each frame, row by row, through compiled passes::

    white balance -> hexcone or HSI hue           (_colour_row, vectorised)
    -> guessed table line, prefetched one row ahead
    -> search in the pixel's table column          (scalar: one cache line per pixel)
    -> phase (-> pre-distortion decoded) -> dphi = wrap(phi - phi_ref) -> h = dphi / (a + b dphi)
                                                   (_finish_row, vectorised but the decoding)

with no full-size temporaries, reading ``uint8``/``uint16`` frames directly (no float conversion
pass). It is the reference-relative path of :func:`huefringe.perframe.measure_frame`
(``unwrap_mode="reference"``) and repeats its arithmetic operation by operation (float32 where
the NumPy reference is float32, float64 where it is float64; the HSI ``arctan2`` is NumPy's own,
in a pass of its own): the heights and the valid mask are bit for bit those of the reference.

``denoise_radius > 0`` adds the uncertainty-weighted edge-preserving filter
(:func:`huefringe.phase.denoise_phase`, called as is) on the phase difference; the per-pixel
phase uncertainty (:func:`huefringe.perframe.phase_sigma` with the table slope of
:meth:`~huefringe.huetable.HueTable.hue_slope`) is computed in the same passes.

Example
-------
>>> prep = prepare(table, cal, white, hue_model="hexcone", min_saturation=0.08,
...                shadow=shadow_mask(white, 0.12), bit_depth=8)        # doctest: +SKIP
>>> for path in frames:                                                  # doctest: +SKIP
...     height, valid = frame_to_height(prep, cv2.imread(path)[..., ::-1])

Table layout
------------
The :class:`~huefringe.huetable.HueTable` is band-major ``(N, H, W)``: a bisection in one
pixel's column touches ~log2(N) cache lines, each in a different band plane, and a frame ends
up reading most of the table (194 MB for 256 bands at 768 x 494). :func:`prepare` copies it once
into a pixel-major layout: each usable pixel's column, rotated to start at its minimum (so sorted
ascending), cut into 64-byte cache lines of 32 entries: line ``j`` holds entries
``29 j - 1 .. 29 j + 30``, its own block of 29 with one entry before and two after, so that the
entries bracketing a hue and those either side of them (the phase filter's slope) are always in
the line of the block the bracketing entry belongs to. Hue tables vary little from pixel to
pixel, so a small table per 32 x 32 tile of the image tells, from the hue, which line of the
column most likely holds it (~98 % of the pixels). A lookup is then one line, prefetched a row
ahead, counted with one 32-wide vector compare; when the guess misses, the next line up or down
(64 bytes away, usually fetched with the guessed one) is tried, then the first entries of the
blocks (one more line) give the right one. A pixel thus costs one cache line of table instead of
about eight.

Memory: ``64 ceil(N / 29) H W`` bytes of columns (576 per pixel for N = 256), 32 per pixel of line
heads (N <= 464), 35 of gains, reference phase, a, b, mask, start and noise, and 1 KB of guess
table per 32 x 32 tile: 244 MB for 256 bands at 768 x 494, 843 MB at 1280 x 1024 (the band-major
table is 194 and 671 MB; it is not kept, and a memory-mapped one is read once). Per frame:
``5 H W`` bytes of output.

Speed: at 768 x 494 with 256 bands, one core spends most of a frame fetching each pixel's table
line from memory (24 MB of lines per frame at scattered offsets: 3.2-3.9 ms for the reads alone
on the development machine); the colour and post-lookup arithmetic run as branch-free loops that
LLVM vectorises (``benchmarks/bench_kernel.py`` gives the current figures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload
from numpy.typing import NDArray

from huefringe.colour import HUE_MODELS, white_gains
from huefringe.height import PlaneCalibration
from huefringe.huetable import HueTable
from huefringe.perframe import (WEIGHT_BLUR_PX, WEIGHT_BLUR_SHAPE, _hue_noise_kernel, capture_noise, height_noise,
                                noise_ratio2, ratio_over, sensor_model, shadow_mask, sigma_from_slope, weight_blur_angle,
                                weight_noise_of)
from huefringe.phase import adaptive_kwargs, denoise_weight, denoise_weighted
from huefringe.phase_error import correct_frequency, correct_one, frequency_inputs
from huefringe.session import Predistortion
from huefringe.uncertainty import (PixelBudget, edge_floor, height_uncertainty, pixel_budget,
                                   texture_term_phase)
from huefringe.uncertainty.frame import _texture_delta_row

__all__ = ["FrameMaps", "Prepared", "frame_maps", "frame_to_height", "prepare"]

_INT_SCALE = {np.dtype(np.uint8): 1.0 / 255.0, np.dtype(np.uint16): 1.0 / 65535.0}
_LINE = 32
"""Entries per 64-byte cache line of a pixel's column."""
_STEP = 29
"""Entries per line's own block: line j holds the column's entries ``29 j - 1 .. 29 j + 30``, its
block ``29 j .. 29 j + 28`` with one entry before and two after (shared with the neighbours)."""
_SHIFT = 6
"""Hue buckets of the guess tables: ``65536 >> _SHIFT`` = 1024 buckets of 64 counts."""
_TILE = 32
"""Side (pixels) of the image tiles that have their own guess table."""


# =============================================================================================
# prepared calibration
# =============================================================================================
@dataclass(eq=False)
class Prepared:
    """Calibration data of one session, laid out for :func:`frame_to_height`.

    Built by :func:`prepare`; treat as read-only. Per-pixel arrays are C-contiguous, ``[v, u]``.
    """

    hue_model: str
    n_bands: int
    shape: tuple[int, int]
    bit_depth: int
    min_saturation: float
    floor_slope: float
    nlines: int
    """Lines per column, ``ceil(N / 29)``."""
    cols: NDArray[np.uint16]
    """``(H, W, 32 nlines)``: each usable pixel's column rotated to start at its minimum (band
    ``start``), so sorted ascending, in overlapping lines (line j: entries 29 j - 1 .. 29 j + 30;
    entry -1 stored as 0, those past the column as 65535); 64-byte aligned. Zero for pixels that
    are never valid."""
    heads: NDArray[np.uint16]
    """``(H, W, P)``: the first entry of every line's block (``29 j``), padded with 65535 to ``P``,
    a multiple of 16."""
    guess: NDArray[np.integer]
    """``(tiles, 1024)``: per 32 x 32 tile and hue bucket, the line that most often brackets it."""
    tiles_x: int
    start: NDArray[np.uint16]
    ok: NDArray[np.bool_]
    """Pixels that can ever be valid: table valid, not in shadow."""
    gains: NDArray[np.float32]
    """``(H, W, 3)`` white-balance gains ``1 / max(white, floor)``."""
    phi_ref: NDArray[np.float32]
    a: NDArray[np.float32]
    b: NDArray[np.float32]
    noise: NDArray[np.float64]
    """Hue noise of one capture (rad) per pixel, for the denoise weights (see ``phase_sigma``)."""
    pd_emitted: NDArray[np.float64] | None = None
    """Pre-distortion (``session.Predistortion``), or None: emitted phases, extended by -2 pi and
    +2 pi as ``Predistortion.decode`` extends them, ..."""
    pd_code: NDArray[np.float64] | None = None
    """... the code phases, extended alike, ..."""
    pd_slope: NDArray[np.float64] | None = None
    """... the slopes between samples, ..."""
    pd_index: NDArray[np.int32] | None = None
    """... and per bucket of ``[emitted[0], emitted[0] + 2 pi)`` the last sample at or below it,
    as ``-index - 1`` where a sample lies within the bucket (then searched)."""
    phase_error: NDArray[np.float64] | None = None
    """The plane calibration's phase-error table (``PlaneCalibration.phase_error``), or None."""
    frequency: NDArray[np.float64] | None = None
    """:func:`huefringe.phase_error.frequency_inputs` where the phase-error table's correction is
    scaled to the local fringe frequency (:func:`huefringe.phase_error.correct_frequency`), else
    None."""
    stats: dict[str, Any] = field(default_factory=dict)
    budget: PixelBudget | None = None
    """Session inputs of the per-pixel height uncertainty (:func:`huefringe.uncertainty.pixel_budget`)."""
    sensor: NDArray[np.float32] | None = None
    """The table's shot + read noise model (``perframe.sensor_model``) when ``own_noise``: with it
    each frame's own hue noise (``perframe.frame_hue_noise``) replaces ``noise`` in the denoise
    weights."""
    u_sensor: NDArray[np.float32] | None = None
    """The same model without ``own_noise``: the filter's weights from the smoothed signal
    (``weight_blur_px``, ``perframe.weight_noise``) and the uncertainty's ratio, the frame's own
    noise against them (the filter sums ``w r`` beside its weights, ``perframe.noise_ratio2``)."""
    weight_blur_px: float = WEIGHT_BLUR_PX
    """``measure_frame``'s ``weight_blur_px``."""
    weight_angle: float | None = None
    """The reference phase's gradient direction (``perframe.fringe_angle``) that the weights'
    Gaussian runs perpendicular to; None: isotropic (``measure_frame``'s ``weight_blur_shape``)."""

    @property
    def nbytes(self) -> int:
        """Bytes of the prepared data."""
        arrays = (self.cols, self.heads, self.guess, self.start, self.ok, self.gains, self.phi_ref, self.a, self.b,
                  self.noise, self.pd_emitted, self.pd_code, self.pd_slope, self.pd_index, self.phase_error)
        return int(sum(x.nbytes for x in arrays if x is not None))


def _unit_white(white: NDArray[Any]) -> NDArray[np.float32]:
    w = np.asarray(white)
    if w.dtype in _INT_SCALE:
        return np.ascontiguousarray(w, dtype=np.float32) * np.float32(_INT_SCALE[w.dtype])
    return np.asarray(w, dtype=np.float32)


def _aligned_empty(shape: tuple[int, ...], align: int = 64) -> NDArray[np.uint16]:
    """uint16 array whose data starts on a cache-line boundary (``malloc`` gives 16 bytes)."""
    n = int(np.prod(shape))
    raw = np.empty(n + align, dtype=np.uint16)
    off = (-raw.ctypes.data % align) // 2
    return raw[off : off + n].reshape(shape)


def prepare(
    table: HueTable,
    cal: PlaneCalibration,
    white: NDArray[Any],
    *,
    hue_model: str | None = None,
    min_saturation: float,
    shadow: NDArray[np.bool_] | float | None = None,
    bit_depth: int = 8,
    floor: float = 1.0 / 255.0,
    floor_slope: float = 0.05,
    predistortion: Predistortion | None = None,
    own_noise: bool = False,
    weight_blur_px: float = WEIGHT_BLUR_PX,
    weight_blur_shape: str = WEIGHT_BLUR_SHAPE,
    phase_error_frequency: bool = False,
) -> Prepared:
    """Prepare a session's calibration for :func:`frame_to_height` (once per session).

    Parameters
    ----------
    table : HueTable
        The object's hue table (captured hue -> code phase); a memory-mapped one is read once.
    cal : PlaneCalibration
        Reference phase and per-pixel height model.
    white : ndarray, (H, W, 3)
        The object's white image: float in [0, 1], or uint8/uint16 codes.
    hue_model : {"hexcone", "hsi"}, optional
        Default: the table's model (frames must be decoded with the model of the table).
    min_saturation : float
        Frame pixels whose white-balanced saturation is ``<= min_saturation`` are invalid.
    shadow : bool ndarray (H, W) or float, optional
        Pixels to reject in every frame (True = shadow), e.g.
        ``perframe.shadow_mask(white, fraction)``; a float is taken as that ``fraction``.
    bit_depth : int
        Sensor bit depth: pixels with a channel at the top code are clipped (invalid).
    floor : float
        White-balance floor (as :func:`huefringe.colour.white_balance`).
    floor_slope : float
        Denoise only: lower bound of the table slope in the phase uncertainty (as
        :func:`huefringe.perframe.phase_sigma`).
    predistortion : Predistortion, optional
        The session's pre-distortion (``Session.predistortion``): the table then gives the
        emitted phase, decoded back to the code phase (as ``measure_frame(predistortion=...)``).
    own_noise, weight_blur_px, weight_blur_shape : bool, float, str
        ``measure_frame``'s: the filter's weights from each pixel's own signal, or from the
        signal smoothed by a Gaussian of ``weight_blur_px`` (``perframe.weight_noise``; 0: the
        table's pooled figure), isotropic or along the fringe.
    phase_error_frequency : bool
        ``measure_frame``'s: the phase-error table's correction scaled to each pixel's fringe
        frequency (:func:`huefringe.phase_error.correct_frequency`) after the filter.
    """
    model = table.model if hue_model is None else hue_model
    if model not in HUE_MODELS:
        raise ValueError(f"unknown hue model {model!r}; expected one of {HUE_MODELS}")
    h, w = table.shape
    wf = _unit_white(white)
    if wf.shape != (h, w, 3):
        raise ValueError(f"white has shape {wf.shape}, the table expects {(h, w, 3)}")
    for name in ("phi_ref", "a", "b"):
        if np.shape(getattr(cal, name)) != (h, w):
            raise ValueError(f"plane calibration {name} has shape {np.shape(getattr(cal, name))}, the table {(h, w)}")
    if shadow is None:
        shadow_arr = np.zeros((h, w), dtype=bool)
    elif np.ndim(shadow) == 0:
        shadow_arr = shadow_mask(wf, float(shadow))  # type: ignore[arg-type]
    else:
        shadow_arr = np.asarray(shadow, dtype=bool)
        if shadow_arr.shape != (h, w):
            raise ValueError(f"shadow has shape {shadow_arr.shape}, expected {(h, w)}")
    ok = np.ascontiguousarray(np.asarray(table.valid, bool) & ~shadow_arr)
    noise = capture_noise(table)  # per-pixel hue noise of one capture, as perframe.phase_sigma

    n = int(table.n_bands)
    nlines = -(-n // _STEP)
    start = np.ascontiguousarray(table.start, dtype=np.uint16)
    cols = _aligned_empty((h, w, nlines * _LINE))
    heads = _aligned_empty((h, w, -(-nlines // 16) * 16))
    _pixel_major(np.asarray(table.table), start, ok, cols, heads)
    tiles_x, tiles_y = -(-w // _TILE), -(-h // _TILE)
    guess = np.zeros((tiles_x * tiles_y, 65536 >> _SHIFT), dtype=np.uint8 if nlines <= 256 else np.uint16)
    _guess_lines(cols, ok, nlines, guess, tiles_x)
    prep = Prepared(
        hue_model=model,
        n_bands=n,
        shape=(h, w),
        bit_depth=int(bit_depth),
        min_saturation=float(min_saturation),
        floor_slope=float(floor_slope),
        nlines=nlines,
        cols=cols,
        heads=heads,
        guess=guess,
        tiles_x=tiles_x,
        start=start,
        ok=ok,
        gains=np.ascontiguousarray(white_gains(wf, floor), dtype=np.float32),
        phi_ref=np.ascontiguousarray(cal.phi_ref, dtype=np.float32),
        a=np.ascontiguousarray(cal.a, dtype=np.float32),
        b=np.ascontiguousarray(cal.b, dtype=np.float32),
        noise=noise,
    )
    if predistortion is not None:
        prep.pd_emitted, prep.pd_code, prep.pd_slope, prep.pd_index = _predistortion_arrays(predistortion)
    if getattr(cal, "phase_error", None) is not None:
        prep.phase_error = np.ascontiguousarray(cal.phase_error, dtype=np.float64)
        if phase_error_frequency:
            prep.frequency = frequency_inputs(cal)
    prep.budget = pixel_budget(table, cal)
    model = sensor_model(table)
    prep.sensor = model if own_noise else None  # measure_frame's own_noise
    prep.u_sensor = None if own_noise else model
    prep.weight_blur_px = float(weight_blur_px)
    prep.weight_angle = weight_blur_angle(cal.phi_ref, weight_blur_shape)
    prep.stats = {
        "table_invalid_fraction": float(np.mean(~np.asarray(table.valid, bool))),
        "shadow_fraction": float(shadow_arr.mean()),
        "prepared_mb": prep.nbytes / 1e6,
    }
    return prep


_PD_BUCKETS = 32768


def _predistortion_arrays(pd: Predistortion) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                                                      NDArray[np.int32]]:
    """The sample arrays ``Predistortion.decode`` interpolates in, their slopes (as ``np.interp``
    precomputes them), and a bucket index into them."""
    two_pi = 2.0 * np.pi
    e = np.concatenate([pd.emitted - two_pi, pd.emitted, pd.emitted + two_pi]).astype(np.float64)
    c = np.concatenate([pd.code - two_pi, pd.code, pd.code + two_pi]).astype(np.float64)
    e0 = float(pd.emitted[0])
    lows = e0 + two_pi * np.arange(_PD_BUCKETS + 1) / _PD_BUCKETS
    index = np.maximum(np.searchsorted(e, lows[:-1], side="right") - 1, 0).astype(np.int32)
    # buckets with no sample within 1e-9 rad of them (far beyond the rounding of the bucket
    # number): their index is the bracketing sample itself; the others (-index - 1) are searched
    inside = np.searchsorted(e, lows[1:] + 1e-9, side="right") - np.searchsorted(e, lows[:-1] - 1e-9, side="right")
    index = np.where(inside == 0, index, -index - 1).astype(np.int32)
    slopes = np.append((c[1:] - c[:-1]) / (e[1:] - e[:-1]), 0.0)
    return np.ascontiguousarray(e), np.ascontiguousarray(c), slopes, index


# =============================================================================================
# compiled pieces: layout
# =============================================================================================
@numba.njit(cache=True, nogil=True)
def _pixel_major(table, start, ok, cols, heads):  # pragma: no cover - numba
    """Rotated, sorted columns in overlapping lines (see the module docstring), and line heads.

    Line ``j`` position ``i`` holds entry ``k = 29 j - 1 + i`` of the sorted column; entry -1
    (line 0, position 0) is stored as 0 and entries past the column as 65535, so that counting
    entries <= a hue stays right; the arithmetic reads those two through :func:`_line_entry`.
    Pixel by pixel: its sorted column gathered (the row's ``N`` table rows stay in cache), then
    its lines written slot by slot.
    """
    n, h, w = table.shape
    nl = cols.shape[2] // 32
    col = np.empty(n, np.uint16)
    for v in range(h):
        for u in range(w):
            if not ok[v, u]:
                cols[v, u, :] = 0
                heads[v, u, :] = 65535
                continue
            s0 = np.int64(start[v, u])
            for k in range(n):  # sorted entry k is band (k + start) mod n
                i = k + s0
                col[k] = table[i - n if i >= n else i, v, u]
            for j in range(nl):
                for p in range(32):
                    k = 29 * j + p - 1
                    cols[v, u, 32 * j + p] = 0 if k < 0 else (col[k] if k < n else 65535)
            for line in range(heads.shape[2]):
                heads[v, u, line] = col[29 * line] if line < nl and 29 * line < n else 65535  # slot 1 of the line


@numba.njit(cache=True, nogil=True)
def _guess_lines(cols, ok, nl, guess, tiles_x):  # pragma: no cover - numba
    """Per tile and hue bucket, the line that brackets the bucket's centre in most pixels.

    Line ``j`` brackets the hues ``[cols[32 j + 1], cols[32 j + 30])``, those whose bracketing
    entry is in its block (the first line also those
    below the column's minimum, the last one those above its maximum); every usable pixel of the
    tile votes, per line, for the buckets whose centre falls in that range.
    """
    h, w, _ = cols.shape
    nb = guess.shape[1]
    size = 65536 // nb
    shift = 0
    while (1 << shift) < size:
        shift += 1
    votes = np.zeros((nl, nb + 1), dtype=np.int32)
    run = np.zeros(nl, dtype=np.int64)
    for t in range(guess.shape[0]):
        ty, tx = t // tiles_x, t % tiles_x
        votes[:, :] = 0
        for v in range(ty * _TILE, min(h, ty * _TILE + _TILE)):
            for u in range(tx * _TILE, min(w, tx * _TILE + _TILE)):
                if not ok[v, u]:
                    continue
                for j in range(nl):
                    lo = 0 if j == 0 else np.int64(cols[v, u, 32 * j + 1])
                    hi = 65536 if j == nl - 1 else np.int64(cols[v, u, 32 * j + 30])
                    k0 = min(nb, (lo - size // 2 + size - 1) >> shift)  # first bucket centre >= lo
                    k1 = min(nb, (hi - size // 2 + size - 1) >> shift)
                    if k1 > k0:
                        votes[j, k0] += 1
                        votes[j, k1] -= 1
        run[:] = 0
        for k in range(nb):
            best = 0
            for j in range(nl):
                run[j] += votes[j, k]
                if run[j] > run[best]:
                    best = j
            guess[t, k] = best


# =============================================================================================
# compiled pieces: per pixel
# =============================================================================================
def _unit(x, scale):  # pragma: no cover - replaced by the overload inside compiled code
    raise NotImplementedError


@overload(_unit, inline="always")
def _unit_ov(x, scale):
    """Sample to float32 in [0, 1], as ``session.read_rgb`` (codes) or ``np.asarray(x, float32)``."""
    if isinstance(x, types.Integer):
        return lambda x, scale: np.float32(x) * scale
    if x == types.float32:
        return lambda x, scale: x
    return lambda x, scale: np.float32(x)


def _clipped(x, xf, top32, top64):  # pragma: no cover - replaced by the overload
    raise NotImplementedError


@overload(_clipped, inline="always")
def _clipped_ov(x, xf, top32, top64):
    """``perframe.clipped_mask``: float32 frames compare in float32 (NEP 50), float64 in float64."""
    if x == types.float64:
        return lambda x, xf, top32, top64: x >= top64
    return lambda x, xf, top32, top64: xf >= top32


@intrinsic
def _prefetch(typingctx, arr, i):
    """Software prefetch of ``arr[i]`` (1-D) into all cache levels (``llvm.prefetch``)."""
    sig = types.void(arr, i)

    def codegen(context, builder, signature, args):  # pragma: no cover - compile time
        aryty, ity = signature.args
        ary = context.make_array(aryty)(context, builder, args[0])
        idx = context.cast(builder, args[1], ity, types.intp)
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [idx], wraparound=False)
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32]),
                                            "llvm.prefetch.p0")
        builder.call(fn, [ptr, i32(0), i32(3), i32(1)])
        return context.get_dummy_value()

    if not (isinstance(arr, types.Array) and arr.ndim == 1):
        return None
    return sig, codegen


def _count_le_codegen(lanes: int):  # pragma: no cover - compile time
    def codegen(context, builder, signature, args):
        aryty, offty, xty = signature.args
        ary = context.make_array(aryty)(context, builder, args[0])
        off = context.cast(builder, args[1], offty, types.intp)
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [off], wraparound=False)
        i16, i32 = ir.IntType(16), ir.IntType(32)
        vty = ir.VectorType(i16, lanes)
        vec = builder.load(builder.bitcast(ptr, vty.as_pointer()), align=2)
        xi = builder.trunc(context.cast(builder, args[2], xty, types.int64), i16)
        splat = builder.insert_element(ir.Constant(vty, ir.Undefined), xi, i32(0))
        splat = builder.shuffle_vector(splat, ir.Constant(vty, ir.Undefined),
                                       ir.Constant(ir.VectorType(i32, lanes), [0] * lanes))
        mty = ir.IntType(lanes)
        mask = builder.bitcast(builder.icmp_unsigned("<=", vec, splat), mty)
        ctpop = cgutils.get_or_insert_function(builder.module, ir.FunctionType(mty, [mty]), f"llvm.ctpop.i{lanes}")
        return builder.zext(builder.call(ctpop, [mask]), ir.IntType(64))

    return codegen


@intrinsic
def _count16_le(typingctx, arr, offset, x):
    """Number of the 16 entries ``arr[offset:offset + 16]`` (uint16, 1-D) that are ``<= x``.

    One vector compare, mask and popcount (``vpcmpuw``/``kmov``/``popcnt`` with AVX-512,
    ``vpcmpgtw``/``pmovmskb``/``popcnt`` with AVX2): no branches, no bisection.
    """
    if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.dtype == types.uint16):
        return None
    return types.intp(arr, offset, x), _count_le_codegen(16)


@intrinsic
def _count32_le(typingctx, arr, offset, x):
    """:func:`_count16_le` over the 32 entries of one 64-byte line (one compare with AVX-512BW)."""
    if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.dtype == types.uint16):
        return None
    return types.intp(arr, offset, x), _count_le_codegen(32)


# Helpers below take scalars only: a helper given an array, once inlined, costs numba two
# reference-count calls per pixel.
@numba.njit(cache=True, inline="always", error_model="numpy")
def _mod(x, m):  # pragma: no cover - numba
    """``np.mod(x, m)`` for ``m > 0`` (float32 or float64, bit for bit), without a libm ``fmod``
    call on the usual range ``-m <= x < 2 m`` (there ``x - m`` is exact, Sterbenz)."""
    if x >= -m and x < m + m:
        if x == 0:
            return x - x  # +0, as NumPy
        if x < 0:
            return x + m
        if x < m:
            return x
        return x - m
    r = np.fmod(x, m)
    if r != 0 and r < 0:
        r = r + m
    return r


@numba.njit(cache=True, inline="always", error_model="numpy")
def _phys(i):  # pragma: no cover - numba
    """Offset in the column lines of entry ``i`` of the sorted column."""
    line = i // 29
    return 32 * line + (i - 29 * line) + 1


@numba.njit(cache=True, inline="always", error_model="numpy")
def _line_entry(cols, o, k, n):  # pragma: no cover - numba
    """Entry ``k`` (any integer) of the sorted column at ``cols[o:]`` continued periodically
    (``huetable._column_entry``): ``column[k mod N] + 65536 floor(k / N)``."""
    off = 0.0
    if k < 0:  # here k >= -2 and N >= 3: one turn down or up at most (no integer division)
        k += n
        off = -65536.0
    elif k >= n:
        k -= n
        off = 65536.0
    if k < 0 or k >= n:
        q = k // n
        k -= q * n
        off += 65536.0 * q
    return np.float64(cols[np.uint64(o + _phys(k))]) + off


@numba.njit(cache=True, inline="always", error_model="numpy")
def _interp(bb, hq, lo_val, hi_val, n):  # pragma: no cover - numba
    """Code phase between band ``bb`` (entry ``lo_val``) and the next one (``hi_val``), as
    ``huetable._to_phase_kernel``."""
    two_pi = 2.0 * np.pi
    c = (bb + (hq - lo_val) / (hi_val - lo_val)) * (two_pi / n)
    if c >= two_pi:
        c -= two_pi
    r = np.float32(c)
    if r >= np.float32(two_pi):
        r = np.float32(0.0)
    return r


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _frame_kernel(rgb, scale, top32, top64, gains, ok, cols, heads, guess, tiles_x, n, start, phi_ref, a, b, noise,
                  atan, min_sat, use_min_sat, floor_slope, pd_e, pd_c, pd_s, pd_index, pe, out_h, out_valid,
                  out_dphi, out_w, out_phase, out_hue, rgb2, scale2, atan2, out_delta):  # pragma: no cover - numba
    """The fused per-pixel loop; returns (clipped, hue undefined, valid, guess missed, guess far)
    counts.

    Rows go through three passes, pass 1 one row ahead of the others: (1) white balance, hue,
    masks (:func:`_colour_row`, vectorised) and the guessed line of each pixel's column; (2) the
    count in that line (:func:`_lookup_row`, and the prefetch of the next row's lines); (3)
    interpolation, pre-distortion, phase difference and height (:func:`_finish_row`). ``out_dphi``
    receives the phase difference before any filtering; with ``out_w`` given (``(3, H, W)``
    float32), the weights of the denoise filter (``phase.denoise_phase``'s ``dz, s2, inv`` of the
    phase difference and its uncertainty) are written instead of the height (the filter runs
    between this loop and :func:`_height_kernel`). ``out_phase``, ``out_hue``, ``out_dphi`` and
    ``out_w`` may be None: numba compiles a version without them (``is None`` pruning); so may the
    pre-distortion ``pd_e, pd_c, pd_s, pd_index`` (no decoding). ``cols`` and ``heads`` are flat
    views.

    ``rgb2`` (or None): a second capture of the same scene (the texture correction's moved
    capture, its scale ``scale2`` and HSI ``atan2``) taken through the same three passes beside
    the first, pixel by pixel, so that its lookups read the column lines the first one's have
    just fetched; its phase difference is never kept: ``out_delta`` receives
    ``uncertainty.texture_delta(dphi2, dphi)`` row by row (``out_dphi`` is then required). Its
    arithmetic is that of a call of its own without the filter (the same functions, ``out_w``
    None), so ``out_delta`` holds the bits of ``texture_delta`` of the two calls' phase
    differences.
    """
    h, w, _ = rgb.shape
    ncols = cols.size // (h * w)
    nheads = heads.size // (h * w)
    nl = ncols // 32
    # pass 2 only looks up; the arithmetic after the lookup is _finish_row's
    rows_hq, rows_g, row_bb, row_lo, row_hi, row_em, row_ph, row_pds = _row_scratch(w)
    row_pm = np.zeros(w, dtype=np.float64)  # denoise: column entries p - 1 and p + 2 (hue_slope)
    row_pp = np.ones(w, dtype=np.float64)
    # the second capture's rows (one pixel each when there is none)
    w2 = w if rgb2 is not None else 1
    rows_hq2, rows_g2, row2_bb, row2_lo, row2_hi, row2_em, row2_ph, row2_pds = _row_scratch(w2)
    row2_h = np.empty((1, w2), dtype=np.float32)  # its height, valid and phase difference (one row)
    row2_valid = np.empty((1, w2), dtype=np.bool_)
    row2_dphi = np.empty((1, w2), dtype=np.float32)
    n_clip = 0
    n_undef = 0
    n_valid = 0
    n_miss = 0
    n_far = 0
    for vi in range(h + 1):
        # ------------------------------------------------------------ pass 1 (row vi): colour and
        # guessed lines, one row ahead of pass 2, which prefetches them, so that the lines have a
        # whole row's time to arrive (a row of lines, 48 KB at 768 px, stays in L2)
        if vi < h:
            hq1 = rows_hq[vi & 1]
            g1 = rows_g[vi & 1]
            nc, nu = _colour_row(rgb, vi, 0, w, scale, top32, top64, gains, ok, atan, min_sat, use_min_sat, hq1,
                                 out_hue)
            n_clip += nc
            n_undef += nu
            _guess_row(guess, vi, tiles_x, hq1, g1)
            if rgb2 is not None:
                _colour_row(rgb2, vi, 0, w, scale2, top32, top64, gains, ok, atan2, min_sat, use_min_sat,
                            rows_hq2[vi & 1], None)
                _guess_row(guess, vi, tiles_x, rows_hq2[vi & 1], rows_g2[vi & 1])
        if vi > 0:
            v = vi - 1
            row_hq = rows_hq[v & 1]
            row_g = rows_g[v & 1]
            # ---------------------------------------------------------------- pass 2: table lookup
            # (and the prefetch of row vi's lines, spread over the loop so that the memory
            # requests overlap its arithmetic instead of queueing in a burst)
            if out_w is not None:  # (two calls: numba prunes the slope entries by ``is None``)
                nm, nf = _lookup_row(cols, heads, start, v, ncols, nheads, nl, n, row_hq, row_g, row_bb, row_lo,
                                     row_hi, row_pm, row_pp, rows_g[vi & 1], vi < h)
            else:
                nm, nf = _lookup_row(cols, heads, start, v, ncols, nheads, nl, n, row_hq, row_g, row_bb, row_lo,
                                     row_hi, None, row_pp, rows_g[vi & 1], vi < h)
            n_miss += nm
            n_far += nf
            # ---------------------------------------------------------------- pass 3: arithmetic
            n_valid += _finish_row(v, row_bb, row_hq, row_lo, row_hi, row_g, phi_ref, a, b, noise, n, floor_slope, pd_e,
                                   pd_c, pd_s, pd_index, pe, row_em, row_ph, row_pds, row_pm, row_pp, out_h, out_valid,
                                   out_phase, out_dphi, out_w)
            if rgb2 is not None:  # the second capture: its lines are those just read, mostly
                row2_hq = rows_hq2[v & 1]
                row2_g = rows_g2[v & 1]
                _lookup_row(cols, heads, start, v, ncols, nheads, nl, n, row2_hq, row2_g, row2_bb, row2_lo, row2_hi,
                            None, row_pp, None, False)
                _finish_row(0, row2_bb, row2_hq, row2_lo, row2_hi, row2_g, phi_ref[v : v + 1], a[v : v + 1],
                            b[v : v + 1], noise[v : v + 1], n, floor_slope, pd_e, pd_c, pd_s, pd_index, pe, row2_em,
                            row2_ph, row2_pds, row_pm, row_pp, row2_h, row2_valid, None, row2_dphi, None)
                _texture_delta_row(row2_dphi[0], out_dphi[v], out_delta[v])
    return n_clip, n_undef, n_valid, n_miss, n_far


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _row_scratch(w):  # pragma: no cover - numba
    """The scratch rows of one capture in :func:`_frame_kernel`: hue in table counts and guessed
    line (-1 = pixel invalid), two rows in flight; the bracketing band, its column entries, the
    emitted phase, the decoded phase and the decoding slope of the row being finished."""
    return (np.empty((2, w), dtype=np.float64), np.empty((2, w), dtype=np.int64), np.zeros(w, dtype=np.float64),
            np.zeros(w, dtype=np.float64), np.ones(w, dtype=np.float64), np.zeros(w, dtype=np.float32),
            np.zeros(w, dtype=np.float32), np.ones(w, dtype=np.float64))


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _guess_row(guess, v, tiles_x, hq_row, out_g):  # pragma: no cover - numba
    """The guessed line of each pixel of row ``v`` from its tile's guess table; -1 where the pixel
    is invalid (``hq < 0``)."""
    tile_row = (v // _TILE) * tiles_x
    for u in range(hq_row.size):
        hq = hq_row[u]
        if hq < 0:
            out_g[u] = -1
            continue
        out_g[u] = np.int64(guess[tile_row + u // _TILE, np.int64(hq) >> _SHIFT])


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _lookup_row(cols, heads, start, v, ncols, nheads, nl, n, row_hq, row_g, row_bb, row_lo, row_hi, row_pm, row_pp,
                g_next, more):  # pragma: no cover - numba
    """Pass 2 of :func:`_frame_kernel` on row ``v``: each pixel's bracketing band ``row_bb`` and
    column entries ``row_lo``, ``row_hi`` (and, with ``row_pm`` given, the entries either side of
    them for the table slope, ``row_pm``, ``row_pp``), from its guessed line ``row_g``; neutral
    values where ``row_g < 0``. With ``g_next`` given and ``more``, prefetches the next row's
    guessed lines. Returns (guess missed, guess far) counts."""
    w = row_hq.size
    n_miss = 0
    n_far = 0
    vi = v + 1
    for u in range(w):
        if g_next is not None and more:
            gx = g_next[u]
            if gx >= 0:
                _prefetch(cols, (vi * w + u) * ncols + 32 * gx)
        gl = row_g[u]
        if gl < 0:  # neutral values for _finish_row, which masks the pixel
            row_hq[u] = 0.0
            row_bb[u] = 0.0
            row_lo[u] = 0.0
            row_hi[u] = 1.0
            if row_pm is not None:
                row_pm[u] = -1.0
                row_pp[u] = 2.0
            continue
        hq = row_hq[u]
        hqi = np.int64(hq)  # entries are integers: entry <= hq  <=>  entry <= floor(hq)
        s0 = np.int64(start[v, u])
        o = (v * w + u) * ncols
        # -- table lookup (huetable._to_phase_kernel). Its bisection finds p + 1, the
        # number of entries <= hue in the rotated, sorted column; p is the bracketing
        # entry. Counted here in the guessed line: f entries of line gl (column entries
        # 29 gl - 1 .. 29 gl + 30) are <= hue; when 2 <= f <= 30, p = 29 gl - 2 + f lies
        # in the line's own block and the entries p - 1 .. p + 2 are all in the line (the
        # first line also takes f = 1, p = -1; the last one f > 30: the column's end).
        # Otherwise the next line down or up, then the line heads, give the line.
        f = _count32_le(cols, o + 32 * gl, hqi)
        if not ((f >= 2 or gl == 0) and (f <= 30 or gl == nl - 1)):
            n_miss += 1
            # mostly the next line down (f <= 1) or up (f >= 31): 64 bytes away, often
            # already cached with the guessed one
            g2 = gl - 1 if f <= 1 else gl + 1
            f2 = 0
            if 0 <= g2 < nl:
                f2 = _count32_le(cols, o + 32 * g2, hqi)
            if 0 <= g2 < nl and (f2 >= 2 or g2 == 0) and (f2 <= 30 or g2 == nl - 1):
                gl = g2
                f = f2
            else:  # heads: E(29 j), the first entry of each block
                n_far += 1
                oh = (v * w + u) * nheads
                cl = 0
                for k in range(0, nheads, 16):
                    cl += _count16_le(heads, oh + k, hqi)
                if cl > nl:  # padding counted
                    cl = nl
                gl = cl - 1 if cl > 0 else 0
                f = _count32_le(cols, o + 32 * gl, hqi)
        cnt = 29 * gl - 1 + f
        p = (cnt if cnt < n else n) - 1  # padding counted: every real entry is <= hue
        if p < 0:
            bb = s0 - 1 if s0 > 0 else n - 1
            lo_val = np.float64(cols[np.uint64(o + _phys(n - 1))]) - 65536.0
            hi_val = np.float64(cols[np.uint64(o + 1)])
        else:
            bb = s0 + p
            if bb >= n:
                bb -= n
            op = o + 32 * gl + p - 29 * gl + 1  # p's place in line gl (its home line)
            lo_val = np.float64(cols[np.uint64(op)])
            if p == n - 1:
                hi_val = np.float64(cols[np.uint64(o + 1)]) + 65536.0
            else:
                hi_val = np.float64(cols[np.uint64(op + 1)])
        row_bb[u] = bb
        row_lo[u] = lo_val
        row_hi[u] = hi_val
        if row_pm is not None:  # HueTable.hue_slope needs the entries either side, in line
            if p >= 1:
                row_pm[u] = np.float64(cols[np.uint64(op - 1)])
            else:
                row_pm[u] = _line_entry(cols, o, p - 1, n)
            if 0 <= p and p + 2 <= n - 1:
                row_pp[u] = np.float64(cols[np.uint64(op + 2)])
            else:
                row_pp[u] = _line_entry(cols, o, p + 2, n)
    return n_miss, n_far


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _colour_row(rgb, v, u0, u1, scale, top32, top64, gains, ok, atan, min_sat, use_min_sat, out_hq,
                out_hue):  # pragma: no cover - numba
    """White balance, clipping, hue and saturation of pixels ``u0 .. u1`` of row ``v``.

    Writes ``out_hq[u]``, the hue in table counts (``hue * 65536 / 2 pi``), or -1 where the pixel
    is invalid (clipped, hue undefined or unsaturated, or not ``ok``); ``out_hue`` (or None)
    the white-balanced hue, NaN where undefined. Hue in float32, as ``colour.hue`` on the float32
    white-balanced image (HSI: from ``atan``, NumPy's float32 ``arctan2`` of the same x, y,
    computed by ``_hsi_xy`` + ``np.arctan2`` before the loop: its SIMD loops differ from libm by
    a few ulp, which the table slope and the pre-distortion amplify). Branch-free, so that LLVM
    vectorises it. Returns (clipped, hue undefined) counts.
    """
    two_pi_f32 = np.float32(2.0 * np.pi)
    third = np.float32(np.pi / 3.0)
    k3 = np.float32(math.sqrt(3.0) / 2.0)
    half = np.float32(0.5)
    zero32 = np.float32(0.0)
    nan32 = np.float32(np.nan)
    to_counts = 65536.0 / (2.0 * np.pi)
    n_clip = 0
    n_undef = 0
    # 1-D row slices indexed from 0: provably non-negative indices, no wraparound selects
    px = rgb[v].reshape(-1)[3 * u0 : 3 * u1]
    gn = gains[v].reshape(-1)[3 * u0 : 3 * u1]
    okr = ok[v, u0:u1]
    hqr = out_hq[u0:u1]
    if atan is not None:
        atr = atan[v, u0:u1]
    if out_hue is not None:
        hur = out_hue[v, u0:u1]
    for i in range(u1 - u0):
        x0 = px[3 * i]
        x1 = px[3 * i + 1]
        x2 = px[3 * i + 2]
        f0 = _unit(x0, scale)
        f1 = _unit(x1, scale)
        f2 = _unit(x2, scale)
        clipped = _clipped(x0, f0, top32, top64) | _clipped(x1, f1, top32, top64) | _clipped(x2, f2, top32, top64)
        r = f0 * gn[3 * i]
        g = f1 * gn[3 * i + 1]
        bl = f2 * gn[3 * i + 2]
        mx = max(max(r, g), bl)
        mn = min(min(r, g), bl)
        c = mx - mn
        if atan is not None:  # HSI
            xx = r - half * (g + bl)
            yy = k3 * (g - bl)
            defined = (xx != 0) | (yy != 0)
            if use_min_sat:
                den = (r + g) + bl
                sat = (den - np.float32(3) * mn) / den
                sat = sat if den > 0 else zero32
                defined = defined & (sat > min_sat)
            hue = atr[i]
        else:
            defined = c != 0
            if use_min_sat:
                sat = c / mx
                sat = sat if mx > 0 else zero32
                defined = defined & (sat > min_sat)
            num = g - bl if mx == r else (bl - r if mx == g else r - g)
            h6 = num / c
            h6 = h6 if mx == r else (h6 + np.float32(2) if mx == g else h6 + np.float32(4))
            hue = h6 * third
        hue = np.float32(hue + two_pi_f32) if hue < 0 else hue
        hue = zero32 if hue >= two_pi_f32 else hue
        hue = hue if defined else nan32
        n_clip += clipped
        n_undef += not defined
        if out_hue is not None:
            hur[i] = hue
        hq = np.float64(hue) * to_counts  # < 65536 for hue < float32(2 pi)
        hqr[i] = hq if (defined & okr[i] & (not clipped)) else -1.0
    return n_clip, n_undef


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _finish_row(v, bb, hq, lo, hi, g, phi_ref, a, b, noise, n, floor_slope, pd_e, pd_c, pd_s, pd_index, pe, em, ph, pds,
                pm, pp, out_h, out_valid, out_phase, out_dphi, out_w):  # pragma: no cover - numba
    """Looked-up bands of row ``v`` (``bb``, ``hq``, ``lo``, ``hi``; ``g < 0`` marks invalid
    pixels) to heights, or to the denoise filter's weights of the phase difference (``out_w``).

    Operation by operation as the reference (see the comments), in three loops: (A) the band
    interpolation (``_interp``) and (C) the phase difference (``phase.wrap``), height or
    uncertainty, both branch-free so that LLVM vectorises them, and between them (B) the
    pre-distortion's decoding, scalar. The wrap uses ``_mod``'s exact fast path, valid while
    ``pi - dphi`` lies in [-2 pi, 4 pi) (``phi_ref`` in [0, 2 pi)); pixels outside it are redone
    with ``_mod``. ``pm``, ``pp``: the column entries before and after the bracketing pair (the
    uncertainty's slope, ``HueTable.hue_slope``); ``em``, ``ph``, ``pds`` are scratch rows.
    Returns the number of valid pixels.
    """
    w = bb.size
    two_pi = 2.0 * np.pi
    pi = np.pi
    step = two_pi / n
    two_pi_f32 = np.float32(two_pi)
    zero32 = np.float32(0.0)
    nan32 = np.float32(np.nan)
    # (A) huetable._to_phase_kernel's interpolation: the emitted (or code) phase
    for u in range(w):
        c = (bb[u] + (hq[u] - lo[u]) / (hi[u] - lo[u])) * step
        c = c - two_pi if c >= two_pi else c
        r = np.float32(c)
        em[u] = zero32 if r >= two_pi_f32 else r
    # (B) Predistortion.decode, bit for bit: np.interp on the extended samples (same
    # bracketing and slope formula), np.mod, float32; and decode_slope, the slope of the
    # bracketing segment. Scalar: a branch-free version with gathers was measured slower.
    if pd_e is not None:
        pd_last = pd_e.size - 1
        pd_e0 = pd_e[pd_e.size // 3]
        pd_nb = pd_index.size
        pd_scale = pd_nb / two_pi
        for u in range(w):
            if g[u] < 0:
                ph[u] = zero32
                pds[u] = 1.0
                continue
            x = _mod(np.float64(em[u]) - pd_e0, two_pi) + pd_e0
            if x > pd_e[pd_last]:
                y = pd_c[pd_last]
                pds[u] = pd_s[pd_last - 1]
            elif x < pd_e[0]:
                y = pd_c[0]
                pds[u] = pd_s[0]
            else:
                kb = min(max(int((x - pd_e0) * pd_scale), 0), pd_nb - 1)
                jp = np.int64(pd_index[kb])
                if jp < 0:  # a sample near the bucket: np.interp's search from there
                    jp = -jp - 1
                    while jp > 0 and pd_e[jp] > x:
                        jp -= 1
                    while jp < pd_last and pd_e[jp + 1] <= x:
                        jp += 1
                pds[u] = pd_s[jp if jp < pd_last else pd_last - 1]
                if jp == pd_last or pd_e[jp] == x:
                    y = pd_c[jp]
                else:
                    sl = pd_s[jp]
                    y = sl * (x - pd_e[jp]) + pd_c[jp]
                    if y != y:
                        y = sl * (x - pd_e[jp + 1]) + pd_c[jp + 1]
                        if y != y and pd_c[jp] == pd_c[jp + 1]:
                            y = pd_c[jp]
            ph[u] = np.float32(_mod(y, two_pi))
    else:
        ph = em
    # (B2) the phase-error table (phase_error.correct, the same compiled correct_one)
    if pe is not None:
        for u in range(w):
            ph[u] = correct_one(ph[u], pe)
    # (C) phase difference (phase.wrap), then h = dphi / (a + b dphi), or, for the denoise
    # filter, dphi and its uncertainty (perframe.phase_sigma with HueTable.hue_slope, times
    # |Predistortion.decode_slope|)
    ref = phi_ref[v]
    av = a[v]
    bv = b[v]
    nz = noise[v]
    hv = out_h[v]
    vv = out_valid[v]
    if out_phase is not None:
        pv = out_phase[v]
    if out_dphi is not None:
        dv = out_dphi[v]
    if out_w is not None:
        wd = out_w[0, v]
        ws = out_w[1, v]
        wi = out_w[2, v]
    n_valid = 0
    n_out = 0
    for u in range(w):
        r = ph[u]
        x = pi - (np.float64(r) - np.float64(ref[u]))
        n_out += (x < -two_pi) | (x >= two_pi + two_pi)
        m = x + two_pi if x < 0 else (x if x < two_pi else x - two_pi)
        dphi = np.float32(pi - m)
        if out_w is not None:
            # HueTable.hue_slope (huetable._to_phase_kernel): central difference over a band
            f = (hq[u] - lo[u]) / (hi[u] - lo[u])
            sc_lo = (0.5 - f) * (lo[u] - pm[u]) + (0.5 + f) * (hi[u] - lo[u])
            sc_hi = (1.5 - f) * (hi[u] - lo[u]) + (f - 0.5) * (pp[u] - hi[u])
            slope = (sc_lo if f < 0.5 else sc_hi) * n / 65536.0
            sig = sigma_from_slope(nz[u], slope, floor_slope)  # perframe.phase_sigma's, per pixel
            if pd_e is not None:
                sig = sig * abs(pds[u])
            ok = g[u] >= 0
            wd[u], ws[u], wi[u] = denoise_weight(dphi, sig, ok)  # phase.denoise_phase's weights
            hv[u] = nan32  # _height_kernel writes the valid ones
        else:
            hh = dphi / (av[u] + bv[u] * dphi)
            ok = (g[u] >= 0) & (hh - hh == 0)
            hv[u] = hh if ok else nan32
        vv[u] = ok
        if out_dphi is not None:
            dv[u] = dphi if g[u] >= 0 else nan32
        if out_phase is not None:
            pv[u] = r if ok else nan32
        n_valid += ok
    if n_out:  # some phi_ref outside [0, 2 pi): those pixels again, with the general _mod
        for u in range(w):
            if g[u] < 0:
                continue
            d = np.float64(ph[u]) - np.float64(ref[u])
            dphi = np.float32(pi - _mod(pi - d, two_pi))
            if out_dphi is not None:
                dv[u] = dphi
            if out_w is not None:
                wd[u] = dphi if wi[u] > 0 else zero32
                continue
            hh = dphi / (av[u] + bv[u] * dphi)
            ok = hh - hh == 0
            n_valid += np.int64(ok) - np.int64(vv[u])
            hv[u] = hh if ok else nan32
            vv[u] = ok
            if out_phase is not None:
                pv[u] = ph[u] if ok else nan32
    return n_valid


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _hsi_xy(rgb, scale, gains, out_x, out_y):  # pragma: no cover - numba
    """The arguments of the HSI ``arctan2`` (``colour.hue_hsi``) of the white-balanced frame."""
    h, w, _ = rgb.shape
    half = np.float32(0.5)
    k3 = np.float32(math.sqrt(3.0) / 2.0)
    for v in range(h):
        for u in range(w):
            r = _unit(rgb[v, u, 0], scale) * gains[v, u, 0]
            g = _unit(rgb[v, u, 1], scale) * gains[v, u, 1]
            bl = _unit(rgb[v, u, 2], scale) * gains[v, u, 2]
            out_x[v, u] = r - half * (g + bl)
            out_y[v, u] = k3 * (g - bl)


def _hsi_atan(rgb: NDArray[Any], scale: float, gains: NDArray[np.float32]) -> NDArray[np.float32]:
    """The HSI hue's ``arctan2(y, x)`` (float32) of a white-balanced frame (:func:`_hsi_xy`)."""
    h, w = rgb.shape[:2]
    x = np.empty((h, w), dtype=np.float32)
    y = np.empty((h, w), dtype=np.float32)
    _hsi_xy(rgb, np.float32(scale), gains, x, y)
    return np.arctan2(y, x, out=y)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _height_kernel(dphi, a, b, valid, out_h, out_phase):  # pragma: no cover - numba
    """Height from a (denoised) float32 phase difference; clears pixels without a finite height."""
    h, w = dphi.shape
    nan32 = np.float32(np.nan)
    n_valid = 0
    for v in range(h):
        for u in range(w):
            if valid[v, u]:
                d = dphi[v, u]
                hh = d / (a[v, u] + b[v, u] * d)
                if hh - hh == 0:
                    out_h[v, u] = hh
                    n_valid += 1
                    continue
                valid[v, u] = False
                if out_phase is not None:
                    out_phase[v, u] = nan32
            out_h[v, u] = nan32
    return n_valid


# =============================================================================================
# public per-frame API
# =============================================================================================
@dataclass
class FrameMaps:
    """Everything :func:`frame_maps` computes for one frame."""

    height: NDArray[np.float32]
    """Height in mm, NaN where invalid."""
    valid: NDArray[np.bool_]
    phase: NDArray[np.float32] | None = None
    """Corrected code phase [0, 2 pi), NaN where invalid (``want_maps``)."""
    hue: NDArray[np.float32] | None = None
    """White-balanced hue, NaN where undefined (``want_maps``)."""
    counts: dict[str, int] = field(default_factory=dict)
    """Pixel counts: ``clipped``, ``hue_undefined``, ``valid``, ``guess_missed`` (lookups whose
    guessed line did not bracket the hue) and ``guess_far`` (of those, the ones where the next
    line up or down did not either, so the line heads were searched): speed statistics, not
    quality ones."""
    dphi: NDArray[np.float32] | None = None
    """Wrapped phase difference to the reference plane before the denoise filter,
    ``float32(wrap(phase - phi_ref))``, NaN where no phase was decoded (``want_dphi``)."""
    uncertainty: NDArray[np.float32] | None = None
    """Standard uncertainty of the height in mm, NaN where the height is NaN
    (``want_uncertainty``; :func:`huefringe.uncertainty.height_uncertainty`)."""
    support: NDArray[np.float32] | None = None
    """Pixels the filter averaged into each height, 0 where NaN (``want_uncertainty``;
    ``perframe.FrameResult.support``)."""
    texture_u: NDArray[np.float32] | None = None
    """The texture term of the uncertainty (mm, NaN where the height is;
    :func:`huefringe.uncertainty.texture_term_phase`), with ``texture_rgb``."""
    noise: NDArray[np.float32] | None = None
    """Standard deviation (mm) of each height from the capture noise alone, NaN where the height is
    NaN (``want_uncertainty``; ``perframe.height_noise``, as ``perframe.FrameResult.noise``)."""
    weight: NDArray[np.float32] | None = None
    """Each pixel's own filter weight ``1 / sigma^2`` before the filter (0 where no phase was
    decoded; ``want_uncertainty``; as ``perframe.FrameResult.weight``): where the filter's window
    has its centroid (:func:`huefringe.uncertainty.lateral_term`'s ``weight``)."""
    bias2: NDArray[np.float32] | None = None
    """The sigma-adaptive filter's own squared bias (rad^2) where it grew the window, NaN where the
    first pass's fixed window stands or the plane was dropped at a step
    (:func:`huefringe.phase.denoise_phase`'s ``bias2``): in the uncertainty; the lateral term's
    centroid part is for the others (``grown``)."""


def _check_frame(prep: Prepared, rgb: NDArray[Any]) -> tuple[NDArray[Any], float]:
    a = np.asarray(rgb)
    if a.shape != (*prep.shape, 3):
        raise ValueError(f"frame has shape {a.shape}, the calibration expects {(*prep.shape, 3)}")
    if a.dtype in _INT_SCALE:
        scale = _INT_SCALE[a.dtype]
    elif a.dtype in (np.float32, np.float64):
        scale = 1.0
    else:
        raise TypeError(f"frame dtype {a.dtype} not supported (uint8, uint16, float32, float64)")
    if not a.flags.c_contiguous:
        a = np.ascontiguousarray(a)
    return a, scale


def frame_maps(
    prep: Prepared,
    rgb: NDArray[Any],
    *,
    denoise_radius: int = 0,
    denoise_k: float = 3.0,
    want_maps: bool = False,
    want_dphi: bool = False,
    want_uncertainty: bool = False,
    out: tuple[NDArray[np.float32], NDArray[np.bool_]] | None = None,
    denoise_adaptive: dict[str, Any] | None = None,
    texture_rgb: NDArray[Any] | None = None,
) -> FrameMaps:
    """One frame through the kernel; :func:`frame_to_height` with optional phase and hue maps.

    ``want_maps=True`` also returns the corrected code phase and the white-balanced hue (as
    ``measure_frame``'s ``phase`` and ``hue``), ``want_dphi=True`` the phase difference before
    denoising (for the unwrapping flags), ``want_uncertainty=True`` the height's standard
    uncertainty (from the filter's sums of weights); ``counts`` hold the pixel counts of the frame
    statistics. ``out`` = (height, valid) buffers to reuse (float32 and bool, shape (H, W)).
    ``denoise_adaptive``: the filter's sigma-adaptive support (``measurement.denoise_adaptive``,
    :func:`huefringe.phase.adaptive_kwargs`), as ``measure_frame``'s. ``texture_rgb``: the capture
    corrected with the texture blur moved by its uncertainty; its phase goes through the kernel
    without the filter, in the same pass as this frame's (each pixel's table lines read once for
    both), and its change is carried through this frame's filter
    (:func:`huefringe.uncertainty.texture_delta`, ``texture_term_phase``): ``texture_u``.
    """
    a, scale = _check_frame(prep, rgb)
    a2, scale2 = _check_frame(prep, texture_rgb) if texture_rgb is not None else (None, 1.0)
    h, w = prep.shape
    if out is None:
        height = np.empty((h, w), dtype=np.float32)
        valid = np.empty((h, w), dtype=bool)
    else:
        height, valid = out
        if height.shape != (h, w) or height.dtype != np.float32 or valid.shape != (h, w) or valid.dtype != bool:
            raise ValueError("out must be (float32 (H, W), bool (H, W))")
    denoise = int(denoise_radius) > 0
    phase = np.empty((h, w), dtype=np.float32) if want_maps else None
    hue = np.empty((h, w), dtype=np.float32) if want_maps else None
    freq = prep.frequency is not None  # the phase-error correction scaled to the fringe frequency, after the filter
    dphi = np.empty((h, w), dtype=np.float32) if denoise or want_dphi or texture_rgb is not None or freq else None
    # the filter's dz, s2, inv (also without the filter when the uncertainty needs them)
    weights = np.empty((3, h, w), dtype=np.float32) if denoise or want_uncertainty else None
    top = 1.0 - 0.5 / (2**prep.bit_depth - 1)
    hsi = prep.hue_model == "hsi"
    # NumPy's own float32 arctan2, as colour.hue_hsi (one extra pass; hexcone needs none), for each
    # capture in a call of its own (the same bits as a frame_maps call of each)
    atan = _hsi_atan(a, scale, prep.gains) if hsi else None
    atan2 = _hsi_atan(a2, scale2, prep.gains) if hsi and a2 is not None else None
    delta = np.empty((h, w), dtype=np.float32) if a2 is not None else None
    noise = prep.noise
    if weights is not None and prep.sensor is not None:  # this frame's own hue noise (as measure_frame)
        noise = np.empty((h, w), dtype=np.float64)
        _hue_noise_kernel(a, np.float32(scale), prep.gains, hsi, prep.sensor, prep.noise, noise)
    r_w = None  # the weights from the smoothed signal (as measure_frame's weight_noise)
    if int(denoise_radius) > 0 and prep.u_sensor is not None and prep.weight_blur_px > 0:
        noise, r_w = weight_noise_of(prep.noise, prep.u_sensor, a, prep.gains, hsi, prep.weight_blur_px, scale,
                                     prep.weight_angle)
    n_clip, n_undef, n_valid, n_miss, n_far = _frame_kernel(
        a, np.float32(scale), np.float32(top), float(top), prep.gains, prep.ok, prep.cols.reshape(-1),
        prep.heads.reshape(-1), prep.guess, prep.tiles_x, prep.n_bands, prep.start, prep.phi_ref, prep.a, prep.b,
        noise, atan, np.float32(prep.min_saturation), prep.min_saturation > 0.0, prep.floor_slope,
        prep.pd_emitted, prep.pd_code, prep.pd_slope, prep.pd_index, prep.phase_error, height, valid, dphi, weights,
        phase, hue, a2, np.float32(scale2), atan2, delta,
    )
    ratio = None
    if want_uncertainty and prep.u_sensor is not None:  # this frame's own noise, for u alone (as measure_frame)
        own = np.empty((h, w), dtype=np.float64)
        _hue_noise_kernel(a, np.float32(scale), prep.gains, hsi, prep.u_sensor, prep.noise, own)
        ratio = noise_ratio2(own, prep.noise)
        if r_w is not None:  # the own figure against the one that weights
            ratio = ratio_over(ratio, r_w)
    sumw = rsum = support = bias2 = None
    carried = np.empty((h, w), dtype=np.float32) if delta is not None and denoise else delta
    if denoise:
        if want_uncertainty:
            sumw, support = np.empty((h, w), dtype=np.float32), np.empty((h, w), dtype=np.float32)
            rsum = np.empty((h, w), dtype=np.float32) if ratio is not None else None
            bias2 = np.empty((h, w), dtype=np.float32)
        smooth = denoise_weighted(weights[0], weights[1], weights[2], radius=int(denoise_radius), k=float(denoise_k),
                                  weight_sum=sumw, ratio=ratio, ratio_sum=rsum, support=support,
                                  carry=delta if denoise else None, carry_mean=carried if denoise else None,
                                  bias2=bias2, **adaptive_kwargs(denoise_adaptive))
    elif want_uncertainty:  # no filter: the weights path, heights from the unfiltered dz
        smooth, sumw = weights[0], weights[2]
        rsum = sumw * ratio if ratio is not None else None
        support = (sumw > 0).astype(np.float32)
    else:  # neither: the kernel's heights stand unless the correction below changes the phase difference
        smooth = dphi
    if freq:
        smooth = correct_frequency(smooth, valid, prep.phi_ref, prep.phase_error, prep.frequency)
    if denoise or want_uncertainty or freq:  # the heights again from the phase difference the chain ends with
        n_valid = _height_kernel(smooth, prep.a, prep.b, valid, height, phase)
    u_map = noise_h = None
    if want_uncertainty:
        if prep.budget is None:
            raise ValueError("the prepared calibration has no uncertainty budget (kernel.prepare sets it)")
        u_map = edge_floor(height, valid, height_uncertainty(smooth, sumw, valid, prep.a, prep.b, prep.budget,
                                                             ratio_sum=rsum, bias2=bias2))
        support = np.where(valid, support, np.float32(0.0)).astype(np.float32)
        noise_h = height_noise(smooth, sumw, valid, prep.a, prep.b)
    counts = {"clipped": int(n_clip), "hue_undefined": int(n_undef), "valid": int(n_valid), "guess_missed": int(n_miss),
              "guess_far": int(n_far)}
    tex_u = None
    if delta is not None:
        tex_u = texture_term_phase(smooth if denoise or freq else dphi, carried, height, prep.a, prep.b)
    return FrameMaps(height, valid, phase, hue, counts, dphi if want_dphi else None, u_map, support, tex_u, noise_h,
                     weights[2] if want_uncertainty and weights is not None else None, bias2)


def frame_to_height(
    prep: Prepared,
    rgb: NDArray[Any],
    *,
    denoise_radius: int = 0,
    denoise_k: float = 3.0,
    out: tuple[NDArray[np.float32], NDArray[np.bool_]] | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Height map of one frame: ``(height float32 mm, NaN where invalid; valid bool)``.

    Parameters
    ----------
    prep : Prepared
        From :func:`prepare`.
    rgb : ndarray (H, W, 3)
        RGB frame: ``uint8``/``uint16`` sensor codes (read directly, scaled by 1/255 or 1/65535
        as :func:`huefringe.session.read_rgb` does) or float in [0, 1].
    denoise_radius : int
        Radius of :func:`huefringe.phase.denoise_phase` on the phase difference; 0 = off
        (``measure_frame``'s default is 2).
    denoise_k : float
        Its edge threshold in combined standard deviations (``denoise_phase``'s ``k``).
    out : (ndarray, ndarray), optional
        Preallocated ``(height, valid)`` buffers, written in place and returned.

    Equals ``perframe.measure_frame(rgb, white, table, cal, unwrap_mode="reference", ...)`` with
    the same parameters (see the module docstring for how exactly).
    """
    m = frame_maps(prep, rgb, denoise_radius=denoise_radius, denoise_k=denoise_k, out=out)
    return m.height, m.valid
