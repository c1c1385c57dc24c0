"""Camera corrections: turn a stored capture into the RGB image both per-frame chains read.

This module sits just above :mod:`huefringe.session` in the layers. It holds what depends on
the camera a lab owns rather than on the method: demosaicing of single-chip Bayer captures
(OpenCV's edge-aware demosaic), and, as the module grows, lens undistortion, channel
registration for lateral chromatic aberration and the pixel-to-X/Y model.

Bayer patterns are named in sensor order, the colour of the photosites of the top-left 2 x 2
block read row by row: ``RGGB`` has red at (row 0, column 0), green at (0, 1) and (1, 0), blue
at (1, 1).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
DEMOSAIC_METHODS = ("edge_aware", "bilinear")

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
    method : {'edge_aware', 'bilinear'}
        ``edge_aware`` (default) interpolates along edges rather than across them
        (``cv2.COLOR_Bayer*2RGB_EA``), which keeps colour fringes out of the hue at fringe
        edges; ``bilinear`` is OpenCV's plain demosaic.

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
    return cv2.cvtColor(np.ascontiguousarray(raw), _CV_BAYER[(pattern, method)])


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
