"""``huefringe.measure``: one call from a capture session to heights in memory, with the packaged
defaults, against the bench's ground truth and against the workflow's stages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile
from bench_helpers import bench_config, process, write

import huefringe
from huefringe.height import accuracy
from huefringe.settings import DEFAULTS_PATH, defaults, load_config


@pytest.fixture(scope="module")
def small_demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("api")
    cfg = bench_config("demo", width=200, height=150, hue_bands=32, repeats=2, frames=2, id="api-demo")
    cfg["scene"]["blocks"] = [  # the demo's blocks, scaled to the small field (as tests/test_workflow.py)
        {"name": "green", "nominal_mm": 3.0, "reflectance": [0.12, 0.65, 0.18], "rect_mm": [6.0, 10.0, 12.0, 20.0]},
        {"name": "blue", "nominal_mm": 1.0, "reflectance": [0.15, 0.25, 0.7], "rect_mm": [17.0, 10.0, 23.0, 20.0]},
        {"name": "red", "nominal_mm": 4.0, "reflectance": [0.7, 0.15, 0.12], "rect_mm": [28.0, 10.0, 34.0, 20.0]},
    ]
    return write(cfg, root)


def test_measure_gives_ground_truth_heights(small_demo: Path) -> None:
    m = huefringe.measure(small_demo)
    assert m.frames == [0, 1] and m.heights.shape == (2, 150, 200) and m.heights.dtype == np.float32
    for n in m.frames:
        truth = tifffile.imread(m.session.ground_truth[n])
        acc = accuracy(m.height(n), truth)
        print(f"frame {n}: median |error| {acc['median_abs_mm']:.4f} mm, p95 {acc['p95_abs_mm']:.4f} mm")
        assert acc["median_abs_mm"] < 0.03, acc
        assert acc["p95_abs_mm"] < 0.12, acc
        valid = m.valid[m.frames.index(n)].mean()
        print(f"frame {n}: valid {valid:.3f}")
        assert valid > 0.85  # the step-edge mask removes the mixed pixels around the three blocks
    assert m.calibration.phi_ref.shape == (150, 200)
    assert set(m.tables) == {"reference", "object"} and m.tables["object"].shape == (150, 200)
    assert m.config == defaults()  # nothing given: the packaged defaults


def test_measure_equals_the_workflow_stages(small_demo: Path, tmp_path: Path) -> None:
    """The same numbers as the stages the workflow runs (written to files), bit for bit."""
    cfg = load_config({"measurement": {"denoise_radius": 1}})
    m = huefringe.measure(small_demo, cfg, frames=[1])
    out = process(small_demo, tmp_path / "out", config=cfg, frames=[1])
    written = tifffile.imread(out["heights"][0])
    np.testing.assert_array_equal(m.height(1), written)
    ref = huefringe.measure(small_demo, {"measurement": {"kernel": False, "denoise_radius": 1}}, frames=[1])
    np.testing.assert_array_equal(ref.height(1), written)  # the NumPy reference chain: the same bytes


def test_config_overrides_the_packaged_defaults(tmp_path: Path) -> None:
    assert DEFAULTS_PATH.is_file() and "sessions" not in defaults()
    f = tmp_path / "my.yaml"
    f.write_text("measurement:\n  denoise_radius: 0\n")
    cfg = load_config(f)
    assert cfg["measurement"]["denoise_radius"] == 0
    assert cfg["measurement"]["unwrap"] == defaults()["measurement"]["unwrap"]  # siblings kept
    repo = load_config(Path(__file__).resolve().parents[1] / "config.yaml")
    assert repo["sessions"] and repo["calibration"] == defaults()["calibration"]
