"""Tests of huefringe.table1: the paper's Table 1 and ours beside it."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from huefringe.metrology import evaluate_session
from huefringe.table1 import CSV_COLUMNS, PAPER_TABLE1, table1_rows, write_table1


def block(per_frame, nominal=1.0, name="blue", method="trapezoidal-hsi"):
    return {"method": method, "steps": [{"name": name, "nominal_mm": nominal, "per_frame_mm": list(per_frame)}]}


def test_paper_values():
    assert list(PAPER_TABLE1) == [100, 80, 60, 40, 20]
    assert [PAPER_TABLE1[p]["proposed"]["sigma_pct"] for p in PAPER_TABLE1] == [1.29, 1.33, 1.38, 1.57, 1.94]
    assert [PAPER_TABLE1[p]["proposed"]["avg_error_pct"] for p in PAPER_TABLE1] == [1.05, 1.2, 1.28, 1.69, 1.98]
    assert [PAPER_TABLE1[p]["three_step"]["sigma_pct"] for p in PAPER_TABLE1] == [3.69, 3.72, 3.78, 3.85, 3.93]
    assert [PAPER_TABLE1[p]["three_step"]["avg_error_pct"] for p in PAPER_TABLE1] == [3.17, 3.14, 3.25, 3.34, 3.37]


def test_rows_from_hand_made_blocks():
    # signed errors cancel (mean error 0) but the mean absolute error does not
    results = {
        60: {"method": block([1.01, 0.99, 1.02, 0.98]), "baseline": block([1.05, 1.03, 1.04, 1.04], method="three-step-phase-shift")},
        20: {"method": block([1.0, 1.02, 1.0, 1.02])},
    }
    rows = table1_rows(results)
    assert [r["period_px"] for r in rows] == [100, 80, 60, 40, 20]
    r60 = rows[2]
    assert r60["period_mm"] == pytest.approx(12.0)
    assert r60["proposed_sigma_pct"] == pytest.approx(100 * math.sqrt(10e-4 / 3))  # 1.8257 %
    assert r60["proposed_avg_error_pct"] == pytest.approx(1.5)
    assert r60["proposed_mean_error_pct"] == pytest.approx(0.0, abs=1e-12)
    assert r60["three_step_avg_error_pct"] == pytest.approx(4.0)
    assert r60["three_step_sigma_pct"] == pytest.approx(100 * np.std([0.05, 0.03, 0.04, 0.04], ddof=1))
    assert r60["paper_proposed_sigma_pct"] == 1.38 and r60["paper_three_step_avg_error_pct"] == 3.25
    assert r60["proposed_frames"] == 4 and r60["three_step_frames"] == 4
    r20 = rows[4]
    assert r20["proposed_avg_error_pct"] == pytest.approx(1.0)
    assert r20["three_step_sigma_pct"] is None and r20["paper_three_step_sigma_pct"] == 3.93
    assert rows[0]["proposed_sigma_pct"] is None and rows[0]["paper_proposed_sigma_pct"] == 1.29
    assert set(rows[0]) == set(CSV_COLUMNS)
    only = table1_rows(results, include_paper_only=False)
    assert [r["period_px"] for r in only] == [60, 20]


def test_nominal_scales_percentages_and_is_checked():
    rows = table1_rows({50: {"method": block([2.02, 1.98, 2.04], nominal=2.0)}}, nominal=2.0, include_paper_only=False)
    assert rows[0]["proposed_avg_error_pct"] == pytest.approx(100 * (0.02 + 0.02 + 0.04) / 3 / 2.0)
    assert rows[0]["paper_proposed_sigma_pct"] is None  # the paper has no 50 px period
    with pytest.raises(ValueError, match="nominal"):
        table1_rows({60: {"method": block([1.0, 1.0], nominal=3.0)}})
    with pytest.raises(KeyError, match="blue"):
        table1_rows({60: {"method": block([1.0, 1.0], name="green")}})


def test_rows_from_evaluated_sessions():
    """End to end from synthetic height maps: period-dependent noise on the blue block."""
    pitch, h, w = 0.2, 60, 80
    spec = {
        "base_roi": [[2, 2, 78, 12], [2, 48, 78, 58]],
        "steps": [{"name": "blue", "nominal_mm": 1.0, "roi": [25, 18, 55, 42]}],
        "tolerance_mm": 0.05,
    }
    rng = np.random.default_rng(5)
    results, truth = {}, {}
    for period, spread in ((100, 0.012), (20, 0.02)):
        for key in ("method", "baseline"):
            s = spread * (3 if key == "baseline" else 1)
            heights = 1.0 + rng.normal(0.005, s, 12)
            maps = []
            for hgt in heights:
                z = np.full((h, w), 0.3)
                z[16:44, 23:57] += hgt
                maps.append(z.astype(np.float32))
            name = "trapezoidal-hsi" if key == "method" else "three-step-phase-shift"
            results.setdefault(period, {})[key] = evaluate_session(maps, spec, pitch, range_mm=4.0, method=name)
            truth[(period, key)] = heights  # float32 storage costs < 1e-6 mm
    rows = {r["period_px"]: r for r in table1_rows(results)}
    for (period, key), hts in truth.items():
        prefix = "proposed" if key == "method" else "three_step"
        pf = np.asarray(results[period][key]["steps"][0]["per_frame_mm"])
        np.testing.assert_allclose(pf, hts, atol=1e-6)
        assert rows[period][f"{prefix}_sigma_pct"] == pytest.approx(100 * np.std(pf, ddof=1), rel=1e-12)
        assert rows[period][f"{prefix}_avg_error_pct"] == pytest.approx(100 * np.mean(np.abs(pf - 1.0)), rel=1e-12)
    assert rows[20]["three_step_sigma_pct"] > rows[20]["proposed_sigma_pct"]


def test_write_table1(tmp_path):
    results = {p: {"method": block(1 + 0.01 * np.sin(np.arange(30) + p)), "baseline": block(1 + 0.03 * np.cos(np.arange(30) * p))} for p in PAPER_TABLE1}
    rows = table1_rows(results)
    md, cs, png = tmp_path / "t" / "table1.md", tmp_path / "t" / "table1.csv", tmp_path / "t" / "table1.png"
    write_table1(rows, md, cs, png)
    text = md.read_text(encoding="utf-8")
    for p, v in PAPER_TABLE1.items():
        line = next(ln for ln in text.splitlines() if ln.startswith(f"| {p} |"))
        for m in ("proposed", "three_step"):
            assert f"{v[m]['sigma_pct']:.2f}" in line and f"{v[m]['avg_error_pct']:.2f}" in line
        row = next(r for r in rows if r["period_px"] == p)
        assert f"{row['proposed_sigma_pct']:.2f}" in line and f"{row['three_step_avg_error_pct']:.2f}" in line
    assert "mean(|h − nominal|)" in text
    with open(cs, newline="", encoding="utf-8") as fh:
        table = list(csv.DictReader(fh))
    assert tuple(table[0]) == CSV_COLUMNS
    assert [int(r["period_px"]) for r in table] == [100, 80, 60, 40, 20]
    for r, row in zip(table, rows, strict=True):
        assert float(r["paper_proposed_sigma_pct"]) == PAPER_TABLE1[row["period_px"]]["proposed"]["sigma_pct"]
        assert float(r["proposed_avg_error_pct"]) == pytest.approx(row["proposed_avg_error_pct"], rel=1e-5)
        assert int(r["proposed_frames"]) == 30
    assert png.read_bytes().startswith(b"\x89PNG\r\n\x1a\n") and png.stat().st_size > 20_000
    assert not list(tmp_path.glob("t/.*"))  # no temporary files left behind
    with pytest.raises(ValueError, match="no Table 1 rows"):
        write_table1([], md, cs, png)
