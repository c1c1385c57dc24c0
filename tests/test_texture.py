"""Texture-edge correction (huefringe.texture) against an analytic blurred capture."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from huefringe import texture


def _scene(sig: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:120, 0:160]
    # blocky two-level reflectance (sharp texture edges) per channel, smoothed a little
    blocks = rng.uniform(0.08, 0.9, (12, 16, 3)).astype(np.float32)
    r = cv2.resize(blocks, (160, 120), interpolation=cv2.INTER_NEAREST)
    r = cv2.GaussianBlur(r, (0, 0), 0.7)
    ph = 2 * np.pi * xx / 40.0
    f = np.stack([0.5 + 0.4 * np.cos(ph - k * 2 * np.pi / 3) for k in range(3)], -1).astype(np.float32)
    b = cv2.GaussianBlur(r * f, (0, 0), sig)
    w = cv2.GaussianBlur(r, (0, 0), sig)
    target = w * cv2.GaussianBlur(f, (0, 0), sig)  # what a uniform reflectance would give
    return b, w, target


@pytest.mark.parametrize("sig", [0.6, 0.9, 1.2])
def test_correction_removes_most_of_the_lean(sig: float) -> None:
    b, w, target = _scene(sig)
    inner = (slice(4, -4), slice(4, -4))
    before = np.sqrt(np.mean((b - target)[inner] ** 2))
    after = np.sqrt(np.mean((texture.correct(b, w, sig**2) - target)[inner] ** 2))
    assert after < 0.3 * before  # measured 0.16-0.20, (before, after)


def test_zero_blur_and_clipped_pixels_unchanged() -> None:
    b, w, _ = _scene(0.9)
    assert np.array_equal(texture.correct(b, w, 0.0), b.astype(np.float32))
    clipped = np.zeros(b.shape[:2], bool)
    clipped[10:20, 10:20] = True
    c = texture.correct(b, w, 0.81, clipped=clipped)
    assert np.array_equal(c[clipped], b[clipped].astype(np.float32))
    assert not np.array_equal(c[~clipped], b[~clipped].astype(np.float32))
