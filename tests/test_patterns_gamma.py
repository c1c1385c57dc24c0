"""Pre-compensated phase-shift files (``huefringe patterns --compensated``): the projector's
per-channel gamma read off a plate hue table, the sinusoids driven through its inverse, and the
refusals of a table that cannot give the response. The files route on the bench (captured phase
against the truth) is in tests/test_rig_chain.py."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from huefringe import cli, colour
from huefringe.compensation import GammaFitError, linearised_levels, projector_gamma
from huefringe.huetable import RAD_PER_COUNT, HueTable
from huefringe.patterns import TWO_PI, band_rgb, phase_shift_intensity, quantise
from huefringe.phase import three_step_phase, wrap
from huefringe.projection import PHASE_SHIFT_LEVELS, PatternsError, write_patterns

#: A camera with the bench presets' crosstalk and ambient light (rows: camera R, G, B).
CROSSTALK = np.array([[0.88, 0.10, 0.02], [0.08, 0.84, 0.08], [0.02, 0.11, 0.87]])
AMBIENT = np.array([0.02, 0.02, 0.025])


def captured_hue(n_bands: int, gamma: list[float], model: str = "hexcone", *, response=None,
                 crosstalk: np.ndarray = CROSSTALK, ambient: np.ndarray = AMBIENT, bits: int = 8) -> np.ndarray:
    """White-balanced captured hue of the ``n_bands`` hue bands (``bits``-bit codes) on a plate, for a
    projector of per-channel ``gamma`` (or ``response(v) -> (..., 3)``) and a camera with this
    ``crosstalk`` and ``ambient`` light."""
    top = 2.0**bits - 1
    v = np.array([quantise(band_rgb(i, n_bands), bits) for i in range(n_bands)], np.float64) / top
    out = (lambda x: x ** np.asarray(gamma)) if response is None else response
    cap = out(v) @ crosstalk.T + ambient
    white = out(np.ones(3)) @ crosstalk.T + ambient
    return np.unwrap(colour.hue(cap / white, model).astype(np.float64))


def calib_folder(root: Path, hue: np.ndarray, model: str = "hexcone") -> Path:
    """A calibration folder whose plate table holds ``hue`` per band at every pixel."""
    n, shape = hue.size, (3, 4)
    counts = np.round(np.mod(hue, TWO_PI) / RAD_PER_COUNT).astype(np.uint16)
    table = HueTable(model=model, n_bands=n, table=np.broadcast_to(counts[:, None, None], (n, *shape)).copy(),
                     valid=np.ones(shape, bool), start=np.zeros(shape, np.uint16), reason=np.zeros(shape, np.uint8),
                     noise_rad=np.zeros(shape, np.float32), stats={})
    folder = root / "calib"
    folder.mkdir()
    table.save(folder / "table_reference.json")
    return folder


@pytest.mark.parametrize("gamma", [[2.2, 2.2, 2.2], [1.8, 2.5, 2.1], [2.6, 2.0, 1.9]])
@pytest.mark.parametrize("model", ["hexcone", "hsi"])
def test_gamma_is_read_off_the_hue_bands(gamma: list[float], model: str) -> None:
    code = TWO_PI * np.arange(48) / 48
    fit = projector_gamma(code, captured_hue(48, gamma, model), model=model)
    # crosstalk (not demixed here) and ambient light bend the ramps a little: measured within 0.015 of
    # the truth, residual 0.011 rad (bench tables, demixed: 0.003)
    np.testing.assert_allclose(fit.gamma, gamma, atol=0.03)
    assert fit.residual_rms_rad < 0.015 and fit.ramp_bands == (14, 14, 14) and fit.n_bands == 48
    # without crosstalk and ambient light, and with 16-bit bands, the fit is exact (the 8-bit codes
    # of the bands alone move it by up to 0.009: the fit takes the drive levels unrounded)
    exact = projector_gamma(code, captured_hue(48, gamma, model, crosstalk=np.eye(3), ambient=np.zeros(3), bits=16),
                            model=model)
    np.testing.assert_allclose(exact.gamma, gamma, atol=2e-3)
    np.testing.assert_allclose(exact.boundary_hue, np.arange(6) * np.pi / 3, atol=1e-3)


def test_linearised_levels_make_the_captured_sinusoid_a_sinusoid() -> None:
    gamma = np.array([1.8, 2.5, 2.1])
    phi = TWO_PI * np.arange(600) / 600
    levels = [phase_shift_intensity(phi, s) for s in range(3)]
    np.testing.assert_allclose(linearised_levels(levels[0], gamma) ** gamma, np.stack([levels[0]] * 3, -1), atol=1e-12)

    def captured(drive: np.ndarray) -> np.ndarray:  # the camera's grey intensity of one projector image
        return colour.intensity((drive**gamma) @ CROSSTALK.T + AMBIENT).astype(np.float64)

    def phase_rms(drives: list[np.ndarray]) -> float:
        got, _ = three_step_phase(*(captured(d) for d in drives))
        return float(np.sqrt(np.mean(wrap(got.astype(np.float64) - phi) ** 2)))

    plain = phase_rms([np.stack([lv] * 3, -1) for lv in levels])
    comp = phase_rms([linearised_levels(lv, gamma) for lv in levels])
    comp8 = phase_rms([quantise(linearised_levels(lv, gamma)) / 255.0 for lv in levels])
    assert plain > 0.15  # gamma ~2 puts harmonics in the grey sinusoid: measured 0.19 rad
    assert comp < 1e-5  # float32 phase
    assert comp8 < 4e-3  # 8-bit codes: measured 1.7e-3 rad


def test_compensated_patterns_write_the_linearised_shift_images(tmp_path: Path) -> None:
    gamma = [1.8, 2.5, 2.1]
    calib = calib_folder(tmp_path, captured_hue(48, gamma))
    w, h, t = 240, 4, 40.0
    out = write_patterns(tmp_path / "p", width=w, height=h, period_px=t, hue_bands=12, repeats=1, frames=1,
                         compensated=calib)
    rec = yaml.safe_load((out / "patterns.yaml").read_text())["compensated"]["phase_shift"]
    assert rec["levels"] == PHASE_SHIFT_LEVELS and rec["hue_bands"] == 48
    np.testing.assert_allclose(rec["gamma"], gamma, atol=0.03)
    with open(out / PHASE_SHIFT_LEVELS, newline="") as fh:
        rows = [r for r in csv.reader(line for line in fh if not line.startswith("#"))]
    assert rows[0] == ["level", "r", "g", "b"] and len(rows) == 258
    table = np.array(rows[1:], np.float64)
    level = np.arange(257) / 256
    np.testing.assert_allclose(table[:, 0], level, atol=5e-7)
    np.testing.assert_allclose(table[:, 1:], level[:, None] ** (1.0 / np.array(rec["gamma"])), atol=5e-7)
    phi = TWO_PI * np.arange(w) / t
    for s in range(3):
        img = cv2.imread(str(next(out.glob(f"*_shift_s{s}.png"))), cv2.IMREAD_UNCHANGED)[..., ::-1]
        assert np.all(img == img[:1])
        want = quantise(linearised_levels(phase_shift_intensity(phi, s), rec["gamma"]))
        np.testing.assert_array_equal(img[0], want)
        assert not np.all(img[0, :, 0] == img[0, :, 1])  # one drive curve per channel
    # with --no-phase-shift nothing of it is written
    none = write_patterns(tmp_path / "q", width=w, height=h, period_px=t, hue_bands=12, repeats=1, frames=1,
                          compensated=calib, phase_shift=False)
    assert not (none / PHASE_SHIFT_LEVELS).exists()
    assert "phase_shift" not in yaml.safe_load((none / "patterns.yaml").read_text())["compensated"]


def _s_curve(v: np.ndarray) -> np.ndarray:
    """A projector response no power law describes (a smoothstep: flat at both ends)."""
    return v * v * (3.0 - 2.0 * v)


def test_a_table_that_cannot_give_the_response_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # a projector whose response is an S curve (flat at both ends): no power law describes it
    hue = captured_hue(48, [2.2, 2.2, 2.2], response=lambda v: _s_curve(v**1.2))
    calib = calib_folder(tmp_path, hue)
    problem = "a per-channel power law does not describe the captured hue"
    with pytest.raises(PatternsError) as exc:
        write_patterns(tmp_path / "p", width=240, height=4, period_px=40.0, hue_bands=12, repeats=1, compensated=calib)
    assert exc.value.argument == "compensated" and problem in exc.value.problem
    assert str(calib / "table_reference.json") in exc.value.problem and not (tmp_path / "p").exists()
    # the CLI says the same, naming the flag, the file and the way out
    assert cli.main(["patterns", str(tmp_path / "p"), "--width", "240", "--height", "4", "--period-px", "40",
                     "--bands", "12", "--repeats", "1", "--compensated", str(calib)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("REFUSED: --compensated: ") and problem in err and "--no-phase-shift" in err
    # ... which writes the pre-distorted trapezoid with plain sinusoids
    assert cli.main(["patterns", str(tmp_path / "p"), "--width", "240", "--height", "4", "--period-px", "40",
                     "--bands", "12", "--repeats", "1", "--compensated", str(calib), "--no-phase-shift"]) == 0
    assert (tmp_path / "p" / "predistortion.csv").is_file()
    # 12 bands captured once: written (the format allows it), with a warning that the workflow refuses the session
    err = capsys.readouterr().err
    assert err.startswith("WARNING: --bands 12 --repeats 1: 12 hue bands captured once give no noise figure")
    assert "repeats >= 2" in err and "at least 19 bands" in err and err.rstrip().endswith("the workflow refuses such a session")
    assert cli.main(["patterns", str(tmp_path / "q"), "--width", "240", "--height", "4", "--period-px", "40",
                     "--bands", "12", "--repeats", "2", "--compensated", str(calib), "--no-phase-shift"]) == 0
    assert "WARNING" not in capsys.readouterr().err


def test_projector_gamma_refuses_bad_input() -> None:
    with pytest.raises(GammaFitError, match="one hue per band"):
        projector_gamma(np.arange(12.0), np.arange(11.0))
    code = TWO_PI * np.arange(8) / 8
    with pytest.raises(GammaFitError, match=r"8 hue bands leave 2, 2, 2 band\(s\) on the R, G, B ramps: .* needs at least 12 bands"):
        projector_gamma(code, captured_hue(8, [2.2, 2.2, 2.2]))
    code = TWO_PI * np.arange(48) / 48
    with pytest.raises(GammaFitError, match="does not wind once round the circle"):
        projector_gamma(code, np.full(48, 1.0))
    with pytest.raises(GammaFitError, match="plausible range"):
        projector_gamma(code, captured_hue(48, [6.0, 2.2, 2.2]))
