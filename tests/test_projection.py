"""huefringe patterns: the projector images decode to the code phase they stand for, within the
quantisation bound, and the manifest lists every capture in the order of the rig contract."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from huefringe import cli, projection
from huefringe.colour import hue_hexcone, hue_hsi, wrap_pi
from huefringe.patterns import TWO_PI, band_phase, trapezoid_rgb
from huefringe.assemble import read_patterns
from huefringe.projection import PatternsError, projector_period, write_patterns
from huefringe.session import load_session

W, H, T, N, R = 240, 4, 37.0, 12, 2
PLANES = [0.0, 2.0, -1.5]
F = 3


def _read_rgb(path: Path) -> tuple[np.ndarray, int]:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None, path
    top = 255 if img.dtype == np.uint8 else 65535
    return img[..., ::-1].astype(np.float64) / top, top


def _bounds(top: int) -> tuple[float, float]:
    """Worst hue change from rounding to the nearest code (half a step ``e = 0.5 / top``).

    On the trapezoid one channel is 1, one is 0 (both exact after rounding) and one is fractional,
    so the hexcone hue ``pi/3 (mid - min) / (max - min)`` moves by at most ``pi/3 * e``
    (8-bit: pi / 1530 = 2.05e-3 rad, 16-bit: 8.0e-6 rad). The HSI hue ``atan2(y, x)`` moves by at
    most ``|d(x, y)| / |(x, y)|`` with ``|d(x, y)| <= e`` for one channel and ``|(x, y)| >= sqrt(3)/2``
    on the trapezoid: ``2 e / sqrt(3)`` (8-bit 2.26e-3 rad). Plus float32 rounding of the hue (1e-6).
    """
    e = 0.5 / top
    return math.pi / 3 * e + 1e-6, 2 * e / math.sqrt(3) + 1e-6


@pytest.fixture(scope="module", params=[8, 16])
def written(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    out = tmp_path_factory.mktemp(f"p{request.param}") / "pat"
    write_patterns(out, width=W, height=H, period_px=T, hue_bands=N, repeats=R, planes_mm=PLANES, frames=F,
                   bit_depth=request.param)
    return out, request.param


def test_manifest_rows_follow_the_contract(written: tuple[Path, int]) -> None:
    out, _ = written
    rows = read_patterns(out)[1]
    assert (out / "manifest.csv").read_text().splitlines()[0] == "order,image,session_path"
    assert len(rows) == 1 + N * R + len(PLANES) + 1 + N * R + F + 3 == 59
    assert [r.order for r in rows] == list(range(len(rows)))
    want = [("0000_white.png", "reference/white.png")]
    want += [(f"{1 + i:04d}_band_{i:03d}.png", f"reference/hue/band_{i:03d}_r{r}.png") for i in range(N) for r in range(R)]
    want += [("0013_trapezoid.png", p) for p in ("reference/planes/z_0.000.png", "reference/planes/z_2.000.png",
                                                 "reference/planes/z_-1.500.png")]
    want += [("0000_white.png", "object/white.png")]
    want += [(f"{1 + i:04d}_band_{i:03d}.png", f"object/hue/band_{i:03d}_r{r}.png") for i in range(N) for r in range(R)]
    want += [("0013_trapezoid.png", f"object/frames/frame_{f:04d}.png") for f in range(F)]
    want += [(f"{14 + s:04d}_shift_s{s}.png", f"object/phase_shift/frame_0000_s{s}.png") for s in range(3)]
    assert [(r.image, r.session_path) for r in rows] == want
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == sorted({r.image for r in rows}) and len(pngs) == 1 + N + 1 + 3
    assert sorted(p.name for p in out.iterdir()) == sorted([*pngs, "manifest.csv", "patterns.yaml"])
    asked = yaml.safe_load((out / "patterns.yaml").read_text())
    assert (asked["hue_bands"], asked["repeats"], asked["planes_mm"], asked["period_px"]) == (N, R, PLANES, T)
    assert (asked["width"], asked["height"], asked["frames"], asked["phase_shift"]) == (W, H, F, True)


def test_images_have_projector_size_and_depth(written: tuple[Path, int]) -> None:
    out, depth = written
    for p in out.glob("*.png"):
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        assert img.shape == (H, W, 3) and img.dtype == (np.uint8 if depth == 8 else np.uint16), p
    white, top = _read_rgb(out / "0000_white.png")
    assert np.all(white == 1.0)


def test_trapezoid_decodes_to_the_code_phase(written: tuple[Path, int]) -> None:
    out, _ = written
    rgb, top = _read_rgb(out / "0013_trapezoid.png")
    assert np.all(rgb == rgb[:1])  # constant along the columns
    x = np.arange(W)
    phi = TWO_PI * x / T
    b_hex, b_hsi = _bounds(top)
    err_hex = np.abs(wrap_pi(hue_hexcone(rgb[0]).astype(np.float64) - phi))
    assert err_hex.max() <= b_hex
    # HSI is not linear in the code phase (about 0.02 rad, paper eqs. 4-5); quantisation adds <= b_hsi to it
    err_hsi = np.abs(wrap_pi(hue_hsi(rgb[0]).astype(np.float64) - hue_hsi(trapezoid_rgb(phi)).astype(np.float64)))
    assert err_hsi.max() <= b_hsi
    if top == 255:
        assert err_hex.max() > 1e-4  # the 8-bit image is really quantised (the bound is not vacuous)


def test_bands_decode_to_their_phase(written: tuple[Path, int]) -> None:
    out, _ = written
    for i in range(N):
        rgb, top = _read_rgb(out / f"{1 + i:04d}_band_{i:03d}.png")
        assert np.all(rgb == rgb[0, 0])
        b_hex, b_hsi = _bounds(top)
        assert abs(wrap_pi(float(hue_hexcone(rgb[0, 0])) - float(band_phase(i, N)))) <= b_hex
        ideal = float(hue_hsi(trapezoid_rgb(band_phase(i, N))))
        assert abs(wrap_pi(float(hue_hsi(rgb[0, 0])) - ideal)) <= b_hsi


def test_shift_images_are_the_sinusoids(written: tuple[Path, int]) -> None:
    out, _ = written
    x = np.arange(W)
    for s in range(3):
        rgb, top = _read_rgb(out / f"{14 + s:04d}_shift_s{s}.png")
        want = 0.5 + 0.5 * np.cos(TWO_PI * x / T + TWO_PI * (s - 1) / 3)
        assert np.all(rgb[..., 0] == rgb[..., 1]) and np.all(rgb[..., 0] == rgb[..., 2])
        assert np.abs(rgb[..., 0] - want[None, :]).max() <= 0.5 / top + 1e-12 <= 1 / 255


def test_magnification_sets_the_projector_period(tmp_path: Path) -> None:
    assert projector_period(60.0, 1.5) == 40.0
    out = write_patterns(tmp_path / "m", width=80, height=2, hue_bands=6, repeats=1, planes_mm=[0, 1],
                         camera_period_px=60.0, magnification=1.5, phase_shift=False)
    asked = yaml.safe_load((out / "patterns.yaml").read_text())
    assert (asked["period_px"], asked["camera_period_px"], asked["magnification"]) == (40.0, 60.0, 1.5)
    rgb, _ = _read_rgb(out / "0007_trapezoid.png")
    assert abs(wrap_pi(float(hue_hexcone(rgb[0, 10])) - TWO_PI * 10 / 40.0)) <= _bounds(255)[0]
    assert len(read_patterns(out)[1]) == 1 + 6 + 2 + 1 + 6 + 1


@pytest.mark.parametrize(
    ("kwargs", "argument"),
    [
        ({"period_px": 5.9}, "period_px"),
        ({"period_px": -10.0}, "period_px"),
        ({"period_px": None, "camera_period_px": 10.0, "magnification": 2.0}, "camera_period_px"),
        ({"period_px": None, "camera_period_px": 60.0}, "period_px"),
        ({"period_px": None, "camera_period_px": 60.0, "magnification": 0.0}, "magnification"),
        ({"hue_bands": 1}, "hue_bands"),
        ({"hue_bands": 5}, "hue_bands"),
        ({"repeats": 0}, "repeats"),
        ({"planes_mm": [0.0]}, "planes_mm"),
        ({"planes_mm": [1.0, 2.0]}, "planes_mm"),
        ({"planes_mm": [0.0, 2.0, 2.0001]}, "planes_mm"),
        ({"frames": 0}, "frames"),
        ({"width": 0}, "width"),
        ({"bit_depth": 12}, "bit_depth"),
    ],
)
def test_bad_input_is_refused_before_writing(tmp_path: Path, kwargs: dict, argument: str) -> None:
    args = {"width": 32, "height": 2, "period_px": 8.0, "hue_bands": 6, "repeats": 1, "planes_mm": [0.0, 1.0]}
    args.update(kwargs)
    with pytest.raises(PatternsError) as err:
        write_patterns(tmp_path / "out", **args)
    assert err.value.argument == argument and str(err.value).startswith(argument + ":")
    assert list(tmp_path.iterdir()) == []


def test_existing_folder_is_refused_and_kept(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(PatternsError, match="already exists") as err:
        write_patterns(out, width=32, height=2, period_px=8.0, hue_bands=6, repeats=1, planes_mm=[0, 1])
    assert err.value.argument == "out_dir"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"] and [p.name for p in out.iterdir()] == ["keep.txt"]
    empty = tmp_path / "empty"
    empty.mkdir()
    write_patterns(empty, width=32, height=2, period_px=8.0, hue_bands=6, repeats=1, planes_mm=[0, 1])
    assert (empty / "manifest.csv").is_file()


def test_interrupted_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls = {"n": 0}
    real = projection.write_png_rgb

    def failing(path, rgb):  # noqa: ANN001 - test double
        calls["n"] += 1
        if calls["n"] == 4:
            raise KeyboardInterrupt
        real(path, rgb)

    monkeypatch.setattr(projection, "write_png_rgb", failing)
    with pytest.raises(KeyboardInterrupt):
        write_patterns(tmp_path / "out", width=32, height=2, period_px=8.0, hue_bands=6, repeats=1, planes_mm=[0, 1])
    assert list(tmp_path.iterdir()) == []


def test_cli_writes_and_refuses(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cli"
    rc = cli.main(["patterns", str(out), "--width", "48", "--height", "3", "--camera-period-px", "30",
                   "--magnification", "2.5", "--bands", "6", "--repeats", "2", "--planes", "0,1.5",
                   "--frames", "2", "--bit-depth", "16"])
    assert rc == 0
    said = capsys.readouterr().out
    assert "wrote 11 projector images" in said
    assert f"{1 + 12 + 2 + 1 + 12 + 2 + 3} captures" in said and str(out) in said
    asked = yaml.safe_load((out / "patterns.yaml").read_text())
    assert asked["period_px"] == 12.0 and asked["bit_depth"] == 16 and asked["planes_mm"] == [0.0, 1.5]
    assert cv2.imread(str(out / "0007_trapezoid.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint16

    rc = cli.main(["patterns", str(tmp_path / "bad"), "--width", "48", "--height", "3", "--period-px", "4"])
    assert rc == 2 and "--period-px" in capsys.readouterr().err
    rc = cli.main(["patterns", str(tmp_path / "bad"), "--width", "48", "--height", "3", "--period-px", "8",
                   "--planes", "0,x"])
    assert rc == 2 and "--planes" in capsys.readouterr().err
    rc = cli.main(["patterns", str(out), "--width", "48", "--height", "3", "--period-px", "8"])
    assert rc == 2 and "OUT" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_manifest_paths_make_a_session_that_check_accepts(tmp_path: Path) -> None:
    """Each manifest row's image copied to its session_path (a camera seeing the projector 1:1) is a
    capture-session/1 folder that ``load_session`` accepts, with the asked N, R, planes and frames."""
    pat = write_patterns(tmp_path / "pat", width=48, height=8, period_px=12.0, hue_bands=6, repeats=2,
                         planes_mm=[0.0, 1.0, 2.5], frames=2)
    asked = yaml.safe_load((pat / "patterns.yaml").read_text())
    ses = tmp_path / "ses"
    for row in read_patterns(pat)[1]:
        (ses / row.session_path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(pat / row.image, ses / row.session_path)
    meta = {"format": "capture-session/1", "id": "projected-1to1",
            "camera": {"width": 48, "height": 8, "bit_depth": 8, "pixel_pitch_mm": 0.1},
            "pattern": {"period_px": asked["period_px"], "hue_bands": asked["hue_bands"], "repeats": asked["repeats"]},
            "planes_mm": asked["planes_mm"]}
    (ses / "session.yaml").write_text(yaml.safe_dump(meta))
    s = load_session(ses, deep=True)
    assert (s.hue_bands, s.repeats, s.planes_mm) == (6, 2, [0.0, 1.0, 2.5])
    assert s.frame_ids == [0, 1] and list(s.phase_shift) == [0]


# --------------------------------------------------------------------------- --compensated (paper Fig. 6)
def _calib_folder(root: Path, amplitude: float = 0.3) -> Path:
    """A calibration folder whose plate hue table has the transfer ``hue = c + a sin(c)`` (every pixel)."""
    from test_patterns_gamma import calib_folder

    c = TWO_PI * np.arange(32) / 32
    return calib_folder(root, c + amplitude * np.sin(c))


@pytest.mark.parametrize("depth", [8, 16])
def test_compensated_trapezoid_decodes_through_its_predistortion(tmp_path: Path, depth: int) -> None:
    from huefringe.session import read_predistortion

    calib = _calib_folder(tmp_path)
    out = write_patterns(tmp_path / "p", width=W, height=H, period_px=T, hue_bands=N, repeats=1, frames=1,
                         bit_depth=depth, compensated=calib)
    pre = read_predistortion(out / "predistortion.csv")
    asked = yaml.safe_load((out / "patterns.yaml").read_text())["compensated"]
    assert asked["predicted_residual_rad"]["before"] > 0.1 > 0.01 > asked["predicted_residual_rad"]["after"]
    # the emitted phase undoes the plate's transfer: F(p(c)) = p + 0.3 sin(p) = c
    assert np.max(np.abs(wrap_pi(pre.emitted + 0.3 * np.sin(pre.emitted) - pre.code))) < 0.01
    rgb, top = _read_rgb(next(out.glob("*_trapezoid.png")))
    assert np.all(rgb == rgb[:1])
    phi = TWO_PI * np.arange(W) / T
    hue = hue_hexcone(rgb[0]).astype(np.float64)
    assert np.max(np.abs(wrap_pi(hue - phi))) > 0.2  # really pre-distorted
    # decoded with the project's own functions: hue -> emitted phase -> code phase, within quantisation
    # (the hexcone bound, magnified by the steepest slope of the decoding)
    slope = float(np.max(np.diff(pre.code) / np.diff(pre.emitted)))
    err = np.abs(wrap_pi(pre.decode(hue).astype(np.float64) - phi))
    assert err.max() <= slope * _bounds(top)[0] + 1e-5
    # bands and white are not pre-distorted; the phase-shift images are pre-compensated for the
    # projector's gamma fitted to the same table (tests/test_patterns_gamma.py)
    plain = write_patterns(tmp_path / "plain", width=W, height=H, period_px=T, hue_bands=N, repeats=1, frames=1,
                           bit_depth=depth)
    for p in plain.glob("*.png"):
        same = (out / p.name).read_bytes() == p.read_bytes()
        assert same == (not p.name.endswith(("_trapezoid.png", "_shift_s0.png", "_shift_s1.png", "_shift_s2.png"))), \
            p.name
    assert not (plain / "predistortion.csv").exists() and not (plain / "phase_shift_levels.csv").exists()
    assert (out / "phase_shift_levels.csv").is_file()


def test_compensated_refuses_a_folder_without_the_table(tmp_path: Path) -> None:
    calib = _calib_folder(tmp_path)
    (calib / "table_reference.maps.npz").unlink()
    with pytest.raises(PatternsError) as exc:
        write_patterns(tmp_path / "p", width=W, height=H, period_px=T, compensated=calib)
    assert exc.value.argument == "compensated" and "table_reference.maps.npz is missing" in exc.value.problem
    assert not (tmp_path / "p").exists()
    with pytest.raises(PatternsError, match="not a folder"):
        write_patterns(tmp_path / "p", width=W, height=H, period_px=T, compensated=tmp_path / "nowhere")


@pytest.mark.parametrize("argv, needle", [
    (["--width", "100000", "--height", "100000", "--period-px", "40"], "--width: must be in 1..16384, got 100000"),
    (["--width", "1", "--height", "1", "--period-px", "40"], "--height: must be in 2..16384, got 1"),
    (["--width", "1", "--height", "8", "--period-px", "40"], "--width: the fringe must repeat at least 2 times across "
                                                             "the projector's 1 px"),
    (["--width", "1024", "--height", "768", "--period-px", "600"], "--period-px: the fringe must repeat at least 2 "
                                                                   "times across the projector's 1024 px"),
    (["--width", "1024", "--height", "768", "--camera-period-px", "900", "--magnification", "1.5"],
     "--camera-period-px: the fringe must repeat at least 2 times"),
])
def test_patterns_refuses_impossible_sizes_before_any_work(argv, needle, tmp_path: Path, capsys) -> None:
    out = tmp_path / "pat"
    assert cli.main(["patterns", str(out), *argv]) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err
    assert not out.exists() and not list(tmp_path.iterdir())


def test_patterns_refuses_an_image_larger_than_the_memory(tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.setattr(projection, "_available_memory", lambda: 2**30)  # a machine with 1 GiB free
    assert cli.main(["patterns", str(tmp_path / "p"), "--width", "16384", "--height", "16384", "--period-px", "40"]) == 2
    err = capsys.readouterr().err
    assert "--width: one 16384 x 16384 image needs about 2.2 GiB of memory while it is written, and 1.0 GiB" in err
    assert not list(tmp_path.iterdir())


def test_bench_names_an_unknown_preset(tmp_path: Path, capsys) -> None:
    assert cli.main(["bench", "--preset", "nosuchpreset", str(tmp_path / "s")]) == 1
    err = capsys.readouterr().err
    assert "REFUSED: --preset: no bench preset 'nosuchpreset'; available: bayer_gauge, demo" in err
