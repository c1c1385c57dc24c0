"""Analytic captures of a codecs sequence: known projector coordinates per camera pixel.

The camera sees a smooth warp of the projector (a homography-like map with a gentle bend), each
frame ``I = A + B * pattern(u)`` plus shot and read noise of a bench-like 8-bit camera (full well
15000 e- at full scale, read noise 0.6 DN), quantised to 8 or 16 bits.
"""

from __future__ import annotations

import numpy as np

from huefringe.codecs import FlatBlock, GrayBlock, PhaseBlock, SequenceSpec
from huefringe.codecs.graycode import index_to_gray

FULL_WELL_E = 15000.0
READ_DN = 0.6


def warp(shape: tuple[int, int], spec: SequenceSpec, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Projector coordinates (ux, uy) of each camera pixel: the projector seen slightly rotated, bent."""
    rng = np.random.default_rng(seed)
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    sx = (spec.projector_width - 80) / w
    sy = (spec.projector_height - 80) / h
    a = rng.uniform(-0.04, 0.04)
    ux = 20 + sx * (xx + a * yy) + 3e-5 * sx * (xx - w / 2) ** 2
    uy = 20 + sy * (0.9 * yy + 0.05 * h + 0.5 * a * (xx - w / 2)) + 2e-5 * sy * (yy - h / 2) ** 2
    return ux, uy


def render(spec: SequenceSpec, ux: np.ndarray, uy: np.ndarray, *, bits: int = 8, a_frac: float = 0.12,
           b_frac: float = 0.40, seed: int = 1, noise: bool = True) -> np.ndarray:
    """Captures of ``spec`` at camera pixels with projector coordinates ``ux``, ``uy``."""
    rng = np.random.default_rng(seed)
    full = float(2**bits - 1)
    u = {"x": ux, "y": uy}
    frames = []
    for b, _ in spec.slices():
        if isinstance(b, FlatBlock):
            pats = [np.full(ux.shape, 1.0 if b.level == "white" else 0.0)]
        elif isinstance(b, PhaseBlock):
            c = u[b.axis]
            pats = [(0.5 + 0.5 * np.cos(2 * np.pi * (c - b.origin_px) / b.period_px + d)) ** (b.encoding_gamma * spec.projector_gamma)
                    for d in b.shifts_rad]
        else:
            g = index_to_gray(np.floor((u[b.axis] + 0.5) / b.code_cell_px).astype(np.int64))
            pats = []
            for k in range(b.code_bits - 1, -1, -1):
                bit = ((g >> k) & 1).astype(np.float64)
                pats.append(bit)
                if b.inverse:
                    pats.append(1.0 - bit)
        for p in pats:
            i = full * (a_frac + 2 * b_frac * p)
            if noise:
                var = (READ_DN * full / 255) ** 2 + i * full / FULL_WELL_E
                i = i + rng.standard_normal(i.shape) * np.sqrt(var)
            frames.append(np.clip(np.round(i), 0, full).astype(np.uint8 if bits == 8 else np.uint16))
    return np.stack(frames)
