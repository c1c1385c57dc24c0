"""Multi-band calibration on virtual-bench sessions: the corrected phase of a flat board matches
the true code phase (known from the bench's geometry) for several rigs and surface colours."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from bench_helpers import bench_config, write

from huefringe.bench import code_phase
from huefringe.huetable import build_table
from huefringe.colour import hue, white_balance
from huefringe.phase import wrap
from huefringe.session import load_session, read_rgb

IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
CROSSTALK = [[0.86, 0.11, 0.03], [0.09, 0.82, 0.09], [0.03, 0.12, 0.85]]

CASES = {
    # name: (gamma per channel, crosstalk, board reflectance, bit depth)
    "gamma 2.2, white board": ((2.2, 2.2, 2.2), IDENTITY, (0.85, 0.85, 0.85), 8),
    "gammas 1.8/2.2/2.6 + crosstalk": ((1.8, 2.2, 2.6), CROSSTALK, (0.85, 0.8, 0.75), 8),
    "strongly red board + crosstalk": ((2.0, 2.2, 2.4), CROSSTALK, (0.8, 0.12, 0.1), 16),
    "dark board (reflectance 0.1)": ((2.2, 2.0, 2.4), CROSSTALK, (0.1, 0.1, 0.1), 16),
}


@pytest.mark.parametrize("name", list(CASES))
def test_table_corrects_hue_on_bench_boards(tmp_path: Path, name: str) -> None:
    gamma, xtalk, refl, bits = CASES[name]
    cfg = bench_config("flat", width=160, height=60, hue_bands=64, repeats=3, frames=1, bit_depth=bits,
                       id="board", planes_mm=[0.0, 3.0])
    cfg["projector"]["gamma"] = list(gamma)
    cfg["camera"]["crosstalk"] = xtalk
    cfg["scene"]["reflectance"] = list(refl)
    s = load_session(write(cfg, tmp_path))
    white = read_rgb(s.object_white)
    table = build_table(s.object_bands, white, model="hexcone")
    raw = hue(white_balance(read_rgb(s.frames[0]), white), "hexcone")
    corrected = table.to_phase(raw)
    p = cfg["projector"]
    u = np.arange(s.width) * s.pixel_pitch_mm
    truth = code_phase(u[None, :] * np.ones((s.height, 1)), cfg["scene"]["height_mm"], projector_x_mm=p["x_mm"],
                       projector_height_mm=p["height_mm"], period_mm=s.period_px * s.pixel_pitch_mm,
                       x_origin_mm=p["x_origin_mm"])
    assert np.isfinite(corrected).mean() > 0.95

    def rms(x: np.ndarray) -> tuple[float, float]:
        """Per-pixel RMS error, and RMS of the column means (every row sees the same code
        phase, so averaging the rows leaves the systematic error the table must remove)."""
        e = wrap(x - truth)
        cols = np.angle(np.nanmean(np.exp(1j * e), axis=0))
        return float(np.sqrt(np.nanmean(e**2))), float(np.sqrt(np.nanmean(cols**2)))

    (before_px, before), (after_px, after) = rms(raw), rms(corrected)
    print(f"{name}: RMS {before:.4f} -> {after:.4f} rad systematic, {before_px:.4f} -> {after_px:.4f} rad per pixel")
    assert before > 0.05  # the rig really bends the hue
    assert after <= before / 5, (before, after)
    assert after_px < before_px
