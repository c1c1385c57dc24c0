"""The per-frame algorithm: one trapezoidal frame to a height map, with its masks and QA.

:func:`measure_frame` is the NumPy reference chain (hue -> hue table -> code phase -> phase
difference -> height); the fused kernel (:mod:`huefringe.kernel`) reproduces it bit for bit and
shares its compiled pieces (:func:`sigma_from_slope`, :func:`capture_noise`,
:func:`shadow_mask`). The workflow's stages (:mod:`huefringe.stages`) call one or the other.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from huefringe.colour import hue as hue_of
from huefringe.colour import intensity, white_balance, white_gains
from huefringe.height import PlaneCalibration
from huefringe.huetable import HueTable, HueTableError
from huefringe import phase_error
from huefringe.phase import adaptive_kwargs, denoise_phase, denoise_weight_sums, unwrap, wrap
from huefringe.session import Predistortion
from huefringe.uncertainty import (PixelBudget, edge_floor, height_uncertainty, pixel_budget, texture_delta,
                                   texture_term_phase)

__all__ = [
    "FrameError",
    "FrameResult",
    "capture_noise",
    "clipped_mask",
    "frame_hue_noise",
    "height_noise",
    "noise_ratio2",
    "frame_stats",
    "measure_frame",
    "phase_sigma",
    "plane_edge_mask",
    "reference_frame_stats",
    "remove_step_edges",
    "sensor_model",
    "shadow_mask",
    "sigma_from_slope",
    "step_edge_mask",
]


class FrameError(ValueError):
    """A frame cannot be measured (lens cap, saturated sensor, no fringe); names the file."""


# --------------------------------------------------------------------------- masks


def shadow_mask(white: NDArray[np.floating], fraction: float) -> NDArray[np.bool_]:
    """Pixels whose white-image intensity is below ``fraction`` of the image's 99th percentile.

    Shadowed pixels receive only ambient light when the projector shows white, so they carry no
    fringe; they are invalid in every frame of the session.
    """
    level = intensity(white)
    return level < fraction * float(np.percentile(level, 99))


def step_edge_mask(height: NDArray[np.floating], jump_mm: float, noise: NDArray[np.floating] | None = None,
                   noise_k: float = 0.0) -> NDArray[np.bool_]:
    """Valid pixels next to a height jump: the mixed pixels of a step edge.

    A pixel whose height differs from a valid 4-neighbour's by more than ``jump_mm`` sees (through
    projector defocus and lens blur) two surfaces at different fringe phases: its colour is a
    mixture and its height belongs to neither. Both pixels of such a pair are returned (True =
    to invalidate). Smooth slopes steeper than ``jump_mm`` per pixel are cut too, so ``jump_mm``
    must exceed the steepest real slope per pixel (0 returns an all-False mask).

    With ``noise`` (each height's noise standard deviation, mm, :func:`height_noise`) a jump the
    pair's own noise explains is no edge: a pair differs by more than ``max(jump_mm, noise_k
    sqrt(s_a^2 + s_b^2))`` (``noise_k`` 0: ``jump_mm`` alone). Float32 arithmetic, as the compiled
    pass (:func:`remove_step_edges`) computes it.

    Parameters
    ----------
    height : ndarray (H, W)
        Height map, NaN where invalid.
    jump_mm : float
        Largest height difference between 4-neighbours kept (mm).
    noise : ndarray (H, W), optional
        Standard deviation of each height from the capture noise (mm; NaN counts as 0).
    noise_k : float
        Jumps up to this many of the pair's combined noise standard deviations are kept.
    """
    h = np.asarray(height, np.float32)
    out = np.zeros(h.shape, bool)
    if jump_mm <= 0:
        return out
    jump, k = np.float32(jump_mm), np.float32(noise_k)
    s = _noise_map(noise, h.shape)
    with np.errstate(invalid="ignore"):
        dx = np.abs(h[:, 1:] - h[:, :-1]) > np.maximum(jump, k * np.sqrt(s[:, 1:] * s[:, 1:] + s[:, :-1] * s[:, :-1]))
        dy = np.abs(h[1:, :] - h[:-1, :]) > np.maximum(jump, k * np.sqrt(s[1:, :] * s[1:, :] + s[:-1, :] * s[:-1, :]))
    out[:, 1:] |= dx
    out[:, :-1] |= dx
    out[1:, :] |= dy
    out[:-1, :] |= dy
    return out


def _noise_map(noise: NDArray[np.floating] | None, shape: tuple[int, ...]) -> NDArray[np.float32]:
    """The edge tests' float32 noise map: 0 where ``noise`` is not finite (or without one)."""
    if noise is None:
        return np.zeros(shape, np.float32)
    s = np.asarray(noise, np.float32)
    if s.shape != shape:
        raise ValueError(f"noise map {s.shape} differs from the height map {shape}")
    return np.ascontiguousarray(np.where(np.isfinite(s), s, np.float32(0.0)))


@numba.njit(cache=True, nogil=True, inline="always")
def _pair_jump(dz, sa, sb, jump, k):  # pragma: no cover - numba
    """A 4-neighbour pair's jump ``dz`` beyond ``max(jump, k sqrt(sa^2 + sb^2))`` (float32)."""
    return abs(dz) > max(jump, k * np.sqrt(sa * sa + sb * sb))


@numba.njit(cache=True, nogil=True)
def _edge_kernel(h, s, jump, k, edge):  # pragma: no cover - numba
    """:func:`step_edge_mask` into ``edge`` (float32 differences, NaN compares False); returns the
    number of pixels marked."""
    rows, cols = h.shape
    n = 0
    for v in range(rows):
        for u in range(cols):
            z = h[v, u]
            sz = s[v, u]
            e = False
            if u > 0:
                e |= _pair_jump(z - h[v, u - 1], sz, s[v, u - 1], jump, k)
            if u + 1 < cols:
                e |= _pair_jump(h[v, u + 1] - z, sz, s[v, u + 1], jump, k)
            if v > 0:
                e |= _pair_jump(z - h[v - 1, u], sz, s[v - 1, u], jump, k)
            if v + 1 < rows:
                e |= _pair_jump(h[v + 1, u] - z, sz, s[v + 1, u], jump, k)
            edge[v, u] = e
            n += e
    return n


#: the step-edge tests of ``measurement.edge_test``
EDGE_TESTS = ("pair", "plane")


def plane_edge_mask(height: NDArray[np.floating], jump_mm: float, tol_mm: float,
                    noise: NDArray[np.floating] | None = None, noise_k: float = 0.0) -> NDArray[np.bool_]:
    """Mixed pixels of step edges by the two-sided local-line test (``measurement.edge_test: plane``).

    Along u and along v, a valid pixel ``z0`` with neighbours ``z-2, z-1 | z1, z2`` is a
    candidate when it differs from ``z-1`` or ``z1`` by more than ``jump_mm`` (the pair test's
    jump, :func:`step_edge_mask`). It stays when every such jump is explained and it lies on a
    side's line: on the line of side ``s`` when ``|z0 - (2 zs1 - zs2)| <= tol_mm`` (the
    one-sided straight-line extrapolation; both pixels of the side valid); a jump to ``zs1`` is
    explained when ``z0`` is on side ``s``'s line (a slope steeper than ``jump_mm`` per pixel goes
    on through ``z0``) or when ``zs2`` is back on the line through the other side,
    ``|zs2 - (3 z0 - 2 z-s1)| <= tol_mm`` (``zs1`` is an isolated outlier: its neighbours stay).
    Otherwise it is returned (True = to invalidate): both pixels next to a real step (whose sides
    do not continue each other, as the pair test: a step's edge is only known to a pixel), the
    pixels between the two planes, and outliers. A missing neighbour explains nothing.

    With ``noise`` (each height's noise standard deviation ``s``, mm, :func:`height_noise`) what
    the pixels' own noise explains is no step: each threshold is at least ``noise_k`` standard
    deviations of the difference it bounds, the jump ``max(jump_mm, noise_k sqrt(s0^2 + s1^2))``,
    the line ``max(tol_mm, noise_k sqrt(s0^2 + 4 s1^2 + s2^2))`` and the outlier test
    ``max(tol_mm, noise_k sqrt(s2^2 + 9 s0^2 + 4 s-1^2))`` (``noise_k`` 0: the fixed ones).
    Float32 arithmetic in this order (``2 zs1 - zs2 = zs1 + zs1 - zs2``,
    ``3 z0 - 2 z-s1 = z0 + d + d``, ``d = z0 - z-s1``), as the compiled pass
    (:func:`remove_step_edges`) computes it; ``jump_mm <= 0`` returns all False.

    Parameters
    ----------
    height : ndarray (H, W)
        Height map, NaN where invalid.
    jump_mm : float
        The candidate jump to a 4-neighbour (mm).
    tol_mm : float
        Largest departure from an extrapolated line that still counts as on it (mm).
    noise : ndarray (H, W), optional
        Standard deviation of each height from the capture noise (mm; NaN counts as 0).
    noise_k : float
        Differences up to this many of their noise standard deviations are explained by noise.
    """
    h = np.asarray(height, np.float32)
    out = np.zeros(h.shape, bool)
    if jump_mm <= 0:
        return out
    jump, tol, k = np.float32(jump_mm), np.float32(tol_mm), np.float32(noise_k)
    rows, cols = h.shape
    pad = np.full((rows + 4, cols + 4), np.nan, np.float32)
    pad[2:-2, 2:-2] = h
    spad = np.zeros((rows + 4, cols + 4), np.float32)
    spad[2:-2, 2:-2] = _noise_map(noise, h.shape)
    f4, f9 = np.float32(4.0), np.float32(9.0)

    def at(a: NDArray[np.float32], dv: int, du: int) -> NDArray[np.float32]:
        return a[2 + dv:2 + dv + rows, 2 + du:2 + du + cols]

    s0 = at(spad, 0, 0)
    with np.errstate(invalid="ignore"):
        for dv, du in ((0, 1), (1, 0)):
            m1, m2, p1, p2 = at(pad, -dv, -du), at(pad, -2 * dv, -2 * du), at(pad, dv, du), at(pad, 2 * dv, 2 * du)
            sm1, sm2, sp1, sp2 = at(spad, -dv, -du), at(spad, -2 * dv, -2 * du), at(spad, dv, du), at(spad, 2 * dv, 2 * du)
            jump_l = np.abs(h - m1) > np.maximum(jump, k * np.sqrt(s0 * s0 + sm1 * sm1))
            jump_r = np.abs(p1 - h) > np.maximum(jump, k * np.sqrt(s0 * s0 + sp1 * sp1))
            on_l = np.abs(h - (m1 + m1 - m2)) <= np.maximum(tol, k * np.sqrt(s0 * s0 + f4 * (sm1 * sm1) + sm2 * sm2))
            on_r = np.abs(h - (p1 + p1 - p2)) <= np.maximum(tol, k * np.sqrt(s0 * s0 + f4 * (sp1 * sp1) + sp2 * sp2))
            dl, dr = h - m1, h - p1
            iso_r = np.abs(p2 - (h + dl + dl)) <= np.maximum(tol, k * np.sqrt(sp2 * sp2 + f9 * (s0 * s0) + f4 * (sm1 * sm1)))
            iso_l = np.abs(m2 - (h + dr + dr)) <= np.maximum(tol, k * np.sqrt(sm2 * sm2 + f9 * (s0 * s0) + f4 * (sp1 * sp1)))
            keep = (~jump_l | on_l | iso_l) & (~jump_r | on_r | iso_r) & (on_l | on_r)
            out |= np.isfinite(h) & (jump_l | jump_r) & ~keep
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _plane_drop(z, m1, m2, p1, p2, s0, sm1, sm2, sp1, sp2, jump, tol, k):  # pragma: no cover - numba
    """One axis of :func:`plane_edge_mask` at a pixel: True = invalidate."""
    f4 = np.float32(4.0)
    f9 = np.float32(9.0)
    jump_l = abs(z - m1) > max(jump, k * np.sqrt(s0 * s0 + sm1 * sm1))
    jump_r = abs(p1 - z) > max(jump, k * np.sqrt(s0 * s0 + sp1 * sp1))
    on_l = abs(z - (m1 + m1 - m2)) <= max(tol, k * np.sqrt(s0 * s0 + f4 * (sm1 * sm1) + sm2 * sm2))
    on_r = abs(z - (p1 + p1 - p2)) <= max(tol, k * np.sqrt(s0 * s0 + f4 * (sp1 * sp1) + sp2 * sp2))
    dl = z - m1
    dr = z - p1
    iso_r = abs(p2 - (z + dl + dl)) <= max(tol, k * np.sqrt(sp2 * sp2 + f9 * (s0 * s0) + f4 * (sm1 * sm1)))
    iso_l = abs(m2 - (z + dr + dr)) <= max(tol, k * np.sqrt(sm2 * sm2 + f9 * (s0 * s0) + f4 * (sp1 * sp1)))
    keep = (not jump_l or on_l or iso_l) and (not jump_r or on_r or iso_r) and (on_l or on_r)
    return (jump_l or jump_r) and not keep


@numba.njit(cache=True, nogil=True)
def _plane_edge_kernel(h, s, jump, tol, k, edge):  # pragma: no cover - numba
    """:func:`plane_edge_mask` into ``edge`` (float32, NaN compares False; the frame padded by two
    NaN pixels, the noise map by zeros); returns the number of pixels marked."""
    rows, cols = h.shape
    pad = np.full((rows + 4, cols + 4), np.float32(np.nan))
    pad[2:rows + 2, 2:cols + 2] = h
    sp = np.zeros((rows + 4, cols + 4), np.float32)
    sp[2:rows + 2, 2:cols + 2] = s
    n = 0
    for v in range(rows):
        r = v + 2
        for u in range(cols):
            c = u + 2
            z = pad[r, c]
            e = False
            if np.isfinite(z):
                s0 = sp[r, c]
                e = _plane_drop(z, pad[r, c - 1], pad[r, c - 2], pad[r, c + 1], pad[r, c + 2],
                                s0, sp[r, c - 1], sp[r, c - 2], sp[r, c + 1], sp[r, c + 2], jump, tol, k) or \
                    _plane_drop(z, pad[r - 1, c], pad[r - 2, c], pad[r + 1, c], pad[r + 2, c],
                                s0, sp[r - 1, c], sp[r - 2, c], sp[r + 1, c], sp[r + 2, c], jump, tol, k)
            edge[v, u] = e
            n += e
    return n


@numba.njit(cache=True, nogil=True)
def _masked(x, edge, fill, out):  # pragma: no cover - numba
    """``out = where(edge, fill, x)``."""
    for v in range(x.shape[0]):
        for u in range(x.shape[1]):
            out[v, u] = fill if edge[v, u] else x[v, u]


@numba.njit(cache=True, nogil=True)
def _finite_keys(z, keys):  # pragma: no cover - numba
    """The values of float32 ``z`` that are not NaN as order-preserving uint32 keys (for
    :func:`_median_keys`, as ``np.nanmedian`` takes them); returns their number and that of the
    finite ones."""
    zb = z.reshape(-1).view(np.uint32)
    zf = z.reshape(-1)
    n = 0
    n_finite = 0
    for i in range(zf.size):
        b = zb[i]
        x = zf[i]
        keys[n] = b ^ (np.uint32(0xFFFFFFFF) if b >> np.uint32(31) else np.uint32(0x80000000))
        n += x == x
        n_finite += x - x == 0
    return n, n_finite


def remove_step_edges(height: NDArray[np.float32], jump_mm: float, *, nan_maps: Sequence[NDArray[np.float32] | None] = (),
                      zero_maps: Sequence[NDArray[np.float32] | None] = (), test: str = "pair",
                      tol_mm: float = 0.1, noise: NDArray[np.floating] | None = None,
                      noise_k: float = 0.0) -> tuple[Any, ...]:
    """Invalidate the mixed pixels of step edges in a height map and the maps that go with it, in
    compiled passes: what ``measurement.edge_jump_mm`` / ``edge_test`` / ``edge_plane_tol_mm`` do
    per frame.

    ``test`` is ``"pair"`` (:func:`step_edge_mask`: both pixels of a 4-neighbour pair differing
    by more than ``jump_mm``) or ``"plane"`` (:func:`plane_edge_mask`: of such candidates, those
    off both sides' extrapolated lines by more than ``tol_mm``); with ``noise`` (each height's
    noise standard deviation, :func:`height_noise`) and ``noise_k`` > 0, what the pixels' own
    noise explains is no step (``measurement.edge_noise_k``). Returns
    ``(height, nan_maps, zero_maps, stats)``: new float32 arrays (NaN on the edge pixels;
    0 in ``zero_maps``; None stays None) and the frame statistics that change, ``edge_fraction``,
    ``valid_fraction`` (finite heights) and ``median_height_mm`` (NumPy's ``nanmedian`` of the
    new heights, None when none is left), equal to ``np.where(step_edge_mask(...), ...)`` (or
    ``plane_edge_mask``) and ``np.nanmedian`` value for value (tested) at about a quarter of
    their cost (1.8 against 7.1 ms on a 640 x 480 frame, pair test).
    """
    if test not in EDGE_TESTS:
        raise ValueError(f"edge test must be one of {EDGE_TESTS}, got {test!r}")
    h = np.ascontiguousarray(height, np.float32)
    edge = np.empty(h.shape, bool)
    sig = _noise_map(noise if noise_k > 0 else None, h.shape)
    if jump_mm > 0 and test == "plane":
        n_edge = _plane_edge_kernel(h, sig, np.float32(jump_mm), np.float32(tol_mm), np.float32(noise_k), edge)
    elif jump_mm > 0:
        n_edge = _edge_kernel(h, sig, np.float32(jump_mm), np.float32(noise_k), edge)
    else:  # as step_edge_mask: 0 switches it off
        edge[...] = False
        n_edge = 0

    def masked(x: NDArray[np.float32] | None, fill: float) -> NDArray[np.float32] | None:
        if x is None:
            return None
        out = np.empty(np.shape(x), np.float32)
        _masked(np.ascontiguousarray(x, np.float32), edge, np.float32(fill), out)
        return out

    hz = masked(h, np.nan)
    keys = np.empty(hz.size, np.uint32)
    n, n_finite = (int(x) for x in _finite_keys(hz, keys))
    stats = {"edge_fraction": float(n_edge / h.size) if h.size else 0.0,
             "valid_fraction": float(n_finite / h.size) if h.size else 0.0,
             "median_height_mm": float(_median_keys(keys, n)) if n_finite else None}
    return hz, [masked(x, np.nan) for x in nan_maps], [masked(x, 0.0) for x in zero_maps], stats


def height_noise(dphi: NDArray[np.floating], sumw: NDArray[np.floating], valid: NDArray[np.bool_],
                 a: NDArray[np.floating], b: NDArray[np.floating]) -> NDArray[np.float32]:
    """Standard deviation (mm) of each height from the capture noise alone: ``|dh/dphi| / sqrt(sumw)``.

    ``sumw`` is the phase filter's sum of inverse-variance weights (``1 / sigma^2`` of the pixel
    itself without the filter), ``sigma`` each pixel's per-capture phase noise from the hue
    table's per-pixel noise (:func:`phase_sigma`); ``h = dphi / (a + b dphi)`` gives
    ``dh/dphi = a / (a + b dphi)^2``. NaN where not ``valid`` or without weight. What the
    step-edge tests (:func:`remove_step_edges`) hold a jump against; both chains compute it from
    the same float32 maps, in this compiled loop.
    """
    out = np.empty(np.shape(dphi), np.float32)
    _height_noise_kernel(np.ascontiguousarray(dphi, np.float32), np.ascontiguousarray(sumw, np.float32),
                         np.ascontiguousarray(valid, bool), np.ascontiguousarray(a, np.float32),
                         np.ascontiguousarray(b, np.float32), out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _height_noise_kernel(dphi, sumw, valid, a, b, out):  # pragma: no cover - numba
    """:func:`height_noise`'s loop (float32)."""
    h, w = dphi.shape
    nan = np.float32(np.nan)
    for v in range(h):
        for u in range(w):
            sw = sumw[v, u]
            q = a[v, u] + b[v, u] * dphi[v, u]
            s = abs(a[v, u]) / (q * q) / np.sqrt(sw)
            out[v, u] = s if valid[v, u] and sw > 0 and s - s == 0 else nan


def clipped_mask(rgb: NDArray[np.floating], bit_depth: int) -> NDArray[np.bool_]:
    """Pixels with any channel at the sensor's maximum code."""
    top = 1.0 - 0.5 / (2**bit_depth - 1)
    return np.any(rgb >= top, axis=-1)


# --------------------------------------------------------------------------- per frame


@dataclass
class FrameResult:
    height: NDArray[np.float32]
    phase: NDArray[np.float32]
    """Corrected code phase of the object, wrapped, [0, 2 pi) (NaN invalid)."""
    hue: NDArray[np.float32]
    """Raw captured hue after white balance (NaN where undefined)."""
    valid: NDArray[np.bool_]
    stats: dict[str, Any] = field(default_factory=dict)
    uncertainty: NDArray[np.float32] | None = None
    """Standard uncertainty of the height (mm), NaN where the height is NaN (:mod:`huefringe.uncertainty`)."""
    support: NDArray[np.float32] | None = None
    """Number of pixels the phase filter averaged into each height (1 without the filter; 0 where
    the height is NaN): what a step's mean shares between neighbours (:func:`~huefringe.uncertainty.step_budget`)."""
    dphi: NDArray[np.float32] | None = None
    """The phase difference before the filter (float32, NaN where not valid)."""
    texture_u: NDArray[np.float32] | None = None
    """The texture term of the uncertainty (mm, NaN where the height is), with ``texture_rgb``
    (:func:`~huefringe.uncertainty.texture_term_phase`)."""
    noise: NDArray[np.float32] | None = None
    """Standard deviation (mm) of each height from the capture noise alone (:func:`height_noise`),
    NaN where the height is NaN: what the step-edge tests hold a jump against."""


def measure_frame(
    rgb: NDArray[np.floating],
    white: NDArray[np.floating],
    table: HueTable,
    cal: PlaneCalibration,
    *,
    hue_model: str = "hexcone",
    min_saturation: float = 0.08,
    shadow: NDArray[np.bool_] | None = None,
    unwrap_mode: str = "reference",
    bit_depth: int = 8,
    below_reference_mm: float = 0.25,
    denoise_radius: int = 2,
    predistortion: Predistortion | None = None,
    denoise_adaptive: Mapping[str, Any] | None = None,
    budget: PixelBudget | None = None,
    own_noise: bool = False,
    texture_rgb: NDArray[np.floating] | None = None,
) -> FrameResult:
    """One trapezoidal frame to a height map: hue -> table -> code phase -> dphi -> height.

    Parameters
    ----------
    rgb, white : ndarray
        The frame and the object's white image, float (H, W, 3) in [0, 1].
    table : HueTable
        The object's per-pixel hue table (captured hue -> projected code phase).
    cal : PlaneCalibration
        Reference phase and the per-pixel phase-to-height model.
    below_reference_mm : float
        Heights below ``-below_reference_mm`` are flagged: objects stand on the plate, so a
        large negative height means the phase difference wrapped (a step too tall for the
        fringe period).
    denoise_radius : int
        Radius of the uncertainty-weighted, edge-preserving phase filter
        (:func:`huefringe.phase.denoise_phase`); 0 switches it off. Each pixel's phase
        uncertainty is its hue noise (from the repeats of the hue bands) divided by the local
        slope of its table, so pixels where projector gamma flattens the hue lean on their
        neighbours while steps stay sharp.
    predistortion : Predistortion, optional
        When the frames were projected through a pre-distortion (paper Fig. 6; the session's
        ``predistortion.csv``), the table gives the *emitted* phase, which is decoded back to
        the code phase.
    denoise_adaptive : mapping, optional
        ``measurement.denoise_adaptive`` (:func:`huefringe.phase.adaptive_kwargs`): the filter's
        sigma-adaptive support and the rejection of pixels no filter can save.
    own_noise : bool
        Each pixel's phase sigma from this frame's own signal through the table's shot + read
        noise model (:func:`frame_hue_noise`) instead of the table's pooled per-pixel noise
        (``measurement.own_noise``; off by default: weighting the filter by it biases the
        heights where the noise varies with the phase, Table 1 at 100 px: mean error 0.93 ->
        1.59 %).
    budget : PixelBudget, optional
        Session inputs of the height uncertainty (:func:`huefringe.uncertainty.pixel_budget`,
        computed when not given); the result's ``uncertainty`` is the kernel's, bit for bit.
    texture_rgb : ndarray, optional
        The capture corrected with the texture blur moved by its uncertainty: its phase (this
        chain without the filter) changes by :func:`~huefringe.uncertainty.texture_delta`, which
        this frame's filter carries through; the result's ``texture_u`` is the kernel's.
    """
    moved_dphi = None
    if texture_rgb is not None:
        moved_dphi = measure_frame(texture_rgb, white, table, cal, hue_model=hue_model, min_saturation=min_saturation,
                                   shadow=shadow, unwrap_mode=unwrap_mode, bit_depth=bit_depth,
                                   below_reference_mm=below_reference_mm, denoise_radius=0, predistortion=predistortion,
                                   budget=budget, own_noise=own_noise).dphi
    balanced = white_balance(rgb, white)
    hue = hue_of(balanced, hue_model, min_saturation=min_saturation)
    emitted, slope = table.to_phase_and_slope(hue)  # the phase's uncertainty needs the table slope
    phase = emitted if predistortion is None else predistortion.decode(emitted)
    phase = phase_error.correct(phase, cal.phase_error)  # the planes' phase-error table (or none)
    clipped = clipped_mask(rgb, bit_depth)
    valid = np.isfinite(phase) & ~clipped
    if shadow is not None:
        valid &= ~shadow
    dphi = wrap(phase.astype(np.float64) - cal.phi_ref)
    un = unwrap(dphi, valid, unwrap_mode)  # type: ignore[arg-type]
    # this frame's own-signal hue noise: in the weights with own_noise, else in the uncertainty only
    own = frame_hue_noise(table, rgb, white_gains(white), hue_model) if own_noise or sensor_model(table) is not None \
        else None
    sigma = phase_sigma(table, slope, noise=own if own_noise else None)
    ratio = noise_ratio2(own, capture_noise(table)) if own is not None and not own_noise else None
    if predistortion is not None:
        sigma = sigma * np.abs(predistortion.decode_slope(emitted))
    sumw = np.zeros(valid.shape, np.float32)
    rsum = np.zeros(valid.shape, np.float32)
    support = np.zeros(valid.shape, np.float32)
    raw_dphi = np.asarray(un.dphi, np.float32)
    delta = texture_delta(moved_dphi, raw_dphi) if moved_dphi is not None else None
    carried = np.empty(valid.shape, np.float32) if delta is not None and denoise_radius > 0 else delta
    if denoise_radius > 0:
        un.dphi = denoise_phase(un.dphi, sigma, valid, radius=denoise_radius, weight_sum=sumw, ratio=ratio,
                                ratio_sum=rsum if ratio is not None else None, support=support,
                                carry=delta, carry_mean=carried, **adaptive_kwargs(denoise_adaptive))
    else:  # one pixel's weight 1 / sigma^2, in the filter's float32 arithmetic
        sumw = denoise_weight_sums(un.dphi, sigma, valid)
        rsum = sumw * ratio if ratio is not None else rsum
        support = (sumw > 0).astype(np.float32)
    height = cal.height(un.dphi)
    valid &= np.isfinite(height)
    height = np.where(valid, height, np.nan).astype(np.float32)
    if budget is None:
        budget = pixel_budget(table, cal)
    u_map = edge_floor(height, valid, height_uncertainty(np.asarray(un.dphi, np.float32), sumw, valid, cal.a, cal.b,
                                                         budget, ratio_sum=rsum if ratio is not None else None))
    support = np.where(valid, support, np.float32(0.0)).astype(np.float32)
    tex_u = texture_term_phase(np.asarray(un.dphi, np.float32), carried, height, cal.a, cal.b) \
        if delta is not None else None
    noise_h = height_noise(np.asarray(un.dphi, np.float32), sumw, valid, cal.a, cal.b)
    stats = frame_stats(
        valid, height, un.flags,
        clipped_fraction=float(clipped.mean()),
        hue_undefined_fraction=float(np.mean(~np.isfinite(hue))),
        table_invalid_fraction=float(np.mean(~table.valid)),
        shadow_fraction=float(shadow.mean()) if shadow is not None else 0.0,
        hue_model=hue_model, unwrap_mode=unwrap_mode, below_reference_mm=below_reference_mm,
    )
    return FrameResult(height, np.where(valid, phase, np.nan).astype(np.float32), hue.astype(np.float32), valid, stats,
                       u_map, support, raw_dphi, tex_u, noise_h)


def frame_stats(valid: NDArray[np.bool_], height: NDArray[np.float32], flags: Mapping[str, NDArray[np.bool_]], *,
                clipped_fraction: float, hue_undefined_fraction: float, table_invalid_fraction: float,
                shadow_fraction: float, hue_model: str, unwrap_mode: str,
                below_reference_mm: float = 0.25) -> dict[str, Any]:
    """The QA figures of one frame (``qa/frames/frame_NNNN.json``).

    ``phase_ambiguity_suspected`` is set when more than 0.1 % of the pixels lie below
    ``-below_reference_mm`` (objects stand on the plate, so a large negative height means the
    phase difference wrapped) or sit on a wrap edge.
    """
    counts = {k: int(np.count_nonzero(v)) for k, v in flags.items()}
    counts["below_reference"] = int(np.count_nonzero(valid & (height < -below_reference_mm)))
    return _qa_record(np.count_nonzero(valid) / valid.size, counts, valid.size,
                      float(np.median(height[valid])) if valid.any() else None,
                      clipped_fraction=clipped_fraction, hue_undefined_fraction=hue_undefined_fraction,
                      table_invalid_fraction=table_invalid_fraction, shadow_fraction=shadow_fraction,
                      hue_model=hue_model, unwrap_mode=unwrap_mode)


def _qa_record(valid_fraction: float, counts: dict[str, int], pixels: int, median_height_mm: float | None, *,
               clipped_fraction: float, hue_undefined_fraction: float, table_invalid_fraction: float,
               shadow_fraction: float, hue_model: str, unwrap_mode: str) -> dict[str, Any]:
    """The QA record of :func:`frame_stats` and :func:`reference_frame_stats`, from their counts."""
    suspect = (counts["below_reference"] + counts["wrap_edge"]) > 0.001 * pixels
    return {
        "valid_fraction": valid_fraction,
        "clipped_fraction": clipped_fraction,
        "hue_undefined_fraction": hue_undefined_fraction,
        "table_invalid_fraction": table_invalid_fraction,
        "shadow_fraction": shadow_fraction,
        "flags": counts,
        "phase_ambiguity_suspected": bool(suspect),
        "median_height_mm": median_height_mm,
        "hue_model": hue_model,
        "unwrap": unwrap_mode,
    }


def phase_sigma(table: HueTable, slope: NDArray[np.floating], floor_slope: float = 0.05,
                noise: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Per-pixel standard deviation (rad) of the code phase decoded from one capture.

    ``sigma_hue / slope``: the hue noise of one capture over the local slope d(captured
    hue)/d(code phase) of the pixel's table (:meth:`HueTable.hue_slope` at the captured hue),
    floored at ``floor_slope``. ``noise`` is the hue noise (rad) per pixel, e.g. the frame's own
    (:func:`frame_hue_noise`); default the table's pooled figure (:func:`capture_noise`).
    """
    slope = np.where(np.isfinite(slope), slope, 1.0)  # (invalid pixels only: the kernel leaves them out)
    if noise is None:
        noise = capture_noise(table)
    out = np.empty(noise.shape, np.float64)
    _phase_sigma_map(noise, np.ascontiguousarray(slope, dtype=np.float64), float(floor_slope), out)
    return out


def capture_noise(table: HueTable) -> NDArray[np.float64]:
    """Per-pixel hue noise (rad) of one capture, from the table's band statistics.

    The standard error of the bands' mean hue times ``sqrt(repeats)``: the repeats' spread, or
    with one repeat the second difference along the bands (``stats["noise_rad"]["source"]``,
    :data:`huefringe.huetable.NOISE_SOURCES`). Pixels without a finite, positive figure (masked
    table pixels, which are never measured) get the median of the others. A table without any
    figure is refused (:class:`~huefringe.huetable.HueTableError`): no noise is ever assumed.
    Used by :func:`phase_sigma` and by the fused kernel (:func:`huefringe.kernel.prepare`).
    """
    repeats = int(table.stats.get("repeats", 1) or 1)
    noise = np.asarray(table.noise_rad, np.float64) * np.sqrt(repeats)
    known = np.isfinite(noise) & (noise > 0)
    if not known.any():
        raise HueTableError("the hue table has no per-pixel noise figure (noise_rad is NaN or 0 everywhere: a table "
                            "written by a build that did not estimate it from a single repeat); rebuild the hue table")
    return np.ascontiguousarray(np.where(known, noise, float(np.median(noise[known]))))


@numba.njit(cache=True, nogil=True)
def sigma_from_slope(noise, slope, floor_slope):  # pragma: no cover - compiled
    """One pixel's code-phase standard deviation ``noise / max(slope, floor_slope)`` (compiled, for
    :func:`phase_sigma` and the fused kernel alike; a branch-free expression, so that it stays
    vectorised in the kernel's row loop)."""
    return noise / max(slope, floor_slope)


@numba.njit(cache=True, nogil=True)
def _phase_sigma_map(noise, slope, floor_slope, out):  # pragma: no cover - compiled
    """:func:`sigma_from_slope` of every pixel."""
    h, w = noise.shape
    for v in range(h):
        for u in range(w):
            out[v, u] = sigma_from_slope(noise[v, u], slope[v, u], floor_slope)


def reference_frame_stats(dphi: NDArray[np.float32], valid: NDArray[np.bool_], height: NDArray[np.float32], *,
                          clipped_fraction: float, hue_undefined_fraction: float, table_invalid_fraction: float,
                          shadow_fraction: float, hue_model: str, near_wrap: float = 0.9 * np.pi,
                          below_reference_mm: float = 0.25, flag_valid: NDArray[np.bool_] | None = None) -> dict[str, Any]:
    """:func:`frame_stats` of a reference-relative frame, flags included, in one compiled pass.

    Equals ``frame_stats(valid, height, phase.unwrap(dphi, flag_valid, "reference").flags, ...,
    unwrap_mode="reference")`` value for value (the flag counts, the valid fraction and the
    median height, NumPy's ``np.median`` of the float32 heights: the middle value, or the
    float32 mean of the two middle ones), without the flag maps, the unwrapped copy and the
    sort: what the kernel's measurement loop needs per frame (``dphi`` is the phase difference
    before the filter, ``valid`` and ``height`` the final ones).

    ``flag_valid`` (default ``valid``) are the pixels the wrap flags are counted on: for
    :func:`measure_frame`'s figures, the pixels valid *before* the phase filter (its ``unwrap``
    call), i.e. ``np.isfinite(dphi)`` of the kernel's ``dphi``. The filter's rejection of noisy
    pixels (``measurement.denoise_adaptive``) and a non-finite height drop pixels from ``valid``
    only; counting the flags on the final ``valid`` instead under-counts ``near_wrap`` and
    ``wrap_edge`` wherever the dropped pixels sit near a wrap (the texture-edge correction's case).
    """
    d = np.ascontiguousarray(dphi)
    ok = np.ascontiguousarray(valid, dtype=bool)
    fv = ok if flag_valid is None else np.ascontiguousarray(flag_valid, dtype=bool)
    z = np.ascontiguousarray(height, dtype=np.float32)
    if not d.shape == ok.shape == z.shape == fv.shape or d.ndim != 2:
        raise ValueError(f"dphi {d.shape}, valid {ok.shape}, flag_valid {fv.shape} and height {z.shape} "
                         "must be the same 2-D shape")
    edge = np.empty((3, d.shape[1]), np.uint8)
    keys = np.empty(d.size + 1, np.uint32)
    n_valid, n_edge, n_near, n_below, n_keys = _reference_counts(d, ok, fv, z, float(near_wrap),
                                                                 np.float32(below_reference_mm), edge, keys)
    counts = {"wrap_edge": int(n_edge), "near_wrap": int(n_near), "isolated": 0, "below_reference": int(n_below)}
    median = (None if n_valid == 0 else float("nan") if n_keys < n_valid  # NaN among them: np.median's NaN
              else float(_median_keys(keys, int(n_keys))))
    return _qa_record(int(n_valid) / ok.size, counts, ok.size, median, clipped_fraction=clipped_fraction,
                      hue_undefined_fraction=hue_undefined_fraction, table_invalid_fraction=table_invalid_fraction,
                      shadow_fraction=shadow_fraction, hue_model=hue_model, unwrap_mode="reference")


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _reference_counts(d, valid, flag_valid, height, near_wrap, below, edge, keys):  # pragma: no cover - numba
    """``phase._wrap_flags`` counted (on ``flag_valid & finite(d)``, differences in float64), the
    pixels below ``-below`` among ``valid``, and the valid heights as order-preserving uint32
    keys (for :func:`_median_keys`). Returns (valid, wrap_edge, near_wrap, below, keys).

    Row by row in branch-free loops (LLVM vectorises them): a pixel is on a wrap edge when one
    of its four neighbour pairs is; ``edge`` is scratch ``(3, W)`` uint8 (the pairs to the right,
    to the row above and to the row below)."""
    h, w = d.shape
    n_valid = 0
    n_near = 0
    n_below = 0
    n_keys = 0
    n_edge = 0
    pi = np.pi
    zb = height.reshape(-1).view(np.uint32)
    right = edge[0]
    up = edge[1]
    down = edge[2]
    up[:] = 0
    for v in range(h):
        dv = d[v]
        okv = valid[v]
        fvv = flag_valid[v]
        hv = height[v]
        zv = zb[v * w : v * w + w]
        for u in range(w):
            ok = okv[u]
            hh = hv[u]
            n_valid += ok
            n_below += ok & (hh < -below)
            b = zv[u]
            keys[n_keys] = b ^ (np.uint32(0xFFFFFFFF) if b >> np.uint32(31) else np.uint32(0x80000000))
            n_keys += ok & (hh == hh)
            x = np.float64(dv[u])
            n_near += fvv[u] & (x - x == 0) & (abs(x) > near_wrap)
        for u in range(w - 1):
            x = np.float64(dv[u])
            y = np.float64(dv[u + 1])
            right[u] = fvv[u] & fvv[u + 1] & (x - x == 0) & (y - y == 0) & (abs(y - x) > pi)
        right[w - 1] = 0
        if v + 1 < h:
            dn = d[v + 1]
            fvn = flag_valid[v + 1]
            for u in range(w):
                x = np.float64(dv[u])
                y = np.float64(dn[u])
                down[u] = fvv[u] & fvn[u] & (x - x == 0) & (y - y == 0) & (abs(y - x) > pi)
        else:
            down[:] = 0
        n_edge += right[0] | up[0] | down[0]
        for u in range(1, w):
            n_edge += right[u] | right[u - 1] | up[u] | down[u]
        for u in range(w):
            up[u] = down[u]
    return n_valid, n_edge, n_near, n_below, n_keys


@numba.njit(cache=True, nogil=True)
def _select_key(keys, n, k, hist):  # pragma: no cover - numba
    """The ``k``-th smallest of ``keys[:n]`` (radix select: top 16 bits, then the low 16)."""
    hist[:] = 0
    for i in range(n):
        hist[keys[i] >> np.uint32(16)] += 1
    top = 0
    while hist[top] <= k:
        k -= hist[top]
        top += 1
    hist[:] = 0
    for i in range(n):
        x = keys[i]
        if (x >> np.uint32(16)) == top:
            hist[x & np.uint32(0xFFFF)] += 1
    low = 0
    while hist[low] <= k:
        k -= hist[low]
        low += 1
    return np.uint32((top << 16) | low)


@numba.njit(cache=True, nogil=True)
def _key_value(key):  # pragma: no cover - numba
    b = key ^ (np.uint32(0x80000000) if key >> np.uint32(31) else np.uint32(0xFFFFFFFF))
    return np.array([b], dtype=np.uint32).view(np.float32)[0]


@numba.njit(cache=True, nogil=True)
def _median_keys(keys, n):  # pragma: no cover - numba
    """``np.median`` of the float32 values of ``keys[:n]``: the middle one, or for even ``n``
    the float32 mean of the two middle ones (``np.mean`` of two float32: sum, then / 2)."""
    hist = np.empty(65536, np.int64)
    hi = _key_value(_select_key(keys, n, n // 2, hist))
    if n % 2:
        return np.float64(hi)
    lo = _key_value(_select_key(keys, n, n // 2 - 1, hist))
    return np.float64((lo + hi) / np.float32(2.0))


# --------------------------------------------------------------------------- sensor noise


#: Bounds of :func:`noise_ratio2`: a pixel's own-signal noise only ever raises its variance above
#: the table's measured per-pixel figure (the first-order propagation of the shot + read model
#: through the hue reads the noise low where the chroma is small: with it alone, |e| <= 2u held for
#: 0.71 of the dark half of photo_sensor with two repeats, docs/noise.md), and never more than
#: 1000 times (keeps the filter's float32 sums finite).
_RATIO2_BOUNDS = (1.0, 1e6)


def noise_ratio2(own: NDArray[np.floating], pooled: NDArray[np.floating]) -> NDArray[np.float32]:
    """``(own / pooled)^2`` per pixel, float32, clipped to ``[1, 1e6]``: how much the frame's
    own-signal noise variance (:func:`frame_hue_noise`) exceeds the table's measured per-pixel one
    that weights the phase filter (:func:`capture_noise`; a frame brighter than the bands keeps the
    measured figure: the model's first-order propagation reads dark pixels low). The filter sums ``w`` times it
    (:func:`huefringe.phase.denoise_phase`'s ``ratio``), so that the uncertainty follows the
    frame's signal while the weights, and so the heights, do not."""
    o = np.ascontiguousarray(own, np.float64)
    out = np.empty(o.shape, np.float32)
    _ratio2_kernel(o.reshape(-1), np.ascontiguousarray(pooled, np.float64).reshape(-1), _RATIO2_BOUNDS[0],
                   _RATIO2_BOUNDS[1], out.reshape(-1))
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _ratio2_kernel(own, pooled, lo, hi, out):  # pragma: no cover - compiled
    """:func:`noise_ratio2`'s loop (NaN -> 1, then clipped)."""
    for i in range(own.size):
        r = own[i] / pooled[i]
        r = r * r
        r = r if r == r else 1.0
        out[i] = np.float32(min(max(r, lo), hi))


def sensor_model(table: HueTable) -> NDArray[np.float32] | None:
    """The table's shot + read noise model as float32 ``(2, 3)``: per channel ``gain`` (row 0)
    and ``read`` (row 1) of ``variance = gain * signal + read`` (full scale 1), fitted on the
    hue bands' repeats (:func:`huefringe.huetable.fit_sensor_noise`); None when the table has
    none (one repeat, or a table built before the model existed)."""
    m = (table.stats or {}).get("sensor_noise")
    if not m:
        return None
    return np.ascontiguousarray(np.array([m["gain"], m["read"]], np.float32))


def frame_hue_noise(table: HueTable, rgb: NDArray[Any], gains: NDArray[np.float32], hue_model: str,
                    scale: float = 1.0) -> NDArray[np.float64]:
    """Per-pixel hue noise (rad) of this capture, from its own signal and the sensor-noise model.

    Each channel's variance ``gain_c * signal_c + read_c`` (:func:`sensor_model`), times the
    white-balance gain squared, propagated through the hue formula by its first derivatives
    (hexcone: ``(pi/3)^2 (v_mid C^2 + v_max (mid - min)^2 + v_min (max - mid)^2) / C^4``,
    ``C = max - min``; HSI: the gradient of ``atan2(y, x)``). Where the table has no model, or
    the hue is undefined, the table's pooled figure (:func:`capture_noise`). ``rgb``: the frame
    as the kernel receives it (float in [0, 1], or integer codes with their ``scale``); the
    fused kernel calls the same compiled loop, so both agree bit for bit.
    """
    fallback = capture_noise(table)
    model = sensor_model(table)
    if model is None:
        return fallback
    out = np.empty(fallback.shape, np.float64)
    _hue_noise_kernel(np.ascontiguousarray(rgb), np.float32(scale), np.ascontiguousarray(gains, np.float32),
                      hue_model == "hsi", model, fallback, out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _hue_noise_kernel(rgb, scale, gains, hsi, model, fallback, out):  # pragma: no cover - compiled
    """:func:`frame_hue_noise`'s loop; branch-free rows (selects), so that LLVM vectorises them."""
    h, w, _ = rgb.shape
    k0, k1, k2 = model[0, 0], model[0, 1], model[0, 2]
    r0, r1, r2 = model[1, 0], model[1, 1], model[1, 2]
    k3 = np.float32(math.sqrt(3.0) / 2.0)
    half = np.float32(0.5)
    zero = np.float32(0.0)
    third2 = np.float32((np.pi / 3.0) ** 2)
    for v in range(h):
        px = rgb[v].reshape(-1)
        gn = gains[v].reshape(-1)
        fb = fallback[v]
        ov = out[v]
        for u in range(w):
            f0 = np.float32(px[3 * u]) * scale
            f1 = np.float32(px[3 * u + 1]) * scale
            f2 = np.float32(px[3 * u + 2]) * scale
            g0, g1, g2 = gn[3 * u], gn[3 * u + 1], gn[3 * u + 2]
            r = f0 * g0
            g = f1 * g1
            bl = f2 * g2
            vr = (k0 * f0 + r0) * (g0 * g0)
            vg = (k1 * f1 + r1) * (g1 * g1)
            vb = (k2 * f2 + r2) * (g2 * g2)
            if hsi:
                xx = r - half * (g + bl)
                yy = k3 * (g - bl)
                q = xx * xx + yy * yy
                dg = xx * k3 + half * yy
                db = half * yy - xx * k3
                var = (yy * yy * vr + dg * dg * vg + db * db * vb) / (q * q)
            else:
                mx = max(max(r, g), bl)
                mn = min(min(r, g), bl)
                c = mx - mn
                mid = ((r + g) + bl) - mx - mn
                hi2 = (mid - mn) * (mid - mn)  # weight of the maximum's variance
                lo2 = (mx - mid) * (mx - mid)  # of the minimum's
                c2 = c * c
                wr = hi2 if r == mx else (lo2 if r == mn else c2)
                wg = hi2 if g == mx else (lo2 if g == mn else c2)
                wb = hi2 if bl == mx else (lo2 if bl == mn else c2)
                var = third2 * (wr * vr + wg * vg + wb * vb) / (c2 * c2)
            s = np.sqrt(np.float64(var))
            ov[u] = s if (s - s == 0) & (var > zero) else fb[u]
