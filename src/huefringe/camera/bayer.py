"""Single-chip Bayer captures: the patterns, mosaic and demosaic (OpenCV's edge-aware demosaic and a
Lanczos one), and :class:`BayerResampling`, which re-demosaics a driver's RGB from its native
photosite values with band-limited interpolation.

Bayer patterns are named in sensor order, the colour of the photosites of the top-left 2 x 2
block read row by row: ``RGGB`` has red at (row 0, column 0), green at (0, 1) and (1, 0), blue
at (1, 1).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray


BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
DEMOSAIC_METHODS = ("edge_aware", "bilinear", "lanczos")
RESAMPLE_SETTINGS = ("lanczos", "edge_aware", "bilinear", "stored")
"""Config ``camera.demosaic`` for sessions whose ``camera.bayer`` names a Bayer pattern: re-demosaic
the stored RGB from its native photosite values with this method, or ``stored`` (as the driver
delivered it)."""

# OpenCV's classic Bayer codes name the pattern from the second row and column of the sensor
# (an RGGB sensor is "BayerBG"); the table maps sensor order to those codes.
_CV_BAYER = {
    ("RGGB", "bilinear"): cv2.COLOR_BayerBG2RGB,
    ("BGGR", "bilinear"): cv2.COLOR_BayerRG2RGB,
    ("GRBG", "bilinear"): cv2.COLOR_BayerGB2RGB,
    ("GBRG", "bilinear"): cv2.COLOR_BayerGR2RGB,
    ("RGGB", "edge_aware"): cv2.COLOR_BayerBG2RGB_EA,
    ("BGGR", "edge_aware"): cv2.COLOR_BayerRG2RGB_EA,
    ("GRBG", "edge_aware"): cv2.COLOR_BayerGB2RGB_EA,
    ("GBRG", "edge_aware"): cv2.COLOR_BayerGR2RGB_EA,
}


def bayer_channel_map(pattern: str, height: int, width: int) -> NDArray[np.int8]:
    """The colour channel (0 = R, 1 = G, 2 = B) of every photosite of a ``pattern`` sensor.

    Parameters
    ----------
    pattern : {'RGGB', 'BGGR', 'GRBG', 'GBRG'}
        Bayer pattern in sensor order.
    height, width : int
        Sensor size in photosites.

    Returns
    -------
    ndarray of int8, shape (height, width)
    """
    _check_pattern(pattern)
    block = np.array(["RGB".index(c) for c in pattern], dtype=np.int8).reshape(2, 2)
    return np.tile(block, ((height + 1) // 2, (width + 1) // 2))[:height, :width]


def mosaic(rgb: NDArray, pattern: str) -> NDArray:
    """Sample an RGB image as a single-chip sensor of ``pattern`` would: one colour per photosite.

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3)
        Image in R, G, B order, any dtype.
    pattern : {'RGGB', 'BGGR', 'GRBG', 'GBRG'}

    Returns
    -------
    ndarray, shape (H, W)
        The raw mosaic, same dtype as ``rgb``.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"mosaic needs an (H, W, 3) image, got shape {rgb.shape}")
    chan = bayer_channel_map(pattern, rgb.shape[0], rgb.shape[1])
    return np.take_along_axis(rgb, chan[..., None].astype(np.intp), axis=2)[..., 0]


def demosaic(raw: NDArray, pattern: str, method: str = "edge_aware") -> NDArray:
    """Demosaic a raw Bayer capture into RGB with OpenCV.

    Parameters
    ----------
    raw : ndarray of uint8 or uint16, shape (H, W)
        The sensor's photosite values (H and W even).
    pattern : {'RGGB', 'BGGR', 'GRBG', 'GBRG'}
        Bayer pattern in sensor order.
    method : {'edge_aware', 'bilinear', 'lanczos'}
        ``edge_aware`` (default) interpolates along edges rather than across them
        (``cv2.COLOR_Bayer*2RGB_EA``); ``bilinear`` is OpenCV's plain demosaic; ``lanczos``
        (:func:`lanczos_demosaic`) resamples each colour's photosite lattice with OpenCV's
        8 x 8 Lanczos kernel: no colour error on the fringe's curved parts, where the two-tap
        interpolations of the other two err (docs/accuracy-cameras.md).

    Returns
    -------
    ndarray, shape (H, W, 3), same dtype as ``raw``, channels R, G, B.

    Raises
    ------
    ValueError
        If the pattern or method is unknown, ``raw`` is not a 2-D 8/16-bit array, or a side is
        odd (no whole 2 x 2 Bayer block).
    """
    _check_pattern(pattern)
    if method not in DEMOSAIC_METHODS:
        raise ValueError(f"unknown demosaic method {method!r}; use one of {', '.join(DEMOSAIC_METHODS)}")
    raw = np.asarray(raw)
    problem = bayer_problem(raw.shape, raw.dtype)
    if problem:
        raise ValueError(problem)
    if method == "lanczos":
        return lanczos_demosaic(raw, pattern)
    return cv2.cvtColor(np.ascontiguousarray(raw), _CV_BAYER[(pattern, method)])


def lanczos_demosaic(raw: NDArray, pattern: str) -> NDArray:
    """Demosaic by band-limited resampling of each colour's photosite lattice across the fringes.

    Each of the four 2 x 2 sub-lattices of the sensor (one colour each, spacing 2 px) is resampled
    onto every pixel, reflected border: first along v (rows, along the fringes) linearly, then
    along u (columns, across the fringes: the method's fringes vary along u) with OpenCV's 8-tap
    Lanczos kernel (``INTER_LANCZOS4``; its half-sample weights are read from ``cv2.remap`` once,
    :func:`_half_sample_kernel`, and applied with ``cv2.filter2D``: the same values within
    rounding as ``cv2.remap`` at 1/13 of its time). R and B are their lattice's resampling; G keeps
    its native value at G photosites and is the mean of its two lattices' resamplings at R and B
    photosites; every native value is kept. Across the fringes a signal below the lattice's Nyquist
    frequency (period 4 px) is reproduced: OpenCV's demosaics interpolate with two taps, which on
    the trapezoid's blurred corners (a fringe period of 48 px, corners blurred over about 1 px)
    leaves an error of half the channel's second difference, alternating from column to column
    (hue rms 0.0094-0.0101 rad there, 0.0021 rad here, ``tests/test_camera_bayer.py``). Along the
    fringes the signal is constant but for the object, and two taps keep the noise low: white
    photosite noise of variance 1 leaves 0.68 at R and B (0.83 with Lanczos along v as well,
    0.56 with OpenCV's).

    Parameters
    ----------
    raw : ndarray of uint8 or uint16, shape (H, W), H and W even
        The sensor's photosite values.
    pattern : {'RGGB', 'BGGR', 'GRBG', 'GBRG'}
        Bayer pattern in sensor order.

    Returns
    -------
    ndarray, shape (H, W, 3), same dtype as ``raw`` (rounded, clipped to the dtype's range).
    """
    _check_pattern(pattern)
    raw = np.asarray(raw)
    problem = bayer_problem(raw.shape, raw.dtype)
    if problem:
        raise ValueError(problem)
    h, w = raw.shape
    kern = _half_sample_kernel()
    out = np.empty((h, w, 3), np.float32)
    g = []
    for i, colour in enumerate(pattern):
        oy, ox = divmod(i, 2)
        lattice = raw[oy::2, ox::2].astype(np.float32)
        wl = lattice.shape[1]
        # along v: the lattice's rows, and between them their mean (positions -1/2 .. H/2 - 1/2)
        pad = np.pad(lattice, ((1, 1), (0, 0)), mode="symmetric")  # = BORDER_REFLECT
        mid = 0.5 * (pad[:-1] + pad[1:])
        rows = np.empty((h, wl), np.float32)
        rows[oy::2] = lattice
        rows[1 - oy::2] = mid[1:] if oy == 0 else mid[:-1]
        # along u: Lanczos at the half-sample positions -1/2 .. W/2 - 1/2
        padded = cv2.copyMakeBorder(rows, 0, 0, 4, 4, cv2.BORDER_REFLECT)
        half = cv2.filter2D(padded, -1, kern, anchor=(3, 0), borderType=cv2.BORDER_REFLECT)[:, 3:wl + 4]
        res = np.empty((h, w), np.float32)
        res[:, ox::2] = rows
        res[:, 1 - ox::2] = half[:, 1:] if ox == 0 else half[:, :-1]
        if colour == "G":
            g.append(res)
        else:
            out[..., "RGB".index(colour)] = res
    chan = bayer_channel_map(pattern, h, w)
    out[..., 1] = np.where(chan == 1, raw, 0.5 * (g[0] + g[1]))
    top = np.iinfo(raw.dtype).max
    return np.rint(np.clip(out, 0.0, top)).astype(raw.dtype)


_HALF_KERNEL: list[NDArray[np.float32]] = []


def _half_sample_kernel() -> NDArray[np.float32]:
    """OpenCV's ``INTER_LANCZOS4`` weights at a half-sample position, as a (1, 8) correlation kernel
    for ``cv2.filter2D`` (anchor 3): ``out(j + 1/2) = sum_k w_k x[j + k]``, ``k = -3 .. 4``; read
    from ``cv2.remap`` of a unit impulse (cached)."""
    if not _HALF_KERNEL:
        impulse = np.zeros((1, 17), np.float32)
        impulse[0, 8] = 1.0
        x = (8.5 - np.arange(-3, 5, dtype=np.float32)).reshape(1, -1)
        _HALF_KERNEL.append(np.ascontiguousarray(cv2.remap(impulse, x, np.zeros_like(x), cv2.INTER_LANCZOS4)))
    return _HALF_KERNEL[0]


@dataclass(frozen=True)
class BayerResampling:
    """Re-demosaic a stored RGB capture of a single-chip camera from its native photosite values.

    A camera driver's demosaic (OpenCV's, and ``huefringe session --bayer``'s) keeps each
    photosite's own colour value; the other two colours are its interpolation. Where the session
    says which pattern the sensor had (``session.yaml`` ``camera.bayer``), the native values are
    taken back (:func:`mosaic` of the stored RGB) and demosaiced again with ``method``
    (config ``camera.demosaic``, default ``lanczos``). OpenCV's demosaics copy the outermost
    row and column from their neighbours, so the native values of that 1-px ring are not the
    sensor's: it is kept as stored.
    """

    pattern: str
    method: str = "lanczos"

    def apply(self, codes: NDArray) -> NDArray:
        """The re-demosaiced copy of an ``(H, W, 3)`` 8/16-bit capture (same dtype)."""
        new = demosaic(mosaic(codes, self.pattern), self.pattern, self.method)
        new[[0, -1]] = codes[[0, -1]]
        new[:, [0, -1]] = codes[:, [0, -1]]
        return new

    def describe(self) -> dict[str, Any]:
        return {"pattern": self.pattern, "method": self.method}


def bayer_resampling(meta: Mapping[str, Any], setting: Any = "lanczos") -> BayerResampling | None:
    """The re-demosaic a session asks for: its ``camera.bayer`` pattern with config ``camera.demosaic``
    (``setting``); None for a three-chip session (no ``camera.bayer``) or ``setting`` ``stored``.

    Raises
    ------
    ValueError
        If ``setting`` is not one of :data:`RESAMPLE_SETTINGS`.
    """
    if setting not in RESAMPLE_SETTINGS:
        raise ValueError(f"camera.demosaic: unknown setting {setting!r}; use one of {', '.join(RESAMPLE_SETTINGS)}")
    pattern = meta.get("camera", meta).get("bayer")
    if pattern is None or setting == "stored":
        return None
    return BayerResampling(str(pattern), str(setting))


def bayer_problem(shape: tuple[int, ...], dtype: np.dtype) -> str | None:
    """Why an image of ``shape`` and ``dtype`` cannot be a raw Bayer capture, or None if it can."""
    if len(shape) != 2:
        kind = f"{shape[2]} channels" if len(shape) == 3 else f"{len(shape)} dimensions"
        return f"a raw Bayer capture has one value per photosite, this image has {kind}"
    if np.dtype(dtype) not in (np.dtype(np.uint8), np.dtype(np.uint16)):
        return f"a raw Bayer capture must be 8 or 16 bit, got {np.dtype(dtype)}"
    if shape[0] % 2 or shape[1] % 2:
        return f"a Bayer mosaic needs an even width and height, got {shape[1]} x {shape[0]}"
    return None


def _check_pattern(pattern: str) -> None:
    if pattern not in BAYER_PATTERNS:
        raise ValueError(f"unknown Bayer pattern {pattern!r}; use one of {', '.join(BAYER_PATTERNS)}")
