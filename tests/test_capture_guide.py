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

from huefringe import cli
from huefringe.assemble import fringe_profile, fringe_spectrum
from huefringe.session import load_session, read_rgb_codes

GUIDE = Path(__file__).resolve().parent.parent / "docs" / "capture.md"


def rehearsal_section() -> str:
    text = GUIDE.read_text(encoding="utf-8")
    start = text.index("## 9. Rehearsing on the bench")
    end = text.find("\n## ", start + 5)
    return text[start:] if end < 0 else text[start:end]


def guide_commands(section: str) -> list[list[str]]:
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    joined = re.sub(r"\\\n\s*", " ", block)
    cmds = [shlex.split(line) for line in joined.splitlines() if line.startswith("./run ")]
    assert all(c[:2] == ["./run", "huefringe"] for c in cmds)
    return [c[2:] for c in cmds]


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
    """Section 10 on bench-rig captures: sl-session, check, calibrate, measure, archive, verify;
    the calibration, the flat board and the steps against the bench's truth."""
    import json

    from rig_helpers import BOARD, SL_BASE, SL_TOPS, write_rig_captures

    from huefringe.bench.rig import StepsScene
    from huefringe.rig import read_calibration

    section = rig_section()
    cmds = guide_commands(section)
    assert [c[0] for c in cmds] == ["sl-session", "check", "rig-calibrate", "rig-measure", "sl-session", "check",
                                    "rig-measure", "archive", "verify"]
    seq = yaml.safe_load(re.search(r"`rig/sequence.yaml`, in\s+full:\n\n```yaml\n(.*?)```", section, re.S).group(1))
    monkeypatch.chdir(tmp_path)
    rig = write_rig_captures(Path("rig"), seq)["rig"]
    for args in cmds:
        assert cli.main(args) == 0, (args, capsys.readouterr())
    # the conventions the page states: --board counts inner corners, --pitch-mm the square
    cal_args = cmds[2]
    assert cal_args[cal_args.index("--board") + 1] == f"{BOARD.cols}x{BOARD.rows}"
    assert float(cal_args[cal_args.index("--pitch-mm") + 1]) == BOARD.pitch_mm
    # --base on the base plane, each --box on one block's top: [x0, x1) columns, [y0, y1) rows
    label = StepsScene().cast(rig.rays)[2]
    measure = cmds[6]
    boxes = [tuple(int(v) for v in measure[i + 1].split(",")) for i, a in enumerate(measure) if a == "--box"]
    bases = [tuple(int(v) for v in measure[i + 1].split(",")) for i, a in enumerate(measure) if a == "--base"]
    assert tuple(bases) == SL_BASE and boxes == list(SL_TOPS.values())
    for (x0, y0, x1, y1), k in [*((b, 0) for b in bases), *((b, i + 1) for i, b in enumerate(boxes))]:
        assert (label[y0:y1, x0:x1] == k).all(), ((x0, y0, x1, y1), k)
    # the calibration against the rig's truth
    calib, truth = read_calibration("rig/calib.yml"), rig.calibration
    for dev in ("camera_matrix", "projector_matrix"):
        assert abs(getattr(calib, dev)[0, 0] / getattr(truth, dev)[0, 0] - 1) < 0.003, dev
    assert abs(calib.baseline_mm - truth.baseline_mm) < 0.3
    # the flat board: form deviation (bench target 0.02 mm; measured 0.019 mm, docs/rig.md)
    board = json.loads(Path("results/board/report.json").read_text())
    print("flat board: form", board["plane"]["form_deviation_mm"], "rms", board["plane"]["rms_mm"])
    assert board["plane"]["form_deviation_mm"] < 0.025
    assert board["plane"]["rms_mm"] < 2 * board["median_sigma_mm"][2]
    # the steps (truth 2, 5, 10 mm; measured +0.022, +0.009, -0.009 mm, docs/rig.md)
    steps = json.loads(Path("results/steps/report.json").read_text())
    assert steps["session_id"] == "steps" and steps["plane"]["fitted_to"] == [list(b) for b in SL_BASE]
    for (height, _), (name, got) in zip(SL_TOPS.items(), steps["boxes"].items(), strict=True):
        print(f"step {height} mm: {got['mean_height_mm']:.4f} mm")
        assert abs(got["mean_height_mm"] - height) < 0.03, (name, height, got)
    assert abs(steps["boxes"]["box2"]["mean_height_mm"] / 10.0 - 1) < 0.003
    # everything the capture-session route writes, renders included (not blank)
    import cv2

    for name in ("cloud.ply", "mesh.ply", "height.tiff", "height.x3p", "height.png", "mesh_top.png",
                 "mesh_oblique1.png", "mesh_oblique2.png", "report.json"):
        assert name in steps["files"] and Path("results/steps", name).stat().st_size > 1000, name
    top = cv2.imread("results/steps/mesh_top.png")
    assert top is not None and top.std() > 10
    out = capsys.readouterr().out
    assert "OK: structured-light session 'board'" in out and "6 calibration poses" in out
    assert "files match their sha256" in out and "session 'steps'" in out
