"""Camera corrections: turn a stored capture into the RGB image both per-frame chains read.

This module sits just above :mod:`huefringe.session` in the layers. It holds what depends on
the camera a lab owns rather than on the method: demosaicing of single-chip Bayer captures
(OpenCV's edge-aware demosaic, and :class:`BayerResampling`, which re-demosaics a driver's RGB
from its native photosite values with band-limited interpolation), lens undistortion, channel
registration for lateral chromatic aberration and the pixel-to-X/Y model.

Bayer patterns are named in sensor order, the colour of the photosites of the top-left 2 x 2
block read row by row: ``RGGB`` has red at (row 0, column 0), green at (0, 1) and (1, 0), blue
at (1, 1).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
import scipy.sparse
from scipy import ndimage

from huefringe.patterns import RAMP_SEXTANTS
from huefringe.session import read_rgb, read_rgb_codes

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


# --------------------------------------------------------------------------- X, Y: one place

CAMERA_MODELS = ("telecentric", "pinhole")
# cv2.undistortPoints inverts the distortion iteratively; its default (5 iterations) leaves
# micrometres at the corners of an ordinary lens, 200 iterations to 1e-14 reach 1e-9 mm
_UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)


@dataclass(frozen=True)
class CameraModel:
    """Where on the plate (X, Y in mm) a pixel looks, at the pixel's own height.

    The one place huefringe turns pixels into X, Y (clouds, meshes, renders, metrology boxes).
    Pixel ``(u, v)`` is column ``u``, row ``v``, its centre at integer coordinates (OpenCV's
    convention). Plate coordinates: a point at height ``h`` above the plate at plate position
    ``(X, Y)`` is OpenCV's board point ``(X, Y, -h)`` (the board's z points away from the camera,
    our heights towards it).

    ``telecentric`` without distortion
        ``X = u * pitch``, ``Y = v * pitch`` at every height (capture-session/1's meaning).
    ``telecentric`` with ``distortion``
        the pixel is first undistorted (``cv2.undistortPoints`` with ``P = matrix``) to
        ``(u', v')`` and ``X = u' * pitch``, ``Y = v' * pitch``. Without a ``matrix`` the
        coefficients are taken in plate millimetres about the image centre:
        ``matrix = [[1/pitch, 0, (W-1)/2], [0, 1/pitch, (H-1)/2], [0, 0, 1]]``.
    ``pinhole``
        the undistorted pixel's ray from the camera centre (``matrix``, ``distortion``) is
        intersected with the plane ``z = -h`` of the plate (``plate_pose``, the board in camera
        coordinates, mm).
    """

    kind: str
    pitch_mm: float
    width: int
    height: int
    matrix: NDArray[np.float64] | None = None
    distortion: NDArray[np.float64] | None = None
    rvec: NDArray[np.float64] | None = None
    tvec: NDArray[np.float64] | None = None
    _grid_cache: list[Any] = field(default_factory=list, repr=False, compare=False)

    @classmethod
    def from_meta(cls, meta: Mapping[str, Any], *, lens_model: bool = True) -> CameraModel:
        """The model of a session's ``session.yaml`` (``meta``, as :func:`huefringe.session.read_meta`
        checked it; the whole mapping or its ``camera`` block).

        ``lens_model=False`` ignores the lens (``model``, ``matrix``, ``distortion``): the plain
        telecentric ``u * pitch`` (config ``camera.lens_model: false``).
        """
        cam = meta.get("camera", meta)
        w, h, pitch = int(cam["width"]), int(cam["height"]), float(cam["pixel_pitch_mm"])
        if not lens_model:
            return cls("telecentric", pitch, w, h)
        kind = str(cam.get("model", "telecentric"))
        k = None if cam.get("matrix") is None else np.asarray(cam["matrix"], np.float64).reshape(3, 3)
        d = None if not cam.get("distortion") else np.asarray(cam["distortion"], np.float64).reshape(-1)
        if d is not None and not np.any(d):
            d = None if kind == "telecentric" else d
        if kind == "telecentric":
            if d is not None and k is None:
                k = np.array([[1.0 / pitch, 0.0, (w - 1) / 2.0], [0.0, 1.0 / pitch, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
            return cls(kind, pitch, w, h, k if d is not None else None, d)
        pose = cam["plate_pose"]
        return cls(kind, pitch, w, h, k, np.zeros(5) if d is None else d,
                   np.asarray(pose["rvec"], np.float64).reshape(3), np.asarray(pose["tvec"], np.float64).reshape(3))

    @property
    def plain(self) -> bool:
        """True for the telecentric camera without distortion: ``X = u * pitch`` exactly."""
        return self.kind == "telecentric" and self.distortion is None

    @property
    def centre(self) -> tuple[float, float]:
        """The optical (distortion) centre ``(cx, cy)`` in pixels: from ``matrix``, else the image centre."""
        if self.matrix is not None:
            return float(self.matrix[0, 2]), float(self.matrix[1, 2])
        return (self.width - 1) / 2.0, (self.height - 1) / 2.0

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary (results' camera.json)."""
        out: dict[str, Any] = {"model": self.kind, "pixel_pitch_mm": self.pitch_mm, "plain": self.plain}
        for key in ("matrix", "distortion", "rvec", "tvec"):
            val = getattr(self, key)
            if val is not None:
                out[key] = np.asarray(val).tolist()
        return out

    def _rays(self, u: NDArray, v: NDArray) -> tuple[NDArray, ...]:
        """Undistorted pixel coordinates (telecentric) or the rays in plate coordinates (pinhole)."""
        pts = np.stack([np.ravel(u), np.ravel(v)], axis=-1).astype(np.float64).reshape(-1, 1, 2)
        if self.kind == "telecentric":
            und = cv2.undistortPoints(pts, self.matrix, self.distortion, P=self.matrix, criteria=_UNDISTORT).reshape(-1, 2)
            return und[:, 0].reshape(np.shape(u)), und[:, 1].reshape(np.shape(u))
        xy = cv2.undistortPoints(pts, self.matrix, self.distortion, criteria=_UNDISTORT).reshape(-1, 2)
        rot, _ = cv2.Rodrigues(self.rvec)
        d = np.column_stack([xy, np.ones(len(xy))]) @ rot  # R^T d for each row d
        c = -rot.T @ self.tvec
        shape = np.shape(u)
        return c, d[:, 0].reshape(shape), d[:, 1].reshape(shape), d[:, 2].reshape(shape)

    def xy_at(self, u: ArrayLike, v: ArrayLike, h: ArrayLike = 0.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(X, Y)`` in mm of pixel coordinates ``(u, v)`` (any shape, fractional allowed) seen at
        height ``h`` (mm; broadcast). NaN where ``h`` is not finite."""
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        h = np.broadcast_to(np.asarray(h, np.float64), u.shape)
        bad = ~np.isfinite(h)
        if self.plain:
            x, y = u * self.pitch_mm, v * self.pitch_mm
        elif self.kind == "telecentric":
            uu, vv = self._rays(u, v)
            x, y = uu * self.pitch_mm, vv * self.pitch_mm
        else:
            c, dx, dy, dz = self._rays(u, v)
            s = (-h - c[2]) / dz
            x, y = c[0] + s * dx, c[1] + s * dy
        x, y = np.array(x, np.float64), np.array(y, np.float64)
        x[bad] = np.nan
        y[bad] = np.nan
        return x, y

    def xy(self, height: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(X, Y)`` maps in mm of a height map ``(H, W)``: each pixel at its own height (NaN
        where the height is NaN). The rays are computed once per model and reused."""
        height = np.asarray(height)
        if height.shape != (self.height, self.width):
            raise ValueError(f"height map {height.shape} does not match the camera's {self.height} x {self.width}")
        bad = ~np.isfinite(height)
        if self.kind == "pinhole":
            c, dx, dy, dz = self._grid()
            s = (-height.astype(np.float64) - c[2]) / dz
            x, y = c[0] + s * dx, c[1] + s * dy
        else:
            gx, gy = self._grid()
            x, y = gx.copy(), gy.copy()
        x[bad] = np.nan
        y[bad] = np.nan
        return x, y

    def _grid(self) -> tuple[Any, ...]:
        """Per-pixel X, Y (telecentric) or rays (pinhole), computed once per model (0.3 s for
        640 x 480 pinhole pixels: the iterative undistortion), then 3 ms per height map."""
        if not self._grid_cache:
            v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
            if self.plain:
                grid: tuple[Any, ...] = (u * self.pitch_mm, v * self.pitch_mm)
            elif self.kind == "telecentric":
                uu, vv = self._rays(u, v)
                grid = (uu * self.pitch_mm, vv * self.pitch_mm)
            else:
                grid = self._rays(u, v)
            self._grid_cache.append(grid)
        return self._grid_cache[0]

    def box_mm(self, box: Sequence[float], h: float = 0.0) -> list[float]:
        """A pixel box ``[u0, v0, u1, v1)`` as ``[X0, Y0, X1, Y1]`` in mm: its corners seen at
        height ``h`` (telecentric without distortion: ``[u0 * pitch, v0 * pitch, ...]`` exactly)."""
        if self.plain:
            return [float(x) * self.pitch_mm for x in box]
        x, y = self.xy_at(np.array([box[0], box[2]], np.float64), np.array([box[1], box[3]], np.float64), h)
        return [float(x[0]), float(y[0]), float(x[1]), float(y[1])]

    def field_mm(self) -> tuple[float, float, float, float]:
        """``(X0, X1, Y0, Y1)``: the plate-plane (h = 0) bounds of the image corners' centres."""
        u = np.array([0.0, self.width - 1.0, 0.0, self.width - 1.0])
        v = np.array([0.0, 0.0, self.height - 1.0, self.height - 1.0])
        x, y = self.xy_at(u, v, 0.0)
        return float(x.min()), float(x.max()), float(y.min()), float(y.max())




# --------------------------------------------------------------------------- lateral chromatic aberration

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


#: the six segments of the trapezoid's period (capture-session/1, "Projected codes") in which one
#: primary alone varies, the other two held at 0 or 1: (start, end) as fractions of the period,
#: the varying primary (0 R, 1 G, 2 B) and its direction (+1 rising, -1 falling)
_MIXING_SEGMENTS = tuple((k / 6, (k + 1) / 6, ch, sign) for k, (ch, sign) in enumerate(RAMP_SEXTANTS))

CA_MIXING_MAX_OFF_DIAGONAL = 0.5
"""A channel-mixing estimate with an off-diagonal entry beyond this (a camera channel answering
another primary half as strongly as its own) or a condition number above 10 is not used: the
registration then works on the camera channels themselves (``mixing`` ``estimable: false``)."""


def mixing_band_pairs(n_bands: int) -> list[tuple[int, int, int, int]]:
    """The hue bands :func:`estimate_channel_mixing` reads: ``(primary, first, last, direction)``
    per segment of the period in which one primary alone varies (first and last band inside it),
    for segments holding two bands at least (``n_bands >= 12`` gives all six)."""
    out = []
    for a, b, k, sign in _MIXING_SEGMENTS:
        first, last = int(np.ceil(a * n_bands - 1e-9)), int(np.ceil(b * n_bands - 1e-9)) - 1
        if last > first:
            out.append((k, first, last, sign))
    return out


def estimate_channel_mixing(bands: Mapping[int, NDArray[np.floating]], n_bands: int, *,
                            shadow: NDArray[np.bool_] | None = None) -> dict[str, Any]:
    """The camera's response to each projector primary, from the uniform hue bands of a plate.

    Lateral chromatic aberration magnifies the image of each projector primary (a narrow band of
    wavelengths), not each camera channel: a camera channel that also sees the neighbouring
    primaries (the colour filters' overlap, crosstalk) records a mix of images magnified
    differently. Between two hue bands of a segment of the period in which one primary alone
    varies (R falls from 1 to 0 while G is 1 and B is 0, ...: capture-session/1's trapezoid), the
    change of the camera's RGB at any pixel is that primary's column of the mixing matrix times
    a positive factor (the plate's reflectance, the irradiance, the projector's gamma: none of
    them known or needed). The column is the sum of those changes over the plate's lit pixels,
    both segments of the primary pooled, scaled to 1 in the primary's own channel.

    Parameters
    ----------
    bands : mapping of band index to (H, W, 3) float image
        The reference hue bands (repeats averaged) named by :func:`mixing_band_pairs`.
    n_bands : int
        ``pattern.hue_bands``.
    shadow : (H, W) bool, optional
        Pixels to leave out.

    Returns
    -------
    dict
        ``matrix`` (3 x 3, column k = the camera's R, G, B response to primary k, ``matrix[k][k]
        = 1``; the identity when not estimable), ``estimable``, ``bands`` (the pairs read),
        ``pixels``, and ``why`` when not estimable; when estimable also the leave-out check's
        ``segment_spread`` and ``max_segment_spread`` (:func:`segment_check`).
    """
    pairs = mixing_band_pairs(n_bands)
    cols = np.zeros((3, 3))
    per_segment: list[tuple[int, NDArray[np.float64]]] = []  # (primary, that segment's change) for the leave-out check
    npix = 0
    for k, first, last, sign in pairs:
        if first not in bands or last not in bands:
            continue
        lo, hi = np.asarray(bands[first], np.float64), np.asarray(bands[last], np.float64)
        ok = np.all((lo > 0.0) & (lo < 1.0) & (hi > 0.0) & (hi < 1.0), axis=-1)  # no clipped channel
        if shadow is not None:
            ok &= ~shadow
        npix = max(npix, int(ok.sum()))
        change = sign * (hi - lo)[ok].sum(axis=0)
        cols[:, k] += change
        per_segment.append((k, change))
    out: dict[str, Any] = {"matrix": np.eye(3).tolist(), "estimable": False,
                           "bands": [list(p) for p in pairs], "pixels": npix}
    diag = np.diag(cols)
    if npix < CA_MIN_PIXELS or np.any(diag <= 0):
        out["why"] = "no segment of the period with two hue bands for every primary" if len(
            {p[0] for p in pairs}) < 3 else "too few unclipped lit pixels in the hue bands"
        return out
    m = cols / diag[None, :]
    off = np.abs(m - np.diag(np.diag(m)))
    if off.max() > CA_MIXING_MAX_OFF_DIAGONAL or np.linalg.cond(m) > 10.0:
        out["why"] = f"implausible mixing (largest off-diagonal {off.max():.2f}, condition {np.linalg.cond(m):.1f})"
        return out
    out.update(matrix=m.tolist(), estimable=True)
    out.update(segment_check(per_segment))
    return out


def segment_check(per_segment: Sequence[tuple[int, NDArray[np.float64]]]) -> dict[str, Any]:
    """The leave-out check of a channel-mixing estimate: each primary's column from each of its two
    ramp segments alone (the rising and the falling one, disjoint bands), each scaled to a unit
    diagonal, and how far they disagree.

    Both segments see the same column of the camera's response whatever the gamma, the plate and the
    illumination; they disagree by the bands' noise, and by whatever is not a fixed linear mixing
    (a camera that stores gamma-encoded values, a drifting exposure between the bands: 0.19 and
    0.014-0.10 in tests/test_camera_demixing.py).

    Returns
    -------
    dict
        ``segment_spread``: (3, 3) ``|column(segment 1) - column(segment 2)|`` per entry (None for
        a primary with one segment), ``max_segment_spread`` (its largest entry, None when a primary
        has no second segment).
    """
    by_primary: dict[int, list[NDArray[np.float64]]] = {}
    for k, change in per_segment:
        if change[k] > 0:
            by_primary.setdefault(k, []).append(change / change[k])
    spread = np.full((3, 3), np.nan)
    for k, c in by_primary.items():
        if len(c) >= 2:
            spread[:, k] = np.abs(c[0] - c[1])
    worst = None if np.isnan(spread).any() else float(spread.max())
    return {"segment_spread": [[None if np.isnan(x) else float(x) for x in row] for row in spread],
            "max_segment_spread": worst}


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


# --------------------------------------------------------------------------- colour crosstalk

DEMIX_AUTO_THRESHOLD = 0.01
"""``camera.colour_demixing: auto`` demixes when the largest off-diagonal of the estimated
crosstalk matrix (columns scaled to a unit diagonal) exceeds this: 1 % of a channel's light read
by another channel (the bench's camera: 2-10 %; a camera without crosstalk reads 0.000-0.003)."""

DEMIX_MAX_SEGMENT_SPREAD = 0.01
"""``auto`` also needs the estimate's leave-out check (:func:`segment_check`) to agree: the columns
that each primary's rising and falling ramp segment give alone may differ by at most this in any
entry (the smallest crosstalk worth undoing). Bench sessions from 16 bands x 1 repeat, 8 bit, at
160 x 120 px upwards read 4e-5 - 7.1e-4 (docs/accuracy.md, Session 9); a spread beyond it means the
bands do not show one fixed linear mixing (a camera's auto exposure drifting 0.2 % a band reads
0.014), and the estimate is not used."""


class CaptureReader:
    """Reads a session's captures as the per-frame chains see them: through the camera corrections.

    ``codes(path)`` gives the sensor codes (what :func:`huefringe.session.read_rgb_codes` reads,
    re-demosaiced first when a :class:`BayerResampling` is set, then registered when a
    :class:`ChannelRegistration` is set); ``rgb(path)`` the same scaled to
    float32 [0, 1] exactly as :func:`huefringe.session.read_rgb` scales it. Without corrections
    both are the session reader's own functions (byte-identical outputs for plain sessions).

    With a ``demix`` matrix (the inverse of the camera's colour crosstalk, :func:`estimate_channel_mixing`)
    ``rgb`` returns ``demix @ rgb`` per pixel: each channel then holds the light of its own
    projector channel only, so that white balance cancels the surface colour (paper eqs. 7-8) on
    coloured coatings as on the plate. A pixel with a channel at full scale keeps its clipped
    values (the chains' clipping test still sees it). ``demixed`` tells the chains to read ``rgb``.
    """

    def __init__(self, registration: ChannelRegistration | None = None, bayer: BayerResampling | None = None,
                 demix: ArrayLike | None = None):
        self.registration = registration
        self.bayer = bayer
        self.demix = None if demix is None else np.asarray(demix, np.float32).reshape(3, 3)

    @property
    def demixed(self) -> bool:
        """Whether :meth:`rgb` demixes the channels (the sensor codes then are not what the chains read)."""
        return self.demix is not None

    def codes(self, path: Any) -> NDArray:
        data = read_rgb_codes(path)
        if self.bayer is not None:
            data = self.bayer.apply(data)
        return data if self.registration is None else self.registration.apply(data)

    def rgb(self, path: Any) -> NDArray[np.float32]:
        if self.registration is None and self.bayer is None and self.demix is None:
            return read_rgb(path)
        data = self.codes(path)
        top = 255 if data.dtype == np.uint8 else 65535
        out = data.astype(np.float32) * np.float32(1.0 / top)
        if self.demix is None:
            return out
        mixed = cv2.transform(np.ascontiguousarray(out), self.demix)
        clipped = (data >= top).any(axis=-1)
        return np.where(clipped[..., None], out, mixed).astype(np.float32)


def demixing_record(setting: Any, mixing: Mapping[str, Any] | None) -> dict[str, Any]:
    """The ``colour_demixing`` entry of ``calib/camera.json`` (``camera.colour_demixing``).

    ``mixing`` is :func:`estimate_channel_mixing`'s record (the camera's response to each projector
    primary, columns scaled to a unit diagonal). ``auto`` applies its inverse when the largest
    off-diagonal exceeds :data:`DEMIX_AUTO_THRESHOLD` and the estimate passes its leave-out check
    (the two ramp segments of every primary agree within :data:`DEMIX_MAX_SEGMENT_SPREAD`;
    ``not_applied_because`` says why not); ``true`` always (when estimable); ``false`` never (also
    when no mixing was estimated). When applied: ``demix`` (the inverse) and ``noise_gain`` (the
    norm of each of its rows: a demixed channel's noise against equal white noise in R, G, B).
    """
    rec: dict[str, Any] = {"setting": setting, "applied": False}
    if setting is False or setting == "false" or mixing is None:
        return rec
    m = np.asarray(mixing["matrix"], np.float64)
    off = float(np.abs(m - np.diag(np.diag(m))).max())
    est = {"matrix": m.tolist(), "max_offdiagonal": off, "estimable": bool(mixing.get("estimable"))}
    if not mixing.get("estimable"):
        est["why"] = mixing.get("why")
    spread = mixing.get("max_segment_spread")
    est["segment_spread"] = mixing.get("segment_spread")
    est["max_segment_spread"] = spread
    forced = setting is True or setting == "true"
    reliable = spread is not None and spread <= DEMIX_MAX_SEGMENT_SPREAD
    applied = bool(mixing.get("estimable")) and (forced or (off > DEMIX_AUTO_THRESHOLD and reliable))
    rec.update(applied=applied, threshold=DEMIX_AUTO_THRESHOLD, max_segment_spread=DEMIX_MAX_SEGMENT_SPREAD,
               estimate=est)
    if mixing.get("estimable") and not forced and off > DEMIX_AUTO_THRESHOLD and not reliable:
        rec["not_applied_because"] = (
            "the leave-out check has no second ramp segment for every primary (fewer than 12 hue bands)"
            if spread is None else
            f"the leave-out check failed: the rising and the falling ramp segments give columns differing by "
            f"{spread:.4f} (limit {DEMIX_MAX_SEGMENT_SPREAD}): the bands do not show one fixed linear channel mixing")
    if applied:
        demix = np.linalg.inv(m)
        rec["demix"] = demix.tolist()
        # each demixed channel's noise against the camera channel's (white, equal noise in R, G, B)
        rec["noise_gain"] = [float(x) for x in np.sqrt((demix ** 2).sum(axis=1))]
    return rec


def camera_record(meta: Mapping[str, Any], settings: Mapping[str, Any], planes: Sequence[NDArray[np.floating]],
                  white: NDArray[np.floating], shadow: NDArray[np.bool_] | None = None,
                  bands: Mapping[int, NDArray[np.floating]] | None = None) -> dict[str, Any]:
    """The results' ``calib/camera.json``: the lens model used for X, Y, the re-demosaic, the
    channel registration and the colour demixing.

    Parameters
    ----------
    meta : mapping
        The session's checked ``session.yaml``.
    settings : mapping
        The config block ``camera`` (``lens_model``, ``chromatic_registration``, ``colour_demixing``).
    planes, white
        The reference planes' captures and the reference white (float [0, 1]) for the estimate
        (read through the record's re-demosaic, :func:`demosaic_record`).
    bands : mapping of band index to image, optional
        The reference hue bands :func:`mixing_band_pairs` names (float [0, 1], repeats averaged,
        read as the planes are): the camera's channel mixing (:func:`estimate_channel_mixing`), in
        which the magnification is estimated and undone and whose inverse demixes every capture
        (:func:`demixing_record`). Without them neither.
    """
    lens = bool(settings.get("lens_model", True))
    mode = settings.get("chromatic_registration", "auto")
    model = CameraModel.from_meta(meta, lens_model=True)
    used = model if lens else CameraModel.from_meta(meta, lens_model=False)
    rec: dict[str, Any] = {"lens_model": lens, "xy_model": used.describe(),
                           "chromatic_registration": {"setting": mode, "applied": False}}
    rec["demosaic"] = demosaic_record(meta, settings)
    mixing = (estimate_channel_mixing(bands, int(meta["pattern"]["hue_bands"]), shadow=shadow) if bands
              else {"matrix": np.eye(3).tolist(), "estimable": False, "why": "no hue bands given"})
    rec["colour_demixing"] = demixing_record(settings.get("colour_demixing", False), mixing if bands else None)
    if mode is False or mode == "false":
        return rec
    est = estimate_lateral_ca(planes, white, float(meta["pattern"]["period_px"]), model.centre, shadow=shadow,
                              mixing=mixing["matrix"] if mixing["estimable"] else None)
    est["mixing"] = mixing
    worst = max(est["corner_displacement_px"].values())
    reach = est["fit_reach_u_px"] / max(est["field_reach_u_px"], 1e-9)
    forced = mode is True or mode == "true"
    applied = forced or (worst > CA_AUTO_THRESHOLD_PX and reach >= CA_AUTO_MIN_REACH)
    rec["chromatic_registration"].update(applied=bool(applied), threshold_px=CA_AUTO_THRESHOLD_PX,
                                         min_reach=CA_AUTO_MIN_REACH, reach=float(reach), estimate=est)
    if not forced and worst > CA_AUTO_THRESHOLD_PX and reach < CA_AUTO_MIN_REACH:
        rec["chromatic_registration"]["not_applied_because"] = (
            f"the estimate reads pixels out to {reach:.2f} of the field's half-width along u only (needs {CA_AUTO_MIN_REACH}): "
            "too small a field for the fringe period to tell a magnification")
    return rec


def corrections(record: Mapping[str, Any] | None, meta: Mapping[str, Any]) -> tuple[CameraModel, CaptureReader]:
    """The X, Y model and the capture reader a ``camera.json`` record (:func:`camera_record`)
    asks for; without one (None): the session's lens model and no registration."""
    if record is None:
        return CameraModel.from_meta(meta), CaptureReader(bayer=bayer_resampling(meta))
    model = CameraModel.from_meta(meta, lens_model=bool(record.get("lens_model", True)))
    dem = record.get("demosaic") or {}
    bayer = BayerResampling(dem["pattern"], dem["method"]) if dem.get("applied") else None
    mix = record.get("colour_demixing") or {}
    demix = mix.get("demix") if mix.get("applied") else None
    reg = record.get("chromatic_registration") or {}
    if not reg.get("applied"):
        return model, CaptureReader(bayer=bayer, demix=demix)
    est = reg["estimate"]
    reg_mix = est.get("mixing") or {}  # records before the mixing estimate: the camera channels registered
    mixing = tuple(tuple(float(x) for x in row) for row in reg_mix["matrix"]) if reg_mix.get("estimable") else None
    return model, CaptureReader(ChannelRegistration(tuple(est["centre"]), float(est["scale"]["R"]),
                                                    float(est["scale"]["B"]), mixing), bayer=bayer, demix=demix)


def demosaic_record(meta: Mapping[str, Any], settings: Mapping[str, Any]) -> dict[str, Any]:
    """The ``demosaic`` entry of ``calib/camera.json``: the session's Bayer pattern (``camera.bayer``,
    None for a three-chip camera), the setting (config ``camera.demosaic``) and whether the
    stored RGB is re-demosaiced (``applied``, with ``method``)."""
    setting = settings.get("demosaic", "lanczos")
    res = bayer_resampling(meta, setting)
    out: dict[str, Any] = {"bayer": meta.get("camera", meta).get("bayer"), "setting": setting, "applied": res is not None}
    if res is not None:
        out.update(res.describe())
    return out
