"""``huefringe.pipeline``: a session prepared once, each frame measured into one ``FrameResult``;
the fused kernel and the NumPy reference chain give the same result, and ``huefringe.measure``
gives what the workflow's stages write."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile
from bench_helpers import bench_config, process, write

import huefringe
from huefringe.pipeline import FramePipeline, FrameResult, frame_results, prepare_frames, prepare_session
from huefringe.session import load_session
from huefringe.settings import load_config


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A small demo session (gauge blocks, two frames) prepared once with the packaged defaults."""
    root = tmp_path_factory.mktemp("pipeline")
    cfg = bench_config("demo", width=160, height=120, pixel_pitch_mm=0.5, period_px=24, hue_bands=32, repeats=2,
                       frames=2, id="pipeline-demo")
    path = write(cfg, root)
    config = load_config()
    s = load_session(path)
    return {"path": path, "session": s, "config": config, "prepared": prepare_session(s, config)}


def _results(small: dict, **measurement) -> list[FrameResult]:
    p, cfg = small["prepared"], small["config"]
    m = {**cfg["measurement"], **measurement}
    out = []
    for r in frame_results(small["session"], p.tables["object"], p.calibration, [0, 1], cfg["hue_model"], m,
                           reader=p.reader):
        out.append(FrameResult(frame=r.frame, height=r.height.copy(), stats=dict(r.stats), phase=r.phase.copy(),
                               hue=r.hue.copy(), uncertainty=r.uncertainty.copy(), support=r.support.copy()))
    return out


def test_prepare_frames_chooses_the_chain(small: dict) -> None:
    p, cfg = small["prepared"], small["config"]
    args = (small["session"], p.tables["object"], p.calibration, cfg["hue_model"])
    fast = prepare_frames(*args, {**cfg["measurement"], "kernel": True}, reader=p.reader)
    ref = prepare_frames(*args, {**cfg["measurement"], "kernel": False}, reader=p.reader)
    spatial = prepare_frames(*args, {**cfg["measurement"], "kernel": True, "unwrap": "spatial"}, reader=p.reader)
    assert isinstance(fast, FramePipeline) and fast.fast and fast.table is None
    assert not ref.fast and ref.table is p.tables["object"]
    assert not spatial.fast  # the kernel unwraps against the reference only


def test_kernel_and_reference_give_the_same_frame_result(small: dict) -> None:
    """Heights and phases bit for bit, uncertainty and support to float32 rounding, the same QA
    figures (the kernel's wrap flags come from its float32 phase difference)."""
    fast, ref = _results(small, kernel=True), _results(small, kernel=False)
    for a, b in zip(fast, ref, strict=True):
        assert a.frame == b.frame
        np.testing.assert_array_equal(a.height, b.height)
        np.testing.assert_array_equal(a.valid, b.valid)
        assert a.valid.mean() > 0.85
        np.testing.assert_array_equal(a.phase, b.phase)
        np.testing.assert_allclose(a.hue, b.hue, rtol=0, atol=1e-5, equal_nan=True)
        np.testing.assert_allclose(a.uncertainty, b.uncertainty, rtol=1e-5, equal_nan=True)
        np.testing.assert_array_equal(np.isnan(a.uncertainty), np.isnan(a.height))
        np.testing.assert_allclose(a.support, b.support, rtol=1e-5)
        assert set(a.stats) == set(b.stats)
        for key in ("valid_fraction", "clipped_fraction", "median_height_mm", "edge_fraction"):
            assert a.stats[key] == pytest.approx(b.stats[key], abs=1e-6), key


def test_measure_and_the_stages_give_identical_heights(small: dict, tmp_path: Path) -> None:
    """``huefringe.measure`` and the stages (files written, then read) agree bit for bit: heights,
    uncertainty and support."""
    m = huefringe.measure(small["path"])
    out = process(small["path"], tmp_path / "out", config=small["config"])
    for i, n in enumerate(m.frames):
        np.testing.assert_array_equal(m.height(n), tifffile.imread(out["heights"][i]))
        np.testing.assert_array_equal(m.uncertainty[i], tifffile.imread(out["uncertainties"][i]))
        np.testing.assert_array_equal(m.support[i], tifffile.imread(out["supports"][i]))
    np.testing.assert_array_equal(m.calibration.phi_ref, small["prepared"].calibration.phi_ref)
