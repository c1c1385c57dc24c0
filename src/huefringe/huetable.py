"""Per-pixel multi-band hue calibration (paper sect. 2.3, Figs. 5-7).

The calibration projects ``N`` uniform hue bands (band ``i`` is the trapezoid of eq. 3 at code
phase ``c_i = 2 pi i / N``), ``R`` times each, on the scene. Per pixel, the circular mean (mean
direction) of the white-balanced captured hue over the repeats gives a *hue table* ``T[i] = captured hue of code
c_i``; its inverse maps a captured hue back to the projected code phase, removing the projector
gamma, the surface colour, the camera crosstalk and ambient light (eqs. 6-9) pixel by pixel.

Table format
------------
``HueTable.table`` is a ``uint16`` array of shape ``(N, H, W)`` (band-major, so each band is one
contiguous plane written once during the streamed build): hue ``= count * 2 pi / 65536``
(resolution 9.6e-5 rad, rounding error <= 4.8e-5 rad). Size in memory and on disk:
``2 * N * H * W`` bytes, e.g. 403 MB for 256 bands at 1024 x 768, 194 MB at 768 x 494, plus per
pixel ``start`` (uint16), ``reason`` (uint8), ``noise_rad`` (float32) and ``valid`` (bool):
``8 * H * W`` bytes more. Building needs the table plus a few ``(H, W)`` work planes, the ``R``
hue planes of one band and the image being decoded: peak ``~ 2 N H W + (4 R + 70) H W`` bytes
(measured: 214 MB traced for 256 bands at 768 x 494, table 194 MB).

For every valid pixel the final table is circularly non-decreasing: read from band ``start``
onwards (modulo N) it is sorted ascending in [0, 65536) with exactly one wrap. The inverse lookup
is then a binary search in that rotated sorted column.

Noise reduction (no spatial mixing)
-----------------------------------
Tables are smoothed only *along the band axis* of each pixel: the distortion curve
``d(c_i) = U(c_i) - c_i`` (``U`` the unwrapped captured hue, ``d`` is 2 pi periodic) is filtered
with a local polynomial (Savitzky-Golay) of order ``smooth_order`` over ``smooth_window`` bands
(defaults 2 and 15), whose support never crosses a sextant boundary ``k pi / 3`` of the code, where
eq. 3 switches channel and per-channel gamma puts a kink in the curve (one-sided windows there;
:func:`band_smoothing_matrix`). No pixel ever borrows data from a neighbour, so tables cannot
bleed across surface-colour edges, whatever the edge contrast. Interior noise gain of the default
filter: 0.39 (variance 0.15). Afterwards the curve is made monotone (mean of the running maximum
and the reversed running minimum) so that the inverse exists.

Masking
-------
Pixels are masked for the first failing reason, in this order (``REASONS``):

``low_signal``
    the white image is below ``min_intensity`` in some channel (shadow, black, a colour that
    reflects almost nothing of one primary);
``low_saturation``
    in some band no repeat had a defined hue (white-balanced saturation <= ``min_saturation``);
``noise``
    the standard error of a band's mean hue (RMS spread over repeats / sqrt(R); with one repeat
    the third difference along the bands, see below) exceeds ``max_noise_steps`` band steps
    ``2 pi / N``;
``coverage``
    the captured hues do not wind exactly once round the circle, or leave a gap larger than
    ``max_gap`` between consecutive bands;
``order``
    the captured hue falls back below its running maximum (over any run of bands, so slow
    reversals count as much as jumps) by more than ``max(order_steps band steps, order_sigmas
    sqrt(2) noise)`` (defaults 2 and 6), or the final quantised table is not circularly sorted.

Per-pixel noise
---------------
``HueTable.noise_rad`` is always estimated, never assumed (``stats["noise_rad"]["source"]``,
:data:`NOISE_SOURCES`): with ``R >= 2`` repeats the pooled spread of the repeats about their mean
over all bands (``R - 1`` degrees of freedom per band), as the standard error of a band mean; with
one repeat the third difference along the bands of each sextant (:func:`_band_noise_kernel`),
which removes the captured-hue curve's level, slope and curvature and leaves ``20 sigma^2``:
within 0.94-0.98 of six repeats' figure in every white-level bin of the bench's ``photo_sensor``
(docs/noise.md).

The Fig. 6 compensation of the projected pattern and the calibration QA figures are in
:mod:`huefringe.compensation`, built on these tables.
"""

from __future__ import annotations

import json
import math
import os
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numba
import numpy as np
from numpy.typing import NDArray

from . import colour
from .io import atomic_path, json_default
from .patterns import TWO_PI
from .session import read_rgb

__all__ = [
    "COUNTS",
    "HueTableError",
    "RAD_PER_COUNT",
    "NOISE_SOURCES",
    "REASONS",
    "HueTable",
    "band_smoothing_matrix",
    "build_table",
    "fit_sensor_noise",
    "hue_band_paths",
    "table_nbytes",
]

class HueTableError(ValueError):
    """Hue-table calibration failed: the bands or white image of a session cannot give a usable
    table (names the folder or file). Plane calibration has its own:
    :class:`huefringe.height.PlaneCalibrationError`."""


COUNTS = 65536
"""Table counts per 2 pi (uint16 full range)."""
RAD_PER_COUNT = TWO_PI / COUNTS
REASONS: tuple[str, ...] = ("valid", "low_signal", "low_saturation", "noise", "coverage", "order")
"""Mask reasons; the index is the code stored in ``HueTable.reason`` (0 = valid)."""
_R_LOW_SIGNAL, _R_LOW_SAT = 1, 2  # the kernels use the codes 3 (noise), 4 (coverage), 5 (order)
_FORMAT = "huefringe-hue-table/1"
NOISE_SOURCES: tuple[str, ...] = ("repeats", "band_difference")
"""How a table's per-pixel noise was found (``stats["noise_rad"]["source"]``): the spread of the
band repeats (``R >= 2``), or the third difference along the bands of the single repeat."""
_TWO_PI_F32 = np.float32(TWO_PI)


def table_nbytes(n_bands: int, height: int, width: int) -> int:
    """Bytes of the ``(N, H, W)`` uint16 table: ``2 N H W`` (403 MB for 256 x 1024 x 768)."""
    return 2 * int(n_bands) * int(height) * int(width)


def hue_band_paths(hue_dir: str | os.PathLike[str], n_bands: int, repeats: int, suffix: str = ".png") -> list[list[Path]]:
    """``[[band_000_r0, band_000_r1, ...], ...]`` paths of a session's ``hue/`` folder."""
    d = Path(hue_dir)
    return [[d / f"band_{i:03d}_r{r}{suffix}" for r in range(repeats)] for i in range(n_bands)]


def band_smoothing_matrix(n_bands: int, window: int, order: int = 2) -> NDArray[np.float64]:
    """Coefficients of the along-band local-polynomial smoother, one row per band.

    Row ``i`` holds the weights of bands ``i - m .. i + m`` (``m = window // 2``) that
    evaluate at band ``i`` a least-squares polynomial of degree ``order`` (Savitzky-Golay). The
    support never crosses a sextant boundary of the code, ``c = k pi / 3``, where the trapezoid of
    eq. 3 switches channel and the captured hue curve has a kink (per-channel gamma makes the
    slope jump there); near a boundary the window is one-sided instead (c = 0 is a boundary, so no
    window wraps round). ``window <= 1`` gives the identity.
    """
    m = max(0, int(window) // 2)
    if window > 1 and window % 2 == 0:
        raise ValueError("smooth_window must be odd")
    if 2 * m + 1 > n_bands:
        raise ValueError("smooth_window must be <= N")
    coef = np.zeros((n_bands, 2 * m + 1), dtype=np.float64)
    if m == 0:
        coef[:, 0] = 1.0
        return coef
    seg = (6 * np.arange(n_bands)) // n_bands  # sextant of each band's code phase
    for i in range(n_bands):
        left = 0
        while left < m and i - left - 1 >= 0 and seg[i - left - 1] == seg[i]:
            left += 1
        right = 0
        while right < m and i + right + 1 < n_bands and seg[i + right + 1] == seg[i]:
            right += 1
        x = np.arange(-left, right + 1, dtype=np.float64)
        deg = min(order, x.size - 1)
        vander = np.vander(x, deg + 1, increasing=True)  # columns 1, x, x^2, ...
        w = np.linalg.pinv(vander)[0]  # weights giving the fitted value at x = 0
        coef[i, m - left : m + right + 1] = w
    return coef


# =============================================================================================
# numba kernels
# =============================================================================================
@numba.njit(cache=True, parallel=False, nogil=True)
def _accumulate_kernel(hues, plane, var_sum, dof, missing):  # pragma: no cover - numba
    """Mean direction of one band's repeats into a uint16 plane; spread into the accumulators.

    The mean direction is the arithmetic mean of the repeats unwrapped about the first valid one,
    ``x0 + mean(wrap(x_r - x0))``: for concentrated samples it equals the circular mean
    ``atan2(sum sin, sum cos)`` to third order in the spread (1e-5 rad at a 0.1 rad spread, below
    the table's 4.8e-5 rad quantisation) and needs no trigonometry.
    """
    n_rep, h, w = hues.shape
    two_pi = 2.0 * np.pi
    scale = 65536.0 / two_pi
    for v in range(h):
        for u in range(w):
            x0 = 0.0
            acc = 0.0
            cnt = 0
            for r in range(n_rep):
                x = np.float64(hues[r, v, u])
                if x == x:
                    if cnt == 0:
                        x0 = x
                    else:
                        d = x - x0
                        if d >= np.pi:
                            d -= two_pi
                        elif d < -np.pi:
                            d += two_pi
                        acc += d
                    cnt += 1
            if cnt == 0:
                missing[v, u] = True
                plane[v, u] = 0
                continue
            m = x0 + acc / cnt
            if cnt >= 2:
                ss = 0.0
                for r in range(n_rep):
                    x = np.float64(hues[r, v, u])
                    if x == x:
                        d = x - m
                        if d >= np.pi:
                            d -= two_pi
                        elif d < -np.pi:
                            d += two_pi
                        ss += d * d
                var_sum[v, u] += ss
                dof[v, u] += cnt - 1
            q = int(math.floor(m * scale + 0.5))
            while q < 0:
                q += 65536
            while q >= 65536:
                q -= 65536
            plane[v, u] = q


#: Order of the difference along the bands that the one-repeat noise estimate takes
#: (:func:`_band_noise_kernel`): the third removes the hue curve's level, slope and curvature.
BAND_DIFFERENCE_ORDER = 3


@numba.njit(cache=True, nogil=True)
def _band_noise_kernel(table, reason, order, out):  # pragma: no cover - numba
    """Hue noise (rad) of one band mean per pixel from a difference of ``order`` along the bands.

    The captured hue is a smooth function of the band's code phase within each sextant of the
    code (eq. 3 ramps one channel there; the curve kinks only at the sextant boundaries). The
    difference of order ``p`` of ``p + 1`` consecutive bands of one sextant (binomial weights
    ``(-1)^j C(p, j)``) removes a polynomial of degree ``p - 1`` (``p = 3``: level, slope and
    curvature, which projector gamma makes large where the noise is small) and leaves noise of
    variance ``C(2p, p) sigma^2`` (20 for ``p = 3``) for independent band means of variance
    ``sigma^2``; runs crossing a sextant boundary (the wrap at band 0 is one) are left out.
    ``out = sqrt(mean(d^2) / C(2p, p))``; NaN where ``reason != 0`` or no run fits a sextant.
    """
    n, h, w = table.shape
    two_pi = 2.0 * np.pi
    rad = two_pi / 65536.0
    seg = np.empty(n, np.int64)
    for i in range(n):
        seg[i] = (6 * i) // n
    coef = np.empty(order + 1)
    var = 0.0
    for j in range(order + 1):
        c = 1.0
        for m in range(j):
            c = c * (order - m) / (m + 1)
        coef[j] = c if j % 2 == 0 else -c
        var += c * c
    steps = np.empty(n)
    for v in range(h):
        for u in range(w):
            if reason[v, u] != 0:
                out[v, u] = np.nan
                continue
            # the unwrapped curve from band 0 (steps wrapped to [-pi, pi))
            acc = 0.0
            steps[0] = 0.0
            for i in range(1, n):
                d = (np.float64(table[i, v, u]) - np.float64(table[i - 1, v, u])) * rad
                d -= two_pi * math.floor((d + np.pi) / two_pi)
                acc += d
                steps[i] = acc
            ss = 0.0
            cnt = 0
            for i in range(0, n - order):
                if seg[i] != seg[i + order]:
                    continue
                x = 0.0
                for j in range(order + 1):
                    x += coef[j] * steps[i + j]
                ss += x * x
                cnt += 1
            out[v, u] = math.sqrt(ss / (var * cnt)) if cnt > 0 else np.nan


@numba.njit(cache=True, parallel=False)
def _finalise_kernel(table, sigma, reason, start, coef, max_noise, max_gap, order_tol_min, order_sigmas):  # pragma: no cover - numba
    """Per-pixel checks, band-axis smoothing, monotone fix and requantisation (in place)."""
    n, h, w = table.shape
    two_pi = 2.0 * np.pi
    rad = two_pi / 65536.0
    step = two_pi / n
    half = coef.shape[1] // 2
    hh = np.empty(n)
    s = np.empty(n)
    d = np.empty(n)
    us = np.empty(n)
    f = np.empty(n)
    q = np.empty(n, dtype=np.int64)
    for v in range(h):
        for u in range(w):
            if reason[v, u] != 0:
                continue
            sig = sigma[v, u]
            if sig == sig and sig > max_noise:
                reason[v, u] = 3
                continue
            for i in range(n):
                hh[i] = table[i, v, u] * rad
            total = 0.0
            smax = -1e9
            smin = 1e9
            for i in range(n):
                j = i + 1 if i + 1 < n else 0
                x = hh[j] - hh[i]
                x = x - two_pi * math.floor((x + np.pi) / two_pi)
                s[i] = x
                total += x
                if x > smax:
                    smax = x
                if x < smin:
                    smin = x
            if abs(total - two_pi) > np.pi or smax > max_gap:
                reason[v, u] = 4
                continue
            tol = order_tol_min
            if sig == sig and order_sigmas * math.sqrt(2.0) * sig > tol:
                tol = order_sigmas * math.sqrt(2.0) * sig
            if smin < -tol:
                reason[v, u] = 5
                continue
            # unwrapped curve and its distortion d = U - c (2 pi periodic)
            acc = hh[0]
            for i in range(n):
                d[i] = acc - i * step
                acc += s[i]
            # largest fall below the running maximum (over 2 turns, so that a reversal across
            # band 0 is seen): a slow reversal spread over many bands is as bad as a jump back
            top = -1e300
            drop = 0.0
            for k in range(2 * n):
                i = k if k < n else k - n
                x = d[i] + i * step + (0.0 if k < n else two_pi)
                if x > top:
                    top = x
                elif top - x > drop:
                    drop = top - x
            if drop > tol:
                reason[v, u] = 5
                continue
            # local polynomial smoothing along the band axis (one coefficient row per band)
            for i in range(n):
                x = 0.0
                for k in range(coef.shape[1]):
                    ck = coef[i, k]
                    if ck != 0.0:
                        jj = i + k - half
                        if jj < 0:
                            jj += n
                        elif jj >= n:
                            jj -= n
                        x += ck * d[jj]
                us[i] = i * step + x
            # monotone fix: mean of running max and reversed running min (bounded by one turn)
            top = us[0] + two_pi
            m = us[0]
            for i in range(n):
                if us[i] > m:
                    m = us[i]
                f[i] = m if m < top else top
            m = top
            for i in range(n - 1, -1, -1):
                if us[i] < m:
                    m = us[i]
                f[i] = 0.5 * (f[i] + m)
            # quantise; f[0] is the minimum: keep the whole curve within one turn (in counts, so
            # that rounding cannot push the last band past the first one)
            q0 = int(math.floor(f[0] / rad + 0.5))
            for i in range(n):
                qi = int(math.floor(f[i] / rad + 0.5))
                if qi > q0 + 65536:
                    qi = q0 + 65536
                q[i] = qi % 65536
            desc = 0
            first = 0
            for i in range(n):
                prev = q[i - 1] if i > 0 else q[n - 1]
                if q[i] < prev:
                    desc += 1
                    first = i
            if desc != 1:
                reason[v, u] = 5
                continue
            start[v, u] = first
            for i in range(n):
                table[i, v, u] = q[i]


@numba.njit(cache=True, inline="always")
def _column_entry(table, s0, k, v, u):  # pragma: no cover - numba
    """Entry ``k`` (any integer) of a pixel's rotated, sorted column continued periodically:
    ``table[(s0 + k) mod N] + 65536 floor(k / N)`` (float64 counts)."""
    n = table.shape[0]
    q = k // n
    i = s0 + k - q * n
    if i >= n:
        i -= n
    return np.float64(table[i, v, u]) + 65536.0 * q


@numba.njit(cache=True, parallel=False)
def _to_phase_kernel(table, start, valid, hue, out, out_slope):  # pragma: no cover - numba
    """Inverse lookup: binary search of each pixel's hue in its rotated sorted table column.

    ``out_slope`` (or None): the slope d(hue)/d(code phase) of the table averaged over one band
    width centred on the hue (see :meth:`HueTable.hue_slope`).
    """
    n, h, w = table.shape
    two_pi = 2.0 * np.pi
    scale = 65536.0 / two_pi
    step = two_pi / n
    two_pi_f32 = np.float32(two_pi)
    for v in range(h):
        for u in range(w):
            x = hue[v, u]
            if not valid[v, u] or not math.isfinite(x):
                out[v, u] = np.nan
                if out_slope is not None:
                    out_slope[v, u] = np.nan
                continue
            hq = (np.float64(x) * scale) % 65536.0  # float modulo; math.floor gives an int64 (overflows)
            if hq >= 65536.0:  # -tiny % 65536 rounds to 65536
                hq -= 65536.0
            s0 = np.int64(start[v, u])
            lo = 0
            hi = n
            while lo < hi:
                mid = (lo + hi) >> 1
                k = s0 + mid
                if k >= n:
                    k -= n
                if np.float64(table[k, v, u]) <= hq:
                    lo = mid + 1
                else:
                    hi = mid
            p = lo - 1
            if p < 0:
                b = s0 - 1 if s0 > 0 else n - 1
                lo_val = np.float64(table[b, v, u]) - 65536.0
                hi_val = np.float64(table[s0, v, u])
            else:
                b = s0 + p
                if b >= n:
                    b -= n
                lo_val = np.float64(table[b, v, u])
                if p == n - 1:
                    hi_val = np.float64(table[s0, v, u]) + 65536.0
                else:
                    k = b + 1
                    if k >= n:
                        k -= n
                    hi_val = np.float64(table[k, v, u])
            if out_slope is not None:
                f = (hq - lo_val) / (hi_val - lo_val)
                if f < 0.5:
                    sc = (0.5 - f) * (lo_val - _column_entry(table, s0, p - 1, v, u)) + (0.5 + f) * (hi_val - lo_val)
                else:
                    sc = (1.5 - f) * (hi_val - lo_val) + (f - 0.5) * (_column_entry(table, s0, p + 2, v, u) - hi_val)
                out_slope[v, u] = sc * n / 65536.0
            c = (b + (hq - lo_val) / (hi_val - lo_val)) * step
            if c >= two_pi:
                c -= two_pi
            r = np.float32(c)
            if r >= two_pi_f32:
                r = np.float32(0.0)
            out[v, u] = r


# =============================================================================================
# the table
# =============================================================================================
@dataclass(eq=False)
class HueTable:
    """Per-pixel hue table of one scene (reference plate or object).

    Attributes
    ----------
    model : {"hexcone", "hsi"}
        Hue model the table was built with (decode frames with the same model).
    n_bands : int
        ``N``; band ``i`` has code phase ``2 pi i / N``.
    table : ndarray of uint16, shape (N, H, W)
        Captured (white-balanced) hue of band ``i`` at each pixel, ``count * 2 pi / 65536``.
        Valid pixels: smoothed and circularly sorted from band ``start``; masked pixels: the raw
        circular means (for QA).
    valid : ndarray of bool, shape (H, W)
    start : ndarray of uint16, shape (H, W)
        Band index where the circularly sorted column has its minimum (its single wrap).
    reason : ndarray of uint8, shape (H, W)
        Mask reason code, index into :data:`REASONS` (0 = valid).
    noise_rad : ndarray of float32, shape (H, W)
        Standard error of the per-band mean hue: from the repeats, or with one repeat from the
        third difference along the bands (``stats["noise_rad"]["source"]``); NaN where masked.
    stats : dict
        Counts per reason, valid fraction, noise statistics, build parameters.
    """

    model: str
    n_bands: int
    table: NDArray[np.uint16]
    valid: NDArray[np.bool_]
    start: NDArray[np.uint16]
    reason: NDArray[np.uint8]
    noise_rad: NDArray[np.float32]
    stats: dict[str, Any] = field(default_factory=dict)

    # ------------------------------------------------------------------ basic properties
    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(H, W)``."""
        return (int(self.table.shape[1]), int(self.table.shape[2]))

    @property
    def nbytes(self) -> int:
        """Bytes of the table and its per-pixel maps."""
        return int(self.table.nbytes + self.valid.nbytes + self.start.nbytes + self.reason.nbytes + self.noise_rad.nbytes)

    def band_hue(self, i: int) -> NDArray[np.float32]:
        """Captured hue of band ``i`` as float32 radians (H, W)."""
        return (self.table[i].astype(np.float32) * np.float32(RAD_PER_COUNT)).astype(np.float32)

    # ------------------------------------------------------------------ inverse lookup
    def to_phase(self, hue: NDArray[np.floating], *, method: Literal["numba", "numpy"] = "numba") -> NDArray[np.float32]:
        """Code phase projected at each pixel, from the captured hue (inverse table lookup).

        Parameters
        ----------
        hue : ndarray, shape (H, W)
            Captured hue in radians (any real value, taken modulo 2 pi; NaN allowed), computed
            with the table's model from a frame white-balanced like the bands (see
            :meth:`phase_from_rgb`).
        method : {"numba", "numpy"}
            ``"numba"`` (default): per-pixel binary search, compiled; ``"numpy"``: the vectorised
            reference (counting comparisons, row chunks). They agree to float32 rounding.

        Returns
        -------
        ndarray of float32, shape (H, W)
            Code phase in [0, 2 pi) by circular piecewise-linear interpolation between the
            bracketing bands; NaN where the pixel is invalid or ``hue`` is NaN.
        """
        hue = np.asarray(hue)
        if hue.shape != self.shape:
            raise ValueError(f"hue has shape {hue.shape}, table expects {self.shape}")
        if method == "numba":
            out = np.empty(self.shape, dtype=np.float32)
            _to_phase_kernel(np.asarray(self.table), self.start, self.valid, np.ascontiguousarray(hue), out, None)
            return out
        if method == "numpy":
            return _to_phase_numpy(np.asarray(self.table), self.start, self.valid, hue)
        raise ValueError(f"unknown method {method!r}")

    def hue_slope(self, hue: NDArray[np.floating]) -> NDArray[np.float64]:
        """Local slope d(captured hue)/d(code phase) of each pixel's table at ``hue``.

        The central difference of the piecewise-linear table over one band width centred on the
        code phase :meth:`to_phase` gives (``[H(c + pi/N) - H(c - pi/N)] / (2 pi/N)``): the
        slopes of the bracketing band and of its nearer neighbour, weighted by how much of the
        window each covers. 1 for an undistorted table, below 1 where projector gamma flattens
        the captured hue. NaN where :meth:`to_phase` is NaN.
        """
        return self.to_phase_and_slope(hue)[1]

    def to_phase_and_slope(self, hue: NDArray[np.floating]) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
        """:meth:`to_phase` and :meth:`hue_slope` from one search of each pixel's column."""
        hue = np.asarray(hue)
        if hue.shape != self.shape:
            raise ValueError(f"hue has shape {hue.shape}, table expects {self.shape}")
        phase = np.empty(self.shape, dtype=np.float32)
        slope = np.empty(self.shape, dtype=np.float64)
        _to_phase_kernel(np.asarray(self.table), self.start, self.valid, np.ascontiguousarray(hue), phase, slope)
        return phase, slope

    def from_phase(self, phase: NDArray[np.floating]) -> NDArray[np.float32]:
        """Forward table: expected captured hue at each pixel for a projected code ``phase``.

        Circular piecewise-linear interpolation between bands; NaN where invalid or phase NaN.
        """
        phase = np.asarray(phase, dtype=np.float64)
        if phase.shape != self.shape:
            raise ValueError(f"phase has shape {phase.shape}, table expects {self.shape}")
        n = self.n_bands
        ok = self.valid & np.isfinite(phase)
        pos = np.mod(np.where(ok, phase, 0.0), TWO_PI) * (n / TWO_PI)
        b = np.minimum(np.floor(pos).astype(np.int64), n - 1)
        frac = pos - b
        tab = np.asarray(self.table)
        lo = np.take_along_axis(tab, b[None], axis=0)[0].astype(np.float64)
        hi = np.take_along_axis(tab, ((b + 1) % n)[None], axis=0)[0].astype(np.float64)
        step = np.mod(hi - lo, COUNTS)
        out = colour.wrap_2pi((lo + frac * step) * RAD_PER_COUNT)
        out[~ok] = np.nan
        return out

    def phase_from_rgb(self, rgb: NDArray[np.floating], white: NDArray[np.floating]) -> NDArray[np.float32]:
        """Decode a captured frame: white balance, hue (table's model) and inverse lookup."""
        p = self.stats.get("params", {})
        bal = colour.white_balance(rgb, white, floor=p.get("floor", 1.0 / 255.0))
        h = colour.hue(bal, self.model, min_saturation=p.get("min_saturation", 0.0))  # type: ignore[arg-type]
        return self.to_phase(h)

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the table as three files beside ``path`` (suffix ignored), each atomically.

        ``<stem>.npy`` the ``(N, H, W)`` uint16 table (memory-mappable), ``<stem>.maps.npz`` the
        per-pixel maps, ``<stem>.json`` the metadata, written last. A CRC-32 of the table is
        stored in both the JSON and the npz, so :meth:`load` detects a mixed set from an
        interrupted overwrite. Returns the JSON path.
        """
        base = _base(path)
        tab = np.ascontiguousarray(self.table)
        token = f"{zlib.crc32(memoryview(tab).cast('B')) & 0xFFFFFFFF:08x}"
        with atomic_path(base.with_suffix(".npy")) as tmp:
            np.save(tmp, tab, allow_pickle=False)
        with atomic_path(base.with_suffix(".maps.npz")) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, valid=self.valid, start=self.start, reason=self.reason,
                                    noise_rad=self.noise_rad, token=np.array(token))
        meta = {
            "format": _FORMAT,
            "model": self.model,
            "n_bands": int(self.n_bands),
            "shape": [int(s) for s in tab.shape],
            "dtype": "uint16",
            "rad_per_count": RAD_PER_COUNT,
            "token": token,
            "stats": self.stats,
        }
        text = json.dumps(meta, indent=2, sort_keys=True, allow_nan=False, default=json_default)
        with atomic_path(base.with_suffix(".json")) as tmp:
            tmp.write_text(text + "\n", encoding="utf-8")
        return base.with_suffix(".json")

    @classmethod
    def load(cls, path: str | os.PathLike[str], *, mmap: bool = True, verify: bool = False) -> HueTable:
        """Read a table written by :meth:`save`; the big array is memory-mapped read-only by default.

        ``verify=True`` recomputes the CRC-32 of the table (reads it all).
        """
        base = _base(path)
        meta = json.loads(base.with_suffix(".json").read_text(encoding="utf-8"))
        if meta.get("format") != _FORMAT:
            raise ValueError(f"{base}.json: not a {_FORMAT} file")
        tab = np.load(base.with_suffix(".npy"), mmap_mode="r" if mmap else None, allow_pickle=False)
        with np.load(base.with_suffix(".maps.npz"), allow_pickle=False) as z:
            maps = {k: z[k] for k in ("valid", "start", "reason", "noise_rad", "token")}
        if list(tab.shape) != meta["shape"] or tab.dtype != np.uint16:
            raise ValueError(f"{base}.npy: shape/dtype {tab.shape}/{tab.dtype} differ from the JSON")
        if str(maps["token"]) != meta["token"]:
            raise ValueError(f"{base}: maps and metadata come from different saves")
        if verify:
            crc = f"{zlib.crc32(memoryview(np.ascontiguousarray(tab)).cast('B')) & 0xFFFFFFFF:08x}"
            if crc != meta["token"]:
                raise ValueError(f"{base}.npy: CRC mismatch (table from another save or damaged)")
        return cls(model=meta["model"], n_bands=int(meta["n_bands"]), table=tab, valid=maps["valid"],
                   start=maps["start"], reason=maps["reason"], noise_rad=maps["noise_rad"], stats=meta["stats"])


def _base(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    for suf in (".json", ".npy", ".npz"):
        if p.name.endswith(suf):
            p = p.with_name(p.name[: -len(suf)])
    if p.name.endswith(".maps"):
        p = p.with_name(p.name[: -len(".maps")])
    return p


def _to_phase_numpy(table: NDArray[np.uint16], start: NDArray[np.uint16], valid: NDArray[np.bool_],
                    hue: NDArray[np.floating], rows_per_chunk: int | None = None) -> NDArray[np.float32]:
    """Vectorised reference of the inverse lookup (counts entries <= hue instead of bisecting)."""
    n, h, w = table.shape
    out = np.full((h, w), np.nan, dtype=np.float32)
    if rows_per_chunk is None:
        rows_per_chunk = max(1, (1 << 22) // max(1, n * w))
    ar = np.arange(n)[:, None, None]
    for v0 in range(0, h, rows_per_chunk):
        sl = slice(v0, min(h, v0 + rows_per_chunk))
        st = start[sl].astype(np.int64)
        hq = np.asarray(hue[sl], dtype=np.float64) * (COUNTS / TWO_PI)
        ok = valid[sl] & np.isfinite(hq)
        hq = np.where(ok, hq - COUNTS * np.floor(hq / COUNTS), 0.0)
        rot = np.take_along_axis(table[:, sl], (st[None] + ar) % n, axis=0).astype(np.float64)  # sorted
        p = np.count_nonzero(rot <= hq[None], axis=0) - 1
        b = np.where(p < 0, (st - 1) % n, (st + p) % n)
        lo_val = np.take_along_axis(rot, np.maximum(p, 0)[None], axis=0)[0]
        lo_val = np.where(p < 0, rot[n - 1] - COUNTS, lo_val)
        hi_val = np.take_along_axis(rot, np.minimum(p + 1, n - 1)[None], axis=0)[0]
        hi_val = np.where(p == n - 1, rot[0] + COUNTS, hi_val)
        with np.errstate(divide="ignore", invalid="ignore"):
            c = (b + (hq - lo_val) / (hi_val - lo_val)) * (TWO_PI / n)
        c = np.where(c >= TWO_PI, c - TWO_PI, c)
        r = c.astype(np.float32)
        r[r >= _TWO_PI_F32] = 0.0
        r[~ok] = np.nan
        out[sl] = r
    return out


# =============================================================================================
# building (streamed)
# =============================================================================================
class _Reader:
    """Images of the bands in order: read on demand, or ``prefetch`` bands ahead in threads."""

    def __init__(self, read: Callable[[Any], Any], band_paths: Sequence[Sequence[Any]], prefetch: int):
        self.read, self.paths, self.prefetch = read, band_paths, max(0, int(prefetch))
        self.pool: Any = None
        self.pending: dict[tuple[int, int], Any] = {}
        self.next_band = 0

    def __enter__(self) -> _Reader:
        if self.prefetch:
            from concurrent.futures import ThreadPoolExecutor

            reps = len(self.paths[0]) if len(self.paths) else 1
            self.pool = ThreadPoolExecutor(max_workers=min(4, self.prefetch * reps), thread_name_prefix="hue-read")
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.pool is not None:
            for f in self.pending.values():
                f.cancel()
            self.pool.shutdown(wait=True)
        self.pending.clear()

    def get(self, i: int, r: int) -> Any:
        if self.pool is None:
            return self.read(self.paths[i][r])
        while self.next_band < len(self.paths) and self.next_band <= i + self.prefetch:
            for rr, p in enumerate(self.paths[self.next_band]):
                self.pending[(self.next_band, rr)] = self.pool.submit(self.read, p)
            self.next_band += 1
        return self.pending.pop((i, r)).result()


#: Stride (px, both axes) of the pixels whose repeats feed the sensor-noise fit; signal bins.
_NOISE_STRIDE = 3
_NOISE_BINS = 64


class _RepeatStats:
    """Per-channel temporal variance of the band repeats against their mean signal (a subsample
    of pixels, binned by signal) for :func:`fit_sensor_noise`."""

    def __init__(self, h: int, w: int, repeats: int) -> None:
        self.repeats = repeats
        shape = (len(range(0, h, _NOISE_STRIDE)), len(range(0, w, _NOISE_STRIDE)), 3)
        self.s1 = np.zeros(shape)
        self.s2 = np.zeros(shape)
        self.lo = np.full(shape, np.inf)
        self.hi = np.full(shape, -np.inf)
        self.var_sum = np.zeros((3, _NOISE_BINS))
        self.sig_sum = np.zeros((3, _NOISE_BINS))
        self.count = np.zeros((3, _NOISE_BINS))
        self.top = None

    def add(self, img: NDArray[np.floating]) -> None:
        x = np.asarray(img[::_NOISE_STRIDE, ::_NOISE_STRIDE], np.float64)
        self.s1 += x
        self.s2 += x * x
        np.minimum(self.lo, x, out=self.lo)
        np.maximum(self.hi, x, out=self.hi)

    def end_band(self) -> None:
        r = self.repeats
        if r >= 2:
            mean = self.s1 / r
            var = np.maximum(self.s2 - r * mean * mean, 0.0) / (r - 1)
            # repeats clipped at either end of the sensor's range have a truncated spread
            ok = (self.lo > 0.0) & (self.hi < 1.0)
            idx = np.minimum((mean * _NOISE_BINS).astype(np.int64), _NOISE_BINS - 1)
            for c in range(3):
                m = ok[..., c]
                k = idx[..., c][m]
                self.var_sum[c] += np.bincount(k, var[..., c][m], _NOISE_BINS)
                self.sig_sum[c] += np.bincount(k, mean[..., c][m], _NOISE_BINS)
                self.count[c] += np.bincount(k, minlength=_NOISE_BINS)
        self.s1[:] = 0.0
        self.s2[:] = 0.0
        self.lo[:] = np.inf
        self.hi[:] = -np.inf

    def fit(self) -> dict[str, Any] | None:
        return fit_sensor_noise(self.sig_sum, self.var_sum, self.count, self.repeats)


def fit_sensor_noise(sig_sum: NDArray[np.floating], var_sum: NDArray[np.floating], count: NDArray[np.floating],
                     repeats: int, min_count: int = 50) -> dict[str, Any] | None:
    """Shot + read noise model ``var_c = gain_c * signal + read_c`` per channel (signal and
    variance in units of the full scale, [0, 1]) from binned repeat statistics.

    ``sig_sum``, ``var_sum``, ``count`` ``(3, bins)``: per signal bin the sums of the repeats'
    mean signal and of their unbiased temporal variance, and the number of pixel-bands. A
    weighted least-squares line through the bins' mean variances (weights ``count / var^2``: a
    sample variance of ``R`` repeats has relative variance ``2 / (R - 1)``); slope and intercept
    are kept non-negative. ``None`` without repeats (``R < 2``) or with fewer than two usable
    bins. ``rel_rms`` is the rms relative misfit of the bins (a check that the model holds).
    """
    if repeats < 2:
        return None
    gain, read, rel = [], [], []
    nbins = 0
    for c in range(3):
        m = count[c] >= min_count
        if np.count_nonzero(m) < 2:
            return None
        s = sig_sum[c][m] / count[c][m]
        v = var_sum[c][m] / count[c][m]
        wgt = count[c][m] / np.maximum(v, 1e-30) ** 2
        a = np.stack([s, np.ones_like(s)], axis=1)
        sw = np.sqrt(wgt)
        g, r = np.linalg.lstsq(a * sw[:, None], v * sw, rcond=None)[0]
        if r < 0:  # through the origin
            g, r = float(np.sum(wgt * s * v) / np.sum(wgt * s * s)), 0.0
        if g < 0:  # read noise only
            g, r = 0.0, float(np.sum(wgt * v) / np.sum(wgt))
        r = max(float(r), 1e-12)
        gain.append(float(g))
        read.append(r)
        rel.append(float(np.sqrt(np.average(((g * s + r) / v - 1.0) ** 2, weights=count[c][m]))))
        nbins += int(np.count_nonzero(m))
    return {"model": "variance = gain * signal + read (full scale = 1)", "gain": gain, "read": read,
            "rel_rms": rel, "bins": nbins, "samples": int(np.sum(count)), "repeats": int(repeats),
            "stride_px": _NOISE_STRIDE}


def build_table(
    band_paths: Sequence[Sequence[str | os.PathLike[str]]],
    white: NDArray[np.floating],
    *,
    model: colour.HueModel = "hexcone",
    read: Callable[[Any], NDArray[np.floating]] = read_rgb,
    min_saturation: float = 0.05,
    min_intensity: float = 0.02,
    floor: float | None = None,
    smooth_window: int = 15,
    smooth_order: int = 2,
    max_noise_steps: float = 2.0,
    max_gap: float = np.pi / 3.0,
    order_steps: float = 2.0,
    order_sigmas: float = 6.0,
    out: NDArray[np.uint16] | None = None,
    prefetch: int = 0,
    progress: bool = False,
) -> HueTable:
    """Build a per-pixel hue table from ``N`` bands x ``R`` repeats, streaming the images.

    Parameters
    ----------
    band_paths : sequence of sequences
        ``band_paths[i][r]`` is band ``i`` (code phase ``2 pi i / N``), repeat ``r``; every band
        must have the same number of repeats ``R >= 1``. Anything ``read`` accepts.
    white : ndarray, shape (H, W, 3)
        Capture of the white projection on the same scene (float in [0, 1]).
    model : {"hexcone", "hsi"}
        Hue model.
    read : callable
        ``read(path) -> (H, W, 3)`` float image in [0, 1]; called once per image, band by band,
        repeat by repeat, in order.
    min_saturation : float
        Repeats whose white-balanced saturation is ``<= min_saturation`` give no hue.
    min_intensity : float
        Pixels whose white image is below this in any channel are masked ``low_signal``.
    floor : float, optional
        White-balance floor (see :func:`huefringe.colour.white_balance`); default
        ``min_intensity / 2``.
    smooth_window, smooth_order : int
        Local-polynomial window (odd, in bands) and degree along the band axis, not crossing the
        code's sextant boundaries (:func:`band_smoothing_matrix`); window <= 1 disables.
    max_noise_steps : float
        Mask ``noise`` when the standard error of a band mean (from the repeats, or with one
        repeat from the third difference along the bands) exceeds this many band steps.
    max_gap : float
        Mask ``coverage`` when two consecutive bands are more than this apart in captured hue.
    order_steps, order_sigmas : float
        Mask ``order`` when the captured hue falls back below its running maximum over the bands
        by more than ``max(order_steps * 2 pi / N, order_sigmas * sqrt(2) * noise)``, ``noise`` the
        pixel's pooled standard error of a band mean. Noise is not the same in every band (in
        the flat stretches that gamma makes at the start of each sextant it is up to ~3x the
        pooled value), hence the large default of 6; smaller reversals are harmless after the
        monotone fix (they act like noise).
    out : ndarray of uint16, shape (N, H, W), optional
        Preallocated table (e.g. a ``numpy.lib.format.open_memmap``) to fill instead of a new one.
    prefetch : int
        Bands to read ahead in background threads (PNG decoding releases the GIL, so reading
        overlaps the hue computation); 0 (default) reads strictly one image after the other in
        the calling thread. At most ``(prefetch + 1) R`` images are alive at a time.
    progress : bool
        Show a tqdm progress bar over bands.

    Returns
    -------
    HueTable

    Notes
    -----
    Images are read one at a time and reduced at once to a hue plane; only one band's ``R`` hue
    planes are alive at a time. Memory is the table (``2 N H W`` bytes) plus
    ``~ (4 R + 70) H W`` bytes of work planes. The per-band mean is the mean direction of the
    repeats (see ``_accumulate_kernel``: equal to the circular mean to third order in the spread).
    """
    n = len(band_paths)
    if n < 6:
        raise ValueError(f"need at least 6 hue bands, got {n}")
    reps = {len(b) for b in band_paths}
    if len(reps) != 1 or 0 in reps:
        raise ValueError(f"every band needs the same number (>= 1) of repeats, got {sorted(reps)}")
    n_rep = reps.pop()
    if model not in colour.HUE_MODELS:
        raise ValueError(f"unknown hue model {model!r}")
    white = np.asarray(white, dtype=np.float32)
    if white.ndim != 3 or white.shape[2] != 3:
        raise ValueError(f"white must be (H, W, 3), got {white.shape}")
    h, w = white.shape[:2]
    if floor is None:
        floor = 0.5 * min_intensity if min_intensity > 0 else 1.0 / 255.0
    if out is None:
        table = np.empty((n, h, w), dtype=np.uint16)
    else:
        if out.shape != (n, h, w) or out.dtype != np.uint16:
            raise ValueError(f"out must be uint16 {(n, h, w)}, got {out.dtype} {out.shape}")
        table = out
    tab = np.asarray(table)  # plain ndarray view (also of a memmap) for the compiled kernels
    gains = colour.white_gains(white, floor)
    reason = np.zeros((h, w), dtype=np.uint8)
    reason[np.min(white, axis=2) < min_intensity] = _R_LOW_SIGNAL
    missing = np.zeros((h, w), dtype=bool)
    var_sum = np.zeros((h, w), dtype=np.float64)
    dof_map = np.zeros((h, w), dtype=np.int32)
    hues = np.empty((n_rep, h, w), dtype=np.float32)

    bands: Any = range(n)
    if progress:
        from tqdm import tqdm

        bands = tqdm(bands, desc="hue bands", unit="band")
    repeat_stats = _RepeatStats(h, w, n_rep)
    with _Reader(read, band_paths, prefetch) as reader:
        for i in bands:
            for r, path in enumerate(band_paths[i]):
                img = np.asarray(reader.get(i, r))
                if img.shape != (h, w, 3):
                    raise ValueError(f"{path}: image shape {img.shape} differs from white {white.shape}")
                colour.balanced_hue(img, gains, model, min_saturation=min_saturation, out=hues[r])
                repeat_stats.add(img)
                del img
            _accumulate_kernel(hues, tab[i], var_sum, dof_map, missing)
            repeat_stats.end_band()
    del hues

    reason[(reason == 0) & missing] = _R_LOW_SAT
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.where(dof_map > 0, np.sqrt(var_sum / np.maximum(dof_map, 1)) / math.sqrt(n_rep), np.nan).astype(np.float64)
    del var_sum, dof_map
    if n_rep == 1:  # no repeats: the noise from the single repeat's differences along the bands
        sigma = np.empty((h, w), np.float64)
        _band_noise_kernel(tab, reason, BAND_DIFFERENCE_ORDER, sigma)
    step = TWO_PI / n
    coef = band_smoothing_matrix(n, smooth_window, smooth_order)
    start = np.zeros((h, w), dtype=np.uint16)
    _finalise_kernel(tab, sigma, reason, start, coef, float(max_noise_steps * step), float(max_gap),
                     float(order_steps * step), float(order_sigmas))
    valid = reason == 0
    noise = sigma.astype(np.float32)
    counts = np.bincount(reason.ravel(), minlength=len(REASONS))
    sv = noise[valid & np.isfinite(noise)]
    stats: dict[str, Any] = {
        "n_bands": n,
        "repeats": n_rep,
        "shape": [h, w],
        "model": model,
        "n_pixels": int(h * w),
        "n_valid": int(counts[0]),
        "valid_fraction": float(counts[0] / (h * w)),
        "masked_by_reason": {REASONS[k]: int(counts[k]) for k in range(1, len(REASONS))},
        "noise_rad": {
            "median": float(np.median(sv)) if sv.size else None,
            "p95": float(np.percentile(sv, 95)) if sv.size else None,
            "source": NOISE_SOURCES[0] if n_rep >= 2 else NOISE_SOURCES[1],
        },
        "sensor_noise": repeat_stats.fit(),
        "table_bytes": int(table.nbytes),
        "params": {
            "min_saturation": float(min_saturation),
            "min_intensity": float(min_intensity),
            "floor": float(floor),
            "smooth_window": int(smooth_window),
            "smooth_order": int(smooth_order),
            "max_noise_steps": float(max_noise_steps),
            "max_gap": float(max_gap),
            "order_steps": float(order_steps),
            "order_sigmas": float(order_sigmas),
        },
    }
    return HueTable(model=model, n_bands=n, table=table, valid=valid, start=start, reason=reason, noise_rad=noise, stats=stats)
