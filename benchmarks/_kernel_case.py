"""The kernel benchmark's case: a realistic hue table, calibration and frame, in memory.

The toy rig (:class:`huefringe.bench.toy.ToyRig`, the forward model of the calibration tests:
per-channel projector gamma, camera crosstalk, ambient light, sensor noise, 8-bit quantisation)
on coloured and dark reflectance patches renders the ``N`` hue bands x ``R`` repeats, the white image and trapezoidal frames of a known height map, so that

* the hue table is built by :func:`huefringe.huetable.build_table` from captured bands (its
  columns are as bent and as noisy as real ones, with masked dark pixels), and
* the kernel's heights can be checked against the height map the frame was rendered from.

The plane calibration is analytic (``h = dphi / (a + b dphi)`` with a telecentric camera and a
pinhole projector 300 mm above the plate), so no calibration planes need rendering.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe.bench.toy import ToyRig
from huefringe.height import PlaneCalibration
from huefringe.huetable import HueTable, build_table
from huefringe.patterns import TWO_PI, band_rgb, trapezoid_rgb
from huefringe.texture import projector_off_light

GAMMA = np.array([2.2, 2.0, 2.4])
MIX = np.array([[0.90, 0.08, 0.02], [0.07, 0.86, 0.07], [0.02, 0.10, 0.88]])


def reflectance(h: int, w: int) -> NDArray[np.float32]:
    """Grey plate with red, green and dark patches and a black (masked) strip."""
    refl = np.full((h, w, 3), 0.85, dtype=np.float32)
    refl[h // 4 : h // 2, w // 8 : w // 3] = (0.85, 0.2, 0.12)
    refl[h // 4 : h // 2, w // 2 : 3 * w // 4] = (0.15, 0.6, 0.2)
    refl[2 * h // 3 :, : w // 3] = 0.12
    refl[2 * h // 3 :, w // 3 : w // 3 + max(4, w // 20)] = 0.003
    return refl


def camera(h: int, w: int, seed: int = 0, noise: float = 0.002) -> ToyRig:
    """The toy rig of the benchmark: :func:`reflectance` seen through gamma, crosstalk and ambient light."""
    return ToyRig(reflectance(h, w), gamma=tuple(GAMMA), crosstalk=MIX, ambient_proj=(0.02, 0.02, 0.02),
                  ambient_cam=(0.01, 0.01, 0.01), alpha=(0.9, 0.9, 0.9), noise=noise, bits=8, seed=seed)


def capture_codes(cam: ToyRig, emitted: NDArray[np.floating]) -> NDArray[np.uint8]:
    """The toy rig's capture as the 8-bit sensor codes a frame file would hold."""
    return np.round(cam.capture(emitted) * np.float32(255)).astype(np.uint8)


def analytic_calibration(h: int, w: int, period_px: float = 37.3, pitch_mm: float = 0.1,
                         projector_x_mm: float = 180.0, projector_h_mm: float = 300.0) -> PlaneCalibration:
    """Reference phase and ``a, b`` of a pinhole projector over a telecentric view (design.md)."""
    u = np.arange(w, dtype=np.float64)
    x = (u - w / 2) * pitch_mm
    k = TWO_PI / (period_px * pitch_mm)
    a = np.broadcast_to(k * (projector_x_mm - x) / projector_h_mm, (h, w))
    b = np.full((h, w), 1.0 / projector_h_mm)
    phi_ref = np.broadcast_to(np.mod(TWO_PI * u / period_px, TWO_PI), (h, w))
    return PlaneCalibration(phi_ref.astype(np.float32), np.ascontiguousarray(a, np.float32), b.astype(np.float32),
                            [0.0, 3.0, 6.0])


def height_map(h: int, w: int) -> NDArray[np.float64]:
    """Two blocks and a dome (mm), within the unambiguous range of :func:`analytic_calibration`."""
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    z = 1.5 * np.exp(-(((uu - 0.7 * w) / (0.15 * w)) ** 2 + ((vv - 0.7 * h) / (0.2 * h)) ** 2))
    z[h // 5 : h // 2, w // 10 : w // 3] += 2.0
    z[h // 5 : h // 2, w // 2 : 3 * w // 4] += 1.0
    return z


def frame_of(cam: ToyRig, cal: PlaneCalibration, z: NDArray[np.float64]) -> NDArray[np.uint8]:
    """Capture of the trapezoidal fringe on the surface ``z``: code phase ``phi_ref + dphi(z)``."""
    a = cal.a.astype(np.float64)
    b = cal.b.astype(np.float64)
    dphi = a * z / (1.0 - b * z)  # inverse of h = dphi / (a + b dphi)
    return capture_codes(cam, trapezoid_rgb(cal.phi_ref.astype(np.float64) + dphi).astype(np.float32))


@dataclass
class KernelCase:
    """What the kernel benchmark measures on: a table, a calibration, a white image and one frame of
    the known surface ``truth``."""

    table: HueTable
    cal: PlaneCalibration
    white: NDArray[np.float32]
    frame: NDArray[np.uint8]
    truth: NDArray[np.float64]
    build_seconds: float
    offset: NDArray[np.float64] | None = None
    """The light without fringe the texture correction takes out (``texture.projector_off_light`` of the bands)."""


def make_case(w: int, h: int, n_bands: int = 256, repeats: int = 2, seed: int = 0) -> KernelCase:
    """Build a table from captured bands (in memory) and render one frame of a known surface."""
    import time

    cam = camera(h, w, seed)
    white = capture_codes(cam, np.ones(3)).astype(np.float32) / np.float32(255)
    keys: Any = [[(i, r) for r in range(repeats)] for i in range(n_bands)]

    def read(key: tuple[int, int]) -> NDArray[np.float32]:
        return capture_codes(cam, band_rgb(key[0], n_bands)).astype(np.float32) * np.float32(1 / 255)

    t = time.perf_counter()
    table = build_table(keys, white, read=read)
    dt = time.perf_counter() - t
    cal = analytic_calibration(h, w)
    z = height_map(h, w)
    offset = projector_off_light((read((i, 0)), band_rgb(i, n_bands)) for i in range(n_bands)
                                 if np.any(band_rgb(i, n_bands) == 0.0)).astype(np.float64)  # as a job holds it
    return KernelCase(table, cal, white, frame_of(cam, cal, z), z, dt, offset)


def tile_case(rig: KernelCase, w: int, h: int) -> KernelCase:
    """The same case on a larger sensor by tiling the table and frame (cheap; timing only)."""
    h0, w0 = rig.table.shape
    ry, rx = -(-h // h0), -(-w // w0)

    def tile(x: NDArray[Any]) -> NDArray[Any]:
        reps = (ry, rx) + (1,) * (x.ndim - 2)
        return np.ascontiguousarray(np.tile(x, reps)[:h, :w])

    t = rig.table
    tab = np.ascontiguousarray(np.tile(np.asarray(t.table), (1, ry, rx))[:, :h, :w])
    table = HueTable(t.model, t.n_bands, tab, tile(t.valid), tile(t.start), tile(t.reason), tile(t.noise_rad),
                     dict(t.stats))
    cal = PlaneCalibration(tile(rig.cal.phi_ref), tile(rig.cal.a), tile(rig.cal.b), list(rig.cal.planes_mm))
    return KernelCase(table, cal, tile(rig.white), tile(rig.frame), tile(rig.truth), float("nan"),
                      None if rig.offset is None else tile(rig.offset))
