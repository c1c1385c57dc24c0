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

A projector image file (:meth:`Pattern.image`, e.g. one written by ``huefringe patterns``) is
projected as a DMD shows it: its pixels are boxes ``scale = P / T`` mm wide on the reference plane
(``P`` the bench's period in mm, ``T`` the file's period in projector pixels), column ``c`` centred
on ``X0 = x_origin + (c - col_shift) * scale`` and row ``r`` on ``Y0 = y_centre + (r - (rows - 1) / 2)
* scale``; each pixel's codes go through the same DMD quantisation, gamma and defocus as an analytic
pattern's.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import gaussian_filter1d
from scipy.special import erf

from huefringe import patterns
from huefringe.camera import demosaic, mosaic

__all__ = ["Pattern", "ProjectorImage", "Rig", "camera_response", "dmd_levels", "emitted_rgb", "rgb3"]

TWO_PI = 2.0 * np.pi


def rgb3(value: float | ArrayLike) -> NDArray[np.float64]:
    """A per-channel quantity given as one number or three numbers, as an array of shape (3,)."""
    a = np.asarray(value, dtype=np.float64)
    return np.full(3, float(a)) if a.ndim == 0 else a.reshape(3).copy()


@dataclass(frozen=True, eq=False)
class ProjectorImage:
    """A projector image file's drive levels and where its pixels land on the reference plane.

    Compared and hashed by identity (it holds an array), so a :class:`Pattern` holding it can key
    the bench's caches.
    """

    levels: NDArray[np.float64]
    """``(rows, cols, 3)`` codes over full scale, in [0, 1]; ``(1, cols, 3)`` for an image whose
    rows are all equal (a fringe: constant along rows)."""
    rows: int
    """Image height in projector pixels (``levels`` may hold a single row)."""
    period_px: float
    """The fringe period ``T`` of the file in projector pixels: one projector pixel is ``P / T`` mm."""
    col_shift: float = 0.0
    """Projector column (pixel centres at integers) on which the code origin ``x_origin`` lands."""
    y_centre_mm: float = 0.0
    """Plate ``Y`` on which the image's centre row ``(rows - 1) / 2`` lands."""

    @property
    def row_constant(self) -> bool:
        """The image is one row repeated (the fringe varies along x only)."""
        return self.levels.shape[0] == 1


@dataclass(frozen=True)
class Pattern:
    """What the projector shows: a uniform colour, the trapezoid (eq. 3), a phase-shift sinusoid
    or a projector image file.

    Use the constructors :meth:`white`, :meth:`hue_band`, :meth:`trapezoid`, :meth:`phase_shift`,
    :meth:`image`.
    """

    kind: Literal["uniform", "trapezoid", "phase_shift", "image"]
    rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)
    step: int = 0
    emit_offset: tuple[float, ...] | None = None
    """Pre-distortion of the trapezoid: ``p(c) - c`` sampled at ``c = 2 pi k / M`` (paper Fig. 6)."""
    source: ProjectorImage | None = None
    """The projector image of kind ``image``."""

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

    @classmethod
    def image(cls, codes: NDArray[np.integer], period_px: float, *, bit_depth: int | None = None,
              col_shift: float = 0.0, y_centre_mm: float = 0.0) -> Pattern:
        """A projector image file as the projector shows it (see the module notes).

        Parameters
        ----------
        codes : ndarray, shape (rows, cols, 3)
            The file's RGB codes (``uint8`` or ``uint16``).
        period_px : float
            Fringe period of the file in projector pixels (``patterns.yaml``'s ``period_px``): the
            file's column ``c`` carries code phase ``2 pi (c - col_shift) / period_px``, as the
            analytic trapezoid at the same plate point.
        bit_depth : int, optional
            Full scale of the codes (default: 8 for ``uint8``, 16 for ``uint16``).
        col_shift : float
            Projector column on which the code origin ``x_origin`` lands (a whole number of periods
            keeps every code phase; :func:`huefringe.bench.projector.image_placement` centres the
            camera's field in the image with it).
        y_centre_mm : float
            Plate ``Y`` of the image's centre row.

        A uniform image (every pixel the same colour) is the uniform pattern of those codes.
        """
        a = np.asarray(codes)
        if a.ndim != 3 or a.shape[2] != 3 or a.dtype not in (np.uint8, np.uint16):
            raise ValueError(f"a projector image must be RGB uint8/uint16 of shape (rows, cols, 3), got {a.dtype} {a.shape}")
        bits = bit_depth if bit_depth is not None else (8 if a.dtype == np.uint8 else 16)
        top = float((1 << bits) - 1)
        flat = a.reshape(-1, 3)
        if np.all(flat == flat[0]):
            r, g, b = (float(v) / top for v in flat[0])
            return cls("uniform", (r, g, b))
        if not (np.isfinite(period_px) and period_px > 0):
            raise ValueError(f"period_px must be a positive number, got {period_px!r}")
        levels = a[:1] if np.all(a == a[:1]) else a
        levels = np.clip(levels.astype(np.float64) / top, 0.0, 1.0)
        levels.setflags(write=False)
        return cls("image", source=ProjectorImage(levels, int(a.shape[0]), float(period_px), float(col_shift),
                                                  float(y_centre_mm)))


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
            read_noise_dn=_read_noise_dn(c, int(s["bit_depth"])),
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


def _read_noise_dn(camera: dict[str, Any], bit_depth: int) -> float:
    """The camera's read noise in DN: ``read_noise_e`` electrons at ``full_well_e`` electrons per
    full scale (``2^bit_depth - 1`` DN) when given, else ``read_noise_dn``."""
    e = camera.get("read_noise_e")
    if e is None:
        return float(camera["read_noise_dn"])
    if camera.get("full_well_e") is None:
        raise ValueError("camera.read_noise_e needs camera.full_well_e (electrons at full scale)")
    return float(e) * ((1 << bit_depth) - 1) / float(camera["full_well_e"])


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
    elif pattern.kind == "image":  # the file's codes per projector pixel (phi unused)
        assert pattern.source is not None
        v = pattern.source.levels
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


def emitted_rgb(pattern: Pattern, x0: NDArray[np.floating] | None, rig: Rig,
                y0: NDArray[np.floating] | None = None) -> NDArray[np.float32]:
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
    y0 : ndarray, optional
        The rays' ``Y`` on the reference plane; needed only by an image whose rows differ.

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
    if pattern.kind == "image":
        return _emitted_image(pattern, x0, y0, rig)
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


def image_scale_mm(image: ProjectorImage, rig: Rig) -> float:
    """Size (mm) of one pixel of a projector image on the reference plane: ``P / T``."""
    return rig.period_mm / image.period_px


def _box_gauss(t: NDArray[np.float64], sigma: float) -> NDArray[np.float64]:
    """A unit box pixel blurred by a Gaussian of ``sigma`` (pixels), at offset ``t`` from its centre."""
    k = 1.0 / (sigma * np.sqrt(2.0))
    return 0.5 * (erf((t + 0.5) * k) - erf((t - 0.5) * k))


def _emitted_image(pattern: Pattern, x0: NDArray[np.float64], y0: NDArray[np.floating] | None,
                   rig: Rig) -> NDArray[np.float32]:
    """Projector output of an image pattern at reference-plane points ``(x0, y0)``.

    Without defocus each point takes the pixel it falls in (pixels are boxes). With defocus
    (``defocus_sigma_mm``, in pixels of this image ``sigma = defocus_sigma_mm / scale``) a point
    takes the box pixels convolved with the Gaussian: for a row-constant image a finely tabulated
    1-D profile (as for analytic patterns), otherwise the exact separable weights
    ``K(r - i) K(c - j)`` with ``K`` the box-Gaussian.
    """
    img = pattern.source
    assert img is not None
    scale = image_scale_mm(img, rig)
    emitted = _projector_output(dmd_levels(pattern, None, rig), rig)  # (rows or 1, cols, 3)
    cols = emitted.shape[1]
    c = (x0 - rig.x_origin_mm) / scale + img.col_shift
    sigma = rig.defocus_sigma_mm / scale
    if img.row_constant:
        if sigma <= 0.0:
            return emitted[0][np.clip(np.round(c), 0, cols - 1).astype(np.intp)].astype(np.float32)
        step, table = _image_table(pattern, rig)
        pos = (c + 0.5 + 6.0 * sigma) / step
        idx = np.clip(pos.astype(np.intp), 0, table.shape[0] - 2)
        frac = (pos - idx).astype(np.float32)[..., None]
        return table[idx] + frac * (table[idx + 1] - table[idx])
    if y0 is None:
        raise ValueError("an image pattern whose rows differ needs the rays' y0")
    r = (np.asarray(y0, dtype=np.float64) - img.y_centre_mm) / scale + 0.5 * (img.rows - 1)
    if sigma <= 0.0:
        ri = np.clip(np.round(r), 0, img.rows - 1).astype(np.intp)
        return emitted[ri, np.clip(np.round(c), 0, cols - 1).astype(np.intp)].astype(np.float32)
    half = int(np.ceil(5.0 * sigma)) + 1
    offs = np.arange(-half, half + 1)
    flat_r, flat_c = r.ravel(), c.ravel()
    out = np.empty((flat_r.size, 3), np.float32)
    chunk = max(1, 2_000_000 // (offs.size * offs.size * 3))
    for s in range(0, flat_r.size, chunk):
        rr, cc = flat_r[s:s + chunk], flat_c[s:s + chunk]
        ir = np.round(rr)[:, None] + offs[None, :]
        ic = np.round(cc)[:, None] + offs[None, :]
        wr, wc = _box_gauss(rr[:, None] - ir, sigma), _box_gauss(cc[:, None] - ic, sigma)
        ir = np.clip(ir, 0, img.rows - 1).astype(np.intp)
        ic = np.clip(ic, 0, cols - 1).astype(np.intp)
        patch = emitted[ir[:, :, None], ic[:, None, :]]  # (n, wr, wc, 3)
        out[s:s + chunk] = np.einsum("ni,nj,nijk->nk", wr, wc, patch) / (wr.sum(1) * wc.sum(1))[:, None]
    return out.reshape(r.shape + (3,))


@lru_cache(maxsize=32)
def _image_table(pattern: Pattern, rig: Rig) -> tuple[float, NDArray[np.float32]]:
    """A row-constant image's defocused profile on a fine grid of projector columns.

    Sample ``k`` sits at column ``-0.5 - 6 sigma + k step``: the box pixels (nearest column),
    blurred by ``gaussian_filter1d`` (edge pixels continued), as :func:`_defocused_table` does
    for analytic patterns.
    """
    img = pattern.source
    assert img is not None
    sigma = rig.defocus_sigma_mm / image_scale_mm(img, rig)
    emitted = _projector_output(dmd_levels(pattern, None, rig), rig)[0]
    cols = emitted.shape[0]
    step = min(sigma / 8.0, 1.0 / 16.0, img.period_px / 1024.0)
    pad = 6.0 * sigma
    n = int(np.ceil((cols + 2.0 * pad) / step)) + 2
    xs = -0.5 - pad + step * np.arange(n)
    profile = emitted[np.clip(np.round(xs), 0, cols - 1).astype(np.intp)]
    table = gaussian_filter1d(profile, sigma / step, axis=0, mode="nearest", truncate=5.0).astype(np.float32)
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
