"""Metrology report: ``metrology/report.json`` (results contract 1) and ``report.html``.

``report.json``
    :func:`build_report_json` assembles the contract's keys (``session``, ``method``, ``frames``,
    ``steps[{name, nominal_mm, mean_mm, std_mm, error_mm, error_pct, pass, per_frame_mm}]`` and
    ``baseline{method: "three-step-phase-shift", steps}`` only when a baseline is given) from the
    per-method blocks of :func:`huefringe.metrology.evaluate_session`. Backward-compatible
    extensions (documented in ``schemas/report.schema.json``):

    - top level: ``tolerance_mm``, ``range_mm``, ``edge_exclusion``, ``min_coverage``,
      ``distance`` (``"vertical"``/``"normal"``), ``verdict`` (``"PASS"`` when every step of
      ``method`` passes; the baseline does not vote), ``base`` (base ROIs, coverage, per-frame
      plane coefficients, residual rms) and any ``extras`` given by the caller (``hue_model``,
      ``provenance``, ...), which may not replace a key set here;
    - per step: ``repeatability_3sigma_mm`` (``3 * std_mm``), ``error_pct_of_range``,
      ``roi``, ``evaluated_roi`` (after edge exclusion), ``coverage``, ``flatness``;
    - ``baseline``: ``frames``, ``verdict`` and the same per-step extensions.

    ``std_mm`` (and ``repeatability_3sigma_mm``) is ``null`` for a single frame, where the
    sample standard deviation is undefined. :func:`validate_report` checks the schema *and* the
    contract's arithmetic (``error_pct``, ``pass``, mean and std of ``per_frame_mm``).

``report.html``
    :func:`write_report_html` writes one self-contained file: inline CSS, figures embedded as
    ``data:image/png;base64`` URIs, no script and no external reference, so it opens offline in
    any browser. Order: verdict, step-height table (baseline side by side), measurement
    conditions, flatness/coverage, figures, provenance (collapsible). All text is escaped.
"""

from __future__ import annotations

import base64
import functools
import hashlib
import html
import importlib.metadata
import importlib.resources
import json
import math
import os
import platform
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np

from huefringe.io import atomic_path, write_figure_png

__all__ = [
    "BASELINE_METHOD",
    "CONTRACT_STEP_KEYS",
    "CONTRACT_TOP_KEYS",
    "FIGURE_ORDER",
    "ReportError",
    "build_report_json",
    "collect_provenance",
    "load_schema",
    "per_frame_figure",
    "render_report_html",
    "sha256_file",
    "software_versions",
    "validate_report",
    "write_report_html",
]

BASELINE_METHOD = "three-step-phase-shift"
CONTRACT_TOP_KEYS: tuple[str, ...] = ("session", "method", "frames", "steps")
CONTRACT_STEP_KEYS: tuple[str, ...] = (
    "name", "nominal_mm", "mean_mm", "std_mm", "error_mm", "error_pct", "pass", "per_frame_mm",
)  # fmt: skip

#: Known figure keys of :func:`write_report_html`, in display order, with their captions.
FIGURE_ORDER: dict[str, str] = {
    "profile": "Cross-section profile across the steps (cf. paper Fig. 9 d)",
    "height": "Height map, mm above the reference plane",
    "render": "Rendered surface",
    "per_frame": "Per-frame step heights with nominal value and tolerance band",
    "calibration_qa": "Calibration quality assurance",
}

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class ReportError(ValueError):
    """A report does not follow the results contract (schema or arithmetic)."""


# --------------------------------------------------------------------------------------------
# report.json
# --------------------------------------------------------------------------------------------


@functools.cache
def load_schema() -> dict[str, Any]:
    """The JSON schema of ``report.json`` shipped as ``huefringe/schemas/report.schema.json``."""
    text = importlib.resources.files("huefringe").joinpath("schemas/report.schema.json").read_text("utf-8")
    schema: dict[str, Any] = json.loads(text)
    jsonschema.Draft202012Validator.check_schema(schema)
    return schema


def _plain(obj: Any) -> Any:
    """Deep copy with NumPy scalars/arrays turned into Python scalars/lists."""
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _ordered_steps(specimen: Mapping[str, Any], result: Mapping[str, Any], label: str) -> list[dict[str, Any]]:
    """The result's steps in specimen order, checked against the specimen's names and nominals."""
    by_name = {s["name"]: s for s in result["steps"]}
    out = []
    for s in specimen["steps"]:
        name = s["name"]
        if name not in by_name:
            raise ReportError(f"{label}: no result for step {name!r} of the specimen")
        step = _plain(by_name.pop(name))
        if float(step["nominal_mm"]) != float(s["nominal_mm"]):
            raise ReportError(
                f"{label}: step {name!r} was evaluated with nominal {step['nominal_mm']} mm, "
                f"the specimen says {s['nominal_mm']} mm"
            )
        missing = [k for k in CONTRACT_STEP_KEYS if k not in step]
        if missing:
            raise ReportError(f"{label}: step {name!r} lacks {missing}")
        head = {k: step.pop(k) for k in CONTRACT_STEP_KEYS}
        out.append(head | step)
    if by_name:
        raise ReportError(f"{label}: steps not in the specimen: {sorted(by_name)}")
    return out


def build_report_json(
    session_id: str,
    specimen: Mapping[str, Any],
    method_result: Mapping[str, Any],
    baseline_result: Mapping[str, Any] | None = None,
    extras: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Assemble ``metrology/report.json`` (results contract 1 plus documented extensions).

    Parameters
    ----------
    session_id : str
        ``id`` of the session (``[a-z0-9-]+``).
    specimen : mapping
        The session's ``specimen`` block (step order, nominals, ``tolerance_mm``).
    method_result : mapping
        Block of :func:`huefringe.metrology.evaluate_session` for the one-shot method.
    baseline_result : mapping, optional
        Block for the three-step phase-shift baseline; its ``method`` must be
        ``"three-step-phase-shift"``. The ``baseline`` key is written only when given.
    extras : mapping, optional
        Further top-level keys (``hue_model``, ``provenance``, ...); they may not replace a key
        this function sets.

    Returns
    -------
    dict
        The report, JSON-ready, validated with :func:`validate_report`.

    Raises
    ------
    ReportError
        Steps that do not match the specimen, a wrong baseline method, a clashing extra key, or
        a report that fails :func:`validate_report`.
    """
    tol = float(specimen["tolerance_mm"])
    report: dict[str, Any] = {
        "session": str(session_id),
        "method": str(method_result["method"]),
        "frames": int(method_result["frames"]),
        "steps": _ordered_steps(specimen, method_result, "method_result"),
    }
    if baseline_result is not None:
        if baseline_result.get("method") != BASELINE_METHOD:
            raise ReportError(f"baseline method must be {BASELINE_METHOD!r}, got {baseline_result.get('method')!r}")
        steps = _ordered_steps(specimen, baseline_result, "baseline_result")
        baseline: dict[str, Any] = {"method": BASELINE_METHOD, "frames": int(baseline_result["frames"]), "steps": steps}
        baseline["verdict"] = "PASS" if all(s["pass"] for s in steps) else "FAIL"
        for key in ("range_mm", "edge_exclusion", "min_coverage", "distance", "base"):
            if key in baseline_result:
                baseline[key] = _plain(baseline_result[key])
        report["baseline"] = baseline
    report["tolerance_mm"] = tol
    for key in ("range_mm", "edge_exclusion", "min_coverage", "distance", "verdict_with_uncertainty"):
        if key in method_result:
            report[key] = _plain(method_result[key])
    report["verdict"] = "PASS" if all(s["pass"] for s in report["steps"]) else "FAIL"
    if "base" in method_result:
        report["base"] = _plain(method_result["base"])
    for key, value in (extras or {}).items():
        if key in report:
            raise ReportError(f"extras may not replace the report key {key!r}")
        report[str(key)] = _plain(value)
    validate_report(report)
    return report


def _close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)


def _check_steps(steps: Sequence[Mapping[str, Any]], where: str, frames: int | None, tol: float | None) -> list[str]:
    problems: list[str] = []
    seen: set[str] = set()
    for i, s in enumerate(steps):
        at = f"{where}[{i}] ({s['name']!r})"
        if s["name"] in seen:
            problems.append(f"{at}: duplicate step name")
        seen.add(s["name"])
        pf = np.asarray(s["per_frame_mm"], dtype=np.float64)
        mean, nominal = float(s["mean_mm"]), float(s["nominal_mm"])
        if frames is not None and pf.size != frames:
            problems.append(f"{at}: per_frame_mm has {pf.size} values, frames is {frames}")
        if not _close(mean, float(pf.mean())):
            problems.append(f"{at}: mean_mm {mean} is not the mean of per_frame_mm ({pf.mean()})")
        if pf.size > 1:
            std = float(np.std(pf, ddof=1))
            if s["std_mm"] is None or not _close(float(s["std_mm"]), std):
                problems.append(f"{at}: std_mm {s['std_mm']} is not the sample std (ddof=1) of per_frame_mm ({std})")
        elif s["std_mm"] is not None:
            problems.append(f"{at}: std_mm must be null for a single frame")
        if not _close(float(s["error_mm"]), mean - nominal):
            problems.append(f"{at}: error_mm {s['error_mm']} != mean_mm - nominal_mm ({mean - nominal})")
        expected_pct = 100.0 * (mean - nominal) / nominal
        if not _close(float(s["error_pct"]), expected_pct):
            problems.append(f"{at}: error_pct {s['error_pct']} != 100 * (mean_mm - nominal_mm) / nominal_mm ({expected_pct})")
        if tol is not None and bool(s["pass"]) != (abs(float(s["error_mm"])) <= tol):
            problems.append(f"{at}: pass {s['pass']} disagrees with |error_mm| <= tolerance_mm ({tol})")
        rep = s.get("repeatability_3sigma_mm")
        if rep is not None and s["std_mm"] is not None and not _close(float(rep), 3.0 * float(s["std_mm"])):
            problems.append(f"{at}: repeatability_3sigma_mm {rep} != 3 * std_mm")
    return problems


def validate_report(report: Mapping[str, Any]) -> None:
    """Check a report against the schema and the contract's arithmetic.

    Parameters
    ----------
    report : mapping
        A ``report.json`` document (as loaded, or from :func:`build_report_json`).

    Raises
    ------
    ReportError
        Listing every problem: schema violations (with their JSON path) and, when the schema
        holds, inconsistent ``mean_mm``/``std_mm``/``error_mm``/``error_pct``/``pass``/``verdict``
        and ``per_frame_mm`` lengths different from ``frames``.
    """
    validator = jsonschema.Draft202012Validator(load_schema())
    errors = sorted(validator.iter_errors(report), key=lambda e: list(e.absolute_path))
    if errors:
        lines = [f"  at /{'/'.join(str(p) for p in e.absolute_path)}: {e.message}" for e in errors]
        raise ReportError("report.json does not follow the results contract:\n" + "\n".join(lines))
    tol = report.get("tolerance_mm")
    tol_f = None if tol is None else float(tol)
    problems = _check_steps(report["steps"], "steps", int(report["frames"]), tol_f)
    if "verdict" in report:
        want = "PASS" if all(s["pass"] for s in report["steps"]) else "FAIL"
        if report["verdict"] != want:
            problems.append(f"verdict {report['verdict']} but the steps say {want}")
    if "baseline" in report:
        b = report["baseline"]
        problems += _check_steps(b["steps"], "baseline.steps", b.get("frames"), tol_f)
        names, bnames = [s["name"] for s in report["steps"]], [s["name"] for s in b["steps"]]
        if sorted(names) != sorted(bnames):
            problems.append(f"baseline steps {bnames} differ from the method's {names}")
    if problems:
        raise ReportError("report.json is inconsistent:\n" + "\n".join(f"  {p}" for p in problems))


# --------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------


def per_frame_figure(report: Mapping[str, Any], out_png: str | os.PathLike[str]) -> Path:
    """Scatter of the per-frame step heights, one panel per step, with nominal and tolerance band.

    Parameters
    ----------
    report : mapping
        A report from :func:`build_report_json` (``tolerance_mm`` draws the band when present;
        the baseline's frames are drawn beside the method's when present).
    out_png : path
        PNG to write (atomically).

    Returns
    -------
    Path
        ``out_png``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    steps = list(report["steps"])
    base = {s["name"]: s for s in report.get("baseline", {}).get("steps", [])}
    tol = report.get("tolerance_mm")
    ncols = min(3, len(steps))
    nrows = math.ceil(len(steps) / ncols)
    fig = Figure(figsize=(4.3 * ncols, 3.5 * nrows + 0.5), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for ax in axes.ravel()[len(steps) :]:
        ax.set_visible(False)
    for ax, s in zip(axes.ravel(), steps, strict=False):
        nominal = float(s["nominal_mm"])
        if tol is not None:
            ax.axhspan(nominal - tol, nominal + tol, color="#2e7d32", alpha=0.15, lw=0, label=f"nominal ± {tol:g} mm")
        ax.axhline(nominal, color="black", lw=1.0, label="nominal")
        pf = np.asarray(s["per_frame_mm"], dtype=float)
        frames = np.arange(pf.size)
        ax.plot(frames, pf, "o", ms=4, color="#1f4e9c", label=str(report.get("method", "method")))
        ax.axhline(float(s["mean_mm"]), color="#1f4e9c", ls="--", lw=1.0, label="mean")
        if s["name"] in base:
            b = np.asarray(base[s["name"]]["per_frame_mm"], dtype=float)
            ax.plot(np.arange(b.size), b, "s", ms=4, mfc="none", color="#c25100", label=BASELINE_METHOD)
            ax.axhline(float(base[s["name"]]["mean_mm"]), color="#c25100", ls=":", lw=1.0, label="baseline mean")
        verdict = "pass" if s["pass"] else "FAIL"
        ax.set_title(f"{s['name']}: nominal {nominal:g} mm ({verdict})", fontsize=10)
        ax.set_xlabel("frame")
        ax.set_ylabel("step height (mm)")
        ax.grid(True, alpha=0.3)
        ax.ticklabel_format(axis="y", useOffset=False)
    axes.ravel()[0].legend(fontsize=7, loc="best")
    fig.suptitle(f"Session {report.get('session', '')}: per-frame step heights", fontsize=11)
    return write_figure_png(fig, out_png)


# --------------------------------------------------------------------------------------------
# provenance helpers
# --------------------------------------------------------------------------------------------


def sha256_file(path: str | os.PathLike[str], chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()


def software_versions(packages: Iterable[str] = ("huefringe", "numpy", "scipy", "matplotlib", "jsonschema")) -> dict[str, str]:
    """Versions of Python, the platform and the given distributions (``"not installed"`` if absent)."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for name in packages:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def collect_provenance(
    session_id: str,
    config: Mapping[str, Any] | None,
    inputs: Iterable[str | os.PathLike[str]],
    *,
    root: str | os.PathLike[str] | None = None,
    packages: Iterable[str] | None = None,
) -> dict[str, Any]:
    """Provenance block for :func:`write_report_html` (and ``extras["provenance"]``).

    Parameters
    ----------
    session_id : str
        Session id.
    config : mapping or None
        Configuration the run used.
    inputs : iterable of path
        Input files to checksum.
    root : path, optional
        Input paths are shown relative to it when possible.
    packages : iterable of str, optional
        Distributions whose versions to list (default: :func:`software_versions` defaults).

    Returns
    -------
    dict
        ``{"session", "config", "software", "inputs_sha256": {path: hex}}``.
    """
    sums: dict[str, str] = {}
    for p in sorted(Path(x) for x in inputs):
        shown = p
        if root is not None:
            try:
                shown = p.resolve().relative_to(Path(root).resolve())
            except ValueError:
                shown = p
        sums[shown.as_posix()] = sha256_file(p)
    return {
        "session": session_id,
        "config": _plain(dict(config or {})),
        "software": software_versions() if packages is None else software_versions(packages),
        "inputs_sha256": sums,
    }


# --------------------------------------------------------------------------------------------
# report.html
# --------------------------------------------------------------------------------------------

_CSS = """
:root { color-scheme: light; }
* { box-sizing: border-box; }
body { font-family: "DejaVu Sans", system-ui, -apple-system, "Segoe UI", Arial, sans-serif;
       margin: 0 auto; max-width: 1280px; padding: 1.2rem 1.5rem 3rem; color: #1b1b1b;
       background: #ffffff; line-height: 1.45; }
h1 { font-size: 1.6rem; margin: .2rem 0 .6rem; }
dl.capture { display: grid; grid-template-columns: max-content 1fr; gap: .1rem .8rem; margin: .4rem 0; }
dl.capture dt { font-weight: 600; } dl.capture dd { margin: 0; }
.simulated { background: #fff4d6; border-left: 5px solid #b26b00; padding: .5rem .8rem; margin: .5rem 0; }
h2 { font-size: 1.25rem; margin: 2rem 0 .6rem; border-bottom: 2px solid #e3e3e3; padding-bottom: .2rem; }
.sub { color: #555; margin: 0; }
.verdict { display: flex; flex-wrap: wrap; align-items: center; gap: .6rem 2rem; color: #ffffff;
           border-radius: 12px; padding: 1.1rem 1.6rem; margin: 1rem 0 1.2rem; }
.verdict-pass { background: #1b6e35; }
.verdict-fail { background: #b3261e; }
.verdict-word { font-size: 4.2rem; font-weight: 800; letter-spacing: .08em; line-height: 1; }
.verdict-detail { font-size: 1.15rem; }
.verdict-detail ul { margin: .3rem 0 0 1.1rem; padding: 0; }
.verdict-baseline { font-size: .95rem; opacity: .9; margin-top: .3rem; }
.table-wrap { overflow-x: auto; }
table { border-collapse: collapse; font-variant-numeric: tabular-nums; margin: .3rem 0; }
th, td { padding: .35rem .65rem; text-align: right; white-space: nowrap; border-bottom: 1px solid #dcdcdc; }
th:first-child, td:first-child { text-align: left; }
thead th { background: #f1f3f5; font-weight: 600; vertical-align: bottom; }
th.group { text-align: center; border-bottom: 2px solid #9aa0a6; }
table#steps { font-size: .9rem; }
table#steps thead th { white-space: normal; min-width: 4.6em; max-width: 7.5em; padding: .3rem .45rem; }
table#steps td { padding: .32rem .45rem; }
table#steps caption { caption-side: top; text-align: left; }
.grp { border-left: 2px solid #9aa0a6; }
td.ok { color: #1b6e35; font-weight: 700; }
td.bad { color: #b3261e; font-weight: 700; background: #fdecea; }
.note { color: #555; font-size: .9rem; max-width: 70rem; }
dl.cond { display: grid; grid-template-columns: max-content auto; gap: .15rem 1.2rem; margin: .3rem 0; }
dl.cond dt { color: #555; }
dl.cond dd { margin: 0; font-variant-numeric: tabular-nums; }
figure { margin: 1.4rem 0; }
figure img { display: block; max-width: 100%; height: auto; border: 1px solid #dcdcdc; }
figcaption { color: #444; font-size: .95rem; margin-top: .35rem; }
details { margin-top: 2rem; border: 1px solid #dcdcdc; border-radius: 8px; padding: .6rem 1rem; }
summary { cursor: pointer; font-weight: 600; font-size: 1.1rem; }
table.kv th { text-align: left; vertical-align: top; color: #444; font-weight: 600; }
table.kv td { text-align: left; white-space: normal; }
.mono, pre { font-family: "DejaVu Sans Mono", ui-monospace, Menlo, Consolas, monospace; font-size: .82rem; }
.mono { word-break: break-all; }
pre { white-space: pre-wrap; word-break: break-word; background: #f6f7f8; padding: .5rem .7rem; margin: 0; }
@media print { .verdict, td.bad { -webkit-print-color-adjust: exact; print-color-adjust: exact; } }
"""


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _num(x: Any, fmt: str) -> str:
    if x is None:
        return "—"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return _e(x)
    if not math.isfinite(v):
        return "—"
    return _e(format(v, fmt))


def _verdict(report: Mapping[str, Any]) -> str:
    v = report.get("verdict")
    if v in ("PASS", "FAIL"):
        return str(v)
    return "PASS" if report.get("steps") and all(s.get("pass") for s in report["steps"]) else "FAIL"


def _step_cells(s: Mapping[str, Any] | None, first_group_class: str) -> list[str]:
    if s is None:
        return [f'<td class="{first_group_class}">—</td>'] + ["<td>—</td>"] * 6
    rep = s.get("repeatability_3sigma_mm")
    if rep is None and s.get("std_mm") is not None:
        rep = 3.0 * float(s["std_mm"])
    ok = bool(s.get("pass"))
    return [
        f'<td class="{first_group_class}">{_num(s.get("mean_mm"), ".4f")}</td>',
        f"<td>{_num(s.get('std_mm'), '.4f')}</td>",
        f"<td>{'±' + _num(rep, '.4f') if rep is not None else '—'}</td>",
        f"<td>{_num(s.get('error_mm'), '+.4f')}</td>",
        f"<td>{_num(s.get('error_pct'), '+.2f')}</td>",
        f"<td>{_num(s.get('error_pct_of_range'), '+.2f')}</td>",
        f'<td class="{"ok" if ok else "bad"}">{"pass" if ok else "FAIL"}</td>',
    ]


_STEP_HEAD = ("Mean (mm)", "Std σ (mm)", "±3σ (mm)", "Error (mm)", "Error / nominal (%)", "Error / range (%)", "Pass")


def _steps_table(report: Mapping[str, Any]) -> str:
    baseline = report.get("baseline")
    bsteps = {s["name"]: s for s in baseline["steps"]} if baseline else {}
    rows = []
    head_method = f"{_e(report.get('method', 'method'))} ({_e(report.get('frames', '?'))} frames)"
    if baseline:
        head_base = f"{_e(baseline.get('method', BASELINE_METHOD))} ({_e(baseline.get('frames', '?'))} frames)"
        sub = "".join(f'<th{" class=grp" if i == 0 else ""}>{_e(h)}</th>' for i, h in enumerate(_STEP_HEAD))
        thead = (
            '<tr><th rowspan="2">Step</th><th rowspan="2">Nominal (mm)</th>'
            f'<th class="group grp" colspan="7" scope="colgroup">{head_method}</th>'
            f'<th class="group grp" colspan="7" scope="colgroup">baseline: {head_base}</th></tr>'
            f"<tr>{sub}{sub}</tr>"
        )
    else:
        thead = "<tr><th>Step</th><th>Nominal (mm)</th>" + "".join(f"<th>{_e(h)}</th>" for h in _STEP_HEAD) + "</tr>"
    for s in report.get("steps", []):
        cells = [f"<td>{_e(s.get('name'))}</td>", f"<td>{_num(s.get('nominal_mm'), '.4f')}</td>"]
        cells += _step_cells(s, "grp" if baseline else "")
        if baseline:
            cells += _step_cells(bsteps.get(s.get("name")), "grp")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    caption = f"Step heights, {_e(report.get('method', ''))}" + (" vs. baseline" if baseline else "")
    return (
        f'<div class="table-wrap"><table id="steps"><caption class="note">'
        f"{caption}</caption><thead>{thead}</thead><tbody>{''.join(rows)}</tbody></table></div>"
    )


def _verdict_block(report: Mapping[str, Any]) -> str:
    verdict = _verdict(report)
    steps = report.get("steps", [])
    npass = sum(1 for s in steps if s.get("pass"))
    tol = report.get("tolerance_mm")
    tol_txt = f" within ±{_num(tol, 'g')} mm" if tol is not None else ""
    detail = (
        f"{npass} of {len(steps)} step heights{tol_txt} · method {_e(report.get('method', ''))} · "
        f"{_e(report.get('frames', '?'))} frames"
    )
    failing = [s for s in steps if not s.get("pass")]
    if failing:
        items = "".join(
            f"<li>{_e(s.get('name'))}: error {_num(s.get('error_mm'), '+.4f')} mm "
            f"({_num(s.get('error_pct'), '+.2f')} % of nominal)</li>"
            for s in failing
        )
        detail += f"<ul>{items}</ul>"
    baseline = report.get("baseline")
    if isinstance(baseline, Mapping) and baseline.get("steps"):
        bpass = sum(1 for s in baseline["steps"] if s.get("pass"))
        detail += (
            f'<div class="verdict-baseline">baseline {_e(baseline.get("method", BASELINE_METHOD))}: '
            f"{bpass} of {len(baseline['steps'])} within tolerance (for comparison; not part of the verdict)</div>"
        )
    cls = "verdict-pass" if verdict == "PASS" else "verdict-fail"
    return (
        f'<section class="verdict {cls}" id="verdict" aria-label="verdict">'
        f'<div class="verdict-word">{verdict}</div><div class="verdict-detail">{detail}</div></section>'
    )


def _conditions(report: Mapping[str, Any]) -> str:
    items: list[tuple[str, str]] = []
    if "tolerance_mm" in report:
        items.append(("Tolerance", f"±{_num(report['tolerance_mm'], 'g')} mm on the mean step height"))
    if "range_mm" in report:
        items.append(("Measuring range", f"{_num(report['range_mm'], 'g')} mm (denominator of “error % range”)"))
    if "edge_exclusion" in report:
        e = float(report["edge_exclusion"])
        items.append(
            ("Edge exclusion", f"{_num(100 * e, '.1f')} % of each top-box side at each edge (central {_num(100 * (1 - 2 * e), '.1f')} % evaluated)")
        )
    if "distance" in report:
        items.append(("Distance to base plane", _e(report["distance"])))
    if "min_coverage" in report:
        items.append(("Minimum coverage", f"{_num(100 * float(report['min_coverage']), '.0f')} % valid pixels per evaluated box"))
    base = report.get("base")
    if isinstance(base, Mapping) and "residual_rms_mm" in base:
        items.append(
            (
                "Base plane fit residual (rms)",
                f"{_num(1000 * float(base['residual_rms_mm']), '.2f')} µm mean, "
                f"{_num(1000 * float(base.get('residual_rms_mm_max', math.nan)), '.2f')} µm worst frame",
            )
        )
    if "hue_model" in report:
        items.append(("Hue model", _e(report["hue_model"])))
    if "unwrap" in report:
        items.append(("Phase unwrapping", _e(report["unwrap"])))
    cal = report.get("calibration") or {}
    if cal.get("unambiguous_range_mm"):
        lo, hi = cal["unambiguous_range_mm"]
        items.append(("Unambiguous depth", f"{_num(lo, '.2f')} to {_num(hi, '.2f')} mm"))
    fq = report.get("frame_qa") or {}
    if "phase_ambiguity_suspected" in fq:
        bad = fq["phase_ambiguity_suspected"]
        items.append(("Phase ambiguity", "none suspected" if not bad else
                      f"<strong>suspected in frames {_e(', '.join(str(n) for n in bad))}</strong> "
                      "(a step may exceed the unambiguous depth)"))
    if not items:
        return ""
    body = "".join(f"<dt>{_e(k)}</dt><dd>{v}</dd>" for k, v in items)
    return f'<h2>Measurement conditions</h2><dl class="cond">{body}</dl>'


def _uncertainty_table(report: Mapping[str, Any]) -> str:
    """The per-step uncertainty budget (GUM, docs/uncertainty.md) and the ISO 14253-1 decisions,
    and the validation against ground truth when the report carries one; empty without ``u_mm``."""
    steps = [s for s in report.get("steps", []) if "u_mm" in s]
    if not steps:
        return ""
    terms = ("noise", "table", "interpolation", "reference", "model")
    head = "".join(f"<th>{t}</th>" for t in terms)
    rows = []
    for s in steps:
        b = s.get("uncertainty_budget", {})
        t = b.get("terms_mm", {})
        cells = "".join(f"<td>{_num(t.get(k), '.4f')}</td>" for k in terms)
        rows.append(f"<tr><td>{_e(s['name'])}</td>{cells}<td>{_num(b.get('base_plane_per_frame_mm'), '.4f')}</td>"
                    f"<td>{_num(b.get('effective_independent_pixels'), '.0f')}</td><td>{_num(s['u_mm'], '.4f')}</td>"
                    f"<td>{_num(s['U_mm'], '.4f')}</td><td>{_e(s.get('conformance', ''))}</td></tr>")
    val = ""
    acc = report.get("accuracy", {}).get("trapezoidal-hsi", {}).get("uncertainty")
    if acc:
        val = (f'<p class="note">Against ground truth: {_num(100 * acc["coverage_2u"], ".1f")} % of the valid pixels '
               f"have |error| ≤ 2u (target 95 ± 3 %); rms error {_num(acc['rms_error_mm'], '.4f')} mm, "
               f"rms u {_num(acc['rms_u_mm'], '.4f')} mm.</p>")
    return ("<h2>Uncertainty budget (mm)</h2><table><tr><th>step</th>" + head +
            "<th>base plane (1 frame)</th><th>independent pixels</th><th>u</th><th>U (k = 2)</th>"
            "<th>ISO 14253-1</th></tr>" + "".join(rows) + "</table>"
            '<p class="note">Standard uncertainties of the mean step height: noise (sensor noise of the frames, '
            "through the phase filter, / √frames), table (hue-table noise) and interpolation (averaged over pixels, "
            "not frames), reference phase and phase-to-height model (correlated: not averaged). ISO 14253-1: pass "
            "when |error| ≤ tolerance − U, fail when |error| > tolerance + U, else undecided; the column "
            f"'pass' above is |error| ≤ tolerance. Decision with U: {_e(report.get('verdict_with_uncertainty', ''))}.</p>"
            + val)


def _flatness_table(report: Mapping[str, Any]) -> str:
    steps = [s for s in report.get("steps", []) if "flatness" in s or "coverage" in s]
    if not steps:
        return ""
    rows = []
    for s in steps:
        f = s.get("flatness", {})
        c = s.get("coverage", {})

        def um(key: str, f: Mapping[str, Any] = f) -> str:
            return _num(None if f.get(key) is None else 1000 * float(f[key]), ".2f")

        def pct(key: str, c: Mapping[str, Any] = c) -> str:
            return _num(None if c.get(key) is None else 100 * float(c[key]), ".1f")

        box = s.get("evaluated_roi")
        rows.append(
            f"<tr><td>{_e(s.get('name'))}</td><td>{um('Sa_mm')}</td><td>{um('Sq_mm')}</td><td>{um('Sz_mm')}</td>"
            f"<td>{pct('roi')}</td><td>{pct('evaluated')}</td><td>{pct('evaluated_min')}</td>"
            f"<td class=mono>{_e(box) if box is not None else '—'}</td></tr>"
        )
    head = (
        "<tr><th>Step</th><th>Sa (µm)</th><th>Sq (µm)</th><th>Sz (µm)</th><th>Coverage ROI (%)</th>"
        "<th>Coverage evaluated (%)</th><th>worst frame (%)</th><th>Evaluated box [u0, v0, u1, v1)</th></tr>"
    )
    return (
        "<h2>Flatness of the tops and coverage</h2>"
        f'<div class="table-wrap"><table id="flatness"><thead>{head}</thead><tbody>{"".join(rows)}</tbody></table></div>'
        '<p class="note">Flatness: least-squares plane removed from the evaluated box of each top '
        "(no other filter); Sa = mean |r|, Sq = rms r, Sz = highest peak + deepest pit; mean over frames. "
        "Coverage: fraction of valid pixels, mean over frames.</p>"
    )


def _figure(key: str, path: str | os.PathLike[str]) -> str:
    data = Path(path).read_bytes()
    if not data.startswith(_PNG_MAGIC):
        raise ValueError(f"figure {key!r}: {path} is not a PNG file")
    uri = "data:image/png;base64," + base64.b64encode(data).decode("ascii")
    caption = FIGURE_ORDER.get(key, key.replace("_", " "))
    return f'<figure id="fig-{_e(key)}"><img src="{uri}" alt="{_e(caption)}"><figcaption>{_e(caption)}</figcaption></figure>'


def _prov_value(value: Any) -> str:
    value = _plain(value)
    if isinstance(value, Mapping):
        if value and all(not isinstance(v, Mapping | list) for v in value.values()):
            rows = "".join(f'<tr><th>{_e(k)}</th><td class="mono">{_e(v)}</td></tr>' for k, v in value.items())
            return f'<table class="kv">{rows}</table>'
        return f"<pre>{_e(json.dumps(value, indent=2, sort_keys=True, default=str, ensure_ascii=False))}</pre>"
    if isinstance(value, list):
        if all(not isinstance(v, Mapping | list) for v in value):
            return "<ul>" + "".join(f'<li class="mono">{_e(v)}</li>' for v in value) + "</ul>"
        return f"<pre>{_e(json.dumps(value, indent=2, default=str, ensure_ascii=False))}</pre>"
    return f'<span class="mono">{_e(value)}</span>'


def _provenance(report: Mapping[str, Any], provenance: Mapping[str, Any]) -> str:
    rows = [f"<tr><th>session</th><td>{_prov_value(report.get('session', ''))}</td></tr>"]
    rows += [f"<tr><th>{_e(k)}</th><td>{_prov_value(v)}</td></tr>" for k, v in provenance.items() if k not in ("session", "capture")]
    return (
        '<details id="provenance"><summary>Provenance: session, configuration, software versions, input checksums</summary>'
        f'<table class="kv">{"".join(rows)}</table></details>'
    )


def render_report_html(
    report: Mapping[str, Any],
    figures: Mapping[str, str | os.PathLike[str]] | None = None,
    provenance: Mapping[str, Any] | None = None,
) -> str:
    """The HTML text of :func:`write_report_html` (pure: reads only the figure files).

    Parameters
    ----------
    report : mapping
        A report from :func:`build_report_json`.
    figures : mapping of str to path, optional
        PNG files by key; known keys (:data:`FIGURE_ORDER`: ``profile``, ``height``, ``render``,
        ``per_frame``, ``calibration_qa``) come first in that order, other keys after them in
        the given order, captioned with their key.
    provenance : mapping, optional
        Shown in the collapsible provenance section (e.g. from :func:`collect_provenance`).

    Returns
    -------
    str
        A complete HTML5 document.

    Raises
    ------
    FileNotFoundError
        A figure file does not exist.
    ValueError
        A figure file is not a PNG.
    """
    figures = dict(figures or {})
    keys = [k for k in FIGURE_ORDER if k in figures] + [k for k in figures if k not in FIGURE_ORDER]
    figs = "".join(_figure(k, figures[k]) for k in keys)
    session = report.get("session", "")
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        '<meta name="generator" content="huefringe.report">',
        f"<title>{_verdict(report)}: metrology report, session {_e(session)}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<header><h1>Metrology report: session {_e(session)}</h1>",
        '<p class="sub">Step heights after ISO 5436-1 (type A, areal form): least-squares base plane, '
        "central part of each top evaluated.</p>",
        _capture_block((provenance or {}).get("capture") or {}),
        "</header>",
        _verdict_block(report),
        "<h2>Step heights</h2>",
        _steps_table(report),
        '<p class="note">Mean and σ over frames (σ: sample standard deviation, n − 1); ±3σ = 3σ (repeatability); '
        "error = mean − nominal; error % nominal = 100 · (mean − nominal) / nominal; "
        "error % range = 100 · error / measuring range; pass = |error| ≤ tolerance.</p>",
        _uncertainty_table(report),
        _conditions(report),
        _flatness_table(report),
        f"<h2>Figures</h2>{figs}" if figs else "",
        _provenance(report, provenance or {}),
        "</body></html>",
    ]
    return "\n".join(p for p in parts if p) + "\n"


def _capture_block(capture: Mapping[str, Any]) -> str:
    """Capture date, operator and instrument (session.yaml ``provenance``), and a notice for simulated data."""
    def field(label: str, key: str) -> str:
        value = capture.get(key)
        shown = _e(value) if value not in (None, "") else '<span class="note">not recorded in session.yaml</span>'
        return f"<dt>{label}</dt><dd>{shown}</dd>"

    out = ['<dl class="capture">', field("Captured", "captured_at"), field("Operator", "operator"),
           field("Instrument", "instrument"), "</dl>"]
    if capture.get("simulated"):
        out.append('<p class="simulated" role="alert"><strong>Simulated data.</strong> This session was written by a '
                   "virtual bench (session.yaml provenance.simulated: true): the figures below measure a simulation, "
                   "not a physical specimen.</p>")
    if capture.get("notes"):
        out.append(f'<p class="note">Notes: {_e(capture["notes"])}</p>')
    return "".join(out)


def write_report_html(
    path: str | os.PathLike[str],
    report: Mapping[str, Any],
    figures: Mapping[str, str | os.PathLike[str]] | None,
    provenance: Mapping[str, Any] | None,
) -> Path:
    """Write the self-contained ``report.html`` atomically.

    Parameters
    ----------
    path : path
        Target file.
    report : mapping
        A report from :func:`build_report_json`.
    figures : mapping of str to path, or None
        Already-made PNG figures, embedded as base64 data URIs (see :func:`render_report_html`);
        each appears only if given.
    provenance : mapping or None
        Session id, configuration, software versions, input checksums (free-form; shown in a
        collapsed ``<details>``). Its ``capture`` entry (the session's ``provenance`` block)
        is shown in the header: capture date, operator, instrument, and a "simulated data"
        notice when ``simulated`` is true.

    Returns
    -------
    Path
        ``path``.
    """
    text = render_report_html(report, figures, provenance)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
