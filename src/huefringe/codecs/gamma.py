"""The projector's gamma estimated from the captures themselves.

A display of gamma ``gamma_p`` showing a pattern encoded with exponent ``g`` puts a fringe of
profile ``(0.5 + 0.5 cos)**(g gamma_p)`` on the object; an N-step fit that assumes a sinusoid
then errs by harmonics ``N +- 1`` of the phase (:func:`~huefringe.codecs.nstep.profile_lut`).
The estimate does not use the white and black frames (ambient and scattered light lift a
fringe's dark parts above the black frame, so a power law between those two frames is the wrong
model). Binary Gray-code patterns carry no gamma: the Gray code's cell centres give each pixel's
phase to within half a cell. For each phase block, the exponent whose profile correction brings
the block's phase closest to the Gray code's (least circular squares) is that block's ``Gamma``;
``gamma_p`` is the median of ``Gamma / g`` over the blocks.

Where the Gray code is too coarse to tell a harmonic (cells of half a period, as in kamino410's
``phase_shifting``), two blocks of different periods on one axis serve instead: their unwrapped
coordinates must agree, and their harmonic errors, at different phases, only cancel at the right
exponent (``periods``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from huefringe.codecs.graycode import decode_gray
from huefringe.codecs.nstep import TWO_PI, profile_lut, shift_matrix
from huefringe.codecs.sequence import GrayBlock, PhaseBlock, SequenceSpec
from huefringe.codecs.temporal import heterodyne, orders_from_reference

__all__ = ["GammaEstimate", "estimate_projector_gamma"]


@dataclass(frozen=True)
class GammaEstimate:
    """Projector gamma estimated against the Gray code (``nan`` without one).

    Attributes
    ----------
    gray : float
        Median over phase blocks of ``Gamma / encoding_gamma`` against the Gray code.
    gray_blocks : tuple of float
        Each phase block's ``Gamma / encoding_gamma`` (capture order; nan without a Gray code of
        cells at most an eighth of the block's period).
    periods : float
        From the agreement of blocks of different periods on one axis (nan with one period).
    pixels : int
        Pixels used.
    """

    gray: float
    gray_blocks: tuple[float, ...]
    periods: float
    pixels: int


def _correct(naive: NDArray[np.float64], shifts: tuple[float, ...], gamma: float) -> NDArray[np.float64]:
    grid, h = profile_lut(shifts, gamma, samples=1024)
    return np.interp(h[0] + np.mod(naive - h[0], TWO_PI), h, grid)


def _coarse(ws: list[NDArray[np.float64]], ps: list[float], gray: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """Absolute coordinate of the finest block from the beat of the two longest periods (and the Gray code)."""
    order = np.argsort(ps)[::-1]
    a, b = int(order[0]), int(order[1])
    wb, pb = heterodyne(ws[a], ps[a], ws[b], ps[b])
    ref = wb if gray is None else orders_from_reference(wb, pb, gray)[0]
    for i in order:
        ref = orders_from_reference(ws[int(i)], ps[int(i)], ref)[0]
    return ref


def _circ_ms(d: NDArray[np.float64]) -> float:
    return float(np.mean(np.angle(np.exp(1j * d)) ** 2))


def estimate_projector_gamma(
    images: list[NDArray[np.number]] | NDArray[np.number],
    spec: SequenceSpec,
    mask: NDArray[np.bool_],
    *,
    bounds: tuple[float, float] = (0.3, 4.0),
    max_pixels: int = 200_000,
) -> GammaEstimate:
    """Estimate the projector gamma of ``spec`` from its captures (module docstring).

    Parameters
    ----------
    images : list of ndarray or ndarray, shape (n_frames, H, W)
        Captures in ``spec``'s order.
    spec : SequenceSpec
        Its blocks' ``encoding_gamma`` are known; its ``projector_gamma`` is not used.
    mask : ndarray of bool, shape (H, W)
        Pixels to use (e.g. a first decode's ``valid``).
    bounds : (float, float)
        Search interval of the exponent.
    max_pixels : int
        Evenly spread subsample of ``mask`` used (the estimate is one number).
    """
    from scipy import optimize  # here, not at import: every process reading a session imports this module

    stack = np.stack(images) if isinstance(images, list) else np.asarray(images)
    idx = np.flatnonzero(np.asarray(mask, bool))
    if idx.size > max_pixels:
        idx = idx[np.linspace(0, idx.size - 1, max_pixels).astype(np.intp)]
    flat = stack.reshape(stack.shape[0], -1)[:, idx].astype(np.float32)
    blocks = [(b, sl) for b, sl in spec.slices() if isinstance(b, PhaseBlock)]
    naive = []
    for b, sl in blocks:
        m = shift_matrix(b.shifts_rad).astype(np.float32)
        naive.append(np.mod(np.arctan2(-(m[2] @ flat[sl]), m[1] @ flat[sl]).astype(np.float64), TWO_PI))
    # Gray code reference, all bits, cell centres
    gray_ref: dict[str, NDArray[np.float64]] = {}
    gray_cell: dict[str, float] = {}
    for b, sl in spec.slices():
        if isinstance(b, GrayBlock) and b.inverse:
            dec = decode_gray(flat[sl][0::2, None, :], 0.0, inverse=flat[sl][1::2, None, :])
            gray_ref[b.axis] = (dec.index[0] + 0.5) * b.code_cell_px - 0.5
            gray_cell[b.axis] = b.code_cell_px
    per_block = []
    for (b, _), nv in zip(blocks, naive, strict=True):
        if b.axis not in gray_ref or gray_cell[b.axis] > b.period_px / 8:  # too coarse to see a harmonic
            per_block.append(np.nan)
            continue
        ref = TWO_PI * (gray_ref[b.axis] - b.origin_px) / b.period_px
        res = optimize.minimize_scalar(
            lambda gp, b=b, nv=nv, ref=ref: _circ_ms(_correct(nv, b.shifts_rad, b.encoding_gamma * gp) - ref),
            bounds=bounds,
            method="bounded",
            options={"xatol": 1e-3},
        )
        per_block.append(float(res.x))
    per_axis: dict[str, list[int]] = {}
    for i, (b, _) in enumerate(blocks):
        per_axis.setdefault(b.axis, []).append(i)
    groups = [ix for ix in per_axis.values() if len({blocks[i][0].period_px for i in ix}) >= 2]
    periods_est = np.nan
    if groups:
        # the orders from a first, uncorrected decode (errors well below half a period)
        first = {}
        for ix in groups:
            ws = [np.mod(blocks[i][0].origin_px + naive[i] * blocks[i][0].period_px / TWO_PI, blocks[i][0].period_px) for i in ix]
            ps = [blocks[i][0].period_px for i in ix]
            ref = gray_ref.get(blocks[ix[0]][0].axis)
            coarse = _coarse(ws, ps, ref)
            first[tuple(ix)] = coarse

        def spread(gp: float) -> float:
            tot = 0.0
            for ix, ref in first.items():
                us = []
                for i in ix:
                    b = blocks[i][0]
                    w = np.mod(b.origin_px + _correct(naive[i], b.shifts_rad, b.encoding_gamma * gp) * b.period_px / TWO_PI, b.period_px)
                    us.append(orders_from_reference(w, b.period_px, ref)[0])
                d = np.asarray(us) - np.mean(us, axis=0)
                tot += float(np.mean(np.minimum(d**2, 25.0)))
            return tot

        periods_est = float(optimize.minimize_scalar(spread, bounds=bounds, method="bounded", options={"xatol": 1e-3}).x)
    finite = [g for g in per_block if np.isfinite(g)]
    return GammaEstimate(
        gray=float(np.median(finite)) if finite else np.nan, gray_blocks=tuple(per_block), periods=periods_est, pixels=int(idx.size)
    )
