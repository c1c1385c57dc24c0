"""The hue table's noise estimate: the band repeats' spread, the third difference along the bands, the sensor's shot + read fit on the hue."""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from ..colour import _hue_noise_kernel, wrap_pi
from ..patterns import BAND_DIFFERENCE_ORDER


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


#: Stride (px, both axes) of the pixels whose bands feed the sensor-noise fit.
_NOISE_STRIDE = 3
#: The sensor-noise fit (:class:`_HueNoiseStats`): at most this many samples over the whole table
#: (evenly taken from each band's), and its reweighting passes.
_FIT_SAMPLES = 400_000
_FIT_PASSES = 3
#: The largest predicted hue noise of one capture (rad) a sample of the fit may have: where the
#: first-order propagation through the hue stops holding (it reads the spread low beyond 0.1 rad;
#: ``perframe.noise_ratio2`` trusts the own figure up to half of it).
FIT_MAX_HUE_SIGMA_RAD = 0.1
#: the third difference's weights squared (``1, -3, 3, -1``)
_D3_WEIGHTS2 = (1.0, 9.0, 9.0, 1.0)
#: How a table's shot + read model was fitted (``stats["sensor_noise"]["source"]``): on the hue's
#: spread between the band repeats, or with one repeat on its third differences along the bands.
SENSOR_SOURCES: tuple[str, ...] = ("repeats", "band_difference")


class _HueNoiseStats:
    """The sensor's shot + read model ``var_c = gain_c * signal_c + read_c`` (full scale 1) fitted
    on the captured hue of the bands as the table reads them (:func:`fit_hue_noise`).

    A frame's own hue noise is this model propagated through the white balance and the hue's first
    derivatives (:func:`huefringe.perframe.frame_hue_noise`); its expectation is linear in the six
    parameters, ``sum_c (gain_c s_c + read_c) J_c^2`` (``s_c`` the channel's signal, ``J_c`` the
    hue's derivative by it), so the fit regresses the hue's own scatter on those terms, evaluated
    by the same compiled propagation with one parameter at a time:

    - ``R >= 2`` repeats: per band and pixel the repeats' squared hue deviations from their mean
      direction, ``sum_r wrap(H_r - mean)^2``, expectation ``(R - 1)`` times the propagated variance
      at the repeats' mean signal;
    - one repeat: within a sextant of the code the captured hue is a smooth function of the band
      (the one-repeat estimate of ``noise_rad``, :func:`_band_noise_kernel`), so the third
      difference ``d`` of four consecutive bands of one sextant is noise of expectation
      ``sum_j c_j^2`` times band ``j``'s propagated variance (``c_j = 1, -3, 3, -1``).

    The hue, not the channels: the quantity the model predicts, with whatever correlation the
    camera's processing (a colour demixing) puts between the channels' noise, and a projector whose
    brightness changes from capture to capture (the same factor on the three channels) does not read
    as noise. Pixels on a grid of :data:`_NOISE_STRIDE`; samples with a channel at 0 or full scale (a
    clipped, truncated spread) or an undefined hue are left out; at most :data:`_FIT_SAMPLES` samples
    (56 bytes each: 22 MB, and about three times that while fitting) are kept for the fit."""

    def __init__(self, h: int, w: int, n_bands: int, repeats: int, gains: NDArray[np.floating], model: str) -> None:
        self.n = int(n_bands)
        self.repeats = int(repeats)
        self.hsi = model == "hsi"
        self.gains = np.ascontiguousarray(np.asarray(gains)[::_NOISE_STRIDE, ::_NOISE_STRIDE], np.float32)
        shape = self.gains.shape[:2]
        self.nan = np.full(shape, np.nan)
        self.out = np.empty(shape)
        self.basis = [np.zeros((2, 3), np.float32) for _ in range(6)]
        for k, b in enumerate(self.basis):
            b[k // 3, k % 3] = 1.0  # gain of R, G, B, then read of R, G, B
        self.per_band = max(1, _FIT_SAMPLES // max(self.n, 1))
        self.ring: list[tuple[int, NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]] = []
        self.band = 0
        self.imgs: list[NDArray[np.float32]] = []
        self.hues: list[NDArray[np.float64]] = []
        self.x: list[NDArray[np.float64]] = []
        self.y: list[NDArray[np.float64]] = []

    def add(self, img: NDArray[np.floating], hue: NDArray[np.floating]) -> None:
        """One capture of the current band (as read) and its white-balanced hue (NaN where none)."""
        self.imgs.append(np.ascontiguousarray(np.asarray(img)[::_NOISE_STRIDE, ::_NOISE_STRIDE], np.float32))
        self.hues.append(np.asarray(hue[::_NOISE_STRIDE, ::_NOISE_STRIDE], np.float64))

    def _terms(self, x: NDArray[np.float32]) -> NDArray[np.float64]:
        """Each parameter's share of the hue variance at signal ``x``, ``(6, h, w)``."""
        reg = np.empty((6, *x.shape[:2]))
        for k, b in enumerate(self.basis):
            _hue_noise_kernel(x, np.float32(1.0), self.gains, self.hsi, b, self.nan, self.out)
            reg[k] = np.nan_to_num(self.out * self.out, nan=0.0)
        return reg

    def _keep(self, xr: NDArray[np.float64], y: NDArray[np.float64], ok: NDArray[np.bool_]) -> None:
        idx = np.flatnonzero((ok & (xr.sum(axis=0) > 0) & np.isfinite(y)).ravel())
        if idx.size > self.per_band:
            idx = idx[np.linspace(0, idx.size - 1, self.per_band).round().astype(np.int64)]
        self.x.append(xr.reshape(6, -1)[:, idx].T)
        self.y.append(y.ravel()[idx])

    def end_band(self) -> None:
        """The current band's samples; the next capture starts the next band."""
        imgs, hues = self.imgs, self.hues
        self.imgs, self.hues = [], []
        if not imgs:
            return
        unclipped = [(np.minimum(np.minimum(x[..., 0], x[..., 1]), x[..., 2]) > 0.0)
                     & (np.maximum(np.maximum(x[..., 0], x[..., 1]), x[..., 2]) < 1.0) for x in imgs]
        if self.repeats >= 2:
            z = np.mean([np.exp(1j * h) for h in hues], axis=0)
            mean = np.angle(z)
            y = sum(wrap_pi(h - mean) ** 2 for h in hues)
            ok = np.logical_and.reduce(unclipped) & np.all(np.isfinite(hues), axis=0)
            sig = np.mean(imgs, axis=0).astype(np.float32)
            self._keep((len(hues) - 1.0) * self._terms(sig), y, ok)
            self.band += 1
            return
        hue = hues[0]
        self.ring = [*self.ring[-3:], (self.band, hue, self._terms(imgs[0]), unclipped[0] & np.isfinite(hue))]
        self.band += 1
        first = self.ring[0][0]
        if len(self.ring) < 4 or (6 * first) // self.n != (6 * self.band - 6) // self.n:
            return  # fewer than four bands yet, or the run crosses a sextant boundary
        hs = [r[1] for r in self.ring]
        steps = [wrap_pi(hs[j + 1] - hs[j]) for j in range(3)]
        d = steps[2] - 2.0 * steps[1] + steps[0]
        xr = sum(c2 * r[2] for c2, r in zip(_D3_WEIGHTS2, self.ring, strict=True))
        self._keep(xr, d * d, self.ring[0][3] & self.ring[1][3] & self.ring[2][3] & self.ring[3][3])

    def fit(self) -> dict[str, Any] | None:
        if not self.x:
            return None
        x, y = np.concatenate(self.x), np.concatenate(self.y)
        self.x, self.y = [], []  # (the samples once, not twice, while fitting)
        return fit_hue_noise(x, y, self.repeats)


def _nnls_weighted(nnls: Any, x: NDArray[np.float64], y: NDArray[np.float64],
                   w: NDArray[np.float64]) -> NDArray[np.float64]:
    """``argmin_{b >= 0} sum w (x b - y)^2`` through the 6 x 6 normal equations: with
    ``G = x^T W x = R^T R`` (``R`` from its eigen-decomposition, null directions dropped) the sum is
    ``|R b - R^-T x^T W y|^2`` plus a constant, so SciPy's ``nnls`` solves a 6 x 6 problem instead of
    an ``N x 6`` one (the same minimiser: on the bench's tables the same fit to 2e-13)."""
    xw = x * w[:, None]
    val, vec = np.linalg.eigh(xw.T @ x)
    keep = val > val.max() * 1e-14
    root = np.sqrt(val[keep])
    return nnls(root[:, None] * vec[:, keep].T, (vec[:, keep].T @ (xw.T @ y)) / root)[0]


def fit_hue_noise(x: NDArray[np.floating], y: NDArray[np.floating], repeats: int,
                  min_samples: int = 1000) -> dict[str, Any] | None:
    """The shot + read model ``var_c = gain_c * signal_c + read_c`` (full scale 1) from samples of
    the hue's scatter ``y`` and their regressors ``x`` ``(N, 6)``, ``E[y] = x . (gain_R, gain_G,
    gain_B, read_R, read_G, read_B)`` (:class:`_HueNoiseStats`: the repeats' squared deviations,
    or with one repeat the squared third differences along the bands).

    Non-negative least squares (SciPy's ``nnls``, columns scaled to unit rms), reweighted by
    ``1 / E[y]^2`` (a sum of squared Gaussians has a variance proportional to its expectation
    squared), :data:`_FIT_PASSES` times. Only samples whose predicted hue noise of one capture
    (``E[y]`` over ``R - 1``, or over 20 with one repeat) is at most :data:`FIT_MAX_HUE_SIGMA_RAD`
    count: beyond it the first-order propagation the model is used through no longer holds (a hue
    of small chroma, whose derivatives diverge; docs/uncertainty.md, "The noise ratio"). The first
    pass takes the samples whose propagation per unit channel variance is within 100 x its median,
    each later one those the previous fit predicts inside the bound. ``rel_rms`` per channel: the
    relative misfit of the mean ``y`` against the mean prediction in ten equal-count bins of the
    prediction, over the counted samples whose prediction that channel dominates (its two terms
    more than half of it; None with fewer than 500). ``None`` with fewer than ``min_samples``
    counted samples.
    """
    from scipy.optimize import nnls  # the table build only: not in a measurement job's imports

    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    per_capture = float(repeats - 1) if repeats >= 2 else float(sum(_D3_WEIGHTS2))
    unit = x[:, 3:].sum(axis=1)  # the hue variance per unit variance of every channel
    use = unit <= 100.0 * np.median(unit) if unit.size else np.zeros(0, bool)
    beta = np.zeros(6)
    for _ in range(_FIT_PASSES):
        if np.count_nonzero(use) < min_samples:
            return None
        xs, ys = x[use], y[use]
        scale = np.sqrt(np.mean(xs * xs, axis=0))
        scale[scale <= 0] = 1.0
        xs = xs / scale
        wt = np.ones(ys.size)
        for _ in range(_FIT_PASSES):
            b = _nnls_weighted(nnls, xs, ys, wt)
            wt = 1.0 / np.maximum(xs @ b, 1e-30) ** 2
        beta = b / scale
        use = x @ beta <= per_capture * FIT_MAX_HUE_SIGMA_RAD**2
    use &= x @ beta > 0
    if np.count_nonzero(use) < min_samples:
        return None
    pred, yu, xu = x[use] @ beta, y[use], x[use]
    rel: list[float | None] = []
    for c in range(3):
        m = (xu[:, c] * beta[c] + xu[:, 3 + c] * beta[3 + c]) > 0.5 * pred
        if np.count_nonzero(m) < 500:
            rel.append(None)  # (JSON has no NaN)
            continue
        p, q = pred[m], yu[m]
        k = np.empty(p.size, np.int64)
        k[np.argsort(p, kind="stable")] = np.arange(p.size) * 10 // p.size  # ten equal-count bins
        ratio = np.bincount(k, q, 10) / np.bincount(k, p, 10)
        rel.append(float(np.sqrt(np.mean((ratio - 1.0) ** 2))))
    return {"model": "variance = gain * signal + read (full scale = 1)", "gain": [float(g) for g in beta[:3]],
            "read": [max(float(r), 1e-12) for r in beta[3:]], "rel_rms": rel, "samples": int(np.count_nonzero(use)),
            "repeats": int(repeats), "source": SENSOR_SOURCES[0] if repeats >= 2 else SENSOR_SOURCES[1],
            "stride_px": _NOISE_STRIDE}
