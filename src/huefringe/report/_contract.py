"""The results contract's report JSON: building it from a method result, the conformity decision, and validation against the schema."""

from __future__ import annotations

import functools
import importlib.metadata
import importlib.resources
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np


BASELINE_METHOD = "three-step-phase-shift"
CONTRACT_TOP_KEYS: tuple[str, ...] = ("session", "method", "frames", "steps")
CONTRACT_STEP_KEYS: tuple[str, ...] = (
    "name", "nominal_mm", "mean_mm", "std_mm", "error_mm", "error_pct", "pass", "per_frame_mm",
)  # fmt: skip


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
    figures: Sequence[Mapping[str, Any]] = (),
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
    figures : sequence of mapping, optional
        Further reported figures beside the steps (flatness, distances, parallelism, spheres of a
        rig session's ``forms``), each with ``name``, ``error_mm``, ``U_mm`` and optionally its own
        ``tolerance_mm``: the ISO 14253-1 decision (``conformity``) covers them with the steps.

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
    report["conformity"] = None  # its place in the file; decided below, with the extras' QA
    if "base" in method_result:
        report["base"] = _plain(method_result["base"])
    for key, value in (extras or {}).items():
        if key in report:
            raise ReportError(f"extras may not replace the report key {key!r}")
        report[str(key)] = _plain(value)
    report["conformity"] = conformity([*report["steps"], *figures], tol, "figure" if figures else "step",
                                      unmodelled_errors(report))
    validate_report(report)
    return report


CONFORMITY_DECISIONS: tuple[str, ...] = ("conforms", "does not conform", "undecided")


def unmodelled_errors(report: Mapping[str, Any]) -> list[str]:
    """Errors the capture QA found that no U holds: the calibration planes' row banding and the
    reference bands' colour flicker (``report["calibration"]``, :mod:`huefringe.row_banding`), in words."""
    cal = report.get("calibration") or {}
    out = []
    banding = cal.get("row_banding") or {}
    if banding.get("suspected"):
        out.append(f"row banding of the calibration planes, {float(banding['amplitude_rad']):.3f} rad RMS")
    flicker = cal.get("colour_flicker") or {}
    if flicker.get("suspected"):
        out.append(f"colour flicker between the reference bands' repeats, {float(flicker['amplitude_rad']):.4f} rad")
    return out


def conformity(steps: Sequence[Mapping[str, Any]], tolerance_mm: float, noun: str = "step",
               unmodelled: Sequence[str] = ()) -> dict[str, Any]:
    """The report's headline: the ISO 14253-1 decision for the whole specimen, with its reason.

    Parameters
    ----------
    steps : sequence of mapping
        The report's steps (``name``, ``error_mm`` and, with the uncertainty, ``U_mm``); an entry
        may carry its own ``tolerance_mm``, its T instead of the common one. A one-sided figure
        (a flatness: nominal 0, ``error_mm`` = the value) follows the same rule.
    tolerance_mm : float
        T, the tolerance on each step's mean height (for every entry without its own).
    noun : str
        What the entries are called in the reason (``step``; ``figure`` for a report with form figures).
    unmodelled : sequence of str
        Errors the capture QA found that the U does not hold (:func:`unmodelled_errors`): with
        any, conformance is not proven (``"conforms"`` becomes ``"undecided"``, and the reason
        names them); a proven non-conformance stands.

    Returns
    -------
    dict
        ``decision``: ``"conforms"`` when every step's ``|error| <= T - U`` (conformance proven),
        ``"does not conform"`` when any step's ``|error| > T + U`` (non-conformance proven),
        otherwise ``"undecided"`` (the uncertainty allows no decision, or no step carries ``U_mm``);
        ``reason``: the steps that decide it, in words, with their numbers; ``rule``; and
        ``conforming``, ``undecided``, ``nonconforming``: the step names in each zone. The
        contract's per-step ``pass`` (``|error| <= T``, U ignored) is not a conformance decision.
    """
    t = float(tolerance_mm)
    rule = "ISO 14253-1: conforms when |error| <= T - U, does not conform when |error| > T + U, else undecided (U = 2u)"
    if not steps or any("U_mm" not in st for st in steps):
        n_in = sum(1 for st in steps if st.get("pass"))
        return {"decision": "undecided", "rule": rule, "conforming": [], "undecided": [st["name"] for st in steps],
                "nonconforming": [],
                "reason": f"no expanded uncertainty U for the step heights, and ISO 14253-1 decides only with it; "
                          f"the tolerance alone (U ignored) holds for {n_in} of {len(steps)} steps"}
    zone: dict[str, list[Mapping[str, Any]]] = {"pass": [], "undecided": [], "fail": []}

    def tol(st: Mapping[str, Any]) -> float:
        return float(st["tolerance_mm"]) if st.get("tolerance_mm") is not None else t

    for st in steps:
        e, u, ts = abs(float(st["error_mm"])), float(st["U_mm"]), tol(st)
        zone["pass" if e <= ts - u else "fail" if e > ts + u else "undecided"].append(st)

    def says(st: Mapping[str, Any], how: str) -> str:
        e, u, t = abs(float(st["error_mm"])), float(st["U_mm"]), tol(st)
        if how == "fail":
            return f"{st['name']}: |error| {e:.4f} mm > T + U = {t + u:.4f} mm"
        low = f"T - U = {t - u:.4f} mm" if u < t else f"0 (U = {u:.4f} mm >= T)"
        return f"{st['name']}: |error| {e:.4f} mm lies between {low} and T + U = {t + u:.4f} mm"

    n = len(steps)
    if zone["fail"]:
        decision = "does not conform"
        reason = "; ".join(says(st, "fail") for st in zone["fail"]) + ": non-conformance proven"
    elif zone["undecided"]:
        decision = "undecided"
        reason = ("; ".join(says(st, "undecided") for st in zone["undecided"])
                  + ": the uncertainty U does not allow a decision"
                  + (f" ({len(zone['pass'])} of {n} {noun}s conform)" if zone["pass"] else ""))
    elif unmodelled:
        decision = "undecided"
        reason = (f"every {noun}'s |error| <= T - U, but the captures show errors that U does not hold ("
                  + "; ".join(unmodelled) + "): conformance not proven; see the capture guide")
    else:
        decision = "conforms"
        reason = f"every {noun}'s |error| <= T - U: conformance proven for all {n} {noun}s"
    return {"decision": decision, "reason": reason, "rule": rule,
            "conforming": [st["name"] for st in zone["pass"]], "undecided": [st["name"] for st in zone["undecided"]],
            "nonconforming": [st["name"] for st in zone["fail"]]}


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
        t = s.get("tolerance_mm", tol)
        if t is not None and bool(s["pass"]) != (abs(float(s["error_mm"])) <= t):
            problems.append(f"{at}: pass {s['pass']} disagrees with |error_mm| <= tolerance_mm ({t})")
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
    if "conformity" in report and tol_f is not None:
        figures = [e for v in (report.get("forms") or {}).values() for e in v]
        want_c = conformity([*report["steps"], *figures], tol_f, unmodelled=unmodelled_errors(report))["decision"]
        if report["conformity"].get("decision") != want_c:
            problems.append(f"conformity decision {report['conformity'].get('decision')!r} but the steps say {want_c!r}")
    if "baseline" in report:
        b = report["baseline"]
        problems += _check_steps(b["steps"], "baseline.steps", b.get("frames"), tol_f)
        names, bnames = [s["name"] for s in report["steps"]], [s["name"] for s in b["steps"]]
        if sorted(names) != sorted(bnames):
            problems.append(f"baseline steps {bnames} differ from the method's {names}")
    if problems:
        raise ReportError("report.json is inconsistent:\n" + "\n".join(f"  {p}" for p in problems))
