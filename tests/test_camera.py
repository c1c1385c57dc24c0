"""Camera corrections: Bayer mosaics and their demosaic."""

from __future__ import annotations

import numpy as np
import pytest

from huefringe import camera


@pytest.mark.parametrize("pattern", camera.BAYER_PATTERNS)
def test_channel_map_names_the_top_left_block(pattern: str) -> None:
    chan = camera.bayer_channel_map(pattern, 4, 6)
    assert ["RGB"[c] for c in chan[:2, :2].ravel()] == list(pattern)
    assert (chan[2:4, 2:4] == chan[:2, :2]).all()


@pytest.mark.parametrize("method", camera.DEMOSAIC_METHODS)
@pytest.mark.parametrize("pattern", camera.BAYER_PATTERNS)
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_demosaic_recovers_a_uniform_colour(pattern: str, method: str, dtype: type) -> None:
    # a uniform colour survives mosaic -> demosaic exactly in the interior, whatever the pattern
    scale = 255 if dtype is np.uint8 else 65535
    rgb = np.empty((16, 20, 3), dtype)
    rgb[...] = (np.array([0.9, 0.5, 0.2]) * scale).astype(dtype)
    out = camera.demosaic(camera.mosaic(rgb, pattern), pattern, method)
    assert out.dtype == dtype and out.shape == rgb.shape
    np.testing.assert_array_equal(out[2:-2, 2:-2], rgb[2:-2, 2:-2])


def test_edge_aware_beats_bilinear_on_a_colour_edge() -> None:
    # a sharp vertical red/blue edge: edge-aware demosaic leaves less false colour across it
    rgb = np.zeros((32, 32, 3), np.uint8)
    rgb[:, :16] = (200, 40, 40)
    rgb[:, 16:] = (40, 40, 200)
    raw = camera.mosaic(rgb, "RGGB")
    err = {m: np.abs(camera.demosaic(raw, "RGGB", m)[4:-4, 4:-4].astype(int) - rgb[4:-4, 4:-4]).mean()
           for m in camera.DEMOSAIC_METHODS}
    assert err["edge_aware"] <= err["bilinear"]


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        (np.zeros((8, 8, 3), np.uint8), "3 channels"),
        (np.zeros((7, 8), np.uint8), "even width and height"),
        (np.zeros((8, 8), np.float32), "8 or 16 bit"),
    ],
)
def test_demosaic_refuses_what_is_not_a_mosaic(raw: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        camera.demosaic(raw, "RGGB")


def test_unknown_pattern_is_named() -> None:
    with pytest.raises(ValueError, match="RGBG"):
        camera.demosaic(np.zeros((4, 4), np.uint8), "RGBG")
