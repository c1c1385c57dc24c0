"""Bench radiometry after paper eqs. 6-8, plus the camera and projector imperfections.

Per colour channel ``k`` (R, G, B):

1. the pattern's value ``I_k`` in [0, 1] is quantised to the DMD's codes (8 bit by default);
2. the projector emits ``g_k(v) = power * v ** gamma_k`` (eq. 6), pixelated on the projector grid
   and blurred by defocus (a Gaussian along the projector's x);
3. the surface reflects ``r_k (E * g_k + a_k)`` (eq. 7), where ``E`` is the Lambertian cosine
   towards the projector (0 in cast shadows: shadowed points get only the ambient ``a_k``);
4. the camera records ``alpha_k (I_ko + b_k)`` (eq. 8) after a Gaussian lens blur, mixes its
   channels with a 3x3 crosstalk matrix, adds shot noise (Gaussian, variance from a full well in
   electrons) and read noise (DN), clips and quantises to 8 or 16 bits. A single-chip Bayer
   sensor (``camera.sensor.kind: bayer``) keeps one colour per photosite before the noise (the
   crosstalk row times the sensitivity is then the colour filter's spectral response of that
   photosite), and the camera delivers the demosaiced RGB (:func:`huefringe.camera.demosaic`).

The phase-shift sinusoids are pre-compensated with the user's *estimate* of the projector gamma
(``I ** (1 / gamma_hat)``); every other pattern is projected as is.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import gaussian_filter1d

from huefringe import patterns
from huefringe.camera import demosaic, mosaic

__all__ = ["Pattern", "Rig", "camera_response", "dmd_levels", "emitted_rgb", "rgb3"]

TWO_PI = 2.0 * np.pi


def rgb3(value: float | ArrayLike) -> NDArray[np.float64]:
    """A per-channel quantity given as one number or three numbers, as an array of shape (3,)."""
    a = np.asarray(value, dtype=np.float64)
    return np.full(3, float(a)) if a.ndim == 0 else a.reshape(3).copy()


@dataclass(frozen=True)
class Pattern:
    """What the projector shows: a uniform colour, the trapezoid (eq. 3) or a phase-shift sinusoid.

    Use the constructors :meth:`white`, :meth:`hue_band`, :meth:`trapezoid`, :meth:`phase_shift`.
    """

    kind: Literal["uniform", "trapezoid", "phase_shift"]
    rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)
    step: int = 0
    emit_offset: tuple[float, ...] | None = None
    """Pre-distortion of the trapezoid: ``p(c) - c`` sampled at ``c = 2 pi k / M`` (paper Fig. 6)."""

    @classmethod
    def white(cls) -> Pattern:
        """Full white (255, 255, 255)."""
        return cls("uniform", (1.0, 1.0, 1.0))

    @classmethod
    def hue_band(cls, i: int, n_bands: int) -> Pattern:
        """Uniform hue band ``i`` of ``n_bands`` (``patterns.band_rgb``)."""
        r, g, b = (float(c) for c in patterns.band_rgb(i, n_bands))
        return cls("uniform", (r, g, b))

    @classmethod
    def trapezoid(cls, emit_offset: tuple[float, ...] | None = None) -> Pattern:
        """The trapezoidal fringe of paper eq. 3, optionally pre-distorted: code ``c`` emits ``p(c)``."""
        return cls("trapezoid", emit_offset=emit_offset)

    @classmethod
    def phase_shift(cls, s: int) -> Pattern:
        """Grey phase-shift sinusoid ``s`` (0, 1, 2) of the capture-session spec."""
        if s not in (0, 1, 2):
            raise ValueError(f"phase-shift step must be 0, 1 or 2, got {s}")
        return cls("phase_shift", step=s)


@dataclass(frozen=True, eq=False)
class Rig:
    """Every physical parameter of the bench (see ``bench.schema.json`` for meanings)."""

    period_mm: float
    projector_x_mm: float
    projector_y_mm: float
    projector_height_mm: float
    x_origin_mm: float
    gamma: NDArray[np.float64]
    gamma_estimate: NDArray[np.float64]
    dmd_bits: int
    projector_pixel_mm: float | None
    defocus_sigma_mm: float
    power: float
    sensitivity: NDArray[np.float64]
    crosstalk: NDArray[np.float64]
    lens_blur_sigma_px: float
    full_well_e: float | None
    read_noise_dn: float
    bit_depth: int
    ambient: NDArray[np.float64]
    stray: NDArray[np.float64]
    plate_reflectance: NDArray[np.float64]
    lambertian: bool
    shadows: bool
    #: single-chip sensor: Bayer pattern in sensor order (None = three-chip) and the demosaic
    cfa_pattern: str | None = None
    demosaic_method: str = "edge_aware"

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> Rig:
        """Build the rig from a validated bench configuration."""
        s, p, c, light, surf, ps = (cfg[k] for k in ("session", "projector", "camera", "light", "surface", "phase_shift"))
        gamma = rgb3(p["gamma"])
        if ps["gamma_estimate"] is not None:
            gamma_est = rgb3(ps["gamma_estimate"])
        else:
            gamma_est = gamma * (1.0 + float(ps["gamma_error"]))
        pix = p["pixel_mm"]
        y = p["y_mm"] if p["y_mm"] is not None else 0.5 * (s["height"] - 1) * s["pixel_pitch_mm"]
        sensor = c.get("sensor") or {"kind": "three_chip"}
        bayer = sensor["kind"] == "bayer"
        return cls(
            period_mm=float(s["period_px"]) * float(s["pixel_pitch_mm"]),
            projector_x_mm=float(p["x_mm"]),
            projector_y_mm=float(y),
            projector_height_mm=float(p["height_mm"]),
            x_origin_mm=float(p["x_origin_mm"]),
            gamma=gamma,
            gamma_estimate=gamma_est,
            dmd_bits=int(p["dmd_bits"]),
            projector_pixel_mm=None if pix is None else float(pix),
            defocus_sigma_mm=float(p["defocus_sigma_px"]) * (float(pix) if pix is not None else 0.0),
            power=float(p["power"]),
            sensitivity=rgb3(c["sensitivity"]),
            crosstalk=np.asarray(c["crosstalk"], dtype=np.float64).reshape(3, 3),
            lens_blur_sigma_px=float(c["lens_blur_sigma_px"]),
            full_well_e=None if c["full_well_e"] is None else float(c["full_well_e"]),
            read_noise_dn=float(c["read_noise_dn"]),
            bit_depth=int(s["bit_depth"]),
            ambient=rgb3(light["ambient"]),
            stray=rgb3(light["stray"]),
            plate_reflectance=rgb3(surf["plate_reflectance"]),
            lambertian=bool(surf["lambertian"]),
            shadows=bool(surf["shadows"]),
            cfa_pattern=str(sensor.get("pattern", "RGGB")) if bayer else None,
            demosaic_method=str(sensor.get("demosaic", "edge_aware")),
        )

    @property
    def projector_xyz(self) -> tuple[float, float, float]:
        """Projector pinhole position (mm)."""
        return (self.projector_x_mm, self.projector_y_mm, self.projector_height_mm)

    @property
    def max_dn(self) -> int:
        """Full-scale digital number of the camera."""
        return (1 << self.bit_depth) - 1


def dmd_levels(pattern: Pattern, phi: ArrayLike | None, rig: Rig) -> NDArray[np.float64]:
    """The DMD's quantised drive levels in [0, 1] for a pattern at code phase ``phi``.

    Parameters
    ----------
    pattern : Pattern
        What is projected.
    phi : array_like or None
        Code phase of each projector sample (ignored for uniform patterns).
    rig : Rig
        Supplies the DMD bit depth and, for phase-shift frames, the gamma estimate used to
        pre-compensate the sinusoid.

    Returns
    -------
    ndarray
        Shape ``phi.shape + (3,)`` (``(3,)`` for uniform patterns).
    """
    q = float((1 << rig.dmd_bits) - 1)
    if pattern.kind == "uniform":
        v = np.asarray(pattern.rgb, dtype=np.float64)
    elif pattern.kind == "trapezoid":
        if pattern.emit_offset is not None:
            off = np.asarray(pattern.emit_offset, dtype=np.float64)
            grid = TWO_PI * np.arange(off.size + 1) / off.size
            phi = np.asarray(phi, dtype=np.float64)
            phi = phi + np.interp(np.mod(phi, TWO_PI), grid, np.append(off, off[0]))
        v = patterns.trapezoid_rgb(phi)
    elif pattern.kind == "phase_shift":
        grey = np.clip(patterns.phase_shift_intensity(phi, pattern.step), 0.0, 1.0)
        v = grey[..., None] ** (1.0 / rig.gamma_estimate)
    else:  # pragma: no cover - guarded by the dataclass constructors
        raise ValueError(f"unknown pattern kind {pattern.kind!r}")
    return np.round(v * q) / q


def _projector_output(levels: NDArray[np.float64], rig: Rig) -> NDArray[np.float64]:
    """Eq. 6: ``g_k(v) = power * v ** gamma_k``."""
    return rig.power * levels**rig.gamma


def _emitted_exact(pattern: Pattern, x0: NDArray[np.float64], rig: Rig) -> NDArray[np.float64]:
    """Projector output at reference-plane positions ``x0`` without defocus."""
    t = x0 - rig.x_origin_mm
    if rig.projector_pixel_mm is not None:
        # projector pixel j is centred on x_origin + j * pixel and shows the phase of its centre
        t = np.round(t / rig.projector_pixel_mm) * rig.projector_pixel_mm
    phi = TWO_PI * t / rig.period_mm
    return _projector_output(dmd_levels(pattern, phi, rig), rig)


def emitted_rgb(pattern: Pattern, x0: NDArray[np.floating] | None, rig: Rig) -> NDArray[np.float32]:
    """Projector irradiance (before shading) reaching the points whose rays meet z = 0 at ``x0``.

    Parameters
    ----------
    pattern : Pattern
        What is projected.
    x0 : ndarray or None
        Reference-plane intersection of each point's projector ray
        (:func:`huefringe.bench.geometry.projector_ray_x0`); unused for uniform patterns.
    rig : Rig
        Projector model: DMD quantisation, gamma, pixelation, defocus, power.

    Returns
    -------
    ndarray
        ``x0.shape + (3,)`` float32, or ``(3,)`` for a uniform pattern.

    Notes
    -----
    Defocus is exact in the projector's frame: the 1-D emitted profile (a function of ``x0``
    only, because fringes are constant along rows and the projector's image plane is parallel
    to the plate) is tabulated finely over the needed range, convolved with the Gaussian and
    linearly interpolated at every ``x0``.
    """
    if pattern.kind == "uniform":
        return _projector_output(dmd_levels(pattern, None, rig), rig).astype(np.float32)
    assert x0 is not None
    x0 = np.asarray(x0, dtype=np.float64)
    sigma = rig.defocus_sigma_mm
    if sigma <= 0.0:
        return _emitted_exact(pattern, x0, rig).astype(np.float32)
    pad = 6.0 * sigma + 2.0 * (rig.projector_pixel_mm or 0.0)
    # table bounds rounded outwards to whole centimetres, so that captures share tables
    lo = float(np.floor((float(x0.min()) - pad) / 10.0) * 10.0)
    hi = float(np.ceil((float(x0.max()) + pad) / 10.0) * 10.0)
    step, table = _defocused_table(pattern, rig, lo, hi)
    n = table.shape[0]
    # linear interpolation on the uniform table (np.interp without the binary search)
    pos = (x0 - lo) * (1.0 / step)
    idx = np.clip(pos.astype(np.intp), 0, n - 2)
    frac = (pos - idx).astype(np.float32)
    out = np.empty(x0.shape + (3,), dtype=np.float32)
    for k in range(3):
        col = table[:, k]
        out[..., k] = col[idx] + frac * np.diff(col)[idx]
    return out


@lru_cache(maxsize=32)
def _defocused_table(pattern: Pattern, rig: Rig, lo: float, hi: float) -> tuple[float, NDArray[np.float32]]:
    """The defocused emitted profile tabulated on ``[lo, hi]`` (step, table of shape (n, 3))."""
    sigma = rig.defocus_sigma_mm
    step = min(sigma / 8.0, (rig.projector_pixel_mm or sigma) / 16.0, rig.period_mm / 1024.0)
    n = int(np.ceil((hi - lo) / step)) + 1
    xs = lo + step * np.arange(n)
    table = gaussian_filter1d(_emitted_exact(pattern, xs, rig), sigma / step, axis=0, mode="nearest", truncate=5.0)
    table = table.astype(np.float32)
    table.setflags(write=False)
    return step, table


def lens_blur(img: NDArray[np.float32], sigma_px: float) -> NDArray[np.float32]:
    """Gaussian lens blur of a camera image (``cv2.GaussianBlur``, reflected borders)."""
    if sigma_px <= 0.0:
        return img
    return cv2.GaussianBlur(np.ascontiguousarray(img, dtype=np.float32), (0, 0), sigmaX=sigma_px, sigmaY=sigma_px)


def camera_response(
    radiance: NDArray[np.floating],
    rig: Rig,
    rng: np.random.Generator | None,
    *,
    blurred: bool = False,
) -> NDArray[np.uint8] | NDArray[np.uint16]:
    """Camera of eq. 8 plus lens blur, crosstalk, noise, clipping and quantisation.

    Parameters
    ----------
    radiance : ndarray, shape (H, W, 3)
        Light leaving the surface towards each pixel, ``I_ko`` of eq. 7.
    rig : Rig
        Camera parameters.
    rng : numpy.random.Generator or None
        Noise source; ``None`` disables noise.
    blurred : bool
        ``radiance`` is already lens-blurred (used by the fast path for uniform patterns).

    Returns
    -------
    ndarray
        ``uint8`` or ``uint16`` RGB image at the rig's bit depth (a Bayer sensor's: demosaiced).
    """
    x = np.asarray(radiance, dtype=np.float32)
    if not blurred:
        x = lens_blur(x, rig.lens_blur_sigma_px)
    # eq. 8 and the crosstalk in one affine map: c = M diag(alpha) (I_ko + b)
    gain = rig.crosstalk * rig.sensitivity[None, :]
    affine = np.concatenate([gain, (gain @ rig.stray)[:, None]], axis=1).astype(np.float32)
    x = cv2.transform(np.ascontiguousarray(x), affine)
    if rig.cfa_pattern is not None:  # one colour per photosite: the colour filter's response
        x = mosaic(x, rig.cfa_pattern)
    if rng is not None and (rig.full_well_e is not None or rig.read_noise_dn > 0.0):
        read_var = np.float32((rig.read_noise_dn / rig.max_dn) ** 2)
        if rig.full_well_e is not None:
            std = np.sqrt(np.maximum(x, 0.0) * np.float32(1.0 / rig.full_well_e) + read_var)
        else:
            std = np.sqrt(read_var)
        x = x + std * rng.standard_normal(x.shape, dtype=np.float32)
    dn = np.rint(np.clip(x, 0.0, 1.0) * np.float32(rig.max_dn))
    out = dn.astype(np.uint8 if rig.bit_depth == 8 else np.uint16)
    if rig.cfa_pattern is not None:
        return demosaic(out, rig.cfa_pattern, rig.demosaic_method)
    return out
