"""The toy rig: a tiny per-pixel forward model of a projector-camera rig, for tests and benchmarks.

Where the virtual bench (:mod:`huefringe.bench`, :class:`huefringe.bench.Rig`) simulates a whole
rig with geometry, optics and a scene, :class:`ToyRig` is paper eqs. 6-8 per pixel and channel
on a reflectance map, with camera crosstalk, the projector column equal to the camera column::

    emitted   e_k  = round(255 I_k) / 255                     (8-bit projector)
    projector p_k  = e_k ** gamma_k                            (eq. 6)
    surface   o_k  = r_k(x, y) (p_k + a_k)                     (eq. 7)
    camera    c    = alpha * (M @ o + b) + noise               (eq. 8, M = 3x3 crosstalk)
    stored         = clip(round(c * (2^bits - 1)) / (2^bits - 1), 0, 1)

It imports nothing of the bench's simulator: the calibration tests check the measuring code on a
model independent of the bench, and the kernel benchmark renders its bands and frames with it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from huefringe.patterns import TWO_PI, band_rgb, trapezoid_rgb

__all__ = ["BandReader", "ToyRig", "surface_rows"]


@dataclass
class ToyRig:
    """The toy rig on ``reflectance`` ``(H, W, 3)``; ``capture`` returns float32 in [0, 1] at ``bits``."""

    reflectance: np.ndarray  # (H, W, 3)
    gamma: tuple[float, float, float] = (2.2, 2.2, 2.2)
    crosstalk: np.ndarray = field(default_factory=lambda: np.eye(3))
    ambient_proj: tuple[float, float, float] = (0.0, 0.0, 0.0)  # a_k
    ambient_cam: tuple[float, float, float] = (0.0, 0.0, 0.0)  # b_k
    alpha: tuple[float, float, float] = (0.9, 0.9, 0.9)
    noise: float = 0.002
    bits: int = 8
    seed: int = 0

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self.reflectance = np.asarray(self.reflectance, dtype=np.float64)

    @property
    def shape(self) -> tuple[int, int]:
        return self.reflectance.shape[:2]

    def capture(self, emitted: np.ndarray, *, noise: float | None = None) -> np.ndarray:
        """Capture of a projected code image (any shape broadcastable to (H, W, 3)), float32."""
        e = np.round(np.clip(np.asarray(emitted, dtype=np.float64), 0, 1) * 255.0) / 255.0
        p = e ** np.asarray(self.gamma)
        o = self.reflectance * (p + np.asarray(self.ambient_proj))
        c = np.asarray(self.alpha) * (o @ np.asarray(self.crosstalk).T + np.asarray(self.ambient_cam))
        sigma = self.noise if noise is None else noise
        if sigma > 0:
            c = c + self.rng.normal(0.0, sigma, c.shape)
        full = float(2**self.bits - 1)
        return np.clip(np.round(c * full) / full, 0.0, 1.0).astype(np.float32)

    def white(self) -> np.ndarray:
        return self.capture(np.ones(3))

    def band(self, i: int, n_bands: int) -> np.ndarray:
        return self.capture(band_rgb(i, n_bands))

    def fringe(self, period_px: float, *, phase0: float = 0.0, noise: float | None = None,
               phase_map: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Capture of the trapezoid along columns (camera column = projector column) and its true code phase."""
        h, w = self.shape
        true = np.mod(phase0 + TWO_PI * np.arange(w) / period_px, TWO_PI)
        emit_phase = true if phase_map is None else phase_map
        img = self.capture(trapezoid_rgb(emit_phase)[None, :, :], noise=noise)
        return img, np.broadcast_to(true[None, :], (h, w)).astype(np.float64)


class BandReader:
    """``read`` callable for build_table: paths are (band, repeat) tuples; records call order."""

    def __init__(self, rig: ToyRig, n_bands: int):
        self.rig, self.n_bands = rig, n_bands
        self.calls: list[tuple[int, int]] = []

    def paths(self, repeats: int) -> list[list[tuple[int, int]]]:
        return [[(i, r) for r in range(repeats)] for i in range(self.n_bands)]

    def __call__(self, key: tuple[int, int]) -> np.ndarray:
        self.calls.append(key)
        return self.rig.band(key[0], self.n_bands)


def surface_rows(h: int, w: int, rows: list[tuple[int, tuple[float, float, float]]]) -> np.ndarray:
    """Reflectance map made of horizontal stripes: ``rows = [(n_rows, (r, g, b)), ...]``."""
    out = np.zeros((h, w, 3))
    v = 0
    for n, rgb in rows:
        out[v : v + n] = rgb
        v += n
    assert v == h, (v, h)
    return out
