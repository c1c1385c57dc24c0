"""The rehearsal of docs/capture.md (section 9) runs exactly as the guide writes it.

The guide's bash block is read from the page, each ``./run huefringe ...`` command run through
the CLI in a fresh folder, with the spec the page shows saved where the page says; a session
comes out whose period, pitch and boxes are what the guide states.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench_helpers import REPO

from huefringe import cli
from huefringe.assemble import fringe_profile, fringe_spectrum
from huefringe.session import load_session, read_rgb_codes

GUIDE = Path(__file__).resolve().parent.parent / "docs" / "capture.md"


def rehearsal_section() -> str:
    text = GUIDE.read_text(encoding="utf-8")
    start = text.index("## 9. Rehearsing on the bench")
    end = text.find("\n## ", start + 5)
    return text[start:] if end < 0 else text[start:end]


def guide_commands(section: str, programs: tuple[str, ...] = ("huefringe",)) -> list[list[str]]:
    """The ``./run PROGRAM ...`` lines of the section's bash block, without ``./run`` (and without
    ``huefringe`` when it is the only program)."""
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    joined = re.sub(r"\\\n\s*", " ", block)
    cmds = [shlex.split(line) for line in joined.splitlines() if line.startswith("./run ")]
    assert all(c[1] in programs for c in cmds), cmds
    return [c[2:] for c in cmds] if programs == ("huefringe",) else [c[1:] for c in cmds]


def test_the_guides_rehearsal_runs_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    section = rehearsal_section()
    cmds = guide_commands(section)
    assert [c[0] for c in cmds] == ["patterns", "bench", "session", "check"]
    assert "save the spec below as rig/spec.yaml" in section
    spec_text = re.search(r"`rig/spec.yaml`, in full:\n\n```yaml\n(.*?)```", section, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    for args in cmds:
        if args[0] == "session":
            Path("rig/spec.yaml").write_text(spec_text, encoding="utf-8")
        assert cli.main([*args, "--quiet"] if args[0] == "bench" else args) == 0, (args, capsys.readouterr())
    s = load_session(tmp_path / "resources" / "rehearsal", deep=True)
    spec = yaml.safe_load(spec_text)
    # the numbers of the guide's table
    assert (s.width, s.height, s.bit_depth) == (640, 480, 8)
    assert (s.pixel_pitch_mm, s.period_px, s.hue_bands, s.repeats) == (0.125, 96, 64, 2)
    assert s.planes_mm == [0.0, 3.0, 6.0] and len(s.frames) == 3
    assert s.specimen == spec["specimen"]
    white = read_rgb_codes(s.reference_white)
    _, period = fringe_spectrum(fringe_profile(read_rgb_codes(s.planes[0.0]), white))
    assert abs(period - 96) < 0.01 * 96, period
    # the boxes follow the convention the guide states: [u0, v0, u1, v1) columns then rows, on
    # the blocks' tops (the green block's top is 3 mm above the base: its fringe is shifted)
    plane0 = read_rgb_codes(s.planes[0.0]).astype(float)
    frame = read_rgb_codes(s.frames[0]).astype(float)
    for step in spec["specimen"]["steps"]:
        u0, v0, u1, v1 = step["roi"]
        assert 0 <= u0 < u1 <= s.width and 0 <= v0 < v1 <= s.height
        moved = np.abs(frame[v0:v1, u0:u1] - plane0[v0:v1, u0:u1]).mean()
        assert moved > 5, (step["name"], moved)  # the step's top moves the fringe
    out = capsys.readouterr().out
    assert "OK: session 'gauge-blocks-rehearsal'" in out and "specimen with 3 steps" in out


def rig_section() -> str:
    text = GUIDE.read_text(encoding="utf-8")
    start = text.index("## 10. Projector-camera rigs")
    end = text.find("\n## ", start + 5)
    return text[start:] if end < 0 else text[start:end]


def test_the_guides_rig_route_runs_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """Section 10 on bench-rig captures: sessions assembled and checked, then the workflow from
    captures to report.html (calibration included) and the archives; against the bench's truth."""
    import json
    import os
    import shutil
    import subprocess
    import sys

    from rig_helpers import BOARD, SL_BASE, SL_TOPS, write_rig_captures

    from huefringe.bench.rig import StepsScene
    from huefringe.rig import read_calibration

    section = rig_section()
    cmds = guide_commands(section, ("huefringe", "snakemake"))
    assert [c[0] if c[0] == "snakemake" else c[1] for c in cmds] == [
        "sl-session", "sl-session", "check", "check", "snakemake", "snakemake", "verify"]
    blocks = {name: yaml.safe_load(re.search(rf"`rig/{name}.yaml`, in\s+full:\n\n```yaml\n(.*?)```", section, re.S).group(1))
              for name in ("sequence", "features", "sessions")}
    monkeypatch.chdir(tmp_path)
    rig = write_rig_captures(Path("rig"), blocks["sequence"])["rig"]
    for name in ("features", "sessions"):
        Path(f"rig/{name}.yaml").write_text(yaml.safe_dump(blocks[name]))
    shutil.copyfile(REPO / "config.yaml", "config.yaml")  # the commands run in the repository's folder
    for args in cmds:
        if args[0] == "snakemake":
            proc = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory",
                                   str(tmp_path), *args[1:]], capture_output=True, text=True,
                                  env={**os.environ, "PYTHONHASHSEED": "0"})
            assert proc.returncode == 0, proc.stderr[-5000:]
        else:
            assert cli.main(args[1:]) == 0, (args, capsys.readouterr())
    # the conventions the page states: --board counts inner corners, --pitch-mm the square
    assembly = cmds[0]
    assert assembly[assembly.index("--board") + 1] == f"{BOARD.cols}x{BOARD.rows}"
    assert float(assembly[assembly.index("--pitch-mm") + 1]) == BOARD.pitch_mm
    # the features' boxes: base boxes on the base plane, each step's on its block's top
    label = StepsScene().cast(rig.rays)[2]
    feats = blocks["features"]
    assert [tuple(b) for b in feats["base"]["boxes"]] == list(SL_BASE)
    assert [tuple(s["box"]) for s in feats["steps"]] == list(SL_TOPS.values())
    for box, k in [*((b, 0) for b in SL_BASE), *((b, i + 1) for i, b in enumerate(SL_TOPS.values()))]:
        x0, y0, x1, y1 = box
        assert (label[y0:y1, x0:x1] == k).all(), (box, k)
    # the calibration the workflow made, against the rig's truth
    calib, truth = read_calibration("results/board/calib/rig.yml"), rig.calibration
    for dev in ("camera_matrix", "projector_matrix"):
        assert abs(getattr(calib, dev)[0, 0] / getattr(truth, dev)[0, 0] - 1) < 0.003, dev
    assert abs(calib.baseline_mm - truth.baseline_mm) < 0.3
    # the report: every figure's truth inside its U, the steps within 1 %
    doc = json.loads(Path("results/steps/metrology/report.json").read_text())
    for s in doc["steps"]:
        print(f"step {s['name']}: {s['mean_mm']:.4f} mm, U {s['U_mm']:.4f} mm")
        assert abs(s["error_mm"]) <= s["U_mm"] and abs(s["error_pct"]) < 1.0, s
    for f in (e for v in doc["forms"].values() for e in v):
        assert abs(f["error_mm"]) <= f["U_mm"], f
    assert doc["conformity"]["decision"] in ("conforms", "undecided")
    for rel in ("xyz/frame_0000.tiff", "cloud/frame_0000.ply", "height/frame_0000.tiff", "x3p/frame_0000.x3p",
                "mesh/frame_0000.ply", "renders/frame_0000_top.png", "metrology/report.html"):
        assert Path("results/steps", rel).stat().st_size > 1000, rel
    out = capsys.readouterr().out
    assert "OK: structured-light session 'board'" in out and "6 calibration poses" in out
    assert "files match their sha256" in out
