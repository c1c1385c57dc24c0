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
