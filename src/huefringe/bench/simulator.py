"""The virtual bench: a configured rig and scene that produce captures and ground truth.

:class:`Bench` ties :mod:`.geometry`, :mod:`.radiometry` and :mod:`.scenes` together. Its
captures are pure functions of the configuration, the pattern, the instant and the noise
generator passed in; nothing is global.

Timing: one-shot frame ``n`` is taken at ``t_n = n / camera.frame_rate_hz``; its three
phase-shift captures at ``t_n + s / phase_shift.frame_rate_hz``; with ``camera.exposure_ms > 0``
and ``motion_blur_subframes > 1`` a capture averages that many sub-exposures spread over the
exposure centred on its instant. White, hue bands and the reference planes are taken with the
object at rest.

Camera lens (:mod:`.lens`, only with ``camera.model``, ``camera.distortion`` or
``camera.lateral_ca_px``): the scene is shaded as above on a plate grid (a margin wider than
the image by what the lens shows beyond it), then every camera (sub-)sample takes the light of
the plate point its ray meets (per colour channel for chromatic aberration; the pinhole's rays
cast against the surface's height field), by bilinear interpolation of the plate grid, before
the lens blur and the sensor.

Colour-sequential projector (:mod:`.colour_sequence`, only with ``projector.colour_sequence``):
each capture takes a start phase of the projector's colour cycle (``colour_phase``, drawn per
image by :meth:`Bench.colour_phase`), and the projector's light reaching camera row ``r`` is
weighted per channel by the share of that colour within the row's exposure window (global or
rolling shutter, ``camera.shutter``); a motion-blurred capture weights each sub-exposure by its
own slice of the window. The object's motion during a rolling shutter's readout is not modelled
(every row sees the object at the capture's instants).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import map_coordinates

from .colour_sequence import ColourSequence, Shutter, row_weights, start_phase
from .geometry import Grid, cast_shadow_mask, lambert_from_parts, lambert_parts, projector_ray_x0
from .lens import Lens
from .radiometry import Pattern, Rig, camera_response, emitted_rgb, lens_blur
from .scenes import Scene, SceneSample, build_scene

__all__ = ["Bench", "Surface", "noise_rng", "simulate_capture"]

F64 = NDArray[np.float64]


@dataclass
class Surface:
    """What the camera sees on its (fine) grid at one instant: plate plus object."""

    height: F64
    grad_x: F64
    grad_y: F64
    reflectance: NDArray[np.float32]  # (rows, cols, 3)
    #: height-independent shading terms, shared by surfaces that differ by a vertical shift
    cache: dict[str, Any] = field(default_factory=dict)
    #: what the camera's lens makes of this very surface (its sampling maps), never shared
    view: dict[str, Any] = field(default_factory=dict)


@dataclass
class Lighting:
    """Projector geometry of a surface: ray footprint ``x0`` on z = 0 and irradiance factor."""

    x0: F64
    irradiance: F64  # Lambertian cosine, 0 in cast shadows
    shadow: NDArray[np.bool_]


def noise_rng(seed: int, name: str) -> np.random.Generator:
    """The noise generator of one image: independent streams keyed by (seed, image name).

    Keying by name (not by writing order) makes every file's bytes independent of which other
    files are written and in which order.
    """
    return np.random.default_rng([int(seed), zlib.crc32(name.encode("utf-8"))])


class Bench:
    """A configured virtual bench.

    Parameters
    ----------
    cfg : dict
        A validated bench configuration (:func:`huefringe.bench.load_bench_config`).
    scene : Scene, optional
        Override the configured scene (tests).
    """

    def __init__(self, cfg: dict[str, Any], scene: Scene | None = None) -> None:
        self.cfg = cfg
        self.rig = Rig.from_config(cfg)
        s = cfg["session"]
        self.grid = Grid(int(s["width"]), int(s["height"]), float(s["pixel_pitch_mm"]), int(cfg["camera"]["supersample"]))
        self.scene = scene if scene is not None else build_scene(cfg)
        self.lens = Lens.from_config(cfg)
        self.margin_px = 0
        if self.lens is None:
            self._xf, self._yf = self.grid.mesh(fine=True)
        else:
            self.margin_px = self._lens_margin()
            m = self.margin_px
            plate = Grid(self.grid.width + 2 * m, self.grid.height + 2 * m, self.grid.pitch_mm, self.grid.supersample)
            xf, yf = plate.mesh(fine=True)
            self._xf, self._yf = xf - m * plate.pitch_mm, yf - m * plate.pitch_mm
        self._ideal: dict[tuple[int, bool], tuple[F64, F64]] = {}
        self._xc, self._yc = self.grid.mesh(fine=False)
        self._rest_fine: SceneSample | None = None
        self._rest_coarse: SceneSample | None = None
        self._rest_surface: dict[str, Surface] = {}
        self._plate_cache: dict[str, Any] = {}
        seq = cfg["projector"].get("colour_sequence")
        self.sequence = None if seq is None else ColourSequence.from_config(seq)
        self.shutter = Shutter.from_config(cfg["camera"].get("shutter"))

    # ---------------------------------------------------------------- colour sequence
    def colour_phase(self, name: str) -> float | None:
        """The colour-cycle start phase of the image ``name`` (None without a colour sequence)."""
        if self.sequence is None:
            return None
        return start_phase(self.shutter, int(self.cfg["session"]["seed"]), name)

    def channel_weights(self, phase: float, subframes: int = 1) -> NDArray[np.float32]:
        """Per-row channel weights ``(subframes, rows, 3)`` of an image starting at ``phase``
        (:func:`.colour_sequence.row_weights`)."""
        assert self.sequence is not None
        exp_s = float(self.cfg["camera"]["exposure_ms"]) * 1e-3
        return row_weights(self.sequence, self.shutter, exp_s, self.grid.height, phase, subframes).astype(np.float32)

    # ---------------------------------------------------------------- timing and motion
    def frame_time(self, n: int) -> float:
        """Instant ``t_n`` (s) of one-shot frame ``n``."""
        return n / float(self.cfg["camera"]["frame_rate_hz"])

    def phase_shift_time(self, n: int, s: int) -> float:
        """Instant (s) of phase-shift capture ``s`` of instant ``n``."""
        return self.frame_time(n) + s / float(self.cfg["phase_shift"]["frame_rate_hz"])

    def motion(self, t: float | None) -> tuple[float, float]:
        """Rigid displacement ``(dx, dz)`` in mm of the object at time ``t`` (None = at rest)."""
        if t is None:
            return 0.0, 0.0
        v = self.cfg["vibration"]
        w = 2.0 * np.pi * float(v["frequency_hz"]) * t
        dz = float(v["amplitude_mm"]) * np.sin(w + float(v["phase_rad"]))
        dx = float(v["lateral_amplitude_mm"]) * np.sin(w + float(v["lateral_phase_rad"]))
        return dx, dz

    def exposure_times(self, t: float) -> list[float]:
        """Sub-exposure instants of a capture centred on ``t``."""
        cam = self.cfg["camera"]
        n = int(cam["motion_blur_subframes"])
        exp_s = float(cam["exposure_ms"]) * 1e-3
        if n <= 1 or exp_s <= 0.0:
            return [t]
        return [t + ((j + 0.5) / n - 0.5) * exp_s for j in range(n)]

    # ---------------------------------------------------------------- surfaces
    def _object(self, t: float | None, fine: bool) -> tuple[SceneSample, float]:
        """The scene sampled where the object is at time ``t``, and its vertical offset."""
        dx, dz = self.motion(t)
        x, y = (self._xf, self._yf) if fine else (self._xc, self._yc)
        if dx != 0.0:
            return self.scene.sample(x - dx, y), dz
        if fine:
            if self._rest_fine is None:
                self._rest_fine = self.scene.sample(x, y)
            return self._rest_fine, dz
        if self._rest_coarse is None:
            self._rest_coarse = self.scene.sample(x, y)
        return self._rest_coarse, dz

    def _compose(self, smp: SceneSample, dz: float) -> Surface:
        m = smp.mask
        h = np.where(m, smp.height + dz, 0.0)
        top = float(h.max())
        if top >= self.rig.projector_height_mm - 1.0:
            raise ValueError(f"the scene reaches {top:.1f} mm, too close to the projector at {self.rig.projector_height_mm} mm")
        refl = np.where(m[..., None], smp.reflectance, self.rig.plate_reflectance).astype(np.float32)
        return Surface(h, np.where(m, smp.grad_x, 0.0), np.where(m, smp.grad_y, 0.0), refl)

    def object_surface(self, t: float | None = None, fine: bool = True) -> Surface:
        """Plate plus the object displaced to its position at time ``t`` (None = at rest)."""
        smp, dz = self._object(t, fine)
        if self.motion(t)[0] != 0.0:
            return self._compose(smp, dz)
        key = "fine" if fine else "coarse"
        if key not in self._rest_surface:
            self._rest_surface[key] = self._compose(smp, 0.0)
        rest = self._rest_surface[key]
        if dz == 0.0:
            return rest
        return Surface(rest.height + dz * smp.mask, rest.grad_x, rest.grad_y, rest.reflectance, rest.cache)

    def plate_surface(self, z_mm: float = 0.0, fine: bool = True) -> Surface:
        """The bare reference plate lifted to ``z_mm``."""
        x = self._xf if fine else self._xc
        zero = np.zeros(x.shape)
        refl = np.broadcast_to(self.rig.plate_reflectance.astype(np.float32), x.shape + (3,))
        return Surface(np.full(x.shape, float(z_mm)), zero, zero, refl, self._plate_cache)

    def ground_truth(self, t: float | None) -> NDArray[np.float32]:
        """True height (mm, float32) at every pixel centre at time ``t``.

        With a lens: the height of the point the pixel centre's (G) ray meets (:meth:`view_truth`).
        """
        if self.lens is not None:
            return self.view_truth(t)[0]
        return self.object_surface(t, fine=False).height.astype(np.float32)

    def view_truth(self, t: float | None) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Height (H, W) and plate ``X, Y`` (H, W, 2), mm, of the point each pixel centre sees.

        The G channel's ray through the pixel centre; NaN where it leaves the simulated plate.
        Without a lens: ``u * pitch``, ``v * pitch`` and :meth:`ground_truth`.
        """
        if self.lens is None:
            xc, yc = self.grid.mesh(fine=False)
            return self.ground_truth(t), np.stack([xc, yc], axis=-1).astype(np.float32)
        surf = self.object_surface(t, fine=True)
        x, y, h = self._cast(surf, 1, fine=False)
        off = self._off_plate(x, y)
        h, x, y = (np.where(off, np.nan, a) for a in (h, x, y))
        return h.astype(np.float32), np.stack([x, y], axis=-1).astype(np.float32)

    # ---------------------------------------------------------------- light
    def lighting(self, surf: Surface) -> Lighting:
        """Ray footprints, Lambertian cosine and cast shadows of a fine-grid surface."""
        rig = self.rig
        x0 = projector_ray_x0(self._xf, surf.height, rig.projector_x_mm, rig.projector_height_mm)
        if rig.lambertian:
            if "lambert" not in surf.cache:
                surf.cache["lambert"] = tuple(
                    p.astype(np.float32)
                    for p in lambert_parts(self._xf, self._yf, surf.grad_x, surf.grad_y, rig.projector_xyz[:2])
                )
            lz = (rig.projector_height_mm - surf.height).astype(np.float32)
            irr = lambert_from_parts(surf.cache["lambert"], lz)
        else:
            irr = np.ones(surf.height.shape, np.float32)
        if rig.shadows:
            shadow = cast_shadow_mask(surf.height, self._xf[0], rig.projector_x_mm, rig.projector_height_mm, x0_mm=x0)
            irr = np.where(shadow, np.float32(0.0), irr)
        else:
            shadow = np.zeros(surf.height.shape, dtype=bool)
        return Lighting(x0, irr, shadow | (irr <= 0.0))

    def radiance(self, surf: Surface, light: Lighting, pattern: Pattern,
                 weights: NDArray[np.float32] | None = None) -> NDArray[np.float32]:
        """Eq. 7 on the fine grid, box-averaged to camera pixels: ``r_k (E g_k + a_k)``.

        ``weights`` (rows, 3): the projector's light ``r_k E g_k`` reaching each camera row is
        multiplied by them (a colour-sequential projector); the ambient term is not.
        """
        y0 = None
        if pattern.source is not None and not pattern.source.row_constant:  # an image whose rows differ
            rig = self.rig
            y0 = projector_ray_x0(self._yf, surf.height, rig.projector_y_mm, rig.projector_height_mm)
        em = light.irradiance[..., None] * emitted_rgb(pattern, light.x0, self.rig, y0)
        if weights is not None:
            em *= surf.reflectance
            out = self.to_camera(em, surf) * weights[:, None, :]
            out += self.to_camera(surf.reflectance * self.rig.ambient.astype(np.float32), surf)
            return out
        em += self.rig.ambient.astype(np.float32)
        em *= surf.reflectance
        return self.to_camera(em, surf)

    # ---------------------------------------------------------------- lens
    def _lens_margin(self) -> int:
        """Plate-grid margin (camera px) that holds every point the lens shows beyond the image."""
        assert self.lens is not None
        w, h = self.grid.width, self.grid.height
        u = np.concatenate([np.arange(w), np.arange(w), np.zeros(h), np.full(h, w - 1.0)]).astype(np.float64)
        v = np.concatenate([np.zeros(w), np.full(w, h - 1.0), np.arange(h), np.arange(h)]).astype(np.float64)
        over = 0.0
        for k in (0, 1, 2):
            ui, vi = self.lens.ideal_pixels(u, v, k)
            over = max(over, float(np.max(-ui)), float(np.max(ui - (w - 1))), float(np.max(-vi)), float(np.max(vi - (h - 1))))
        return int(np.ceil(max(over, 0.0))) + 3

    def _ideal_samples(self, channel: int, fine: bool) -> tuple[F64, F64]:
        """Undistorted image coordinates of the camera's (sub-)samples of one channel."""
        key = (channel if self.lens is not None and self.lens.ca_scale(channel) != 1.0 else 1, fine)
        if key not in self._ideal:
            assert self.lens is not None
            n = self.grid.supersample if fine else 1
            off = (np.arange(n) + 0.5) / n - 0.5
            us = (np.arange(self.grid.width)[:, None] + off[None, :]).ravel()
            vs = (np.arange(self.grid.height)[:, None] + off[None, :]).ravel()
            uu, vv = np.meshgrid(us, vs)
            self._ideal[key] = self.lens.ideal_pixels(uu, vv, key[0])
        return self._ideal[key]

    def _plate_index(self, x: F64, y: F64) -> tuple[F64, F64]:
        """Fractional (row, column) of plate positions on the fine plate grid."""
        n, p, m = self.grid.supersample, self.grid.pitch_mm, self.margin_px
        return (y / p + m + 0.5) * n - 0.5, (x / p + m + 0.5) * n - 0.5

    def _off_plate(self, x: F64, y: F64) -> NDArray[np.bool_]:
        r, c = self._plate_index(x, y)
        rows, cols = self._xf.shape
        return ~((r >= 0) & (r <= rows - 1) & (c >= 0) & (c <= cols - 1) & np.isfinite(r) & np.isfinite(c))

    def _cast(self, surf: Surface, channel: int, fine: bool) -> tuple[F64, F64, F64]:
        """Plate ``(X, Y, h)`` met by the rays of one channel's (sub-)samples on a fine surface."""
        assert self.lens is not None
        ui, vi = self._ideal_samples(channel, fine)
        hmap = surf.height

        def height_at(x: F64, y: F64) -> F64:
            r, c = self._plate_index(x, y)
            return map_coordinates(hmap, [r, c], order=1, mode="nearest")

        lo, hi = float(hmap.min()), float(hmap.max())
        return self.lens.cast(ui, vi, height_at, (lo, hi), 0.5 * self.grid.fine_pitch_mm)

    def _sampling(self, surf: Surface) -> list[tuple[F64, F64]]:
        """Per channel, the fine plate-grid (row, column) each camera sub-sample takes its light from."""
        if "maps" not in surf.view:
            maps: dict[float, tuple[F64, F64]] = {}
            out = []
            for k in range(3):
                sc = self.lens.ca_scale(k) if self.lens is not None else 1.0
                if sc not in maps:
                    x, y, _ = self._cast(surf, k, fine=True)
                    maps[sc] = self._plate_index(x, y)
                out.append(maps[sc])
            surf.view["maps"] = out
        return surf.view["maps"]

    def to_camera(self, fine_img: NDArray[np.floating], surf: Surface) -> NDArray[np.float32]:
        """A fine-grid image of ``surf`` (``(rows, cols, 3)``) as the camera's pixels receive it.

        Without a lens: the box average (:meth:`Grid.downsample`). With one: each sub-sample
        takes channel ``k`` from the plate point its channel-``k`` ray meets (bilinear), then
        the box average.
        """
        if self.lens is None:
            return self.grid.downsample(fine_img)
        a = np.asarray(fine_img, dtype=np.float32)
        maps = self._sampling(surf)
        out = np.empty(maps[1][0].shape + (a.shape[2],), np.float32)
        for k in range(a.shape[2]):
            out[..., k] = map_coordinates(a[..., k], maps[k], order=1, mode="nearest")
        return self.grid.downsample(out)

    # ---------------------------------------------------------------- captures
    def capture(
        self,
        pattern: Pattern,
        *,
        t: float | None = None,
        plane_z: float | None = None,
        rng: np.random.Generator | None = None,
        colour_phase: float | None = None,
    ) -> NDArray[np.uint8] | NDArray[np.uint16]:
        """One camera image.

        Parameters
        ----------
        pattern : Pattern
            What the projector shows.
        t : float, optional
            Instant (s) for a capture of the moving object; ``None`` = object at rest.
        plane_z : float, optional
            Capture the bare plate lifted to this height instead of the object.
        rng : numpy.random.Generator, optional
            Noise source (``None``: noiseless).
        colour_phase : float, optional
            Colour-cycle start phase of a colour-sequential projector (:meth:`colour_phase`);
            ignored without one (default 0).
        """
        seq = self.sequence is not None
        phase = float(colour_phase or 0.0)
        if plane_z is not None:
            surf = self.plate_surface(plane_z)
            w = self.channel_weights(phase)[0] if seq else None
            rad = self.radiance(surf, self.lighting(surf), pattern, w)
        else:
            times = [None] if t is None else self.exposure_times(t)
            ws = self.channel_weights(phase, len(times)) if seq else None
            rad = np.zeros((self.grid.height, self.grid.width, 3), np.float32)
            for j, ti in enumerate(times):
                surf = self.object_surface(ti)
                rad += self.radiance(surf, self.lighting(surf), pattern, None if ws is None else ws[j])
            rad /= np.float32(len(times))
        return camera_response(rad, self.rig, rng)

    def uniform_capturer(
        self, plane_z: float | None = None
    ) -> Callable[..., NDArray[np.uint8] | NDArray[np.uint16]]:
        """A fast capture function for uniform patterns (white, hue bands) of a static surface.

        For a uniform projected colour ``c`` the radiance ``r (E c + a)`` is affine in ``c``, and
        so is the lens blur; both parts are computed once. The returned function takes
        ``(pattern, rng, colour_phase=None)`` (:meth:`capture`).
        """
        surf = self.plate_surface(plane_z) if plane_z is not None else self.object_surface(None)
        light = self.lighting(surf)
        sig = self.rig.lens_blur_sigma_px
        lit = lens_blur(self.to_camera(surf.reflectance * light.irradiance[..., None], surf), sig)
        amb = lens_blur(self.to_camera(surf.reflectance * self.rig.ambient, surf), sig)
        rig = self.rig

        def capture(pattern: Pattern, rng: np.random.Generator | None,
                    colour_phase: float | None = None) -> NDArray[np.uint8] | NDArray[np.uint16]:
            if pattern.kind != "uniform":
                raise ValueError("uniform_capturer only handles uniform patterns")
            c = emitted_rgb(pattern, None, rig)
            if self.sequence is not None:  # per-row weights of the projector's light
                w = self.channel_weights(float(colour_phase or 0.0))[0]
                return camera_response(lit * (c * w)[:, None, :] + amb, rig, rng, blurred=True)
            return camera_response(lit * c + amb, rig, rng, blurred=True)

        return capture


def simulate_capture(
    cfg: dict[str, Any],
    pattern: Pattern,
    *,
    t: float | None = None,
    plane_z: float | None = None,
    rng: np.random.Generator | None = None,
) -> NDArray[np.uint8] | NDArray[np.uint16]:
    """One capture of a configured bench (convenience wrapper around :class:`Bench`).

    Parameters
    ----------
    cfg : dict
        Validated bench configuration.
    pattern : Pattern
        What is projected.
    t : float, optional
        Instant of the moving object (``None`` = at rest).
    plane_z : float, optional
        Capture the bare plate at this height instead of the scene.
    rng : numpy.random.Generator, optional
        Noise source; ``None`` = noiseless.
    """
    return Bench(cfg).capture(pattern, t=t, plane_z=plane_z, rng=rng)
