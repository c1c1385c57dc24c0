"""Paper Table 1 (Chen, Nguyen & Shu): the 1.0 mm gauge block at five fringe periods.

The paper measured a blue-coated 1.0 +- 0.001 mm gauge block 30 times per fringe period (20 to
100 camera pixels, 0.2 mm pixel pitch) with the proposed trapezoidal-HSI method and with the
traditional three-step phase shifting, and reports for each a standard deviation sigma (%) and
an "average error" e-bar (%). :data:`PAPER_TABLE1` holds those numbers;
:func:`table1_rows` computes ours from :func:`huefringe.metrology.evaluate_session` blocks and
:func:`write_table1` writes them side by side (Markdown, CSV, figure).

Definitions used for our values (the paper does not state its formulas)
-----------------------------------------------------------------------
- ``sigma % = 100 * std(h_i, ddof=1) / nominal`` over the per-frame step heights ``h_i``;
- ``average error % = 100 * mean(|h_i - nominal|) / nominal``: the paper's "average error" is
  read as the mean *absolute* per-frame error (a signed mean error could cancel and would not
  grow with sigma as the paper's values do). The paper's numbers support this reading: for an
  unbiased normal scatter ``mean|e| = sqrt(2/pi) sigma = 0.80 sigma``, and the paper's proposed
  method at 100 px has e-bar = 1.05 % for sigma = 1.29 % (0.80 * 1.29 = 1.03). The signed error of
  the mean is kept in the rows as ``*_mean_error_pct`` for reference.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Mapping
from typing import Any

import numpy as np

from huefringe.io import atomic_path, write_figure_png

__all__ = [
    "CSV_COLUMNS",
    "PAPER_NOMINAL_MM",
    "PAPER_PITCH_MM",
    "PAPER_REPEATS",
    "PAPER_TABLE1",
    "table1_rows",
    "write_table1",
]

PAPER_NOMINAL_MM: float = 1.0
PAPER_PITCH_MM: float = 0.2
PAPER_REPEATS: int = 30

#: Table 1 of the paper: period (camera px) -> method -> sigma % and average error %.
PAPER_TABLE1: dict[int, dict[str, dict[str, float]]] = {
    100: {"proposed": {"sigma_pct": 1.29, "avg_error_pct": 1.05}, "three_step": {"sigma_pct": 3.69, "avg_error_pct": 3.17}},
    80: {"proposed": {"sigma_pct": 1.33, "avg_error_pct": 1.20}, "three_step": {"sigma_pct": 3.72, "avg_error_pct": 3.14}},
    60: {"proposed": {"sigma_pct": 1.38, "avg_error_pct": 1.28}, "three_step": {"sigma_pct": 3.78, "avg_error_pct": 3.25}},
    40: {"proposed": {"sigma_pct": 1.57, "avg_error_pct": 1.69}, "three_step": {"sigma_pct": 3.85, "avg_error_pct": 3.34}},
    20: {"proposed": {"sigma_pct": 1.94, "avg_error_pct": 1.98}, "three_step": {"sigma_pct": 3.93, "avg_error_pct": 3.37}},
}

#: Columns of the rows and of the CSV, in order.
CSV_COLUMNS: tuple[str, ...] = (
    "period_px",
    "period_mm",
    "step",
    "nominal_mm",
    "proposed_frames",
    "proposed_sigma_pct",
    "paper_proposed_sigma_pct",
    "proposed_avg_error_pct",
    "paper_proposed_avg_error_pct",
    "proposed_mean_error_pct",
    "three_step_frames",
    "three_step_sigma_pct",
    "paper_three_step_sigma_pct",
    "three_step_avg_error_pct",
    "paper_three_step_avg_error_pct",
    "three_step_mean_error_pct",
)

_METHODS = (("proposed", "method"), ("three_step", "baseline"))


def _step_stats(block: Mapping[str, Any], step_name: str, nominal: float, where: str) -> dict[str, Any]:
    steps = {s["name"]: s for s in block["steps"]}
    if step_name not in steps:
        raise KeyError(f"{where}: no step {step_name!r} (steps: {sorted(steps)})")
    s = steps[step_name]
    if "nominal_mm" in s and not math.isclose(float(s["nominal_mm"]), nominal, rel_tol=1e-12, abs_tol=0.0):
        raise ValueError(f"{where}: step {step_name!r} has nominal {s['nominal_mm']} mm, expected {nominal} mm")
    h = np.asarray(s["per_frame_mm"], dtype=np.float64)
    if h.size == 0 or not np.all(np.isfinite(h)):
        raise ValueError(f"{where}: step {step_name!r} needs finite per_frame_mm values")
    return {
        "frames": int(h.size),
        "sigma_pct": float(100.0 * np.std(h, ddof=1) / nominal) if h.size > 1 else None,
        "avg_error_pct": float(100.0 * np.mean(np.abs(h - nominal)) / nominal),
        "mean_error_pct": float(100.0 * (np.mean(h) - nominal) / nominal),
    }


def table1_rows(
    results: Mapping[int, Mapping[str, Mapping[str, Any]]],
    step_name: str = "blue",
    nominal: float = PAPER_NOMINAL_MM,
    *,
    pitch_mm: float = PAPER_PITCH_MM,
    include_paper_only: bool = True,
) -> list[dict[str, Any]]:
    """Our Table 1 values beside the paper's, one row per fringe period.

    Parameters
    ----------
    results : mapping
        ``{period_px: {"method": block, "baseline": block}}``, blocks from
        :func:`huefringe.metrology.evaluate_session` (only ``steps[].name``, ``nominal_mm`` and
        ``per_frame_mm`` are read); either key may be missing.
    step_name : str
        The step measured (the paper: the blue 1.0 mm block).
    nominal : float
        Nominal step height in mm, the denominator of the percentages; must equal the block's
        ``nominal_mm`` when that is present.
    pitch_mm : float
        Pixel pitch for the ``period_mm`` column.
    include_paper_only : bool
        Also give rows for paper periods absent from ``results`` (our values ``None``).

    Returns
    -------
    list of dict
        Keys :data:`CSV_COLUMNS`, sorted by decreasing period (the paper's order). Ours:
        ``*_sigma_pct = 100 * std(h, ddof=1) / nominal`` (``None`` for one frame),
        ``*_avg_error_pct = 100 * mean(|h - nominal|) / nominal``,
        ``*_mean_error_pct = 100 * (mean(h) - nominal) / nominal``; ``paper_*`` from
        :data:`PAPER_TABLE1` (``None`` for periods the paper did not use).
    """
    nominal = float(nominal)
    if not (math.isfinite(nominal) and nominal != 0):
        raise ValueError(f"nominal must be a finite non-zero number, got {nominal!r}")
    res = {int(k): v for k, v in results.items()}
    periods = set(res) | (set(PAPER_TABLE1) if include_paper_only else set())
    rows: list[dict[str, Any]] = []
    for period in sorted(periods, reverse=True):
        row: dict[str, Any] = dict.fromkeys(CSV_COLUMNS)
        row.update(period_px=period, period_mm=period * float(pitch_mm), step=step_name, nominal_mm=nominal)
        paper = PAPER_TABLE1.get(period)
        for prefix, key in _METHODS:
            if paper is not None:
                row[f"paper_{prefix}_sigma_pct"] = paper[prefix]["sigma_pct"]
                row[f"paper_{prefix}_avg_error_pct"] = paper[prefix]["avg_error_pct"]
            block = res.get(period, {}).get(key)
            if block is not None:
                st = _step_stats(block, step_name, nominal, f"period {period} {key}")
                row[f"{prefix}_frames"] = st["frames"]
                row[f"{prefix}_sigma_pct"] = st["sigma_pct"]
                row[f"{prefix}_avg_error_pct"] = st["avg_error_pct"]
                row[f"{prefix}_mean_error_pct"] = st["mean_error_pct"]
        rows.append(row)
    return rows


def _f(x: Any, fmt: str = ".2f") -> str:
    return "–" if x is None else format(float(x), fmt)


def _markdown(rows: list[dict[str, Any]]) -> str:
    step = rows[0]["step"] if rows else "?"
    nominal = rows[0]["nominal_mm"] if rows else PAPER_NOMINAL_MM
    lines = [
        f"# Table 1: {step} gauge block, nominal {nominal:g} mm — ours vs. the paper",
        "",
        "| Period (px) | Period (mm) | Proposed σ (%) ours | Proposed σ (%) paper | Proposed ē (%) ours | Proposed ē (%) paper "
        "| Three-step σ (%) ours | Three-step σ (%) paper | Three-step ē (%) ours | Three-step ē (%) paper | Frames (ours) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        frames = "/".join("–" if r[f"{p}_frames"] is None else str(r[f"{p}_frames"]) for p, _ in _METHODS)
        lines.append(
            f"| {r['period_px']} | {_f(r['period_mm'], 'g')} "
            f"| {_f(r['proposed_sigma_pct'])} | {_f(r['paper_proposed_sigma_pct'])} "
            f"| {_f(r['proposed_avg_error_pct'])} | {_f(r['paper_proposed_avg_error_pct'])} "
            f"| {_f(r['three_step_sigma_pct'])} | {_f(r['paper_three_step_sigma_pct'])} "
            f"| {_f(r['three_step_avg_error_pct'])} | {_f(r['paper_three_step_avg_error_pct'])} | {frames} |"
        )
    lines += [
        "",
        f"σ (%) = 100 · std(h, ddof = 1) / nominal over the per-frame step heights h; "
        f"ē (%) = 100 · mean(|h − nominal|) / nominal (the paper's “average error” read as the mean absolute "
        f"per-frame error). Paper: {PAPER_REPEATS} measurements per period, pixel pitch {PAPER_PITCH_MM:g} mm. "
        "Frames (ours): proposed/three-step. – = not measured.",
        "",
    ]
    return "\n".join(lines)


def _figure(rows: list[dict[str, Any]], png_path: str | os.PathLike[str]) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 4.2), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    styles = {"proposed": ("#1f4e9c", "o", "trapezoidal HSI"), "three_step": ("#c25100", "s", "three-step phase shift")}
    periods = np.array([r["period_px"] for r in rows], dtype=float)
    for ax, (quantity, label) in zip(axes, (("sigma_pct", "σ (%)"), ("avg_error_pct", "average error ē (%)")), strict=True):
        for prefix, (colour, marker, name) in styles.items():
            for source, ls, mfc, who in (("", "-", colour, "ours"), ("paper_", "--", "none", "paper")):
                y = np.array([np.nan if r[f"{source}{prefix}_{quantity}"] is None else r[f"{source}{prefix}_{quantity}"] for r in rows], dtype=float)
                ok = np.isfinite(y)
                if ok.any():
                    ax.plot(periods[ok], y[ok], ls=ls, marker=marker, color=colour, mfc=mfc, label=f"{name}, {who}")
        ax.set_xlabel("fringe period (camera px)")
        ax.set_ylabel(label)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    step = rows[0]["step"] if rows else ""
    fig.suptitle(f"Table 1: {step} gauge block {rows[0]['nominal_mm'] if rows else PAPER_NOMINAL_MM:g} mm, ours vs. paper", fontsize=11)
    write_figure_png(fig, png_path)


def write_table1(
    rows: list[dict[str, Any]],
    md_path: str | os.PathLike[str],
    csv_path: str | os.PathLike[str],
    png_path: str | os.PathLike[str],
) -> None:
    """Write Table 1 (ours beside the paper's) as Markdown, CSV and a figure, atomically.

    Parameters
    ----------
    rows : list of dict
        From :func:`table1_rows`.
    md_path : path
        Markdown table with the definitions as a note.
    csv_path : path
        CSV with the header :data:`CSV_COLUMNS`; empty cells where a value is absent; numbers
        with 6 significant digits.
    png_path : path
        Figure: sigma % and average error % against the fringe period, ours (solid) and the
        paper's (dashed), both methods.
    """
    if not rows:
        raise ValueError("no Table 1 rows to write")
    with atomic_path(md_path) as tmp:
        tmp.write_text(_markdown(rows), encoding="utf-8")
    with atomic_path(csv_path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(CSV_COLUMNS)
        for r in rows:
            w.writerow(["" if r.get(c) is None else (format(r[c], ".6g") if isinstance(r[c], float) else r[c]) for c in CSV_COLUMNS])
    _figure(rows, png_path)
