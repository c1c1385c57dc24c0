"""Structured-light sessions (huefringe.session, docs/spec/structured-light-session.md): assembly
from a folder of captures and a sequence YAML, validation (every refusal names its file), decoding
through huefringe.codecs, and capture-session/1 folders untouched by the new format."""

from __future__ import annotations

import filecmp
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
import yaml
from session_factory import make_session

from huefringe import codecs as C
from huefringe.cli import main
from huefringe.codecs.checks import smooth_fit, smooth_region
from huefringe.session import SessionError, load_session
from huefringe.session import SL_FORMAT as FORMAT, assemble_sl_session, load_sl_session, session_format

KAMINO = Path(__file__).resolve().parents[1].parent / "shared" / "real" / "kamino410-phase-shifting"
REPO_GAMMA = 1.6448412125348637  # kamino410's gamma_result.txt ("gamma p")

SEQUENCE = {
    "projector": {"width": 64, "height": 48},
    "frames": "img_*.png",
    "blocks": [
        {"phase": {"axis": "x", "period_px": 32, "steps": 4}},
        {"gray": {"axis": "x", "bits": 3, "cell_px": 8}},
        {"phase": {"axis": "y", "period_px": 24, "shifts_deg": [-120, 0, 120]}},
        {"gray": {"axis": "y", "cells": 6, "cell_px": 8}},
        "white",
        "black",
    ],
}


def _write_captures(folder: Path, seq: dict = SEQUENCE) -> C.SequenceSpec:
    """The projector images seen by a camera of the projector's size: offset 20 DN, gain 0.8."""
    spec = C.sequence_from_mapping(seq, folder / "sequence.yaml", folder)
    folder.mkdir(parents=True, exist_ok=True)
    for i, im in enumerate(C.generate(spec)):
        cv2.imwrite(str(folder / f"img_{i + 1}.png"), np.round(20 + 0.8 * im).astype(np.uint8))
    return spec


def _write_calibration(path: Path, width: int = 64, height: int = 48, cx: float = 31.5, cy: float = 23.5) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.array([[80.0, 0, cx], [0, 80.0, cy], [0, 0, 1]]))
    fs.write("camera_distortion", np.zeros((1, 5)))
    fs.write("projector_matrix", np.array([[90.0, 0, 32], [0, 90.0, 24], [0, 0, 1]]))
    fs.write("projector_distortion", np.zeros((1, 5)))
    fs.write("R", np.eye(3))
    fs.write("T", np.array([[-100.0], [0.0], [0.0]]))
    fs.write("camera_width", width)
    fs.write("camera_height", height)
    fs.release()
    return path


@pytest.fixture
def rig(tmp_path: Path):
    caps = tmp_path / "caps"
    spec = _write_captures(caps)
    seq = tmp_path / "seq.yaml"
    seq.write_text(yaml.safe_dump({**SEQUENCE, "id": "synthetic-rig", "calibration": "rig.yml",
                                   "provenance": {"operator": "J. Doe"}}))
    _write_calibration(tmp_path / "rig.yml")
    return caps, seq, spec


def _refused(fn, *args, **kw) -> str:
    with pytest.raises(SessionError) as exc:
        fn(*args, **kw)
    return str(exc.value)


def test_assembled_session_loads_and_decodes_to_the_projector_columns(rig, tmp_path: Path) -> None:
    caps, seq, spec = rig
    out = assemble_sl_session(caps, seq, tmp_path / "out")
    s = load_sl_session(out, deep=True)
    assert session_format(out) == FORMAT and s.id == "synthetic-rig"
    assert (s.width, s.height, s.bit_depth) == (64, 48, 8) and len(s.captures) == spec.n_frames == 21
    assert s.calibration == out / "calibration/rig.yml" and s.meta["provenance"] == {"operator": "J. Doe"}
    # copies in sequence order: img_10.png is frame 9, not frame 1 (numeric, not text order)
    assert filecmp.cmp(caps / "img_10.png", out / "captures/0009.png", shallow=False)
    assert s.spec.blocks == spec.blocks
    dec = C.decode_sequence(s.read_captures(), s.spec)
    yy, xx = np.mgrid[0:48, 0:64]
    for axis, truth in (("x", xx), ("y", yy)):
        d = dec[axis]
        assert d.valid.mean() > 0.95, axis
        err = d.coord[d.valid] - truth[d.valid]
        print(f"synthetic {axis}: RMS {np.sqrt(np.mean(err**2)):.4f} px, {d.valid.mean():.1%} valid")
        assert np.sqrt(np.mean(err**2)) < 0.1, (axis, np.sqrt(np.mean(err**2)))
    # the session's sequence.yaml is the codecs' own form: huefringe decode reads it as is
    assert C.load_sequence(out / "sequence.yaml").n_frames == 21


def test_sixteen_bit_tiff_captures(tmp_path: Path) -> None:
    caps = tmp_path / "caps"
    spec = C.sequence_from_mapping({**SEQUENCE, "frames": "img_*.tif"}, tmp_path / "seq.yaml", caps)
    caps.mkdir()
    for i, im in enumerate(C.generate(spec, np.uint16)):
        tifffile.imwrite(caps / f"img_{i + 1}.tif", np.round(5000 + 0.8 * im).astype(np.uint16))
    (tmp_path / "seq.yaml").write_text(yaml.safe_dump({**SEQUENCE, "frames": "img_*.tif"}))
    s = load_sl_session(assemble_sl_session(caps, tmp_path / "seq.yaml", tmp_path / "out"), deep=True)
    assert s.bit_depth == 16 and s.captures[20].name == "0020.tiff"
    assert s.spec.frames == "[0-9][0-9][0-9][0-9].tiff" and len(C.read_captures(s.root / "captures", s.spec)) == 21
    d = C.decode_sequence(s.read_captures(), s.spec)["x"]
    err = d.coord[d.valid] - np.mgrid[0:48, 0:64][1][d.valid]
    assert d.valid.mean() > 0.95 and np.sqrt(np.mean(err**2)) < 0.01


def test_assembly_refusals_name_the_file_and_write_nothing(rig, tmp_path: Path) -> None:
    caps, seq, _ = rig
    out = tmp_path / "out"
    (caps / "img_3.png").write_bytes((caps / "img_3.png").read_bytes()[:200])  # truncated
    cv2.imwrite(str(caps / "img_5.png"), np.zeros((40, 64), np.uint8))  # another size
    cv2.imwrite(str(caps / "img_7.png"), np.zeros((48, 64), np.uint16))  # another bit depth
    (tmp_path / "rig.yml").write_text("this is no calibration {")
    text = _refused(assemble_sl_session, caps, seq, out)
    assert f"{caps / 'img_3.png'}: truncated PNG" in text
    assert f"{caps / 'img_5.png'}: image is 64 x 40, img_1.png is 64 x 48" in text
    assert f"{caps / 'img_7.png'}: image is 16-bit, img_1.png is 8-bit" in text
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["caps", "rig.yml", "seq.yaml"]


def test_assembly_refuses_a_count_unlike_the_sequence(rig, tmp_path: Path) -> None:
    caps, seq, _ = rig
    (caps / "img_21.png").unlink()
    text = _refused(assemble_sl_session, caps, seq, tmp_path / "out")
    assert f"{caps}: 20 files match 'img_*.png', the sequence {seq} has 21 frames" in text
    assert not (tmp_path / "out").exists()


def test_assembly_refuses_a_calibration_of_another_camera(rig, tmp_path: Path) -> None:
    caps, seq, _ = rig
    other = _write_calibration(tmp_path / "other.xml", 1280, 1024, 640, 512)
    text = _refused(assemble_sl_session, caps, seq, tmp_path / "out", calibration=other)
    assert f"{other}: calibrated for a 1280 x 1024 camera, the captures are 64 x 48" in text
    assert f"{other}: principal point (640, 512) px lies outside the 64 x 48 captures" in text
    (tmp_path / "rig.yml").write_text("this is no calibration {")
    assert f"{tmp_path / 'rig.yml'}: not an OpenCV FileStorage file" in _refused(assemble_sl_session, caps, seq, tmp_path / "out")


@pytest.mark.parametrize(
    ("block", "words"),
    [
        ({"gray": {"axis": "x", "bits": 2, "cell_px": 8}}, "blocks[1].gray: 2 bits of 8 px cells cover 32 px, the projector has 64 along x"),
        ({"gray": {"axis": "x", "bits": 3, "cell_px": 0}}, "blocks[1].gray.cell_px must be a finite number > 0, got 0.0"),
        ({"phase": {"axis": "x", "period_px": float("nan"), "steps": 4}}, "blocks[1].phase.period_px must be a finite number > 0, got nan"),
    ],
)
def test_assembly_refuses_sequence_keys_out_of_range(rig, tmp_path: Path, block, words) -> None:
    caps, seq, _ = rig
    doc = yaml.safe_load(seq.read_text())
    doc["blocks"][1] = block
    seq.write_text(yaml.safe_dump(doc))
    assert f"{seq}: {words}" in _refused(assemble_sl_session, caps, seq, tmp_path / "out")


def test_assembly_refuses_a_non_empty_output(rig, tmp_path: Path) -> None:
    caps, seq, _ = rig
    (tmp_path / "out").mkdir()
    (tmp_path / "out/keep.txt").write_text("mine")
    assert f"{tmp_path / 'out'}: already exists and is not empty" in _refused(assemble_sl_session, caps, seq, tmp_path / "out")
    assert (tmp_path / "out/keep.txt").read_text() == "mine"


def test_poses_are_stored_and_checked(rig, tmp_path: Path) -> None:
    caps, seq, _ = rig
    for name in ("p00", "p01"):
        _write_captures(tmp_path / "poses" / name)
    (tmp_path / "poses/p01/img_2.png").unlink()
    text = _refused(assemble_sl_session, caps, seq, tmp_path / "out", poses=tmp_path / "poses")
    assert f"{tmp_path / 'poses/p01'}: 20 files match 'img_*.png'" in text and "p00" not in text
    _write_captures(tmp_path / "poses" / "p01")
    s = load_sl_session(assemble_sl_session(caps, seq, tmp_path / "out", poses=tmp_path / "poses"))
    assert sorted(s.poses) == ["p00", "p01"] and all(len(v) == 21 for v in s.poses.values())
    assert np.array_equal(s.read_captures("p01")[4], s.read_captures()[4])


def test_a_damaged_session_is_refused_listing_every_problem(rig, tmp_path: Path) -> None:
    caps, seq, _ = rig
    out = assemble_sl_session(caps, seq, tmp_path / "out")
    (out / "captures/0003.png").unlink()
    (out / "captures/0021.png").write_bytes((out / "captures/0000.png").read_bytes())
    (out / "captures/notes.txt").write_text("x")
    with open(out / "calibration/rig.yml", "a") as f:
        f.write("# edited\n")
    meta = yaml.safe_load((out / "session.yaml").read_text())
    meta["camera"]["lens"] = "50 mm"
    (out / "session.yaml").write_text(yaml.safe_dump(meta))
    # the schema is checked first, alone
    assert f"{out / 'session.yaml'}: at camera: unknown key(s): 'lens'" in _refused(load_sl_session, out)
    del meta["camera"]["lens"]
    (out / "session.yaml").write_text(yaml.safe_dump(meta))
    text = _refused(load_sl_session, out)
    assert f"{out / 'captures/0003.png'}: missing capture 3 of the sequence's 21 frames" in text
    assert f"{out / 'captures/0021.png'}: capture beyond the sequence's 21 frames" in text
    assert f"{out / 'captures/notes.txt'}: unexpected file" in text
    assert f"{out / 'calibration/rig.yml'}: sha256 differs from session.yaml" in text
    assert main(["check", str(out)]) == 1


def test_sequence_disagreeing_with_session_yaml_is_refused(rig, tmp_path: Path) -> None:
    caps, seq, _ = rig
    out = assemble_sl_session(caps, seq, tmp_path / "out")
    doc = yaml.safe_load((out / "sequence.yaml").read_text())
    doc["projector"]["width"] = 128
    doc["blocks"] = doc["blocks"][:-1]
    (out / "sequence.yaml").write_text(yaml.safe_dump(doc))
    text = _refused(load_sl_session, out)
    assert f"{out / 'sequence.yaml'}: projector 128 x 48, session.yaml declares 64 x 48" in text
    assert f"{out / 'sequence.yaml'}: 20 frames, session.yaml declares sequence/frames 21" in text
    (out / "sequence.yaml").write_text("blocks: [{phase: {axis: z}}]")
    assert f"{out / 'sequence.yaml'}: " in _refused(load_sl_session, out)


def test_deep_check_finds_corrupt_pixels_and_ground_truth_is_checked(rig, tmp_path: Path) -> None:
    caps, seq, _ = rig
    out = assemble_sl_session(caps, seq, tmp_path / "out")
    p = out / "captures/0002.png"
    data = bytearray(p.read_bytes())
    data[60:90] = b"\x00" * 30  # inside the IDAT stream, header and IEND intact
    p.write_bytes(bytes(data))
    load_sl_session(out)
    assert f"{p}: cannot decode image" in _refused(load_sl_session, out, deep=True)
    (out / "ground_truth").mkdir()
    tifffile.imwrite(out / "ground_truth/x.tiff", np.zeros((48, 64), np.float32))
    tifffile.imwrite(out / "ground_truth/y.tiff", np.zeros((48, 64), np.float64))
    text = _refused(load_sl_session, out)
    assert f"{out / 'ground_truth/y.tiff'}: ground truth must be float32 48 x 64" in text and "x.tiff" not in text


def test_cli_sl_session_and_check(rig, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    caps, seq, _ = rig
    (caps / "img_1.png").unlink()
    assert main(["sl-session", str(caps), str(seq), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "REFUSED: no session written" in err and f"{caps}: 20 files match" in err
    _write_captures(caps)
    assert main(["sl-session", str(caps), str(seq), str(tmp_path / "out"), "--id", "bench-3"]) == 0
    assert main(["check", "--deep", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "OK: structured-light session 'bench-3'" in out and "21 captures (phase x, gray x, phase y, gray y, white, black)" in out
    assert "calibration calibration/rig.yml" in out


def test_capture_sessions_load_and_check_as_capture_sessions(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = make_session(tmp_path / "s")
    assert session_format(root) == "capture-session/1"
    assert load_session(root).id == "test-session"
    assert main(["check", str(root)]) == 0
    assert "OK: session 'test-session'" in capsys.readouterr().out
    # and a structured-light folder is not a capture session
    with pytest.raises(SessionError, match="format"):
        meta = yaml.safe_load((root / "session.yaml").read_text())
        (root / "session.yaml").write_text(yaml.safe_dump({**meta, "format": FORMAT}))
        load_session(root)


@pytest.mark.skipif(not KAMINO.is_dir(), reason=f"no real captures at {KAMINO} (shared/ beside the clone)")
def test_real_kamino410_plane_session(tmp_path: Path) -> None:
    """kamino410/phase-shifting's flat plane (54 captures, two encoding exponents per axis, Gray
    code, white, black) assembled, checked and decoded at half resolution (every second pixel)."""
    src = KAMINO / "gamma_correction"
    seq = tmp_path / "plane.yaml"
    seq.write_text(yaml.safe_dump({"kamino410": {"config": "config.xml", "program": "gamma_correction"},
                                   "projector": {"gamma": REPO_GAMMA}, "id": "kamino410-plane"}))
    out = assemble_sl_session(src, seq, tmp_path / "plane")
    s = load_sl_session(out)
    assert (s.width, s.height, s.bit_depth, len(s.captures)) == (1936, 1216, 8, 54)
    assert filecmp.cmp(src / "pat53.png", out / "captures/0053.png", shallow=False)
    assert s.spec.projector_gamma == REPO_GAMMA
    ims = np.stack(s.read_captures())[:, ::2, ::2]
    dec = C.decode_sequence(ims, s.spec)
    region = smooth_region([dec["x"].coord, dec["y"].coord], dec["x"].valid & dec["y"].valid, 10.0, 4)
    assert region.mean() > 0.7  # the plate fills most of the view
    for a in "xy":
        f = smooth_fit(dec[a].coord, region, 6)
        print(f"plane {a}: RMS {f.rms:.3f} px, p95 {f.p95:.3f} px over {f.pixels} px ({region.mean():.1%})")
        assert f.rms <= 1.5 and f.p95 <= 2.5, (a, f.rms, f.p95)


def test_sequence_and_calibration_problems_are_listed_at_once(rig, tmp_path: Path) -> None:
    caps, _, _ = rig
    other = _write_calibration(tmp_path / "other.yml", 1280, 1024, 640, 512)
    seq = tmp_path / "bad.yaml"
    seq.write_text(yaml.safe_dump({**SEQUENCE, "blocks": [{"phase": {"axis": "x", "period_px": float("nan"), "steps": 4}}]}))
    text = _refused(assemble_sl_session, caps, seq, tmp_path / "out", calibration=other)
    assert f"{seq}: blocks[0].phase.period_px must be a finite number > 0, got nan" in text
    assert f"{other}: calibrated for a 1280 x 1024 camera, the captures are 64 x 48" in text
    assert not (tmp_path / "out").exists()


def test_gray_code_only_session_with_skipped_frames(tmp_path: Path) -> None:
    """OpenCV's Gray code with white and black, and two extra frames the rig also captured."""
    seq = {"projector": {"width": 64, "height": 48}, "frames": "img_*.png",
           "blocks": [{"skip": 2}, {"gray": {"axis": "x", "bits": 6, "cell_px": 1, "inverse": True}},
                      {"gray": {"axis": "y", "bits": 6, "cell_px": 1, "inverse": True}}, "white", "black"]}
    caps = tmp_path / "caps"
    spec = _write_captures(caps, seq)
    (tmp_path / "seq.yaml").write_text(yaml.safe_dump(seq))
    s = load_sl_session(assemble_sl_session(caps, tmp_path / "seq.yaml", tmp_path / "out"))
    assert len(s.captures) == 2 + 24 + 2 and isinstance(s.spec.blocks[0], C.SkipBlock)
    dec = C.decode_sequence(s.read_captures(), s.spec)
    yy, xx = np.mgrid[0:48, 0:64]
    assert dec["x"].absolute and np.array_equal(dec["x"].coord, xx) and np.array_equal(dec["y"].coord, yy)


def test_bmp_captures_decode_byte_identically_to_png(tmp_path: Path) -> None:
    """A crop of kamino410's mugs (32 frames) as PNG, 8-bit grey BMP and 24-bit colour BMP."""
    if not KAMINO.is_dir():
        pytest.skip(f"no real captures at {KAMINO} (shared/ beside the clone)")
    src = KAMINO / "object2"
    folders = {k: tmp_path / k for k in ("png", "bmp", "bmp-colour")}
    for name, f in folders.items():
        f.mkdir()
        (f / "config.xml").write_bytes((src / "config.xml").read_bytes())
        for p in sorted(src.glob("pat*.png")):
            im = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)[1040:1200, 520:720]
            if name == "bmp-colour":
                im = cv2.merge([im, im, im])
            cv2.imwrite(str(f / (p.stem + (".png" if name == "png" else ".bmp"))), im)
    decoded = {}
    for name, f in folders.items():
        seq = tmp_path / f"{name}.yaml"
        seq.write_text(yaml.safe_dump({"kamino410": {"config": "config.xml", "program": "phase_shifting"},
                                       "frames": "pat*.png" if name == "png" else "pat*.bmp"}))
        s = load_sl_session(assemble_sl_session(f, seq, tmp_path / f"s-{name}"), deep=True)
        assert s.meta["camera"] == {"width": 200, "height": 160, "bit_depth": 8, "channels": 3 if name == "bmp-colour" else 1}
        assert s.captures[0].suffix == (".png" if name == "png" else ".bmp")
        decoded[name] = C.decode_sequence(s.read_captures(), s.spec)
        glob = "pat*.png" if name == "png" else "pat*.bmp"
        assert np.array_equal(np.stack(s.read_captures()), np.stack(C.read_captures(f, C.SequenceSpec(
            s.spec.blocks, s.spec.projector_width, s.spec.projector_height, s.spec.projector_gamma, glob))))
    assert decoded["png"]["x"].valid.mean() > 0.5
    for name in ("bmp", "bmp-colour"):
        for a in "xy":
            assert np.array_equal(decoded[name][a].coord, decoded["png"][a].coord, equal_nan=True)
            assert np.array_equal(decoded[name][a].reasons, decoded["png"][a].reasons)
