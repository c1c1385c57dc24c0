"""The real-rig chain's two verbs against each other: ``huefringe patterns`` writes the manifest a
capture script follows, the captures (here: the bench's, taken in the manifest's order and
renamed as a camera names its files) go through ``huefringe session``, and the assembled
session measures exactly as the bench's own."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import yaml

from bench_helpers import bench_config, write
from huefringe import cli
from huefringe.api import measure
from huefringe.session import load_session


def test_patterns_manifest_drives_the_assembler_to_the_bench_session(tmp_path: Path) -> None:
    cfg = bench_config("flat", width=160, height=120, hue_bands=16, repeats=2, frames=2, period_px=24, id="rig-chain")
    bench = load_session(write(cfg, tmp_path / "bench"))
    planes = ",".join(f"{z:g}" for z in bench.planes_mm)
    pat = tmp_path / "patterns"
    assert cli.main(["patterns", str(pat), "--width", "640", "--height", "480", "--camera-period-px", "24",
                     "--magnification", "0.5", "--bands", "16", "--repeats", "2", "--planes", planes,
                     "--frames", "2"]) == 0
    assert yaml.safe_load((pat / "patterns.yaml").read_text())["period_px"] == 48  # 24 camera px / 0.5
    with open(pat / "manifest.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    # the technician's camera: one file per manifest row, numbered as camera software does
    caps = tmp_path / "camera"
    caps.mkdir()
    for row in rows:  # the bench session has every capture of the manifest, phase-shift triple included
        shutil.copyfile(bench.root / row["session_path"], caps / f"IMG_{int(row['order']) + 1}.png")
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump({"id": "rig-chain", "pixel_pitch_mm": bench.pixel_pitch_mm, "period_px": 24,
                                    "provenance": {"operator": "T. Est", "simulated": True}}))
    out = tmp_path / "session"
    assert cli.main(["session", str(caps), str(pat), str(spec), str(out)]) == 0
    s = load_session(out, deep=True)
    assert (s.hue_bands, s.repeats, s.planes_mm, s.frame_ids) == (16, 2, bench.planes_mm, bench.frame_ids)
    direct, assembled = measure(bench), measure(s)
    np.testing.assert_array_equal(assembled.heights, direct.heights)
    flat = direct.heights[0][np.isfinite(direct.heights[0])]
    assert flat.size > 0.9 * 160 * 120 and abs(np.median(flat) - cfg["scene"]["height_mm"]) < 0.05
