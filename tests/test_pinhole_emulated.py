"""End to end through a pinhole camera with lens distortion, emulated from a telecentric bench
session (tests/pinhole_helpers.py): heights need no resampling, X, Y come from the lens model."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from bench_helpers import CONFIG, bench_config, process, write
from pinhole_helpers import pinhole_copy
from huefringe import metrology, pipeline, stages
from huefringe.height import accuracy
from huefringe.io import read_tiff


def test_pinhole_session_measures_with_the_lens_model(tmp_path: Path) -> None:
    cfg = bench_config("plain_gauge", frames=1, hue_bands=24, repeats=1)
    cfg["vibration"]["amplitude_mm"] = 0.0
    src = write(cfg, tmp_path)
    pin = tmp_path / "pinhole"
    pinhole_copy(src, pin)  # 300 mm, k1 -0.5 (2.4 px at the corners), 2.7 px of parallax at a 4 mm block's corner
    out = {}
    for lens in (True, False):
        c = copy.deepcopy(CONFIG)
        c["camera"] = {**CONFIG["camera"], "lens_model": lens, "chromatic_registration": False,
                       "colour_demixing": False}
        paths = process(pin, tmp_path / f"out-{lens}", config=c)
        s = paths["session"]
        model = pipeline.session_corrections(s, paths["camera"])[0]
        h = read_tiff(paths["heights"][0])
        ev = metrology.evaluate_session([h], s.specimen, s.pixel_pitch_mm, range_mm=6.0, camera=model)
        out[lens] = (accuracy(h, read_tiff(s.ground_truth[0])), ev, stages.xy_block(s, model, paths["heights"]))
    acc, ev, xy = out[True]
    assert acc["median_abs_mm"] < 0.02 and acc["coverage"] > 0.85  # heights as a telecentric session's
    assert max(abs(st["error_mm"]) for st in ev["steps"]) < 0.02
    assert xy["summary"]["p95_mm"] < 0.02 and xy["summary"]["corner_p95_mm"] < 0.006
    # the corners' worst pixel: 0.062 mm with the white-edge texture blur and the
    # filter's target 0.002 rad, which took the corners' p95 from 0.0075 to 0.0036 mm (one pixel's height)
    assert xy["summary"]["corner_max_mm"] < 0.07
    assert out[False][2]["summary"]["corner_max_mm"] > 1.0  # u * pitch is millimetres off at the corners
    np.testing.assert_array_equal(read_tiff(tmp_path / "out-True" / "heights" / "frame_0000.tiff"),
                                  read_tiff(tmp_path / "out-False" / "heights" / "frame_0000.tiff"))
