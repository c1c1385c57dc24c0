"""One-shot frames whose fringe order comes from another session: the base plane alone, captured
once with Gray code + phase (bench preset rig-base-plane), and the gauge blocks captured one-shot
without coded blocks (rig-oneshot-on-base, ``oneshot: {reference: {session: ../rig-base-plane}}``),
measured with the bench rig's true calibration against the scene's truth; and the refusals."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import tifffile
import yaml

from bench_helpers import CONFIG
from test_rig_workflow import rig_workdir, snakemake
from huefringe.bench.rig import RIGS
from huefringe.bench.rig_session import load_sl_bench_config, write_sl_session
from huefringe.plan import PlanError, plan_sessions
from huefringe.rig import write_calibration
from huefringe.rig.measure import RigError
from huefringe.session import SessionError, load_sl_session
from huefringe.stages import measure_rig_session

TRUTH = {"block-3": 3.0, "block-1": 1.0, "block-4": 4.0}


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("oneshot-ref")
    out = {n: write_sl_session(load_sl_bench_config(n), root / n) for n in ("rig-base-plane", "rig-oneshot-on-base")}
    out["calibration"] = write_calibration(root / "true-rig.yml", RIGS["holdout-wide"].calibration)
    return out


@pytest.fixture(scope="module")
def measured(sessions: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("oneshot-ref-out")
    cfg = json.loads(json.dumps(CONFIG))
    cfg["codecs"]["noise"] = {"read_dn": 1.0, "full_well_e": None}
    measure_rig_session(sessions["rig-oneshot-on-base"], out, cfg, calibration=sessions["calibration"], surfaces=False)
    return out


def test_the_session_holds_no_coded_blocks_and_names_its_reference(sessions: dict[str, Path]) -> None:
    s = load_sl_session(sessions["rig-oneshot-on-base"], deep=True)
    assert s.spec.axes() == [] and s.spec.oneshot_frames == 3
    assert s.meta["oneshot"] == {"reference": {"session": "../rig-base-plane"}}
    assert s.oneshot_reference == sessions["rig-base-plane"].resolve()
    assert sorted(s.ground_truth) == ["xyz"]


def test_steps_against_the_truth_through_the_reference_plane(measured: Path) -> None:
    doc = json.loads((measured / "metrology/report.json").read_text())
    steps = {s["name"]: s for s in doc["steps"]}
    assert set(steps) == set(TRUTH)
    for name, true in TRUTH.items():
        s = steps[name]
        assert len(s["per_frame_mm"]) == 3
        err = s["mean_mm"] - true
        # true calibration: no calibration term in U, the points term only (a few um)
        assert abs(err) <= s["U_mm"], (name, err, s["U_mm"])
        assert abs(err) / true <= 0.003, (name, err)
        assert 0.0005 < s["U_mm"] < 0.01
    ref = doc["provenance"]["oneshot_reference"]
    assert ref["session"] == "rig-base-plane" and doc["geometry"]["oneshot_reference"] == ref
    assert "reference session rig-base-plane" in doc["geometry"]["route"]
    assert any("rig-base-plane" in k for k in doc["provenance"]["inputs_sha256"])


def test_every_lit_pixel_measured_and_within_2u(measured: Path, sessions: dict[str, Path]) -> None:
    acc = json.loads((measured / "accuracy.json").read_text())
    assert acc["coverage_of_truth"] >= 0.99 and acc["valid_without_truth"] == 0
    assert 0.92 <= acc["within_2u"] <= 0.98, acc["within_2u"]
    assert acc["median_abs_error_mm"] < 0.04
    qa = json.loads((measured / "qa/frames/frame_0000.json").read_text())
    assert qa["order"]["reference_session"] == str(sessions["rig-base-plane"].resolve())
    assert 9.0 < qa["order"]["unambiguous_range_mm"]["front_median_mm"] < 13.0
    # the block tops, 1 to 4 mm in front of the reference plane, measured at the right order
    xyz = tifffile.imread(measured / "xyz/frame_0000.tiff")
    truth = tifffile.imread(sessions["rig-oneshot-on-base"] / "ground_truth/xyz.tiff")
    both = np.isfinite(xyz[..., 2]) & np.isfinite(truth[..., 2])
    assert np.mean(np.abs(xyz[..., 2] - truth[..., 2])[both] < 1.0) == 1.0


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _edit(path: Path, **keys: object) -> None:
    doc = yaml.safe_load(path.read_text())
    doc.update(keys)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))


def test_a_reference_of_another_camera_axis_or_calibration_is_refused_naming_the_file(
        sessions: dict[str, Path], tmp_path: Path) -> None:
    ref = _copy(sessions["rig-base-plane"], tmp_path / "bad-ref")
    shot = _copy(sessions["rig-oneshot-on-base"], tmp_path / "shot")
    _edit(ref / "session.yaml", camera={"width": 320, "height": 480, "bit_depth": 8, "channels": 1},
          calibration={"session": "../other-poses"})
    seq = yaml.safe_load((ref / "sequence.yaml").read_text())
    seq["blocks"] = [b for b in seq["blocks"] if not (isinstance(b, dict) and "gray" in b)]
    (ref / "sequence.yaml").write_text(yaml.safe_dump(seq))
    _edit(shot / "session.yaml", oneshot={"reference": {"session": "../bad-ref"}})
    with pytest.raises(SessionError) as exc:
        load_sl_session(shot)
    msg = str(exc.value)
    assert str(shot / "session.yaml") in msg
    assert "320 x 480 camera, this session's is 640 x 480" in msg
    assert "decodes axis x only within one period (the trapezoid's axis)" in msg
    assert "must be captured on the same rig with the same calibration" in msg


def test_a_missing_reference_is_refused_before_work(sessions: dict[str, Path], tmp_path: Path) -> None:
    shot = _copy(sessions["rig-oneshot-on-base"], tmp_path / "shot")
    _edit(shot / "session.yaml", oneshot={"reference": {"session": "../nowhere"}})
    load_sl_session(shot)  # the folder may be one the workflow's bench writes: refused where it is needed
    with pytest.raises(RigError, match=r"session\.yaml: oneshot/reference: .*nowhere holds no session"):
        measure_rig_session(shot, tmp_path / "out", CONFIG, calibration=sessions["calibration"], surfaces=False)
    assert not (tmp_path / "out/xyz").exists() or not any((tmp_path / "out/xyz").iterdir())
    cfg = json.loads(json.dumps(CONFIG))
    cfg["sessions"] = [str(shot)]
    with pytest.raises(PlanError, match=r"one-shot reference session .*nowhere is refused"):
        plan_sessions(cfg)


def test_a_reference_field_without_trapezoid_frames_is_refused(sessions: dict[str, Path], tmp_path: Path) -> None:
    ref = _copy(sessions["rig-base-plane"], tmp_path / "plane")
    _edit(ref / "session.yaml", oneshot={"reference": {"session": "../plane"}})
    with pytest.raises(SessionError, match="names this session itself|no trapezoid blocks"):
        load_sl_session(ref)


def test_assembly_writes_the_reference_relative_to_the_session(sessions: dict[str, Path], tmp_path: Path) -> None:
    from huefringe.session import assemble_sl_session

    src, root = sessions["rig-oneshot-on-base"], sessions["rig-base-plane"].parent
    seq = yaml.safe_load((src / "sequence.yaml").read_text())
    seq.update(id="assembled", oneshot_reference=str(root / "rig-base-plane"), calibration_session=str(root / "rig-poses"))
    (tmp_path / "seq.yaml").write_text(yaml.safe_dump(seq))
    out = assemble_sl_session(src / "captures", tmp_path / "seq.yaml", root / "assembled")
    s = load_sl_session(out)
    assert s.meta["oneshot"] == {"reference": {"session": "../rig-base-plane"}}
    assert s.oneshot_reference == sessions["rig-base-plane"].resolve()


def test_the_workflow_plans_the_reference_as_an_input_of_the_one_shot_rules(tmp_path: Path) -> None:
    work = rig_workdir(tmp_path, "rig-oneshot-on-base", ("rig-base-plane", "rig-poses"))
    plans = plan_sessions(yaml.safe_load((work / "config.yaml").read_text()), base=work)
    assert plans["rig-oneshot-on-base"].reference_id == "rig-base-plane"
    assert not plans["rig-base-plane"].measure and plans["rig-base-plane"].calibrated_by == "rig-poses"
    proc = snakemake(work, "-n", "--cores", "2")   # fails the test, with its output, unless it plans
    out = proc.stdout + proc.stderr
    for rule in ("rule rig_oneshot_rig_oneshot_on_base:", "rule rig_metrology:"):
        block = out.split(rule, 1)[1].split("\n\n", 1)[0]
        inputs = block.split("input:", 1)[1].splitlines()[0]
        assert "sessions/rig-base-plane/session.yaml" in inputs, (rule, inputs)
    assert "rule rig_measure:" not in out   # the reference is written, not measured
