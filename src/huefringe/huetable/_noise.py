"""The hue table's noise estimate: the band repeats' spread, the third difference along the bands, the sensor's shot + read fit."""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray


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
