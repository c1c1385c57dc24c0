"""The real-rig chain's two verbs against each other: ``huefringe patterns`` writes the manifest a
capture script follows, the captures (here: the bench's, taken in the manifest's order and
renamed as a camera names its files) go through ``huefringe session``, and the assembled
session measures exactly as the bench's own; then the bench is fed the projector files themselves
(``huefringe bench --patterns``), plain and compensated (``huefringe patterns --compensated``)."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
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


# --------------------------------------------------------------------------- the bench fed the files
# The full chain a lab runs, with the bench as projector and camera: ``huefringe patterns`` writes
# the image files, ``huefringe bench CONFIG CAMERA --patterns DIR`` shows each file in manifest order
# and saves IMG_0001.png ..., ``huefringe session`` assembles them. Gauge blocks (four steps) at
# 160 x 120 px, 0.5 mm pitch (the preset's 80 x 60 mm field), 16 bands, 1024 x 768 projector.
#: Measured with the defaults. On these untextured blocks the phase's texture-blur estimate is a ratio of
#: two near-zero sums (it once read 0.0 and 42.8 px^2 on two 640 x 480 sessions 1 DN apart); its
#: significance test must refuse it on both routes, or the routes would not compare; the white image's
#: edges then give the blur on each route alike.
MEASURE = None
GAUGE = {"width": 160, "height": 120, "pixel_pitch_mm": 0.5, "period_px": 24, "hue_bands": 16, "repeats": 2,
         "frames": 2, "id": "rig-files"}


def _errors(heights: np.ndarray, truth: list[np.ndarray]) -> tuple[float, float, float]:
    """Median and p95 of |height - truth| over every valid pixel of every frame, and the coverage."""
    ok = np.isfinite(heights)
    err = np.abs(heights - np.stack(truth))[ok]
    return float(np.median(err)), float(np.percentile(err, 95)), float(ok.mean())


def _steps(result: object, session: object) -> list[float]:
    from huefringe.metrology import evaluate_session

    ev = evaluate_session(list(result.heights), session.specimen, session.pixel_pitch_mm,  # type: ignore[attr-defined]
                          range_mm=max(session.planes_mm) - min(session.planes_mm))  # type: ignore[attr-defined]
    return [s["error_mm"] for s in ev["steps"]]


@pytest.fixture(scope="module")
def gauge_chain(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    import tifffile

    root = tmp_path_factory.mktemp("rig-files")
    cfg = bench_config("plain_gauge", **GAUGE)
    direct = load_session(write(cfg, root / "bench"))
    (root / "bench.yaml").write_text(yaml.safe_dump(cfg))
    spec = root / "spec.yaml"
    spec.write_text(yaml.safe_dump({"id": "rig-files", "pixel_pitch_mm": 0.5, "period_px": 24,
                                    "specimen": direct.meta["specimen"], "provenance": {"simulated": True}}))
    mag = cfg["projector"]["pixel_mm"] / GAUGE["pixel_pitch_mm"]  # 0.1 mm projector pixels: 0.2 camera px each
    planes = ",".join(f"{z:g}" for z in direct.planes_mm)

    def chain(name: str, *extra: str) -> object:
        pat, cam, out = root / f"patterns-{name}", root / f"camera-{name}", root / f"session-{name}"
        assert cli.main(["patterns", str(pat), "--width", "1024", "--height", "768", "--camera-period-px", "24",
                         "--magnification", f"{mag:g}", "--bands", "16", "--repeats", "2", "--planes", planes,
                         "--frames", "2", *extra]) == 0
        assert cli.main(["bench", str(root / "bench.yaml"), str(cam), "--patterns", str(pat), "--quiet"]) == 0
        assert cli.main(["session", str(cam), str(pat), str(spec), str(out)]) == 0
        return load_session(out, deep=True)

    plain = chain("plain")
    m_plain = measure(plain, MEASURE)
    calib = root / "calib"  # what the workflow's hue_table rule leaves in results/<id>/calib
    calib.mkdir()
    m_plain.tables["reference"].save(calib / "table_reference.json")
    comp = chain("compensated", "--compensated", str(calib))
    truth = [tifffile.imread(direct.ground_truth[f]) for f in direct.frame_ids]
    return {"cfg": cfg, "root": root, "direct": direct, "plain": plain, "comp": comp, "truth": truth,
            "m_direct": measure(direct, MEASURE), "m_plain": m_plain, "m_comp": measure(comp, MEASURE)}


def test_bench_fed_the_projector_files_measures_as_the_bench_session(gauge_chain: dict[str, object]) -> None:
    g = gauge_chain
    root, plain, direct = g["root"], g["plain"], g["direct"]
    # the camera folder holds one file per manifest row, named as a camera names them
    with open(root / "patterns-plain" / "manifest.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    cams = sorted(p.name for p in (root / "camera-plain").iterdir())
    assert cams == [f"IMG_{k + 1:04d}.png" for k in range(len(rows))]
    assert plain.frame_ids == direct.frame_ids and plain.planes_mm == direct.planes_mm  # type: ignore[attr-defined]
    med_d, p95_d, cov_d = _errors(g["m_direct"].heights, g["truth"])  # type: ignore[attr-defined]
    med_f, p95_f, cov_f = _errors(g["m_plain"].heights, g["truth"])  # type: ignore[attr-defined]
    assert med_d < 0.03  # the direct session measures as bench sessions do
    # untextured: the phase's blur estimate is refused on every route, and the blur is read from the
    # white image's coating edges instead (texture.blur_from_white): the bench lens, 0.81 px^2
    blurs = []
    for m in (g["m_direct"], g["m_plain"], g["m_comp"]):
        rec = m.calibration.stats["texture_blur"]  # type: ignore[attr-defined]
        assert "rejected" in rec and "rejected" not in rec["white_edges"], rec
        assert rec["sigma2_px2"] == rec["white_edges"]["sigma2_px2"], rec
        blurs.append(rec["sigma2_px2"])
    assert 0.81 * 0.85 <= min(blurs) and max(blurs) <= 0.81 * 1.15, blurs  # measured 0.838 (direct)
    assert max(blurs) - min(blurs) < 0.05, blurs
    assert abs(med_f - med_d) <= max(0.1 * med_d, 0.002)  # measured: 0.0169 vs 0.0168 mm, p95 0.142 vs 0.140
    assert abs(p95_f - p95_d) <= max(0.1 * p95_d, 0.002)
    assert abs(cov_f - cov_d) < 0.02
    # the images differ from the direct session's only by what was projected: same ripple, not the same bytes
    a = cv2.imread(str(plain.planes[0.0]), cv2.IMREAD_UNCHANGED)  # type: ignore[attr-defined]
    b = cv2.imread(str(direct.planes[0.0]), cv2.IMREAD_UNCHANGED)  # type: ignore[attr-defined]
    diff = np.abs(a.astype(np.int64) - b.astype(np.int64))
    assert 0 < np.median(diff) < 0.01 * 65535
    # the camera's crosstalk, estimated from 16 bands x 2 repeats on both routes: the bench's to 2e-4, and
    # each primary's two ramp segments agree (docs/accuracy.md: measured 1.6e-4, spread 1.9e-4)
    m_true = np.asarray(g["cfg"]["camera"]["crosstalk"]) * np.asarray(g["cfg"]["camera"]["sensitivity"])[None, :]  # type: ignore[index]
    m_true = m_true / np.diag(m_true)[None, :]
    for m in (g["m_direct"], g["m_plain"]):
        rec = m.camera_record["colour_demixing"]  # type: ignore[attr-defined]
        assert rec["applied"] and np.abs(np.asarray(rec["estimate"]["matrix"]) - m_true).max() < 1e-3
        assert rec["estimate"]["max_segment_spread"] < 1e-3
    # the four steps too (errors at this coarse 0.5 mm pitch and 16 bands; measured with the colour
    # demixing: 0.006/0.017/0.032/-0.002 mm from the files, 0.004/0.017/0.032/-0.001 mm direct; without
    # 0.003/0.005/0.022/0.003 and 0.003/0.003/0.024/0.003 mm). Over 20 bench seeds of this session the red
    # step reads +18.7 um (sd 11.3) demixed and +20.1 um (sd 11.0) not: the demixing does not move it
    # (paired -1.4 +- 1.1 um); this seed's +7 um is the seed's (docs/accuracy.md). The bounds:
    # the ensemble's mean + 2 sd (red 0.041, the others 0.015-0.028 mm), and the routes' agreement.
    steps = (_steps(g["m_plain"], plain), _steps(g["m_direct"], direct))
    bounds = (0.02, 0.03, 0.042, 0.03)  # green, navy, red, charcoal
    for e_f, e_d, bound in zip(steps[0], steps[1], bounds, strict=True):
        assert abs(e_f) < bound and abs(e_d) < bound and abs(e_f - e_d) < 0.005


def _plate_hue_rms(session: object, cfg: dict, m: object) -> float:
    """RMS (rad) of the white-balanced hexcone hue of the plane z = 0 about the true code phase
    (offset removed), read as the measurement ``m`` reads its captures (the camera's crosstalk
    demixed): the plate's transfer-function ripple that compensation flattens."""
    from huefringe import colour
    from huefringe.bench import Bench
    from huefringe.camera import corrections

    rig = Bench(cfg).rig
    read = corrections(m.camera_record, session.meta)[1].rgb  # type: ignore[attr-defined]
    wb = colour.white_balance(read(session.planes[0.0]), read(session.reference_white))  # type: ignore[attr-defined]
    truth = 2 * np.pi * (np.arange(wb.shape[1]) * GAUGE["pixel_pitch_mm"] - rig.x_origin_mm) / rig.period_mm
    e = colour.wrap_pi(colour.hue(wb, "hexcone") - truth[None, :])
    e = colour.wrap_pi(e - np.nanmedian(e))
    return float(np.sqrt(np.nanmean(e**2)))


def test_compensated_patterns_flatten_the_plate_hue_and_decode(gauge_chain: dict[str, object]) -> None:
    g = gauge_chain
    root, comp, plain, cfg = g["root"], g["comp"], g["plain"], g["cfg"]
    # patterns folder: the trapezoid pre-distorted, bands plain, predistortion.csv copied into the session
    assert (root / "patterns-compensated" / "predistortion.csv").is_file()
    assert comp.predistortion is not None and plain.predistortion is None  # type: ignore[attr-defined]
    asked = yaml.safe_load((root / "patterns-compensated" / "patterns.yaml").read_text())
    assert asked["compensated"]["table"] == "table_reference.json"
    pat_plain, pat_comp = root / "patterns-plain", root / "patterns-compensated"
    for name in ("0001_band_000.png", "0000_white.png"):
        assert (pat_plain / name).read_bytes() == (pat_comp / name).read_bytes()
    trap = next(pat_comp.glob("*_trapezoid.png")).name
    assert (pat_plain / trap).read_bytes() != (pat_comp / trap).read_bytes()
    # the captured plate hue becomes linear in the code phase (paper Fig. 6): measured 0.169 -> 0.030 rad
    before, after = _plate_hue_rms(plain, cfg, g["m_plain"]), _plate_hue_rms(comp, cfg, g["m_comp"])
    assert before > 0.1 and after < 0.3 * before
    # and the session decodes through predistortion.csv to the same accuracy
    med_d, p95_d, cov_d = _errors(g["m_direct"].heights, g["truth"])  # type: ignore[attr-defined]
    med_c, p95_c, cov_c = _errors(g["m_comp"].heights, g["truth"])  # type: ignore[attr-defined]
    assert med_c <= 1.15 * med_d + 0.002  # measured: 0.0175 vs 0.0168 mm
    assert p95_c <= 1.1 * p95_d  # measured: 0.092 vs 0.140 mm
    assert cov_c > cov_d - 0.02
    # measured: -0.003/0.010/-0.007/-0.020 mm without demixing, 0.000/0.043/-0.013/-0.035 mm with (the
    # pre-distorted route was not run over seeds: its bound stays the 0.05 mm tolerance)
    for e in _steps(g["m_comp"], comp):
        assert abs(e) < 0.05


def test_refused_compensation_folder_and_mismatched_patterns(gauge_chain: dict[str, object], tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    g = gauge_chain
    empty = tmp_path / "calib"
    empty.mkdir()
    assert cli.main(["patterns", str(tmp_path / "p"), "--width", "640", "--height", "480", "--period-px", "60",
                     "--compensated", str(empty)]) == 2
    err = capsys.readouterr().err
    assert "--compensated" in err and "table_reference.json is missing" in err and not (tmp_path / "p").exists()
    # a period that puts projector pixels of another size on the bench's plate than projector.pixel_mm
    assert cli.main(["patterns", str(tmp_path / "p60"), "--width", "1024", "--height", "768", "--period-px", "60",
                     "--bands", "16", "--repeats", "1", "--planes", "0,3,6"]) == 0
    capsys.readouterr()
    assert cli.main(["bench", str(g["root"] / "bench.yaml"), str(tmp_path / "cam"), "--patterns",
                     str(tmp_path / "p60"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "patterns.yaml" in err and "projector.pixel_mm" in err and "--period-px 120" in err
    assert not (tmp_path / "cam").exists()
    # an image too narrow for the camera's field (80 mm at 0.1 mm per projector pixel)
    assert cli.main(["patterns", str(tmp_path / "narrow"), "--width", "640", "--height", "768", "--period-px", "120",
                     "--bands", "16", "--repeats", "1", "--planes", "0,3,6"]) == 0
    assert cli.main(["bench", str(g["root"] / "bench.yaml"), str(tmp_path / "cam"), "--patterns",
                     str(tmp_path / "narrow"), "--quiet"]) == 2
    assert "projector columns are needed" in capsys.readouterr().err
    # a compensated patterns folder without its predistortion.csv: the assembler refuses, naming it
    pat = tmp_path / "comp-copy"
    shutil.copytree(g["root"] / "patterns-compensated", pat)
    (pat / "predistortion.csv").unlink()
    assert cli.main(["session", str(g["root"] / "camera-compensated"), str(pat), str(g["root"] / "spec.yaml"),
                     str(tmp_path / "s")]) == 2
    assert "predistortion.csv: missing" in capsys.readouterr().err


# --------------------------------------------------------------------------- pre-compensated phase shifts
# The three-step sinusoids on a projector of gamma ~2 carry harmonics (a phase error of the
# projector's, not of the method's); ``huefringe patterns --compensated`` drives them through the
# inverse of the per-channel gamma fitted to the plate's hue table. Flat board (the ``flat``
# preset's 2 mm plate) at 160 x 120 px, 16 bands, through the files route, gamma [1.8, 2.5, 2.1].
FLAT = {"width": 160, "height": 120, "pixel_pitch_mm": 0.5, "period_px": 24, "hue_bands": 16, "repeats": 2,
        "frames": 1, "id": "rig-ps"}
FLAT_GAMMA = [1.8, 2.5, 2.1]


def _three_step_errors(session: object, cfg: dict, m: object) -> tuple[float, float, float]:
    """Three-step phase RMS about the true code phase (rad, constant offset removed, interior columns), its
    row-averaged RMS, and the RMS of the height it gives through ``m``'s plane calibration (mm),
    decoded as the workflow's baseline_frames does."""
    from huefringe import colour
    from huefringe.bench import Bench
    from huefringe.bench.geometry import code_phase
    from huefringe.camera import corrections
    from huefringe.phase import three_step_phase, unwrap, wrap

    rig = Bench(cfg).rig
    z = float(cfg["scene"]["height_mm"])
    x = np.arange(FLAT["width"]) * FLAT["pixel_pitch_mm"]
    truth = code_phase(x, z, projector_x_mm=rig.projector_x_mm, projector_height_mm=rig.projector_height_mm,
                       period_mm=rig.period_mm, x_origin_mm=rig.x_origin_mm)
    read = corrections(m.camera_record, session.meta)[1].rgb  # type: ignore[attr-defined]
    phi, mod = three_step_phase(*(colour.intensity(read(p)) for p in session.phase_shift[0]))  # type: ignore[attr-defined]
    assert np.all(mod > 0.1)
    # the outermost two columns at each side are left out: the bench's lens blur reads beyond the
    # image there (+-0.09 rad in the row means whatever was projected)
    e = wrap(phi.astype(np.float64) - truth[None, :])[:, 2:-2]
    e = wrap(e - np.angle(np.mean(np.exp(1j * e))))
    cal = m.calibration  # type: ignore[attr-defined]
    h = cal.height(unwrap(wrap(phi.astype(np.float64) - cal.phi_ref), mod > 0.1, "reference").dphi)
    ok = np.isfinite(h)
    assert ok.mean() > 0.95
    return (float(np.sqrt(np.mean(e**2))), float(np.sqrt(np.mean(e.mean(axis=0) ** 2))),
            float(np.sqrt(np.mean((h[ok] - z) ** 2))))


def test_pre_compensated_phase_shift_files_remove_the_projector_gamma_error(tmp_path: Path) -> None:
    cfg = bench_config("flat", **FLAT)
    cfg["projector"]["gamma"] = FLAT_GAMMA
    (tmp_path / "bench.yaml").write_text(yaml.safe_dump(cfg))
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump({"id": "rig-ps", "pixel_pitch_mm": 0.5, "period_px": 24,
                                    "provenance": {"simulated": True}}))
    mag = cfg["projector"]["pixel_mm"] / FLAT["pixel_pitch_mm"]

    def chain(name: str, *extra: str) -> object:
        pat, cam, out = tmp_path / f"patterns-{name}", tmp_path / f"camera-{name}", tmp_path / f"session-{name}"
        assert cli.main(["patterns", str(pat), "--width", "1024", "--height", "768", "--camera-period-px", "24",
                         "--magnification", f"{mag:g}", "--bands", "16", "--repeats", "2", "--planes", "0,3,6",
                         "--frames", "1", *extra]) == 0
        assert cli.main(["bench", str(tmp_path / "bench.yaml"), str(cam), "--patterns", str(pat), "--quiet"]) == 0
        assert cli.main(["session", str(cam), str(pat), str(spec), str(out)]) == 0
        return load_session(out, deep=True)

    plain = chain("plain")
    m_plain = measure(plain)
    calib = tmp_path / "calib"
    calib.mkdir()
    m_plain.tables["reference"].save(calib / "table_reference.json")
    comp = chain("compensated", "--compensated", str(calib))
    m_comp = measure(comp)
    rec = yaml.safe_load((tmp_path / "patterns-compensated" / "patterns.yaml").read_text())["compensated"]["phase_shift"]
    np.testing.assert_allclose(rec["gamma"], FLAT_GAMMA, atol=0.05)  # measured 1.786, 2.513, 2.109 (16 bands)
    assert (tmp_path / "patterns-compensated" / "phase_shift_levels.csv").is_file()
    rms_p, row_p, h_p = _three_step_errors(plain, cfg, m_plain)
    rms_c, row_c, h_c = _three_step_errors(comp, cfg, m_comp)
    assert rms_p > 0.15 and row_p > 0.15 and h_p > 0.4  # measured: 0.185 rad (0.185 row means), 0.632 mm
    assert rms_c < 0.012 and rms_c < 0.1 * rms_p  # measured: 0.0081 rad (pre-compensated with the true gamma: the same)
    assert row_c < 0.003  # the systematic part; measured: 0.0011 rad
    assert h_c < 0.08 and h_c < 0.1 * h_p  # measured: 0.046 mm
