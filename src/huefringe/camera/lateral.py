"""Lateral chromatic aberration: its estimate from the reference planes' fringes
(:func:`estimate_lateral_ca`) and the registration of R and B onto G
(:class:`ChannelRegistration`).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
import scipy.sparse
from scipy import ndimage


CA_AUTO_THRESHOLD_PX = 0.1
"""``camera.chromatic_registration: auto`` registers R and B when the estimated displacement of
either at the farthest image corner exceeds this (px); see docs/design.md for why 0.1 px."""

CA_MIN_PIXELS = 200
"""A plane whose usable pixels (1.5 periods left out at each side, fringe amplitude kept) are fewer
than this is not fitted; with no plane fitted the estimate is ``estimable: false``, scale 0."""

CA_AUTO_MIN_REACH = 0.3
"""``auto`` also needs the pixels the estimate reads to reach this fraction of the field's half-width
from the centre along u (the fringes' direction, the lever arm of a magnification): a fit over a
narrow strip near the centre (a small image, a long period: 1.5 periods are left
out at each side) extrapolates its scale to the corners and read 2.9-4.2 px of aberration on a
200 x 150 px board that had none."""


def _unmix(image: NDArray, mixing: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """The primaries' images ``mixing^-1 c`` of a camera image (as float64); the image itself without mixing."""
    img = np.asarray(image, np.float64)
    return img if mixing is None else img @ np.linalg.inv(mixing).T


def _quadrature(signal: NDArray[np.float64], period_px: float) -> NDArray[np.complex128]:
    """Local complex amplitude of the fringe's fundamental: a Gabor filter along u (carrier
    ``2 pi / period``, Gaussian sigma of half a period), smoothed over a few rows along v."""
    sigma = 0.5 * float(period_px)
    half = int(np.ceil(3 * sigma))
    x = np.arange(-half, half + 1, dtype=np.float64)
    env = np.exp(-0.5 * (x / sigma) ** 2)
    kc = (env * np.cos(2 * np.pi * x / period_px)).reshape(1, -1)
    ks = (env * np.sin(2 * np.pi * x / period_px)).reshape(1, -1)
    kc -= kc.mean()  # no response to the mean level
    re = cv2.filter2D(signal, cv2.CV_64F, kc, borderType=cv2.BORDER_REFLECT)
    im = cv2.filter2D(signal, cv2.CV_64F, ks, borderType=cv2.BORDER_REFLECT)
    z = re + 1j * im
    return cv2.GaussianBlur(z.real, (0, 0), sigmaX=0.5, sigmaY=3.0) + 1j * cv2.GaussianBlur(z.imag, (0, 0), sigmaX=0.5, sigmaY=3.0)


def estimate_lateral_ca(planes: Sequence[NDArray[np.floating]], white: NDArray[np.floating], period_px: float,
                        centre: tuple[float, float], *, shadow: NDArray[np.bool_] | None = None,
                        mixing: ArrayLike | None = None) -> dict[str, Any]:
    """Estimate the radial magnification of R and B relative to G from fringe images of flat planes.

    On a plane the three channels of the trapezoid are shifted copies of one another; a channel
    magnified by ``1 + s`` about the optical centre ``(cx, cy)`` shows its fringes displaced by
    ``s (u - cx)`` along u. Each channel's fundamental phase along the rows (FFT band-pass,
    analytic signal) gives ``wrap(phi_c - phi_G) = d0 - k (u) s (u - cx)`` with ``k`` the local
    fringe frequency (rad/px, from G): ``d0`` and a fringe-periodic error (three harmonics of
    ``phi_G``, one set per plane) and ``s`` by least squares, weighted by the
    fringe amplitude, 1.5 periods at each image side left out (the filter's half-width). The phases are local (a Gabor
    filter along u, :func:`_quadrature`), so the fringe period may vary over the field.

    Parameters
    ----------
    planes : sequence of (H, W, 3) float images
        Captures of the trapezoid on flat planes (the reference planes).
    white : (H, W, 3) float image
        The white capture of the same plate (white balance).
    period_px : float
        Fringe period in camera pixels (session.yaml ``pattern.period_px``).
    centre : (cx, cy)
        The magnification centre: the distortion centre of ``camera.matrix``, else the image centre.
    shadow : (H, W) bool, optional
        Pixels to leave out.
    mixing : (3, 3) array, optional
        The camera's response to the projector primaries (:func:`estimate_channel_mixing`): the
        planes and the white are unmixed into the primaries' images first, and ``s`` is the
        magnification of the R and B primaries against G (what the lens does). Without it the
        camera channels are compared (biased by their crosstalk: on the plain gauge bench with
        10 % crosstalk they read 0.54 px for 0.50 px at the corners).

    Returns
    -------
    dict
        ``scale`` ``{"R": s_R, "B": s_B}`` (magnification minus 1), their standard errors
        ``scale_se``, the per-plane values ``scale_per_plane``, ``corner_displacement_px`` (the
        radial displacement at the farthest image corner, ``|s| r_max``), ``centre``, ``pixels``.
    """
    cx, cy = float(centre[0]), float(centre[1])
    mix = None if mixing is None else np.asarray(mixing, np.float64).reshape(3, 3)
    wb = np.maximum(_unmix(white, mix), 1e-3)
    h, w = wb.shape[:2]
    margin = int(np.ceil(1.5 * period_px))  # the filter's half-width: no reflected sample in the window
    u = np.arange(w, dtype=np.float64)
    rows: dict[str, list[tuple[float, float, int]]] = {"R": [], "B": []}
    acc = {c: [0.0, 0.0] for c in "RB"}  # sums over planes of the centred normal equations (own d0 per plane)
    npix = 0
    fit_radius = 0.0  # the farthest pixel from the centre that the fit reads: how far it extrapolates
    for img in planes:
        sig = _unmix(img, mix) / wb
        z = [_quadrature(np.ascontiguousarray(sig[..., c]), period_px) for c in range(3)]
        zg = z[1]
        k = np.empty((h, w))
        k[:, 1:-1] = np.angle(zg[:, 2:] * np.conj(zg[:, :-2])) / 2.0
        k[:, 0], k[:, -1] = k[:, 1], k[:, -2]
        kv = np.zeros((h, w))  # fringes not quite vertical: the radial model's v displacement shows too
        kv[1:-1] = np.angle(zg[2:] * np.conj(zg[:-2])) / 2.0
        lever = k * (u[None, :] - cx) + kv * (np.arange(h, dtype=np.float64)[:, None] - cy)
        amp = np.abs(zg)
        ok = np.zeros((h, w), bool)
        ok[4:h - 4, margin:w - margin] = True
        ok &= amp > 0.2 * np.median(amp)
        if shadow is not None:
            ok &= ~shadow
        if int(ok.sum()) < CA_MIN_PIXELS:  # a field narrower than 3 periods: nothing to fit on this plane
            continue
        npix = int(ok.sum())
        if npix:
            uu = np.nonzero(ok.any(axis=0))[0]  # the fringes run along u: the lever arm is u - cx
            fit_radius = max(fit_radius, float(np.max(np.abs(uu - cx))))
        for c, name in ((0, "R"), (2, "B")):
            d = np.angle(z[c] * np.conj(zg))
            d0 = np.angle(np.sum(np.exp(1j * d[ok]) * amp[ok]))
            dd = np.angle(np.exp(1j * (d - d0)))[ok]
            wt = (np.abs(z[c]) * amp)[ok]
            pg = np.angle(zg)[ok]
            # nuisance: d0 and the fringe-periodic phase error (harmonic leakage through the filter,
            # gamma, crosstalk), cos/sin of n phi_G, n = 1..3; then the magnification regressor
            a = np.column_stack([np.ones(dd.size)] + [f(n * pg) for n in (1, 2, 3) for f in (np.cos, np.sin)]
                                + [-lever[ok]])
            ata, atb = (a * wt[:, None]).T @ a, (a * wt[:, None]).T @ dd
            nn = np.linalg.solve(ata[:-1, :-1], np.column_stack([ata[:-1, -1], atb[:-1]]))
            acc[name][0] += ata[-1, -1] - ata[-1, :-1] @ nn[:, 0]  # Schur complement: the scale alone
            acc[name][1] += atb[-1] - ata[-1, :-1] @ nn[:, 1]
            sol = np.linalg.solve(ata, atb)
            rows[name].append((float(sol[-1]), float(np.sqrt(np.average((dd - a @ sol) ** 2, weights=wt))), int(dd.size)))
    r_max = float(max(np.hypot(x - cx, y - cy) for x in (0, w - 1) for y in (0, h - 1)))
    out: dict[str, Any] = {"centre": [cx, cy], "period_px": float(period_px), "planes": len(planes), "pixels": npix,
                           "scale": {}, "scale_se": {}, "scale_per_plane": {}, "corner_displacement_px": {},
                           "corner_radius_px": r_max, "fit_reach_u_px": fit_radius,
                           "field_reach_u_px": float(max(cx, w - 1 - cx)), "estimable": bool(rows["R"])}
    for name in "RB":
        sxx, sxy = acc[name]
        scale = sxy / sxx if sxx > 0 else 0.0  # no plane fitted: no magnification read (estimable False)
        per = [p[0] for p in rows[name]]
        se = float(np.std(per, ddof=1) / np.sqrt(len(per))) if len(per) > 1 else None  # JSON: null
        out["scale"][name] = float(scale)
        out["scale_se"][name] = se
        out["scale_per_plane"][name] = per
        out["corner_displacement_px"][name] = abs(float(scale)) * r_max
    return out


@dataclass(frozen=True)
class ChannelRegistration:
    """Undo a radial magnification ``1 + s`` of the R and B primaries about ``centre``.

    The image is unmixed into the primaries' images ``p = mixing^-1 c`` (``mixing``: the camera's
    response to the projector primaries, :func:`estimate_channel_mixing`; the identity without
    one: the camera channels themselves), the R and B primaries are resampled,
    ``p_c'(x) = p_c(centre + (1 + s_c) (x - centre))``, and mixed back,
    ``registered = c + mixing[:, R] (p_R' - p_R) + mixing[:, B] (p_B' - p_B)``: G's primary is not
    moved, and a camera channel's share of another primary moves with that primary, as the lens
    moved it. The resampling is cubic B-spline interpolation at the exact positions
    (``scipy.ndimage.spline_filter1d``, then two sparse products: separable, as the magnification
    is; whole-sample mirrored border); the result is rounded back to the sensor's codes, so that
    both per-frame chains (the NumPy reference and the numba kernel) read the same image.
    """

    centre: tuple[float, float]
    scale_r: float
    scale_b: float
    mixing: tuple[tuple[float, ...], ...] | None = None

    def _magnified(self, plane: NDArray[np.float32], scale: float) -> NDArray[np.float64]:
        """``plane(centre + (1 + scale)(x - centre))``: cubic B-spline coefficients (two 1-D
        prefilters), then the separable interpolation as two sparse products (4 taps a row)."""
        if scale == 0.0:
            return plane.astype(np.float64)
        h, w = plane.shape
        coef = ndimage.spline_filter1d(plane, 3, axis=0, mode="mirror", output=np.float32)
        coef = ndimage.spline_filter1d(coef, 3, axis=1, mode="mirror", output=np.float32)
        wu = _spline_rows(w, float(scale), float(self.centre[0]))
        wv = _spline_rows(h, float(scale), float(self.centre[1]))
        return np.asarray(wv @ np.asarray(wu @ coef.T).T)

    def apply(self, image: NDArray) -> NDArray:
        """The registered copy of an ``(H, W, 3)`` image (codes or float), same dtype."""
        img = np.asarray(image)
        mix = np.eye(3) if self.mixing is None else np.asarray(self.mixing, np.float64)
        c = np.ascontiguousarray(img, dtype=np.float64)
        prim = c if self.mixing is None else cv2.transform(c, np.linalg.inv(mix))  # p = M^-1 c per pixel
        moved = np.zeros_like(c)  # p' - p of the R and B primaries, G's zero
        for k, s in ((0, self.scale_r), (2, self.scale_b)):
            pk = np.ascontiguousarray(prim[..., k], dtype=np.float32)
            moved[..., k] = self._magnified(pk, float(s)) - pk
        out = c + cv2.transform(moved, mix)
        if np.issubdtype(img.dtype, np.integer):
            np.rint(out, out=out)
            return np.clip(out, 0, np.iinfo(img.dtype).max, out=out).astype(img.dtype)
        return out.astype(img.dtype)


@functools.lru_cache(maxsize=8)
def _spline_rows(n: int, scale: float, centre: float) -> scipy.sparse.csr_matrix:
    """The ``(n, n)`` matrix of cubic B-spline weights that samples spline coefficients at
    ``centre + (1 + scale)(i - centre)``, ``i = 0 .. n - 1`` (whole-sample mirrored border)."""
    x = centre + (1.0 + scale) * (np.arange(n, dtype=np.float64) - centre)
    j = np.floor(x).astype(np.int64)[:, None] + np.arange(-1, 3)[None, :]
    t = np.abs(x[:, None] - j)
    wt = np.where(t < 1.0, 2.0 / 3.0 - t ** 2 + 0.5 * t ** 3, np.where(t < 2.0, (2.0 - t) ** 3 / 6.0, 0.0))
    period = max(2 * (n - 1), 1)
    jm = np.mod(j, period)
    jm = np.where(jm > n - 1, period - jm, jm)
    return scipy.sparse.csr_matrix((wt.ravel(), (np.repeat(np.arange(n), 4), jm.ravel())), shape=(n, n))


# Cubic B-splines rather than OpenCV's Lanczos (cv2.remap rounds every position to 1/32 px): on
# the plain gauge bench lens (CA 0.5 px, in the primaries, true magnification) the registered
# median is 0.0107 mm with cubic splines (scipy.ndimage.affine_transform order 3; this separable
# form gives the same to 1e-4 of the fringe amplitude inside, 2 x faster), 0.0108 quintic, 0.0111
# cv2 Lanczos, 0.0146 cv2 bicubic (no CA: 0.0107); on a sine of period 6 px the interpolation error
# is 1.5e-3 of the amplitude (cubic spline) against 8.4e-3 (cv2 Lanczos).
