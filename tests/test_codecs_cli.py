"""``huefringe decode``: a folder of captures and a sequence YAML in, maps out; refusals name the file."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from codecs_helpers import render, warp
from huefringe.cli import main
from huefringe.codecs import load_sequence
from huefringe.io import read_tiff

SEQ = {
    "projector": {"width": 512, "height": 384},
    "frames": "cap_*.png",
    "blocks": [
        {"phase": {"axis": "x", "period_px": 16, "steps": 4}},
        {"gray": {"axis": "x", "cells": 64, "cell_px": 8}},
        {"phase": {"axis": "y", "period_px": 16, "shifts_deg": [-120, 0, 120]}},
        {"gray": {"axis": "y", "cells": 48, "cell_px": 8}},
        "white",
        "black",
    ],
}


@pytest.fixture()
def folder(tmp_path: Path) -> tuple[Path, Path, np.ndarray, np.ndarray]:
    seq = tmp_path / "seq.yaml"
    seq.write_text(yaml.safe_dump(SEQ))
    spec = load_sequence(seq)
    ux, uy = warp((48, 64), spec, 2)
    caps = tmp_path / "caps"
    caps.mkdir()
    for i, im in enumerate(render(spec, ux, uy, seed=2)):
        cv2.imwrite(str(caps / f"cap_{i + 1}.png"), im)  # natural order: cap_2 before cap_10
    return caps, seq, ux, uy


def test_decode_writes_the_maps(folder, tmp_path, capsys):
    caps, seq, ux, uy = folder
    out = tmp_path / "out"
    assert main(["decode", str(caps), str(seq), str(out)]) == 0
    assert "OK:" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"{k}_{a}.tif" for k in ("coord", "sigma", "modulation") for a in "xy"]
        + ["valid_x.png", "valid_y.png", "reasons_x.png", "reasons_y.png", "quality.png", "decode.json"]
    )
    for a, u in (("x", ux), ("y", uy)):
        c = read_tiff(out / f"coord_{a}.tif")
        v = cv2.imread(str(out / f"valid_{a}.png"), cv2.IMREAD_GRAYSCALE) > 0
        assert v.mean() > 0.99
        assert np.sqrt(np.mean((c - u)[v] ** 2)) < 0.05
        assert np.isnan(c[~v]).all()


def test_refusals_name_the_file_and_write_nothing(folder, tmp_path, capsys):
    caps, seq, _, _ = folder
    (caps / "cap_3.png").unlink()
    out = tmp_path / "out"
    assert main(["decode", str(caps), str(seq), str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{caps}: 32 files match 'cap_*.png', the sequence has 33 frames" in err
    assert not out.exists() and not list(tmp_path.glob(".out.*"))

    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"projector": {"width": 512}, "blocks": [{"phase": {"axis": "z", "period_px": -1, "steps": 2}}, "grey"]}))
    assert main(["decode", str(caps), str(bad), str(out)]) == 2
    err = capsys.readouterr().err
    for part in (str(bad), "width and height must be integers", "axis must be x", "period_px must be a finite number > 0", "steps must be an integer >= 3", "blocks[1]"):
        assert part in err, part

    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("mine")
    assert main(["decode", str(caps), str(seq), str(tmp_path / "full")]) == 2
    assert "exists and is not an empty folder" in capsys.readouterr().err
    assert (tmp_path / "full" / "keep.txt").read_text() == "mine"


def test_reasons_image_and_a_run_with_nothing_valid_does_not_end_ok(folder, tmp_path, capsys):
    caps, seq, _, _ = folder
    out = tmp_path / "out"
    assert main(["decode", str(caps), str(seq), str(out)]) == 0
    for a in "xy":
        r = cv2.imread(str(out / f"reasons_{a}.png"), cv2.IMREAD_UNCHANGED)
        v = cv2.imread(str(out / f"valid_{a}.png"), cv2.IMREAD_GRAYSCALE) > 0
        assert r.dtype == np.uint8 and ((r == 0) == v).all()
    capsys.readouterr()
    # the thresholds come from --configfile as in the workflow: a modulation no pixel reaches
    cfg = tmp_path / "strict.yaml"
    cfg.write_text(yaml.safe_dump({"codecs": {"min_modulation_dn": 250.0}}))
    out2 = tmp_path / "out2"
    assert main(["decode", str(caps), str(seq), str(out2), "--configfile", str(cfg)]) == 1
    cap = capsys.readouterr()
    assert "OK" not in cap.out
    assert "FAILED:" in cap.err and "x: 0.0% valid" in cap.err and "below codecs.min_valid_fraction 1.0%" in cap.err
    r = cv2.imread(str(out2 / "reasons_x.png"), cv2.IMREAD_UNCHANGED)
    assert ((r & 2) != 0).all()  # low signal, on every pixel
    summary = yaml.safe_load((out2 / "decode.json").read_text())
    assert summary["axes"]["x"]["dropped_fraction"]["low_signal"] == 1.0
    assert summary["thresholds"]["min_modulation_dn"] == 250.0


def test_gray_code_only_folder_decodes_through_the_command(tmp_path, capsys):
    """OpenCV's GrayCodePattern layout with white and black, as scan3d-capture shoots it."""
    from huefringe.codecs import opencv_graycode_patterns

    seq = tmp_path / "seq.yaml"
    seq.write_text(yaml.safe_dump({"projector": {"width": 128, "height": 96}, "frames": "*.bmp",
                                   "blocks": [{"gray": {"axis": "x", "bits": 7, "cell_px": 1, "inverse": True}},
                                              {"gray": {"axis": "y", "bits": 7, "cell_px": 1, "inverse": True}},
                                              "white", "black"]}))
    pats = np.concatenate([opencv_graycode_patterns(128, 96), np.full((1, 96, 128), 255, np.uint8), np.zeros((1, 96, 128), np.uint8)])
    caps = tmp_path / "caps"
    caps.mkdir()
    for i, p in enumerate(pats):  # the camera sees the projector one to one, 20 DN ambient
        cv2.imwrite(str(caps / f"{i:02d}.bmp"), (20 + 0.8 * p).astype(np.uint8))
    out = tmp_path / "out"
    assert main(["decode", str(caps), str(seq), str(out)]) == 0
    assert "OK:" in capsys.readouterr().out
    cx, cy = read_tiff(out / "coord_x.tif"), read_tiff(out / "coord_y.tif")
    yy, xx = np.mgrid[0:96, 0:128]
    assert np.array_equal(cx, xx) and np.array_equal(cy, yy)
    assert np.allclose(read_tiff(out / "sigma_x.tif"), 1 / np.sqrt(12))


def test_an_explicit_frame_list_uses_a_folder_with_extra_frames_as_it_is(folder, tmp_path, capsys):
    """The same captures under names whose numbers do not give the order, among frames the
    sequence does not use (a colour frame, another exposure), named in ``frames:`` one by one."""
    import shutil

    from huefringe.session import assemble_sl_session, load_sl_session

    caps, seq, _, _ = folder
    n = load_sequence(seq).n_frames
    messy = tmp_path / "messy"
    messy.mkdir()
    order = np.random.default_rng(5).permutation(n)           # capture i stored as img_<order[i]>
    listed = []
    for i in range(n):
        name = f"img_{order[i]:02d}.png"
        shutil.copyfile(caps / f"cap_{i + 1}.png", messy / name)
        listed.append(name)
    junk = np.random.default_rng(6).integers(0, 256, (48, 64), dtype=np.uint8)
    for extra in ("img_99.png", "colour_01.png", "cap_1.png"):
        cv2.imwrite(str(messy / extra), junk)
    seq_list = tmp_path / "seq_list.yaml"
    seq_list.write_text(yaml.safe_dump({**SEQ, "frames": listed}))
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["decode", str(caps), str(seq), str(a)]) == 0
    assert main(["decode", str(messy), str(seq_list), str(b)]) == 0
    for f in ("coord_x.tif", "coord_y.tif", "sigma_x.tif", "sigma_y.tif", "reasons_x.png", "reasons_y.png"):
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    # sl-session takes the listed files in their order as well: the stored captures are the clean folder's
    s = load_sl_session(assemble_sl_session(messy, seq_list, tmp_path / "session"))
    assert [p.read_bytes() for p in s.captures] == [(caps / f"cap_{i + 1}.png").read_bytes() for i in range(n)]
    # written back by the sequence writer as a list, read back equal
    from huefringe.codecs import sequence_from_mapping, sequence_to_mapping

    spec = load_sequence(seq_list)
    assert sequence_to_mapping(spec)["frames"] == listed
    assert sequence_from_mapping(sequence_to_mapping(spec), seq_list, tmp_path) == spec
    capsys.readouterr()


def test_a_wrong_frame_list_is_refused_with_every_problem(folder, tmp_path, capsys):
    caps, seq, _, _ = folder
    n = load_sequence(seq).n_frames
    names = [f"cap_{i + 1}.png" for i in range(n)]
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**SEQ, "frames": [*names[:-1], names[0], "sub/x.png"]}))
    assert main(["decode", str(caps), str(bad), str(tmp_path / "o")]) != 0
    err = capsys.readouterr().err
    assert str(bad) in err
    assert "cap_1.png listed more than once" in err and "'sub/x.png'" in err and f"{n + 1} file names, the blocks have {n} frames" in err
    missing = tmp_path / "missing.yaml"
    missing.write_text(yaml.safe_dump({**SEQ, "frames": [*names[:-2], "gone_a.png", "gone_b.png"]}))
    assert main(["decode", str(caps), str(missing), str(tmp_path / "o")]) != 0
    err = capsys.readouterr().err
    assert "gone_a.png: missing capture" in err and "gone_b.png: missing capture" in err
    assert not (tmp_path / "o").exists()
