"""Camera colour crosstalk: its estimate from the reference bands, and the demixing that removes the
red gauge block's step bias (docs/accuracy.md, "Gauge-block steps")."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import tifffile

from huefringe import bench, metrology, patterns, stages
from huefringe.camera import CaptureReader, demixing_record, estimate_channel_mixing, mixing_band_pairs
from huefringe.settings import load_config

REPO = Path(__file__).resolve().parents[1]
CONFIG = load_config(REPO / "config.yaml")

#: the demo bench's camera crosstalk (rows camera R, G, B; columns projector R, G, B) and sensitivity
CROSSTALK = np.array([[0.90, 0.08, 0.02], [0.07, 0.86, 0.07], [0.02, 0.10, 0.88]])
SENS = np.array([0.95, 1.0, 0.9])


def _bands(n: int, m: np.ndarray, gamma=(2.2, 2.0, 2.4), reflect=(0.72, 0.13, 0.11), amb=0.02) -> np.ndarray:
    light = patterns.trapezoid_rgb(patterns.band_phase(np.arange(n), n)) ** np.asarray(gamma)
    return (np.asarray(reflect) * (light + amb)) @ m.T + 0.01


def _images(colours: np.ndarray) -> dict[int, np.ndarray]:
    """The bands estimate_channel_mixing reads, as uniform 20 x 20 px images of their colours."""
    n = colours.shape[0]
    idx = {i for _, a, b, _ in mixing_band_pairs(n) for i in (a, b)}
    return {i: np.broadcast_to(colours[i], (20, 20, 3)).astype(np.float64) for i in idx}


@pytest.mark.parametrize("n", [64, 72, 96])
def test_estimate_recovers_the_matrix_whatever_gamma_and_colour(n: int) -> None:
    m = CROSSTALK * SENS[None, :]
    est = estimate_channel_mixing(_images(_bands(n, m)), n)
    want = m / np.diag(m)[None, :]  # columns scaled to a unit diagonal
    assert est["estimable"]
    np.testing.assert_allclose(est["matrix"], want, atol=1e-9)
    none = estimate_channel_mixing(_images(_bands(n, np.diag(SENS))), n)
    rec_none = demixing_record("auto", none)
    assert rec_none["estimate"]["max_offdiagonal"] < 1e-9 and not rec_none["applied"]
    rec = demixing_record("auto", est)
    assert rec["estimate"]["max_offdiagonal"] == pytest.approx(0.10 / 0.86)
    assert rec["applied"] and not demixing_record(False, est)["applied"]
    # demixed, a red coating's colour is the plate's up to one gain per channel: white balance cancels it
    d = np.asarray(rec["demix"])
    red, plate = _bands(n, m, amb=0.0) - 0.01, _bands(n, m, reflect=(0.9, 0.9, 0.9), amb=0.0) - 0.01
    ratio = (red @ d.T) / (plate @ d.T)
    ok = (plate @ d.T) > 0.05
    for k in range(3):
        assert np.ptp(ratio[ok[:, k], k]) < 1e-9


def test_reader_keeps_clipped_pixels(tmp_path: Path) -> None:
    import cv2

    img = np.array([[[255, 10, 20], [200, 30, 40]]], np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), img[..., ::-1])
    d = np.linalg.inv(CROSSTALK)
    out = CaptureReader(demix=d).rgb(tmp_path / "a.png")
    np.testing.assert_allclose(out[0, 0], img[0, 0] / 255.0, atol=1e-7)  # clipped: as stored
    np.testing.assert_allclose(out[0, 1], d @ (img[0, 1] / 255.0), atol=1e-6)


@pytest.fixture(scope="module")
def demo_small(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo's rig and blocks (green 3, blue 1, red 4 mm) at 400 x 300 px, one frame at rest
    (smaller, the blocks' tops are so few pixels that one frame's noise hides the crosstalk's bias)."""
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("demo")))
    cfg["session"].update(width=400, height=300, frames=1)
    cfg["phase_shift"]["enabled"] = False
    cfg["vibration"]["amplitude_mm"] = 0.0
    return bench.write_session(cfg, tmp_path_factory.mktemp("demix") / "s")


def _steps(session: Path, out: Path, demixing) -> dict[str, float]:
    cfg = copy.deepcopy(CONFIG)
    cfg["camera"]["colour_demixing"] = demixing
    p = stages.measure_session(session, out, cfg)
    s = p["session"]
    ev = metrology.evaluate_session([tifffile.imread(h) for h in p["heights"]], s.specimen, s.pixel_pitch_mm,
                                 range_mm=max(s.planes_mm) - min(s.planes_mm))
    return {st["name"]: 1e3 * st["error_mm"] for st in ev["steps"]}


def test_demixing_removes_the_red_step_bias(demo_small: Path, tmp_path: Path) -> None:
    off = _steps(demo_small, tmp_path / "off", False)
    on = _steps(demo_small, tmp_path / "on", "auto")
    print("step errors um, demixing off", off, "on", on)
    # measured: red +12.9 -> +5.4 um; green +1.6 -> +3.9, blue +2.2 -> +4.8 um (one frame's step
    # means, U about 20 um: the demixed frame's noise is another draw)
    assert off["red"] > 9.0  # the crosstalk's bias on the red coating
    assert abs(on["red"]) < 7.5
    assert abs(on["green"] - off["green"]) < 3.5 and abs(on["blue"] - off["blue"]) < 3.5
