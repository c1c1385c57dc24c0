"""Checks of decoded coordinates against geometry known without a calibration.

A flat surface seen by a camera maps camera pixels to projector pixels by a smooth function (a
homography bent by both lenses' distortion): what a smooth 2-D polynomial leaves of the decoded
coordinates there is the decoder's error (phase noise, fringe-profile harmonics, order errors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from numpy.polynomial import legendre
from scipy import ndimage

__all__ = ["SmoothFit", "largest_region", "smooth_fit", "smooth_region"]


@dataclass(frozen=True)
class SmoothFit:
    """Residuals of a smooth 2-D fit.

    Attributes
    ----------
    residual : ndarray of float64
        Coordinate minus fit (projector px); NaN outside the fitted pixels.
    rms, p95 : float
        RMS and 95th percentile of ``|residual|`` (projector px).
    pixels : int
        Pixels fitted.
    """

    residual: NDArray[np.float64]
    rms: float
    p95: float
    pixels: int


def largest_region(valid: NDArray[np.bool_], erode_px: int) -> NDArray[np.bool_]:
    """The largest 4-connected region of ``valid``, eroded by ``erode_px`` (away from its edges)."""
    lab, n = ndimage.label(valid)
    if n == 0:
        return np.zeros_like(valid)
    big = lab == (np.argmax(np.bincount(lab.ravel())[1:]) + 1)
    return ndimage.binary_erosion(big, iterations=erode_px) if erode_px > 0 else big


def smooth_region(
    coords: list[NDArray[np.floating]], valid: NDArray[np.bool_], jump_px: float, erode_px: int
) -> NDArray[np.bool_]:
    """The largest region of ``valid`` pixels not crossed by a jump of any coordinate map.

    A pixel whose coordinate differs from a 4-neighbour's by more than ``jump_px`` (a depth edge:
    another surface) is removed before the largest region is taken, so that a surface touching
    the one of interest in the image stays out of it.
    """
    ok = np.asarray(valid, bool).copy()
    for c in coords:
        c = np.where(valid, c, np.nan)
        for axis in (0, 1):
            d = np.abs(np.diff(c, axis=axis))
            bad = ~(d <= jump_px)
            if axis == 0:
                ok[:-1] &= ~bad
                ok[1:] &= ~bad
            else:
                ok[:, :-1] &= ~bad
                ok[:, 1:] &= ~bad
    return largest_region(ok, erode_px)


def smooth_fit(coord: NDArray[np.floating], mask: NDArray[np.bool_], degree: int) -> SmoothFit:
    """Least-squares 2-D polynomial of total ``degree`` in the camera pixel, fitted over ``mask``.

    Examples
    --------
    >>> yy, xx = np.mgrid[0:50, 0:80].astype(float)
    >>> f = smooth_fit(3 + 0.5 * xx + 1e-3 * xx * yy, np.ones((50, 80), bool), 2)
    >>> f.rms < 1e-9, f.pixels
    (True, 4000)
    """
    yy, xx = np.nonzero(mask)
    z = np.asarray(coord, np.float64)[mask]
    x = (xx - xx.mean()) / max(np.ptp(xx), 1) * 2
    y = (yy - yy.mean()) / max(np.ptp(yy), 1) * 2
    # Legendre products of total degree <= degree (well conditioned on [-1, 1]); normal equations
    vx, vy = legendre.legvander(x, degree), legendre.legvander(y, degree)
    a = np.stack([vx[:, i] * vy[:, j] for i in range(degree + 1) for j in range(degree + 1 - i)], axis=1)
    coef = np.linalg.solve(a.T @ a, a.T @ z)
    r = z - a @ coef
    res = np.full(mask.shape, np.nan)
    res[mask] = r
    return SmoothFit(residual=res, rms=float(np.sqrt(np.mean(r**2))), p95=float(np.percentile(np.abs(r), 95)), pixels=int(r.size))
