"""A colour-sequential projector and the camera's shutter on the bench, and the QA's row-banding detector."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from huefringe import bench
from huefringe.bench.colour_sequence import ColourSequence, Shutter, row_weights, start_phase
from huefringe.bench.radiometry import Pattern
from huefringe.bench.simulator import Bench
from huefringe.height import fit_poly2d
from huefringe.pipeline import _plane_phases, reference_colour_flicker, session_hue_table, session_plane_calibration
from huefringe.row_banding import (FLICKER_THRESHOLD_RAD, THRESHOLD_RAD, repeat_hue_flicker, row_banding,
                                   row_periodic_rms)
from huefringe.session import load_session

from bench_helpers import CONFIG

WHEEL = {"segments": "RGB", "duty": [1 / 3, 1 / 3, 1 / 3], "refresh_hz": 60.0, "cycles_per_refresh": 3.0}
CYCLE_S = 1.0 / 180.0


# ------------------------------------------------------------------ the weights


def test_integer_cycles_weigh_every_channel_one_whatever_the_start_and_shutter():
    seq = ColourSequence.from_config(WHEEL)
    for shutter in (Shutter("global"), Shutter("rolling", 37e-6)):
        for phase in (0.0, 0.123, 0.9):
            w = row_weights(seq, shutter, 2 * CYCLE_S, 300, phase)
            assert w.shape == (1, 300, 3) and np.abs(w - 1.0).max() < 1e-9
            slices = row_weights(seq, shutter, 2 * CYCLE_S, 300, phase, subframes=3)  # 2/3 cycle each
            assert np.abs(slices - 1.0).max() > 0.4 and np.abs(slices.mean(axis=0) - 1.0).max() < 1e-9


def test_one_and_a_half_cycles_from_red_give_the_analytic_shares():
    # window [0, 1.5 T]: R shown 2T/3, G T/2, B T/3, over 1.5 T / 3 each in a whole cycle
    seq = ColourSequence.from_config(WHEEL)
    w = row_weights(seq, Shutter("global"), 1.5 * CYCLE_S, 4, 0.0)[0]
    np.testing.assert_allclose(w, np.tile([4 / 3, 1.0, 2 / 3], (4, 1)), atol=1e-12)


def test_dark_spokes_and_duty_and_subframes():
    # R 0.5, G 0.25, B 0.15 of the cycle, 0.1 dark: half a cycle from phase 0 shows R only
    seq = ColourSequence.from_config({**WHEEL, "duty": [0.5, 0.25, 0.15], "cycles_per_refresh": 1.0})
    t = 1 / 60
    assert [s[0] for s in seq.segments] == [0, 1, 2]
    np.testing.assert_allclose(seq.segments[1][1], 0.5 + 0.1 / 3)
    w = row_weights(seq, Shutter("global"), 0.5 * t, 1, 0.0)[0, 0]
    np.testing.assert_allclose(w, [2.0, 0.0, 0.0], atol=1e-12)
    whole = row_weights(seq, Shutter("global"), 1.3 * t, 2, 0.2)[:, 0]
    slices = row_weights(seq, Shutter("global"), 1.3 * t, 2, 0.2, subframes=4)
    np.testing.assert_allclose(slices.mean(axis=0)[0], whole[0], atol=1e-12)


def test_rolling_weights_repeat_every_cycle_of_rows():
    seq = ColourSequence.from_config(WHEEL)
    line = CYCLE_S / 50.0  # a band every 50 rows
    w = row_weights(seq, Shutter("rolling", line), 2.25 * CYCLE_S, 200, 0.3)[0]
    np.testing.assert_allclose(w[50:], w[:-50], atol=1e-9)
    assert np.ptp(w[:, 0]) > 0.3  # a quarter cycle too much: a third of it is red, +-1/3 * 1/2.25 swings
    g = row_weights(seq, Shutter("global"), 2.25 * CYCLE_S, 200, 0.3)[0]
    assert np.ptp(g, axis=0).max() == 0.0


def test_start_phase_is_drawn_per_name_and_reproducible():
    sh = Shutter()
    a, b = start_phase(sh, 7, "object/white.png"), start_phase(sh, 7, "object/frames/frame_0000.png")
    assert a != b and a == start_phase(sh, 7, "object/white.png") and 0.0 <= a < 1.0
    assert start_phase(Shutter(start_phase=0.25), 7, "x") == 0.25


# ------------------------------------------------------------------ the bench


def _cfg(**over):
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("demo")))
    cfg["session"].update(width=200, height=200, hue_bands=24, repeats=1, frames=1, ground_truth=False)
    cfg["phase_shift"]["enabled"] = False
    cfg["camera"]["exposure_ms"] = 12.5
    if over.get("sequence"):
        cfg["projector"]["colour_sequence"] = dict(WHEEL)
        cfg["camera"]["exposure_ms"] = over["sequence"] * CYCLE_S * 1e3
    if over.get("line_us"):
        cfg["camera"]["shutter"] = {"kind": "rolling", "line_time_us": over["line_us"]}
    if over.get("noiseless"):
        cfg["camera"].update(full_well_e=None, read_noise_dn=0.0)
    tag = "-".join(f"{k}{v}" for k, v in sorted(over.items())).replace(".", "p").replace("_", "").lower()
    cfg["session"]["id"] = f"cs-{tag}" if over else "cs-3ccd"
    return bench.validate_bench_config(cfg)


def test_config_refuses_what_cannot_be_simulated():
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("flat")))
    cfg["projector"]["colour_sequence"] = dict(WHEEL)
    cfg["camera"]["exposure_ms"] = 0.0
    with pytest.raises(bench.BenchConfigError, match="exposure_ms > 0"):
        bench.validate_bench_config(cfg)
    cfg["camera"]["exposure_ms"] = 10.0
    cfg["projector"]["colour_sequence"]["duty"] = [0.5, 0.5, 0.5]
    with pytest.raises(bench.BenchConfigError, match="duty"):
        bench.validate_bench_config(cfg)
    cfg["projector"]["colour_sequence"]["duty"] = [0.3, 0.3, 0.3]
    cfg["camera"]["shutter"] = {"kind": "rolling"}
    with pytest.raises(bench.BenchConfigError, match="line_time_us"):
        bench.validate_bench_config(cfg)
    cfg["camera"]["shutter"] = {"kind": "rolling", "line_time_us": 20}
    assert bench.validate_bench_config(cfg)["camera"]["shutter"]["start_phase"] == "random"


def test_whole_cycles_capture_as_the_simultaneous_projector_does():
    plain, dlp = Bench(_cfg(noiseless=True)), Bench(_cfg(sequence=2, line_us=50, noiseless=True))
    a = plain.capture(Pattern.trapezoid(), plane_z=0.0).astype(int)
    b = dlp.capture(Pattern.trapezoid(), plane_z=0.0, colour_phase=dlp.colour_phase("x")).astype(int)
    assert np.abs(a - b).max() <= 1
    wa = plain.uniform_capturer(0.0)(Pattern.white(), None).astype(int)
    wb = dlp.uniform_capturer(0.0)(Pattern.white(), None, 0.7).astype(int)
    assert np.abs(wa - wb).max() <= 1


def test_rolling_white_rows_carry_the_weights_of_their_window():
    """The projector's light in each row is scaled by that row's weights; the ambient is not."""
    cfg = _cfg(sequence=2.25, line_us=50, noiseless=True)
    cfg["session"]["bit_depth"] = 16
    cfg["light"].update(ambient=0.0, stray=0.0)
    cfg["projector"]["power"] = 0.5  # no clipping at the weights' +33 %
    cfg["camera"].update(crosstalk=np.eye(3).tolist(), lens_blur_sigma_px=0.0)
    dlp, plain = Bench(cfg), Bench({**cfg, "projector": {k: v for k, v in cfg["projector"].items() if k != "colour_sequence"}})
    w = dlp.channel_weights(0.4)[0].astype(np.float64)
    got = dlp.uniform_capturer(0.0)(Pattern.white(), None, 0.4).astype(np.float64)
    ref = plain.uniform_capturer(0.0)(Pattern.white(), None).astype(np.float64)
    ratio = np.median(got / ref, axis=1)  # per row and channel
    np.testing.assert_allclose(ratio, w, rtol=2e-3)
    assert np.ptp(w[:, 0]) > 0.2


# ------------------------------------------------------------------ the detector


def _plane(shape=(300, 400), amp=0.0, noise=0.03, period_rows=110.0, seed=1):
    h, w = shape
    y, x = np.mgrid[:h, :w].astype(float)
    phi0 = 2 * np.pi * x / 60 + 0.3 * (x / w) ** 2 + 0.1 * y / h
    tri = 4 * np.abs((y / period_rows) % 1 - 0.5) - 1  # a triangle wave along the rows
    band = amp * tri / np.sqrt(np.mean(tri**2)) * np.sqrt(2) * np.sin(3 * phi0)  # RMS amp, sign varies along x
    rng = np.random.default_rng(seed)
    return np.mod(phi0 + band + noise * rng.standard_normal(shape), 2 * np.pi)


@pytest.mark.parametrize("amp", [0.03, 0.1])
def test_detector_recovers_an_injected_row_periodic_phase_error(amp):
    rb = row_banding(_plane(amp=amp), np.ones((300, 400), bool), period_px=60)
    assert rb.amplitude_rad == pytest.approx(amp, rel=0.05)
    assert rb.amplitude_px == pytest.approx(amp * 60 / (2 * np.pi), rel=0.05)
    assert rb.suspected and rb.period_rows == pytest.approx(100.0)  # the bin nearest 110 rows of 300


def test_detector_stays_quiet_on_noise_and_below_threshold():
    valid = np.ones((300, 400), bool)
    valid[:, :40] = False
    quiet = row_banding(_plane(noise=0.05), valid, period_px=60)
    assert quiet.amplitude_rad < 0.005 and not quiet.suspected and quiet.period_rows is None
    assert quiet.noise_rad == pytest.approx(0.05, rel=0.05)
    weak = row_banding(_plane(amp=0.01, noise=0.03), valid, period_px=60)
    assert weak.amplitude_rad == pytest.approx(0.01, rel=0.15) and not weak.suspected  # below THRESHOLD_RAD
    assert THRESHOLD_RAD == 0.02


def test_flicker_is_the_spread_of_the_repeats_mean_hue():
    rng = np.random.default_rng(3)
    offsets = [[0.0, 0.02, -0.02], [0.1, 0.1, 0.1], [6.27, 0.0, 0.0133]]  # the last one across the wrap
    hues = [[np.mod(2.0 + o + 0.05 * rng.standard_normal((60, 80)), 2 * np.pi) for o in band] for band in offsets]
    hues[0][0][:5] = np.nan
    fl = repeat_hue_flicker(hues)
    dev = [0.0, 0.02, -0.02, 0.0, 0.0, 0.0, 6.27 - 2 * np.pi - 0.0011, -0.0011, 0.0133 - 0.0011]
    assert fl.amplitude_rad == pytest.approx(np.sqrt(np.sum(np.square(dev)) / 6), rel=0.02)
    assert fl.bands == 3 and fl.repeats == 3 and fl.suspected
    assert fl.max_rad == pytest.approx(0.02, abs=1e-3)
    quiet = repeat_hue_flicker([[np.full((4, 4), 1.0), np.full((4, 4), 1.0 + 1e-4)]])
    assert quiet.amplitude_rad == pytest.approx(np.sqrt(2) * 5e-5) and not quiet.suspected
    none = repeat_hue_flicker([[np.full((4, 4), 1.0)]])
    assert none.amplitude_rad is None and not none.suspected and FLICKER_THRESHOLD_RAD == 0.005


def _phases(session: Path):
    s = load_session(session)
    cal = CONFIG["calibration"]
    t = session_hue_table(s, "reference", CONFIG["hue_model"], cal)
    return s, t, _plane_phases(s, t, CONFIG["hue_model"], cal)


def test_qa_fires_on_a_rolling_shutter_and_stays_quiet_on_3ccd_and_whole_cycles(tmp_path):
    out, flicker = {}, {}
    for name, over in {"3ccd": {}, "whole": {"sequence": 2, "line_us": 100},
                       "rolling": {"sequence": 2.25, "line_us": 100}, "global": {"sequence": 2.25}}.items():
        cfg = _cfg(**over)
        cfg["session"]["repeats"] = 2
        s, t, _ = _phases(bench.write_session(cfg, tmp_path / cfg["session"]["id"]))
        stats = session_plane_calibration(s, t, CONFIG["hue_model"], CONFIG["calibration"]).stats
        out[name], flicker[name] = stats["row_banding"], stats["colour_flicker"]
    # a global shutter: every image its own colour balance, uniform over it: the repeats disagree, no rows
    assert flicker["global"]["suspected"] and flicker["global"]["amplitude_rad"] > 5 * FLICKER_THRESHOLD_RAD
    assert not out["global"]["suspected"]
    for quiet in ("3ccd", "whole"):
        assert flicker[quiet]["amplitude_rad"] < 0.1 * FLICKER_THRESHOLD_RAD and not flicker[quiet]["suspected"]
    assert not out["3ccd"]["suspected"] and not out["whole"]["suspected"]
    assert out["3ccd"]["amplitude_rad"] < 0.25 * THRESHOLD_RAD and out["whole"]["amplitude_rad"] < 0.25 * THRESHOLD_RAD
    rb = out["rolling"]
    assert rb["suspected"] and rb["amplitude_rad"] > 5 * THRESHOLD_RAD
    assert rb["period_rows"] == pytest.approx(1e6 * CYCLE_S / 100, rel=0.25)  # a band every 55.6 rows
    assert rb["amplitude_mm"] > 0.0

    # the bench's injected error: the same images without noise, against the simultaneous projector's
    phase = {}
    for name, over in {"plain": {"noiseless": True}, "dlp": {"sequence": 2.25, "line_us": 100, "noiseless": True}}.items():
        cfg = _cfg(**over)
        cfg["session"]["repeats"] = 2
        _, _, (ph, valid) = _phases(bench.write_session(cfg, tmp_path / cfg["session"]["id"]))
        phase[name] = (ph, valid)
    for z, key in ((0.0, "0.000"), (3.0, "3.000"), (6.0, "6.000")):
        ok = phase["plain"][1][z] & phase["dlp"][1][z]
        d = np.angle(np.exp(1j * (phase["dlp"][0][z] - phase["plain"][0][z])))  # small: no unwrapping
        injected = row_periodic_rms(d - fit_poly2d(d, ok, 3), ok)[0]
        assert rb["planes"][key]["amplitude_rad"] == pytest.approx(injected, rel=0.15), z


def test_flicker_qa_takes_the_reference_tables_hue_and_gives_the_numbers_of_reading_again(tmp_path):
    from huefringe.huetable import HueTable

    cfg = _cfg(sequence=2.25)
    cfg["session"]["repeats"] = 3
    s = load_session(bench.write_session(cfg, tmp_path / cfg["session"]["id"]))
    cal = CONFIG["calibration"]
    t = session_hue_table(s, "reference", CONFIG["hue_model"], cal)
    t.save(tmp_path / "ref.npz")
    loaded = HueTable.load(tmp_path / "ref.npz")
    rec = loaded.stats["colour_flicker_means"]
    assert rec["bands"] == [0, 2, 3, 4, 6, 8, 9, 10, 12, 14, 15, 16, 18, 20, 21, 22]     # 16 of 24, evenly spread
    assert all(len(m) == 3 and all(isinstance(v, float) for v in m) for m in rec["mean_hue_rad"])
    assert rec["floor"] == 0.5 * float(cal["min_intensity"]) == loaded.stats["params"]["floor"]   # the table's own

    class NoReading:
        def rgb(self, path):
            raise AssertionError(f"{path} read again")

    from_table = reference_colour_flicker(s, CONFIG["hue_model"], cal, NoReading(), table=loaded)
    read_again = reference_colour_flicker(s, CONFIG["hue_model"], cal)
    assert from_table == read_again                                   # every QA number bit for bit
    assert from_table["suspected"] and from_table["amplitude_rad"] > 5 * FLICKER_THRESHOLD_RAD
    assert from_table["bands"] == 16 and from_table["repeats"] == 3
    # another hue model or minimum saturation than the table's: the images are read again
    other = {**cal, "min_saturation": float(cal["min_saturation"]) + 0.01}
    with pytest.raises(AssertionError, match="read again"):
        reference_colour_flicker(s, CONFIG["hue_model"], other, NoReading(), table=loaded)
    # a table whose means do not say their white-balance floor: read again
    loaded.stats["colour_flicker_means"] = {k: v for k, v in rec.items() if k != "floor"}
    with pytest.raises(AssertionError, match="read again"):
        reference_colour_flicker(s, CONFIG["hue_model"], cal, NoReading(), table=loaded)
