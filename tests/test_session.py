"""The capture-session reader accepts valid sessions and refuses broken ones with the right message."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from session_factory import make_session, write_image

from huefringe.cli import main
from huefringe.session import SessionError, load_session, read_rgb, read_rgb_codes


@pytest.mark.parametrize(("bit_depth", "ext"), [(8, ".png"), (16, ".png"), (8, ".tiff"), (16, ".tiff")])
def test_valid_sessions_load(tmp_path: Path, bit_depth: int, ext: str) -> None:
    root = make_session(tmp_path / "s", bit_depth=bit_depth, ext=ext)
    s = load_session(root, deep=True)
    assert s.id == "test-session"
    assert (s.width, s.height, s.bit_depth) == (32, 24, bit_depth)
    assert len(s.reference_bands) == 6 and all(len(r) == 2 for r in s.object_bands)
    assert list(s.planes) == [0.0, 1.0, 2.0]
    assert s.frame_ids == [0, 1]
    assert sorted(s.phase_shift) == [0, 1] and sorted(s.ground_truth) == [0, 1]
    img = read_rgb(s.frames[0])
    assert img.shape == (24, 32, 3) and img.dtype == np.float32
    assert 0.0 <= img.min() and img.max() <= 1.0 and img.max() > 0.9


def test_read_rgb_scales_16_bit_and_keeps_channel_order(tmp_path: Path) -> None:
    rgb = np.zeros((4, 5, 3), np.uint16)
    rgb[..., 0] = 65535  # pure red
    rgb[..., 2] = 32768
    for ext in (".png", ".tiff"):
        p = tmp_path / f"red{ext}"
        write_image(p, rgb)
        out = read_rgb(p)
        np.testing.assert_allclose(out[0, 0], [1.0, 0.0, 32768 / 65535], atol=1e-6)
        codes = read_rgb_codes(p)  # what the kernel reads: the same pixels, unscaled
        assert codes.dtype == np.uint16 and codes.flags.c_contiguous
        np.testing.assert_array_equal(codes, rgb)
        np.testing.assert_array_equal(codes.astype(np.float32) * np.float32(1 / 65535), out)
    p8 = tmp_path / "rgb8.png"
    write_image(p8, (np.arange(60).reshape(4, 5, 3) * 4).astype(np.uint8))
    np.testing.assert_array_equal(read_rgb_codes(p8), (np.arange(60).reshape(4, 5, 3) * 4).astype(np.uint8))


def _edit_yaml(root: Path, edit: Callable[[dict], None]) -> None:
    meta = yaml.safe_load((root / "session.yaml").read_text())
    edit(meta)
    (root / "session.yaml").write_text(yaml.safe_dump(meta))


def _truncate(p: Path) -> None:
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])


def _wrong_size(root: Path) -> None:
    write_image(root / "object/frames/frame_0001.png", np.zeros((24, 31, 3), np.uint8))


def _mixed_depth(root: Path) -> None:
    write_image(root / "reference/hue/band_002_r1.png", np.zeros((24, 32, 3), np.uint16))


def _grey(root: Path) -> None:
    import cv2

    cv2.imwrite(str(root / "object/white.png"), np.zeros((24, 32), np.uint8))


def _rgba(root: Path) -> None:
    import cv2

    cv2.imwrite(str(root / "reference/white.png"), np.zeros((24, 32, 4), np.uint8))


def _empty_frames(root: Path) -> None:
    for p in (root / "object/frames").iterdir():
        p.unlink()
    shutil.rmtree(root / "object/phase_shift")
    shutil.rmtree(root / "ground_truth")


def _extra_plane(root: Path) -> None:
    shutil.copy(root / "reference/planes/z_1.000.png", root / "reference/planes/z_3.000.png")


BROKEN: dict[str, tuple[Callable[[Path], None], str, str]] = {
    # name: (breakage, file the message must name, words it must contain)
    "missing file": (lambda r: (r / "object/hue/band_003_r1.png").unlink(), "object/hue/band_003_r1.png", "missing file"),
    "missing session.yaml": (lambda r: (r / "session.yaml").unlink(), "session.yaml", "missing file"),
    "wrong size": (_wrong_size, "object/frames/frame_0001.png", "31 x 24"),
    "mixed bit depth": (_mixed_depth, "reference/hue/band_002_r1.png", "16-bit"),
    "truncated png": (lambda r: _truncate(r / "object/frames/frame_0000.png"), "object/frames/frame_0000.png", "truncated"),
    "unknown key": (lambda r: _edit_yaml(r, lambda m: m["camera"].update(gain=2)), "session.yaml", "unknown key"),
    "unknown top key": (lambda r: _edit_yaml(r, lambda m: m.update(operator="bob")), "session.yaml", "operator"),
    "bad id": (lambda r: _edit_yaml(r, lambda m: m.update(id="Gauge Blocks!")), "session.yaml", "at id"),
    "roi outside": (
        lambda r: _edit_yaml(r, lambda m: m["specimen"]["steps"][0].update(roi=[20, 8, 40, 16])),
        "session.yaml",
        "outside the 32 x 24 image",
    ),
    "empty frames folder": (_empty_frames, "object/frames", "no frames"),
    "plane file not listed": (_extra_plane, "reference/planes/z_3.000.png", "not listed in planes_mm"),
    "listed plane missing": (lambda r: _edit_yaml(r, lambda m: m.update(planes_mm=[0.0, 1.0, 2.0, 5.0])), "z_5.000.png", "missing file"),
    "no reference plane": (lambda r: _edit_yaml(r, lambda m: m.update(planes_mm=[1.0, 2.0])), "session.yaml", "reference plane"),
    "greyscale image": (_grey, "object/white.png", "greyscale"),
    "rgba image": (_rgba, "reference/white.png", "RGBA"),
    "incomplete phase shift": (lambda r: (r / "object/phase_shift/frame_0001_s2.png").unlink(), "frame_0001_s2.png", "three phase-shift"),
    "wrong format": (lambda r: _edit_yaml(r, lambda m: m.update(format="capture-session/2")), "session.yaml", "capture-session/1"),
    "bad bit depth": (lambda r: _edit_yaml(r, lambda m: m["camera"].update(bit_depth=12)), "session.yaml", "camera/bit_depth"),
    "not yaml": (lambda r: (r / "session.yaml").write_text("format: [unclosed"), "session.yaml", "not valid YAML"),
    "band outside range": (
        lambda r: shutil.copy(r / "object/hue/band_000_r0.png", r / "object/hue/band_007_r0.png"),
        "object/hue/band_007_r0.png",
        "outside",
    ),
}


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_broken_sessions_are_refused_naming_file_and_problem(tmp_path: Path, name: str) -> None:
    root = make_session(tmp_path / "s")
    breakage, file_part, words = BROKEN[name]
    breakage(root)
    before = {p: p.read_bytes() for p in root.rglob("*") if p.is_file()}
    with pytest.raises(SessionError) as info:
        load_session(root)
    msg = str(info.value)
    line = next((ln for ln in msg.splitlines() if file_part in ln), None)
    assert line is not None, f"message does not name {file_part}: {msg}"
    assert words in line, f"expected {words!r} in {line!r}"
    after = {p: p.read_bytes() for p in root.rglob("*") if p.is_file()}
    assert after == before, "validation must not modify the session"


def test_corrupt_pixels_caught_by_deep_check(tmp_path: Path) -> None:
    root = make_session(tmp_path / "s")
    p = root / "object/frames/frame_0000.png"
    data = bytearray(p.read_bytes())
    data[60:90] = b"\x00" * 30  # inside the IDAT stream, header and IEND intact
    p.write_bytes(bytes(data))
    load_session(root)  # headers are fine
    with pytest.raises(SessionError, match="frame_0000.png"):
        load_session(root, deep=True)


def test_cli_check_exit_status(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = make_session(tmp_path / "s")
    assert main(["check", str(root)]) == 0
    assert "OK: session 'test-session'" in capsys.readouterr().out
    (root / "object/white.png").unlink()
    assert main(["check", str(root)]) == 1
    out = capsys.readouterr().out
    assert "REFUSED" in out and "object/white.png: missing file" in out


def _write_predistortion(root: Path, rows: list[tuple[float, float]], header: str = "code_phase_rad,emitted_phase_rad") -> None:
    text = "# test\n" + header + "\n" + "".join(f"{c},{e}\n" for c, e in rows)
    (root / "predistortion.csv").write_text(text)


def test_predistortion_extension_read_and_inverted(tmp_path: Path) -> None:
    root = make_session(tmp_path / "s")
    code = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    emitted = code + 0.2 * np.sin(code)  # invertible pre-distortion
    _write_predistortion(root, list(zip(code, emitted, strict=True)))
    s = load_session(root)
    assert s.predistortion is not None and root / "predistortion.csv" in s.input_files()
    phi = np.linspace(0.01, 6.2, 50)
    back = s.predistortion.decode(phi + 0.2 * np.sin(phi))
    np.testing.assert_allclose(back, phi, atol=2e-3)


@pytest.mark.parametrize(
    ("rows", "header", "words"),
    [
        ([(0.1 * i, 0.1 * i) for i in range(20)], "code,emitted", "header"),
        ([(0.1 * i, 0.1 * (20 - i)) for i in range(20)], "code_phase_rad,emitted_phase_rad", "rise strictly"),
        ([(0.1 * i, 0.1 * i) for i in range(5)], "code_phase_rad,emitted_phase_rad", "at least 16 rows"),
    ],
)
def test_bad_predistortion_refused(tmp_path: Path, rows, header, words) -> None:
    root = make_session(tmp_path / "s")
    _write_predistortion(root, rows, header)
    with pytest.raises(SessionError, match=words) as info:
        load_session(root)
    assert "predistortion.csv" in str(info.value)


# --------------------------------------------------------------------------- provenance block
PROVENANCE_YAML = """provenance:
  captured_at: 2026-11-30T14:05:00Z
  operator: J. Doe
  instrument: bench-2 (DLP 1024x768, 8-bit colour camera)
  simulated: false
  notes: free text
"""


def test_provenance_block_is_read_with_an_iso_date(tmp_path: Path) -> None:
    root = make_session(tmp_path / "s")
    assert load_session(root).provenance == {}
    with open(root / "session.yaml", "a") as f:
        f.write(PROVENANCE_YAML)  # unquoted, as in the spec: YAML reads a timestamp
    s = load_session(root)
    assert s.provenance == {"captured_at": "2026-11-30T14:05:00Z", "operator": "J. Doe",
                            "instrument": "bench-2 (DLP 1024x768, 8-bit colour camera)", "simulated": False,
                            "notes": "free text"}
    for written, read in [("2026-11-30", "2026-11-30"), ("'2026-11-30T15:05:00+01:00'", "2026-11-30T15:05:00+01:00"),
                          ("2026-11-30T14:05:00", "2026-11-30T14:05:00")]:
        text = (root / "session.yaml").read_text().replace("2026-11-30T14:05:00Z", written)
        (tmp_path / "t").mkdir(exist_ok=True)
        shutil.copytree(root, tmp_path / "t" / "s", dirs_exist_ok=True)
        (tmp_path / "t" / "s" / "session.yaml").write_text(text)
        assert load_session(tmp_path / "t" / "s").provenance["captured_at"] == read


@pytest.mark.parametrize(
    ("provenance", "expected"),
    [
        ({"simulated": "yes"}, "at provenance/simulated: 'yes' is not of type 'boolean'"),
        ({"captured_at": "last tuesday"}, "at provenance/captured_at: 'last tuesday' is not an ISO 8601 date"),
        ({"captured_at": "2026-13-40"}, "at provenance/captured_at: '2026-13-40' is not an ISO 8601 date"),
        ({"operator": 7}, "at provenance/operator: 7 is not of type 'string'"),
        ({"opertor": "J. Doe"}, "at provenance: unknown key(s): 'opertor' was unexpected"),
        ("J. Doe", "at provenance: 'J. Doe' is not of type 'object'"),
    ],
)
def test_bad_provenance_is_refused_naming_session_yaml(tmp_path: Path, provenance, expected: str) -> None:
    root = make_session(tmp_path / "s")
    _edit_yaml(root, lambda m: m.update(provenance=provenance))
    with pytest.raises(SessionError) as exc:
        load_session(root)
    msg = str(exc.value)
    assert f"{root / 'session.yaml'}: {expected}" in msg, msg


@pytest.mark.parametrize(("text", "expected"), [
    ("", "is empty; expected a mapping with the keys format, id, camera"),
    ("# nothing but a comment\n", "is empty"),
    ("- format: capture-session/1\n", "must be a mapping of keys (format, id, camera, pattern, planes_mm, ...), got a list"),
    ("just text\n", "must be a mapping of keys"),
])
def test_empty_or_non_mapping_session_yaml(tmp_path: Path, text: str, expected: str, capsys) -> None:
    root = make_session(tmp_path / "s")
    (root / "session.yaml").write_text(text)
    with pytest.raises(SessionError) as exc:
        load_session(root)
    assert f"{root / 'session.yaml'}: {expected}" in str(exc.value) and "None is not" not in str(exc.value)
    assert main(["check", str(root)]) == 1
    err = capsys.readouterr()
    assert expected in err.out + err.err and "Traceback" not in err.out + err.err


def test_cli_version_and_top_level_help(capsys) -> None:
    from huefringe import __version__

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"huefringe {__version__}"
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    for sub in ("check", "bench", "archive", "verify"):
        assert f"\n    {sub} " in out, out
    assert "snakemake --cores 2" in out and "``" not in out


def test_workflow_plan_names_every_refused_session_at_once(tmp_path: Path) -> None:
    import json as jsonlib

    from bench_helpers import CONFIG

    from huefringe.plan import PlanError, plan_sessions

    good = make_session(tmp_path / "good")
    bad1 = make_session(tmp_path / "bad1")
    (bad1 / "session.yaml").write_text("")
    bad2 = make_session(tmp_path / "bad2")
    _edit_yaml(bad2, lambda m: m.update(id="Bad!"))
    cfg = jsonlib.loads(jsonlib.dumps(CONFIG))
    cfg["sessions"], cfg["bench_sessions"] = [str(bad1), str(good), str(bad2)], {}
    with pytest.raises(PlanError) as exc:
        plan_sessions(cfg)
    msg = str(exc.value)
    assert msg.startswith("2 of 3 sessions refused:")
    assert f"{bad1 / 'session.yaml'}: is empty" in msg and f"{bad2 / 'session.yaml'}: at id" in msg
    assert str(good) not in msg


def test_workflow_plan_refuses_hue_bands_captured_once_too_few_for_a_noise_figure(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Twelve hue bands captured once hold no run of four bands in a sextant of the code, so the
    hue table cannot estimate any pixel's noise: the plan refuses such a session folder, a bench
    YAML that would write one and a one-shot rig sequence alike, naming each file, before any work
    (the format itself allows them: the folder loads, and 24 bands once or 12 twice are planned)."""
    import json as jsonlib

    from bench_helpers import CONFIG

    from huefringe import bench
    from huefringe.plan import PlanError, plan_sessions

    folder = make_session(tmp_path / "once", bands=12, repeats=1)
    load_session(folder)
    assert main(["check", str(folder)]) == 0  # the format's check passes it, and says the run will not
    out = capsys.readouterr().out
    assert out.startswith("OK: session") and "\nWARNING: 12 hue bands captured once give no noise figure" in out
    assert out.rstrip().endswith("the workflow refuses to measure this session")
    fine = [make_session(tmp_path / "n24", bands=24, repeats=1), make_session(tmp_path / "twice", bands=12, repeats=2)]
    _edit_yaml(fine[1], lambda m: m.update(id="twice"))
    demo = yaml.safe_load(bench.preset_path("demo").read_text())
    demo["session"].update(hue_bands=12, repeats=1)
    (tmp_path / "demo12.yaml").write_text(yaml.safe_dump(demo))
    rig = yaml.safe_load(bench.preset_path("rig-oneshot").read_text())
    rig["sequence"]["blocks"] = [{"hue_bands": {"n": 12, "repeats": 1}} if isinstance(b, dict) and "hue_bands" in b else b
                                 for b in rig["sequence"]["blocks"]]
    rig.pop("calibration_session")
    (tmp_path / "rig12.yaml").write_text(yaml.safe_dump(rig))
    cfg = jsonlib.loads(jsonlib.dumps(CONFIG))
    cfg["sessions"] = [str(folder), *map(str, fine), "sessions/demo12", "sessions/rig12"]
    cfg["bench_sessions"] = {"sessions/demo12": "demo12.yaml", "sessions/rig12": "rig12.yaml"}
    with pytest.raises(PlanError) as exc:
        plan_sessions(cfg, base=tmp_path)
    msg = str(exc.value)
    assert msg.startswith("3 of 5 sessions refused:"), msg
    why = "cannot be measured: 12 hue bands captured once give no noise figure"
    assert f"{folder / 'session.yaml'}: at pattern: {why}" in msg
    assert f"{tmp_path / 'demo12.yaml'}: at session: {why}" in msg
    assert f"{tmp_path / 'rig12.yaml'}: at sequence.blocks' hue_bands: {why}" in msg
    assert msg.count("capture each band at least twice (repeats >= 2) or use at least 19 bands") == 3
    assert not any(str(p) in msg for p in fine)
    cfg["sessions"] = list(map(str, fine))
    assert len(plan_sessions(cfg, base=tmp_path)) == 2
    assert main(["check", str(fine[0])]) == 0 and "WARNING" not in capsys.readouterr().out
