"""perframe.reference_frame_stats: frame_stats with unwrap's reference flags, value for value."""

from __future__ import annotations

import numpy as np
import pytest

from huefringe.perframe import frame_stats, reference_frame_stats
from huefringe.phase import unwrap

KW = dict(clipped_fraction=0.01, hue_undefined_fraction=0.02, table_invalid_fraction=0.03, shadow_fraction=0.1,
          hue_model="hexcone")


def _both(dphi, valid, height):
    flags = unwrap(dphi, valid, "reference").flags
    return frame_stats(valid, height, flags, unwrap_mode="reference", **KW), reference_frame_stats(dphi, valid, height,
                                                                                                   **KW)


@pytest.mark.parametrize("seed", range(12))
def test_random_maps_give_frame_stats_values(seed: int) -> None:
    rng = np.random.default_rng(seed)
    h, w = (int(x) for x in rng.integers(2, 70, 2))
    dphi = rng.uniform(-np.pi, np.pi, (h, w)).astype(np.float32)
    if seed % 2:  # smooth phase with wraps: real wrap edges and near-wrap pixels
        dphi = np.angle(np.exp(1j * (np.arange(w)[None, :] * 0.9 + np.arange(h)[:, None] * 0.3))).astype(np.float32)
    valid = rng.random((h, w)) > rng.uniform(0.0, 0.9)
    height = np.where(valid, rng.normal(0.0, 0.4, (h, w)), np.nan).astype(np.float32)
    if seed % 3 == 0:  # ties, as quantised heights have, and an even count
        height = np.round(height, 1).astype(np.float32)
    dphi[rng.random((h, w)) < 0.05] = np.nan  # valid pixels without a phase (flags skip them)
    a, b = _both(dphi, valid, height)
    assert a == b
    assert isinstance(b["median_height_mm"], float) or b["median_height_mm"] is None


def test_flags_and_median_on_a_known_map() -> None:
    dphi = np.zeros((4, 6), np.float32)
    dphi[:, 3:] = 3.0  # |3.0 - 0| < pi: no edge; near_wrap: |3.0| > 0.9 pi
    dphi[1, 1] = -3.0  # near_wrap, but its neighbours are 0 or -3.1: no edge
    dphi[2, 2] = 3.1
    dphi[2, 1] = -3.1  # a pair 6.2 apart: both pixels on a wrap edge
    valid = np.ones((4, 6), bool)
    valid[0, 0] = False
    height = np.arange(24, dtype=np.float32).reshape(4, 6) - 2.0
    a, b = _both(dphi, valid, height)
    assert a == b
    assert b["flags"]["wrap_edge"] == 2 and b["flags"]["near_wrap"] == 12 + 3
    assert b["flags"]["below_reference"] == 1  # -1 mm at (0, 1); the -2 at (0, 0) is invalid
    assert b["median_height_mm"] == float(np.median(height[valid])) == 10.0  # 23 values: the middle one
    assert b["valid_fraction"] == 23 / 24


def test_no_valid_pixel_and_a_nan_height_as_frame_stats() -> None:
    dphi = np.zeros((3, 4), np.float32)
    height = np.ones((3, 4), np.float32)
    a, b = _both(dphi, np.zeros((3, 4), bool), height)
    assert a == b and b["median_height_mm"] is None and b["valid_fraction"] == 0.0
    height[1, 2] = np.nan  # a valid pixel without a height: np.median gives NaN
    a, b = _both(dphi, np.ones((3, 4), bool), height)
    assert np.isnan(a["median_height_mm"]) and np.isnan(b["median_height_mm"])
    a.pop("median_height_mm"), b.pop("median_height_mm")
    assert a == b


@pytest.mark.parametrize("seed", range(6))
def test_flags_on_the_pixels_valid_before_the_filter(seed: int) -> None:
    """flag_valid: the wrap flags counted on measure_frame's pre-filter mask (its unwrap call),
    the valid fraction, below-reference count and median on the final one (a subset: the
    filter's rejects); on a wrapping phase this differs from counting on the final mask."""
    rng = np.random.default_rng(100 + seed)
    h, w = (int(x) for x in rng.integers(8, 60, 2))
    dphi = np.angle(np.exp(1j * (np.arange(w)[None, :] * 0.9 + np.arange(h)[:, None] * 0.3))).astype(np.float32)
    before = rng.random((h, w)) > 0.2
    dphi[~before] = np.nan  # the kernel's dphi: NaN where no phase was decoded
    after = before & (rng.random((h, w)) > 0.3)  # the filter rejects some pixels
    height = np.where(after, rng.normal(0.0, 0.4, (h, w)), np.nan).astype(np.float32)
    want = frame_stats(after, height, unwrap(dphi, before, "reference").flags, unwrap_mode="reference", **KW)
    got = reference_frame_stats(dphi, after, height, flag_valid=np.isfinite(dphi), **KW)
    assert got == want
    old = reference_frame_stats(dphi, after, height, **KW)  # flags on the final mask: fewer
    assert old["flags"]["near_wrap"] < got["flags"]["near_wrap"]
    assert old["valid_fraction"] == got["valid_fraction"] and old["median_height_mm"] == got["median_height_mm"]
