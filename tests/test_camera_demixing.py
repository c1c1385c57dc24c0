"""The colour-demixing estimate on bench sessions against the bench's own crosstalk, and the ``auto``
gate's leave-out check (docs/accuracy.md, "Colour crosstalk: the demixing")."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from bench_helpers import CONFIG, bench_config, write
from huefringe import camera
from huefringe.patterns import band_rgb
from huefringe.session import load_session
from huefringe.pipeline import session_camera_record

#: test_rig_chain's coarse plain gauge: 160 x 120 px at 0.5 mm, period 24 px, 16 bands x 2 repeats
COARSE = {"width": 160, "height": 120, "pixel_pitch_mm": 0.5, "period_px": 24, "hue_bands": 16, "repeats": 2,
          "frames": 1, "id": "coarse"}
#: a strong crosstalk (rows camera R, G, B; columns projector R, G, B)
STRONG = [[0.75, 0.20, 0.05], [0.15, 0.70, 0.15], [0.05, 0.20, 0.75]]


def _truth(cfg: dict) -> np.ndarray:
    """The bench camera's response to the projector primaries, columns scaled to a unit diagonal."""
    m = np.asarray(cfg["camera"]["crosstalk"], np.float64) * np.asarray(cfg["camera"]["sensitivity"])[None, :]
    return m / np.diag(m)[None, :]


@pytest.mark.parametrize(("crosstalk", "bits", "repeats", "tol"), [
    (None, 16, 2, 1e-3),  # the preset's 10 % crosstalk; measured error 1.6e-4, spread 1.9e-4
    (STRONG, 8, 1, 1e-3),  # strong, 8 bit, one repeat; measured error 1.9e-4, spread 1.6e-4
])
def test_estimate_on_a_coarse_bench_session_is_the_bench_crosstalk(tmp_path: Path, crosstalk, bits: int,
                                                                   repeats: int, tol: float) -> None:
    cfg = bench_config("plain_gauge", **{**COARSE, "bit_depth": bits, "repeats": repeats})
    if crosstalk is not None:
        cfg["camera"]["crosstalk"] = crosstalk
    s = load_session(write(cfg, tmp_path))
    rec = session_camera_record(s, CONFIG["camera"], CONFIG["calibration"])["colour_demixing"]
    est = rec["estimate"]
    want = _truth(cfg)
    err = np.abs(np.asarray(est["matrix"]) - want).max()
    print("estimate error", err, "segment spread", est["max_segment_spread"], "noise gain", rec.get("noise_gain"))
    assert rec["setting"] == "auto" and rec["applied"], rec
    assert err < tol
    # the leave-out check: each primary's two ramp segments agree within the bands' noise
    assert est["max_segment_spread"] < tol < camera.DEMIX_MAX_SEGMENT_SPREAD
    np.testing.assert_allclose(np.asarray(rec["demix"]) @ want, np.eye(3), atol=3 * tol)
    # a demixed channel's noise: the inverse's row norms (10 % crosstalk: 1.02-1.03; strong: 1.10-1.16)
    gain = np.sqrt((np.linalg.inv(want) ** 2).sum(axis=1))
    np.testing.assert_allclose(rec["noise_gain"], gain, rtol=0.01)
    assert min(rec["noise_gain"]) > 1.0


def _plate_bands(n: int, mix: np.ndarray, band_gain=None) -> dict[int, np.ndarray]:
    """The bands estimate_channel_mixing reads, of a plate (reflectance 0.3-0.7 per pixel and
    primary, gamma 2.2 / 1.9 / 2.4, ambient, black level) seen through ``mix``; ``band_gain(i)``
    scales band i's exposure (a camera's auto exposure left on)."""
    rng = np.random.default_rng(5)
    refl = rng.uniform(0.3, 0.7, (40, 50, 3))
    gamma = np.array([2.2, 1.9, 2.4])
    out = {}
    for _, first, last, _ in camera.mixing_band_pairs(n):
        for i in (first, last):
            g = 1.0 if band_gain is None else band_gain(i)
            out[i] = np.clip(g * (refl * (0.02 + 0.98 * band_rgb(i, n) ** gamma)) @ mix.T * 0.8 + 0.01, 0, 1)
    return out


def test_gate_refuses_bands_that_show_no_fixed_mixing() -> None:
    mix = _truth(bench_config("plain_gauge"))
    good = camera.estimate_channel_mixing(_plate_bands(32, mix), 32)
    assert good["max_segment_spread"] < 1e-12 and camera.demixing_record("auto", good)["applied"]
    # auto exposure left on: every band 1.5 % brighter than the one before. The sum of changes
    # still reads a plausible matrix (4.3e-2 off the truth), but the rising and falling segments disagree
    drift = camera.estimate_channel_mixing(_plate_bands(32, mix, lambda i: 1.015 ** i), 32)
    assert drift["estimable"]
    spread = drift["max_segment_spread"]
    assert spread > 3 * camera.DEMIX_MAX_SEGMENT_SPREAD  # measured 0.104 (0.2 % a band: 0.014)
    rec = camera.demixing_record("auto", drift)
    assert not rec["applied"] and "demix" not in rec
    assert "leave-out check failed" in rec["not_applied_because"] and f"{spread:.4f}" in rec["not_applied_because"]
    assert rec["estimate"]["max_segment_spread"] == spread
    forced = camera.demixing_record(True, drift)  # "true": the user's decision, applied anyway
    assert forced["applied"] and "not_applied_because" not in forced
    # a camera that stores gamma-encoded values (output ** (1 / 2.2), as sRGB): no linear mixing to undo,
    # the pooled estimate 0.05-0.06 off the crosstalk, the segments 0.19-0.20 apart (measured, 16-96 bands)
    for n in (16, 96):
        encoded = camera.estimate_channel_mixing({i: v ** (1 / 2.2) for i, v in _plate_bands(n, mix).items()}, n)
        assert encoded["estimable"] and encoded["max_segment_spread"] > 0.15
        assert not camera.demixing_record("auto", encoded)["applied"]
    # 11 bands: blue has one ramp segment only, nothing to check it against
    few = camera.estimate_channel_mixing(_plate_bands(11, mix), 11)
    assert few["estimable"] and few["max_segment_spread"] is None
    assert few["segment_spread"][0][2] is None and few["segment_spread"][0][1] is not None
    rec = camera.demixing_record("auto", few)
    assert not rec["applied"] and "fewer than 12 hue bands" in rec["not_applied_because"]
    # a camera without crosstalk: nothing to undo, and no reason to give
    none = camera.demixing_record("auto", camera.estimate_channel_mixing(_plate_bands(32, np.eye(3)), 32))
    assert not none["applied"] and "not_applied_because" not in none


def test_camera_json_without_the_check_reads_as_stored() -> None:
    """Records of estimates without the leave-out check (no ``max_segment_spread``) are not
    demixed by auto; the corrections a stored camera.json asks for are read as stored."""
    mix = _truth(bench_config("plain_gauge"))
    est = camera.estimate_channel_mixing(_plate_bands(32, mix), 32)
    old = copy.deepcopy(est)
    old.pop("max_segment_spread")
    assert not camera.demixing_record("auto", old)["applied"]
    rec = {"colour_demixing": camera.demixing_record("auto", est)}
    meta = {"camera": {"width": 50, "height": 40, "pixel_pitch_mm": 0.5}}
    reader = camera.corrections(rec, meta)[1]
    np.testing.assert_allclose(reader.demix, np.linalg.inv(mix), atol=1e-6)
