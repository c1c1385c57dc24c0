"""End to end: Snakemake on a small bench session writes everything the results contract names."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
import tifffile
import trimesh
import x3pio
import yaml
from bench_helpers import CONFIG, REPO, bench_config

from huefringe.archive import read_crate, verify_archive
from huefringe.report import validate_report


def small_bench_yaml(path: Path, **session) -> Path:
    cfg = bench_config("demo", width=200, height=150, hue_bands=24, repeats=2, frames=3, id="e2e-demo", **session)
    cfg["scene"]["blocks"] = [
        {"name": "green", "nominal_mm": 3.0, "reflectance": [0.12, 0.65, 0.18], "rect_mm": [6.0, 10.0, 12.0, 20.0]},
        {"name": "blue", "nominal_mm": 1.0, "reflectance": [0.15, 0.25, 0.7], "rect_mm": [17.0, 10.0, 23.0, 20.0]},
        {"name": "red", "nominal_mm": 4.0, "reflectance": [0.7, 0.15, 0.12], "rect_mm": [28.0, 10.0, 34.0, 20.0]},
    ]
    path.write_text(yaml.safe_dump(cfg))
    return path


def run_snakemake(workdir: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(workdir),
           "--cores", "2", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "PYTHONHASHSEED": "0"})
    if check and proc.returncode != 0:
        raise AssertionError(f"snakemake failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-5000:]}")
    return proc


def workdir_with_config(tmp_path: Path, **overrides) -> Path:
    bench_yaml = small_bench_yaml(tmp_path / "bench.yaml")
    cfg = json.loads(json.dumps(CONFIG))
    cfg["sessions"] = ["sessions/e2e-demo"]
    cfg["bench_sessions"] = {"sessions/e2e-demo": str(bench_yaml)}
    cfg["render"].update(width=400, height=300)
    cfg.pop("table1", None)
    for k, v in overrides.items():
        cfg[k] = v
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    return tmp_path


@pytest.fixture(scope="module")
def e2e(tmp_path_factory: pytest.TempPathFactory) -> Path:
    work = workdir_with_config(tmp_path_factory.mktemp("e2e"))
    proc = run_snakemake(work)
    (work / "run.stderr").write_text(proc.stderr)  # what the user saw at the end of the run
    return work


def test_the_end_of_a_run_says_each_verdict_and_where_the_report_is(e2e: Path) -> None:
    from huefringe.io import tiff_pixel_pitch_mm

    tail = (e2e / "run.stderr").read_text().split("huefringe: results")[-1]
    doc = json.loads((e2e / "results" / "e2e-demo" / "metrology" / "report.json").read_text())
    decision = doc["conformity"]["decision"]
    assert f"  e2e-demo: {decision.upper()} (ISO 14253-1) - {doc['conformity']['reason']}" in tail
    assert "      report: results/e2e-demo/metrology/report.html" in tail
    # height and uncertainty TIFFs carry their lateral scale (resolution tags), not only the X3P
    res = e2e / "results" / "e2e-demo"
    for rel in ("height/frame_0000.tiff", "uncertainty/frame_0002.tiff", "baseline/height/frame_0000.tiff"):
        assert tiff_pixel_pitch_mm(res / rel) == pytest.approx(0.2, rel=1e-9), rel


def test_results_contract(e2e: Path) -> None:
    res = e2e / "results" / "e2e-demo"
    for n in range(3):
        h = tifffile.imread(res / "height" / f"frame_{n:04d}.tiff")
        assert h.dtype == np.float32 and h.shape == (150, 200)
        assert 0.85 < np.isfinite(h).mean() < 1.0  # shadows and the mixed pixels of step edges are NaN (0.896 measured)
        pcd = o3d.io.read_point_cloud(str(res / "cloud" / f"frame_{n:04d}.ply"))
        assert len(pcd.points) == int(np.isfinite(h).sum()) and pcd.has_colors()
        pts = np.asarray(pcd.points)
        assert pts[:, 0].max() == pytest.approx(199 * 0.2, abs=1e-6)  # X = u * pitch, mm
        qa = json.loads((res / "qa" / "frames" / f"frame_{n:04d}.json").read_text())
        assert qa["valid_fraction"] == pytest.approx(np.isfinite(h).mean())
        x3p = x3pio.read(res / "x3p" / f"frame_{n:04d}.x3p")  # x3p.frames: all (the default)
        assert np.array_equal(x3p.layers[0].z, h.astype(np.float64) * 1e-3, equal_nan=True)
        assert x3p.header.x.increment == pytest.approx(0.2e-3, rel=1e-15)
    # phase and hue maps of the rendered frame only (measurement.maps: rendered, render.frames: first)
    assert sorted(p.name for p in (res / "phase").iterdir()) == ["frame_0000.tiff"]
    assert sorted(p.name for p in (res / "hue").iterdir()) == ["frame_0000.tiff"]
    mesh = trimesh.load(res / "mesh" / "frame_0000.ply", process=False)
    assert len(mesh.faces) > 10000
    o3 = o3d.io.read_triangle_mesh(str(res / "mesh" / "frame_0000.ply"))  # two-manifold for slicers and CAD
    assert o3.is_vertex_manifold() and o3.is_edge_manifold() and len(o3.get_non_manifold_vertices()) == 0
    assert json.loads((res / "mesh" / "frame_0000.stats.json").read_text())["non_manifold_vertices"] == 0
    for view in ("top", "oblique1", "oblique2"):
        img = (res / "renders" / f"frame_0000_{view}.png")
        assert img.stat().st_size > 5000
    doc = json.loads((res / "metrology" / "report.json").read_text())
    validate_report(doc)
    assert doc["session"] == "e2e-demo" and doc["method"] == "trapezoidal-hsi" and doc["frames"] == 3
    assert [s["name"] for s in doc["steps"]] == ["green", "blue", "red"]
    assert doc["baseline"]["method"] == "three-step-phase-shift"
    assert all(abs(s["error_mm"]) < 0.05 for s in doc["steps"]), doc["steps"]
    html = (res / "metrology" / "report.html").read_text()
    assert "e2e-demo" in html and "data:image/png;base64," in html
    acc = json.loads((res / "accuracy.json").read_text())
    assert acc["trapezoidal-hsi"]["summary"]["median_abs_mm"] < 0.05


def test_snakemake_report_includes_the_metrology_page(e2e: Path, tmp_path: Path) -> None:
    import zipfile

    out = tmp_path / "snakemake-report.zip"
    run_snakemake(e2e, "--report", str(out))
    page = (e2e / "results" / "e2e-demo" / "metrology" / "report.html").read_bytes()
    with zipfile.ZipFile(out) as z:
        names = z.namelist()
        # Snakemake keeps each reported file under <report>/data/raw/<hash>/<name>
        inside = [n for n in names if n.startswith("snakemake-report/data/raw/") and n.endswith("/report.html")]
        assert [z.read(n) == page for n in inside] == [True], names  # the self-contained page, byte for byte
        caption = (REPO / "workflow" / "report" / "metrology_html.rst").read_text().split(":")[0]
        texts = [z.read(n).decode("utf-8", "replace") for n in names if n.endswith((".html", ".js", ".json"))
                 and not n.startswith("snakemake-report/data/raw/")]
        assert any(caption[:60] in t for t in texts), [n for n in names if "data/raw" not in n]


def test_archive_target_packs_each_session_and_indexes_them(e2e: Path) -> None:
    """``snakemake archive``: rule archive_session per session, then rule archive's index."""
    run_snakemake(e2e, "archive")
    out = e2e / "results" / "e2e-demo.archive.zip"
    assert verify_archive(out).ok
    (row,) = json.loads((e2e / "results" / "archives.json").read_text())["archives"]
    assert row["file"] == out.name and row["session"] == "e2e-demo" and row["bytes"] == out.stat().st_size
    names = {e["@id"] for e in read_crate(out)["@graph"]}
    assert "results/x3p/frame_0002.x3p" in names


def test_rerun_is_a_no_op(e2e: Path) -> None:
    proc = run_snakemake(e2e, "-n")
    assert "Nothing to be done" in proc.stdout + proc.stderr


def test_bad_session_refused_before_any_work(tmp_path: Path) -> None:
    sess = tmp_path / "broken"
    sess.mkdir()
    (sess / "session.yaml").write_text("format: capture-session/1\nid: Broken!\n")
    cfg = json.loads(json.dumps(CONFIG))
    cfg["sessions"] = [str(sess)]
    cfg["bench_sessions"] = {}
    cfg.pop("table1", None)
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    proc = run_snakemake(tmp_path, check=False)
    assert proc.returncode != 0
    err = proc.stdout + proc.stderr
    assert "session.yaml" in err and "at id" in err and "Traceback" not in err
    assert not (tmp_path / "results").exists()


def test_unknown_config_key_refused(tmp_path: Path) -> None:
    cfg = json.loads(json.dumps(CONFIG))
    cfg["measurement"]["unwarp"] = "spatial"
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    proc = run_snakemake(tmp_path, "-n", check=False)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0 and "measurement: Additional properties are not allowed ('unwarp' was unexpected)" in out
    assert "the configuration (config.yaml) is not valid" in out and "Failed validating" not in out  # no schema dump


def test_config_problems_name_each_key_path() -> None:
    from huefringe.plan import config_problems

    schema = Path(__file__).resolve().parents[1] / "workflow" / "schemas" / "config.schema.yaml"
    assert config_problems(json.loads(json.dumps(CONFIG)), schema) == []
    cfg = json.loads(json.dumps(CONFIG))
    cfg["measurement"]["kernel"] = 3
    cfg["mesh"]["frames"] = "some"
    cfg["extra"] = 1
    problems = config_problems(cfg, schema)
    assert any(p.startswith("measurement.kernel: 3 is not of type 'boolean'") for p in problems), problems
    assert any(p.startswith("mesh.frames:") for p in problems), problems
    assert any(p.startswith("(top level): Additional properties") and "'extra'" in p for p in problems), problems
