"""huefringe.assemble / ``huefringe session``: a bench session taken apart into a flat folder of
numbered camera files plus a patterns folder (manifest.csv + patterns.yaml per the shared
contract), assembled back, measured, and every refusal."""

from __future__ import annotations

import csv
import datetime as dt
import hashlib
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
import yaml

from bench_helpers import bench_config, write
from huefringe import camera, cli
from huefringe.api import measure
from huefringe.assemble import assemble_session, fringe_profile, fringe_spectrum, natural_key
from huefringe.session import Session, SessionError, load_session, read_rgb_codes

PERIOD = 24


def capture_order(s: Session) -> list[tuple[str, Path]]:
    """(session_path, file) of every capture in the contract's capture order."""
    out = [("reference/white.png", s.reference_white)]
    for part, bands in (("reference", s.reference_bands),):
        out += [(f"{part}/hue/band_{i:03d}_r{r}.png", p) for i, reps in enumerate(bands) for r, p in enumerate(reps)]
    out += [(f"reference/planes/z_{z:.3f}.png", s.planes[z]) for z in s.planes_mm]
    out.append(("object/white.png", s.object_white))
    out += [(f"object/hue/band_{i:03d}_r{r}.png", p) for i, reps in enumerate(s.object_bands) for r, p in enumerate(reps)]
    out += [(f"object/frames/frame_{n:04d}.png", s.frames[n]) for n in s.frame_ids]
    if 0 in s.phase_shift:
        out += [(f"object/phase_shift/frame_0000_s{k}.png", p) for k, p in enumerate(s.phase_shift[0])]
    return out


def write_patterns(s: Session, folder: Path) -> Path:
    """A patterns folder per the contract (no projector PNGs: the assembler reads only the two files)."""
    folder.mkdir(parents=True)
    names = {"white.png": "0000_white.png"}
    with open(folder / "manifest.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["order", "image", "session_path"])
        for k, (rel, _) in enumerate(capture_order(s)):
            stem = Path(rel).stem
            image = ("white" if stem == "white" else stem.rsplit("_r", 1)[0] if stem.startswith("band_")
                     else "trapezoid" if "/planes/" in rel or "/frames/" in rel else "shift_" + stem[-2:])
            w.writerow([k, names.get(image, f"{k:04d}_{image}.png"), rel])
    meta = {"width": 1024, "height": 768, "bit_depth": 8, "period_px": 60, "hue_bands": s.hue_bands,
            "repeats": s.repeats, "planes_mm": s.planes_mm, "frames": len(s.frames), "phase_shift": bool(s.phase_shift)}
    (folder / "patterns.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return folder


def write_spec(s: Session, path: Path, **extra) -> Path:
    spec = {"id": s.id, "pixel_pitch_mm": s.pixel_pitch_mm, "period_px": s.period_px,
            "provenance": {"operator": "T. Est", "simulated": True}, **extra}
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def disassemble(s: Session, folder: Path, convert=lambda a: a, ext: str = ".png") -> list[Path]:
    """Numbered camera files cap_1 ... cap_N (natural order, not lexical) of the session's captures."""
    folder.mkdir(parents=True)
    files = []
    for k, (_, p) in enumerate(capture_order(s)):
        data = convert(read_rgb_codes(p))
        f = folder / f"cap_{k + 1}{ext}"
        if ext == ".png":
            assert cv2.imwrite(str(f), data if data.ndim == 2 else cv2.cvtColor(data, cv2.COLOR_RGB2BGR))
        else:
            tifffile.imwrite(f, data, photometric="rgb" if data.ndim == 3 else "minisblack")
        files.append(f)
    return files


def snapshot(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def bench8(tmp_path_factory: pytest.TempPathFactory) -> Session:
    cfg = bench_config("flat", width=160, height=120, hue_bands=16, repeats=2, frames=2, period_px=PERIOD, id="asm8")
    return load_session(write(cfg, tmp_path_factory.mktemp("b8")))


@pytest.fixture(scope="module")
def bench16(tmp_path_factory: pytest.TempPathFactory) -> Session:
    cfg = bench_config("flat", width=160, height=120, hue_bands=16, repeats=2, frames=1, period_px=PERIOD,
                       bit_depth=16, id="asm16")
    return load_session(write(cfg, tmp_path_factory.mktemp("b16")))


@pytest.fixture(scope="module")
def m8(bench8: Session):
    return measure(bench8)


def test_natural_order() -> None:
    assert sorted(["cap_10.png", "cap_2.png", "cap_1.png"], key=natural_key) == ["cap_1.png", "cap_2.png", "cap_10.png"]


@pytest.mark.parametrize("ext", [".png", ".tiff"])
def test_round_trip_8bit_identical_images_and_heights(bench8: Session, m8, tmp_path: Path, ext: str) -> None:
    caps = tmp_path / "caps"
    disassemble(bench8, caps, ext=ext)
    before = snapshot(caps)
    out = assemble_session(caps, write_patterns(bench8, tmp_path / "pat"), write_spec(bench8, tmp_path / "spec.yaml"),
                           tmp_path / "out")
    assert snapshot(caps) == before
    s = load_session(out, deep=True)
    assert (s.width, s.height, s.bit_depth, s.period_px, s.hue_bands, s.repeats) == (160, 120, 8, PERIOD, 16, 2)
    assert s.meta["provenance"]["operator"] == "T. Est"
    pairs = capture_order(bench8)
    assert len(pairs) == 2 + 2 * 32 + 3 + 2 + 3
    for rel, p in pairs:
        np.testing.assert_array_equal(read_rgb_codes(out / rel), read_rgb_codes(p), err_msg=rel)
    m = measure(s)
    np.testing.assert_array_equal(m.heights, m8.heights)
    flat = m8.heights[0][np.isfinite(m8.heights[0])]
    assert flat.size > 0.9 * 160 * 120 and abs(np.median(flat) - 2.0) < 0.05  # the 2.0 mm board


def test_round_trip_16bit_and_12bit(bench16: Session, tmp_path: Path) -> None:
    pat = write_patterns(bench16, tmp_path / "pat")
    out16 = assemble_session(disassemble(bench16, tmp_path / "c16")[0].parent, pat,
                             write_spec(bench16, tmp_path / "s16.yaml"), tmp_path / "o16")
    for rel, p in capture_order(bench16):
        np.testing.assert_array_equal(read_rgb_codes(out16 / rel), read_rgb_codes(p), err_msg=rel)
    h_orig = measure(bench16).heights
    np.testing.assert_array_equal(measure(out16).heights, h_orig)

    caps12 = tmp_path / "c12"
    disassemble(bench16, caps12, convert=lambda a: a >> 4, ext=".tiff")  # 12-bit data in 16-bit TIFFs
    out12 = assemble_session(caps12, pat, write_spec(bench16, tmp_path / "s12.yaml", bit_depth_in=12), tmp_path / "o12")
    s12 = load_session(out12, deep=True)
    assert s12.bit_depth == 16
    for rel, p in capture_order(bench16):
        np.testing.assert_array_equal(read_rgb_codes(out12 / rel), (read_rgb_codes(p) >> 4) << 4, err_msg=rel)
    h12 = measure(s12).heights
    both = np.isfinite(h12) & np.isfinite(h_orig)
    assert both.mean() > 0.9
    diff = np.abs(h12 - h_orig)[both]
    assert np.percentile(diff, 99) < 0.01 and np.median(diff) < 0.002, (np.median(diff), np.percentile(diff, 99))


def test_bayer_mosaics_are_demosaiced(bench8: Session, tmp_path: Path) -> None:
    caps = tmp_path / "raw"
    disassemble(bench8, caps, convert=lambda a: camera.mosaic(a, "GRBG"))
    when = dt.datetime(2026, 12, 3, 10, 0, tzinfo=dt.timezone.utc)  # an unquoted YAML timestamp
    pat = write_patterns(bench8, tmp_path / "pat")
    out = assemble_session(caps, pat, write_spec(bench8, tmp_path / "spec.yaml", bayer="GRBG",
                                                 provenance={"captured_at": when}), tmp_path / "out")
    assert load_session(out, deep=True).meta["provenance"]["captured_at"] == "2026-12-03T10:00:00Z"
    # the CLI's --bayer gives the same files as the spec's bayer
    assert cli.main(["session", str(caps), str(pat), str(write_spec(bench8, tmp_path / "plain.yaml")),
                     str(tmp_path / "cli"), "--bayer", "GRBG"]) == 0
    rel = "object/frames/frame_0001.png"
    np.testing.assert_array_equal(read_rgb_codes(tmp_path / "cli" / rel), read_rgb_codes(out / rel))
    for rel, p in capture_order(bench8):
        expect = camera.demosaic(camera.mosaic(read_rgb_codes(p), "GRBG"), "GRBG")
        np.testing.assert_array_equal(read_rgb_codes(out / rel), expect, err_msg=rel)


def test_fringe_spectrum_measures_the_period(bench8: Session) -> None:
    white = read_rgb_codes(bench8.reference_white)
    amp, period = fringe_spectrum(fringe_profile(read_rgb_codes(bench8.planes[0.0]), white))
    assert amp > 0.3 and abs(period - PERIOD) < 0.02 * PERIOD, (amp, period)
    amp, _ = fringe_spectrum(fringe_profile(read_rgb_codes(bench8.reference_bands[5][0]), white))
    assert amp < 0.03


# --------------------------------------------------------------------------- refusals


@pytest.fixture
def kit(bench8: Session, tmp_path: Path):
    caps = tmp_path / "caps"
    files = disassemble(bench8, caps)
    return caps, files, write_patterns(bench8, tmp_path / "pat"), write_spec(bench8, tmp_path / "spec.yaml"), tmp_path


def refused(kit, *, spec=None, bayer=None, out=None) -> str:
    caps, _, pat, spec0, tmp = kit
    before = snapshot(caps)
    out = out or tmp / "out"
    with pytest.raises(SessionError) as exc:
        assemble_session(caps, pat, spec or spec0, out, bayer=bayer)
    assert snapshot(caps) == before
    assert not (tmp / "out").exists()
    assert not [p for p in tmp.iterdir() if p.name.startswith(".out.")]
    return str(exc.value)


def test_refuses_missing_and_extra_captures(kit) -> None:
    caps, files, *_ = kit
    files[-1].unlink()
    files[-2].unlink()
    msg = refused(kit)
    assert "2 missing" in msg and "object/phase_shift/frame_0000_s1.png" in msg and str(caps) in msg
    shutil.copy(files[0], files[-1])  # now one missing in the middle: the numbering gap names it
    files[-1].rename(caps / "cap_75.png")
    msg = refused(kit)
    assert "1 missing; the file numbering has gaps: no file numbered 73-74 between cap_72.png and cap_75.png" in msg
    (caps / "cap_75.png").unlink()
    shutil.copy(files[0], files[-2])
    shutil.copy(files[0], files[-1])
    shutil.copy(files[0], caps / "cap_999.png")
    msg = refused(kit)
    assert "75 captures for 74 manifest rows: 1 extra; 3 of the captures are copies of another" in msg
    for name in ("cap_73.png", "cap_74.png", "cap_999.png"):
        assert f"{name}: has the same pixel values as cap_1.png: a copy" in msg


def test_refuses_size_and_bit_depth_mismatch(kit) -> None:
    caps, files, *_ = kit
    img = cv2.imread(str(files[7]), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(files[7]), img[:, :158])
    msg = refused(kit)
    assert "cap_8.png" in msg and "158 x 120" in msg and "cap_1.png" in msg
    cv2.imwrite(str(files[7]), img.astype(np.uint16) * 257)
    msg = refused(kit)
    assert "cap_8.png" in msg and "16-bit" in msg


def test_refuses_bayer_that_does_not_fit(kit, bench8: Session) -> None:
    assert "does not fit Bayer pattern RGGB" in refused(kit, bayer="RGGB") and "cap_1.png" in refused(kit, bayer="RGGB")
    caps, files, *_ = kit
    for f in files:  # single-channel but odd width
        raw = camera.mosaic(cv2.imread(str(f))[:, :159], "RGGB")
        cv2.imwrite(str(f), raw)
    msg = refused(kit, bayer="RGGB")
    assert "cap_1.png" in msg and "even width and height" in msg
    assert "not an RGB image" in refused(kit)  # raw files without a Bayer pattern


@pytest.mark.parametrize("change, needle", [
    ({"pixel_pitch_mm": None}, "pixel_pitch_mm"),
    ({"id": "Bad Id"}, "Bad Id"),
    ({"bayer": "RGBG"}, "RGBG"),
    ({"colour": 3}, "colour"),
    ({"camera": {"width": 10}}, "camera"),
])
def test_refuses_bad_spec(kit, change, needle) -> None:
    *_, spec, tmp = kit
    data = yaml.safe_load(spec.read_text())
    for k, v in change.items():
        if v is None:
            data.pop(k)
        else:
            data[k] = v
    bad = tmp / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    msg = refused(kit, spec=bad)
    assert "bad.yaml" in msg and needle in msg


def test_refuses_existing_nonempty_out(kit) -> None:
    caps, _, pat, spec, tmp = kit
    out = tmp / "taken"
    out.mkdir()
    (out / "x.txt").write_text("keep")
    with pytest.raises(SessionError, match="taken: already exists and is not empty"):
        assemble_session(caps, pat, spec, out)
    assert [p.name for p in out.iterdir()] == ["x.txt"]
    before = snapshot(caps)
    with pytest.raises(SessionError, match="lies inside the captures folder"):
        assemble_session(caps, pat, spec, caps / "session")
    assert snapshot(caps) == before


def test_refuses_a_wrong_period(kit, bench8: Session) -> None:
    *_, tmp = kit
    msg = refused(kit, spec=write_spec(bench8, tmp / "p30.yaml", period_px=30))
    assert "cap_34.png" in msg and "30" in msg and "is 23.9" in msg  # cap_34 is reference/planes/z_0.000
    # within 5 % passes
    caps, _, pat, *_ = kit
    assemble_session(caps, pat, write_spec(bench8, tmp / "p25.yaml", period_px=25), tmp / "ok")


def test_refuses_captures_out_of_order(kit) -> None:
    caps, files, *_ = kit
    a, b = files[0].read_bytes(), files[5].read_bytes()  # reference white <-> a reference band
    files[0].write_bytes(b)
    files[5].write_bytes(a)
    msg = refused(kit)
    assert "cap_6.png" in msg and "brighter than the white" in msg and "likely out of order" in msg
    files[0].write_bytes(a)
    files[5].write_bytes(b)
    p, q = files[3].read_bytes(), files[33].read_bytes()  # a band <-> the z=0 plane
    files[3].write_bytes(q)
    files[33].write_bytes(p)
    msg = refused(kit)
    assert "cap_4.png: shows a fringe" in msg and "cap_34.png: shows no fringe" in msg


def test_cli_session(kit, capsys) -> None:
    caps, files, pat, spec, tmp = kit
    assert cli.main(["session", str(caps), str(pat), str(spec), str(tmp / "cli")]) == 0
    assert load_session(tmp / "cli", deep=True).id == "asm8"
    files[-1].unlink()
    assert cli.main(["session", str(caps), str(pat), str(spec), str(tmp / "cli2")]) == 2
    err = capsys.readouterr().err
    assert "1 missing" in err and not (tmp / "cli2").exists()


@pytest.mark.parametrize("preset, size", [("dental", (160, 120)), ("demo", (320, 240))])
def test_content_checks_accept_objects_with_texture_and_steps(preset: str, size: tuple[int, int], tmp_path: Path) -> None:
    """Shading, albedo and gauge-block shadows in the object's bands stay below the fringe level
    (measured: at most 0.015 (dental) and 0.04 (demo) of white, fringes 0.43-0.49)."""
    cfg = bench_config(preset, width=size[0], height=size[1], hue_bands=16, repeats=2, frames=1, id=f"t-{preset}")
    s = load_session(write(cfg, tmp_path / "b"))
    out = assemble_session(disassemble(s, tmp_path / "caps")[0].parent, write_patterns(s, tmp_path / "pat"),
                           write_spec(s, tmp_path / "spec.yaml"), tmp_path / "out")
    for rel, p in capture_order(s):
        np.testing.assert_array_equal(read_rgb_codes(out / rel), read_rgb_codes(p), err_msg=rel)
    obj_white = read_rgb_codes(s.object_white)
    amps = [fringe_spectrum(fringe_profile(read_rgb_codes(p), obj_white))[0] for reps in s.object_bands for p in reps]
    assert max(amps) < 0.05


def test_refuses_a_manifest_that_breaks_the_layout(kit) -> None:
    caps, files, pat, spec, tmp = kit
    text = (pat / "manifest.csv").read_text()
    (pat / "manifest.csv").write_text(text.replace("reference/hue/band_003_r1.png", "reference/hue/band_3_r1.png"))
    assert "manifest.csv: line 10 (order 8): session_path 'reference/hue/band_3_r1.png'" in refused(kit)
    # paths of the right form but an incomplete layout (band 003 repeat 1 twice -> r2): load_session refuses,
    # named under OUT, nothing left behind
    (pat / "manifest.csv").write_text(text.replace("reference/hue/band_003_r1.png", "reference/hue/band_003_r2.png"))
    msg = refused(kit)
    assert str(tmp / "out") in msg and "nothing written" in msg and ".part" not in msg


# --------------------------------------------------------------------------- what a user meets at the rig


def session_cli(kit, *extra: str, out: str = "cli") -> tuple[int, str]:
    """``huefringe session CAPTURES PATTERNS SPEC OUT [extra]`` as a user types it: exit code and stderr."""
    caps, _, pat, spec, tmp = kit
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = cli.main(["session", str(caps), str(pat), str(spec), str(tmp / out), *extra])
    assert code == 0 or not (tmp / out).exists()
    return code, err.getvalue()


def test_a_copied_capture_is_named_as_the_copy_not_the_last_file(kit) -> None:
    caps, files, *_ = kit
    shutil.copy(files[40], caps / "cap_41 copy.png")  # a file manager's copy of one good capture
    code, err = session_cli(kit)
    assert code == 2
    assert "75 captures for 74 manifest rows: 1 extra; 1 of the captures is a copy of another" in err
    assert "cap_41 copy.png: has the same pixel values as cap_41.png: a copy, not a second capture" in err
    assert "cap_74.png" not in err  # the last good file is not blamed
    # re-saved in another format: the same pixels, still named
    (caps / "cap_41 copy.png").unlink()
    tifffile.imwrite(caps / "cap_41 copy.tiff", cv2.cvtColor(cv2.imread(str(files[40])), cv2.COLOR_BGR2RGB),
                     photometric="rgb")
    code, err = session_cli(kit)
    assert "cap_41 copy.tiff: has the same pixel values as cap_41.png" in err
    # near-identical: a handful of pixels one code apart (a re-encoded copy), and in place of a capture
    (caps / "cap_41 copy.tiff").unlink()
    img = cv2.imread(str(files[40]))
    img[5, 7, 1] += 1
    cv2.imwrite(str(files[41]), img)  # cap_42 (band 19 r1) overwritten by a near copy of cap_41
    code, err = session_cli(kit)
    assert code == 2 and "cap_42.png: is near-identical to" in err and "cap_41.png: a copy" in err


def test_swapped_hue_bands_are_named_at_assembly(kit) -> None:
    caps, files, *_ = kit
    # reference band i repeat r is capture 2 + 2 i + r (cap_1 is the white): bands 3 and 9 swapped
    for r in (0, 1):
        a, b = files[1 + 2 * 3 + r], files[1 + 2 * 9 + r]
        da, db = a.read_bytes(), b.read_bytes()
        a.write_bytes(db)
        b.write_bytes(da)
    code, err = session_cli(kit)
    assert code == 2
    lines = [ln for ln in err.splitlines() if "hue band captured out of order" in ln]
    assert len(lines) == 4, err
    assert "cap_8.png: goes to reference/hue/band_003_r0.png (hue band 003) but its hue" in err
    assert "is that of band 009" in err and "is that of band 003" in err
    assert "cap_8.png: goes to" in err and "cap_9.png: goes to reference/hue/band_003_r1.png" in err
    line9 = next(ln for ln in lines if "cap_9.png" in ln)
    assert line9.endswith("swapped with cap_21.png?") and lines[0].endswith("swapped with cap_20.png?")


def test_a_wrong_bayer_pattern_is_named_with_the_likely_one(kit, bench8: Session) -> None:
    caps, files, *_ = kit
    for (_, p), f in zip(capture_order(bench8), files):
        assert cv2.imwrite(str(f), camera.mosaic(read_rgb_codes(p), "RGGB"))
    code, err = session_cli(kit, "--bayer", "GBRG")
    assert code == 2
    assert "REFUSED: no session written (1 problem(s))" in err, err
    assert "the Bayer pattern GBRG does not fit these mosaics" in err and "point to RGGB: give --bayer RGGB" in err
    assert "out of order" not in err
    for other in ("RGGB", "BGGR", "GRBG", "GBRG"):
        assert f"{other} " in err.split("compared (")[1]
    assert session_cli(kit, "--bayer", "RGGB", out="ok")[0] == 0


def test_a_mixed_folder_is_reported_in_one_pass(kit) -> None:
    caps, files, *_ = kit
    files[3].write_bytes(files[3].read_bytes()[:200])  # truncated
    img = cv2.imread(str(files[7]), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(files[7]), img[:, :158])  # another size
    cv2.imwrite(str(files[9]), cv2.imread(str(files[9]), cv2.IMREAD_UNCHANGED).astype(np.uint16) * 257)  # 16-bit
    code, err = session_cli(kit)
    assert code == 2
    assert "cap_4.png: cannot decode image" in err
    assert "cap_8.png: 158 x 120 px, 3 channel(s), 8-bit differs from 71 of the 73 captures (160 x 120 px" in err
    assert "cap_10.png: 160 x 120 px, 3 channel(s), 16-bit differs from 71 of the 73" in err


def test_a_full_disk_is_refused_before_writing(kit, monkeypatch) -> None:
    import collections

    from huefringe import assemble

    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(assemble.shutil, "disk_usage", lambda p: usage(10**9, 10**9 - 1000, 1000))
    code, err = session_cli(kit)
    assert code == 2 and "cli: needs about 0.0 GB" in err and "has 0.0 GB free" in err


def test_check_deep_names_swapped_hue_bands_of_a_session(bench8: Session, tmp_path: Path, capsys) -> None:
    sess = tmp_path / "s"
    shutil.copytree(bench8.root, sess)
    assert cli.main(["check", "--deep", str(sess)]) == 0
    a, b = sess / "object/hue/band_002_r0.png", sess / "object/hue/band_011_r0.png"
    da, db = a.read_bytes(), b.read_bytes()
    a.write_bytes(db)
    b.write_bytes(da)
    assert cli.main(["check", str(sess)]) == 0  # the quick check reads headers only
    capsys.readouterr()
    assert cli.main(["check", "--deep", str(sess)]) == 1
    out = capsys.readouterr().out
    assert "band_002_r0.png: object hue band 002, but its hue" in out and "is that of band 011" in out
    assert "band_011_r0.png: object hue band 011, but its hue" in out and "is that of band 002" in out
