"""The HTML report: the per-frame figures and the Jinja templates' context and rendering."""

from __future__ import annotations

import base64
import functools
import importlib.metadata
import importlib.resources
import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from huefringe.io import atomic_path, write_figure_png
from ._contract import BASELINE_METHOD, _plain, conformity


#: Known figure keys of :func:`write_report_html`, in display order, with their captions.
FIGURE_ORDER: dict[str, str] = {
    "profile": "Cross-section profile across the steps along one image row, named in the figure (cf. paper Fig. 9 d)",
    "height": "Height map, mm above the reference plane",
    "render": "Rendered surface",
    "per_frame": "Per-frame step heights with nominal value and tolerance band",
    "calibration_qa": "Calibration quality assurance: hue along a row of the flat reference plate before and after "
                      "the multi-band hue calibration, and its error against the true code phase in mrad "
                      "(cf. paper Fig. 7 c, d)",
}

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------


def per_frame_figure(report: Mapping[str, Any], out_png: str | os.PathLike[str]) -> Path:
    """Scatter of the per-frame step heights, one panel per step, with nominal and tolerance band.

    With ``U_mm`` per step, the interval mean ± U is shaded and the panel's title gives the
    ISO 14253-1 zone beside the contract's pass; one legend for all panels sits below them.

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
        if s.get("U_mm") is not None:  # the ISO 14253-1 decision compares this interval with the band
            m, big_u = float(s["mean_mm"]), float(s["U_mm"])
            ax.axhspan(m - big_u, m + big_u, color="#1f4e9c", alpha=0.12, lw=0, label="mean ± U (k = 2)")
        if s["name"] in base:
            b = np.asarray(base[s["name"]]["per_frame_mm"], dtype=float)
            ax.plot(np.arange(b.size), b, "s", ms=4, mfc="none", color="#c25100", label=BASELINE_METHOD)
            ax.axhline(float(base[s["name"]]["mean_mm"]), color="#c25100", ls=":", lw=1.0, label="baseline mean")
        verdict = "pass" if s["pass"] else "FAIL"
        zone = f", ISO 14253-1 {s['conformance']}" if s.get("conformance") else ""
        ax.set_title(f"{s['name']}: nominal {nominal:g} mm ({verdict}{zone})", fontsize=10)
        ax.set_xlabel("frame")
        ax.set_ylabel("step height (mm)")
        ax.grid(True, alpha=0.3)
        ax.ticklabel_format(axis="y", useOffset=False)
    # one legend for all panels, below them: inside a panel it covers the tolerance band and data
    handles, labels = axes.ravel()[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(7, len(labels)), fontsize=8, frameon=False)
    fig.suptitle(f"Session {report.get('session', '')}: per-frame step heights", fontsize=11)
    return write_figure_png(fig, out_png)


# --------------------------------------------------------------------------------------------
# report.html (Jinja2 templates in huefringe/templates/, autoescaped)
# --------------------------------------------------------------------------------------------

#: What each method name means, in words (banner and measurement conditions).
METHOD_WORDS: dict[str, dict[str, str]] = {
    "trapezoidal-hsi": {
        "short": "trapezoidal HSI phase shifting",
        "long": "the paper's trapezoidal HSI phase shifting (Chen, Nguyen & Shu): one colour frame whose "
                "hue encodes the projected code phase, calibrated per pixel with multi-band hue tables",
    },
    "oneshot-trapezoid-triangulation": {
        "short": "one-shot trapezoid on a calibrated rig",
        "long": "oneshot-trapezoid via rig calibration: the paper's one-shot trapezoidal colour frame, its hue through "
                "the per-pixel hue table to the projector coordinate, the fringe order from the session's coded blocks, "
                "triangulated with the projector-camera rig calibration",
    },
    BASELINE_METHOD: {
        "short": "three-step phase shifting",
        "long": "traditional three-step phase shifting of grey sinusoidal fringes (three frames per height map)",
    },
}

#: Which RGB -> hue formula each ``hue_model`` is (huefringe.colour).
HUE_MODEL_WORDS: dict[str, str] = {
    "hexcone": "HSV hexcone hue (Smith), exactly linear in the code phase of the trapezoidal pattern",
    "hsi": "the paper's HSI hue, eqs. 1-2 (arccos form), nearly linear in the code phase "
           "(about 0.02 rad peak deviation, absorbed by the hue tables)",
}

_STEP_HEAD = ("Mean (mm)", "Std σ (mm)", "±3σ (mm)", "Error (mm)", "Error / nominal (%)", "Error / range (%)", "Pass")
_BUDGET_TERMS = ("noise", "table", "interpolation", "reference", "model")
_RIG_BUDGET_TERMS = ("points_mm", "calibration_mm")
_ZONE_CLASS = {"pass": "ok", "fail": "bad", "undecided": "undecided"}


def _num(x: Any, fmt: str) -> str:
    """``format(x, fmt)`` for a finite number, "—" for None/NaN/inf, ``str(x)`` for a non-number."""
    if x is None:
        return "—"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    if not math.isfinite(v):
        return "—"
    if fmt == "d":
        return str(int(round(v)))
    return format(v, fmt)


def _box(box: Sequence[Any] | None, fmt: str) -> str:
    """``[a, b, c, d)``: a half-open box, each number formatted with :func:`_num`."""
    if box is None:
        return "—"
    return "[" + ", ".join(_num(x, fmt) for x in box) + ")"


def _is_flat(v: Any) -> bool:
    return not isinstance(v, Mapping | list | tuple)


def _tojson_pretty(v: Any, sort_keys: bool) -> str:
    return json.dumps(v, indent=2, sort_keys=sort_keys, default=str, ensure_ascii=False)


@functools.cache
def _environment() -> Any:
    """The Jinja2 environment on the packaged templates: autoescape on, undefined names are errors."""
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("huefringe", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
    )
    env.filters.update(num=_num, box=_box, tojson_pretty=_tojson_pretty)
    env.tests["flat"] = _is_flat
    return env


def _css() -> Any:
    import markupsafe

    return markupsafe.Markup(importlib.resources.files("huefringe").joinpath("templates/report.css").read_text("utf-8"))


def _verdict(report: Mapping[str, Any]) -> str:
    v = report.get("verdict")
    if v in ("PASS", "FAIL"):
        return str(v)
    return "PASS" if report.get("steps") and all(s.get("pass") for s in report["steps"]) else "FAIL"


def _with_rep3(s: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(s)
    rep = s.get("repeatability_3sigma_mm")
    if rep is None and s.get("std_mm") is not None:
        rep = 3.0 * float(s["std_mm"])
    out["rep3"] = rep
    out.setdefault("error_pct_of_range", None)
    out.setdefault("conformance", None)
    return out


BoxMM = Callable[[Sequence[Any]], list[float]]
"""A pixel box ``[u0, v0, u1, v1)`` -> ``[X0, Y0, X1, Y1]`` in mm (a lens model's, e.g. from
:meth:`huefringe.camera.CameraModel.xy_at` at the plate)."""


def _mm_box(box: Sequence[Any] | None, pitch: float | BoxMM | None) -> list[float] | None:
    if box is None or pitch is None:
        return None
    if callable(pitch):
        return pitch(box)
    return [float(x) * pitch for x in box]


def _flat_rows(report: Mapping[str, Any], pitch: float | BoxMM | None) -> list[dict[str, Any]]:
    rows = []
    for s in report.get("steps", []):
        if "flatness" not in s and "coverage" not in s:
            continue
        f, c = s.get("flatness") or {}, s.get("coverage") or {}

        def scaled(d: Mapping[str, Any], key: str, k: float) -> float | None:
            return None if d.get(key) is None else k * float(d[key])

        box = s.get("evaluated_roi")
        rows.append({
            "name": s.get("name"),
            "Sa_um": scaled(f, "Sa_mm", 1000), "Sq_um": scaled(f, "Sq_mm", 1000), "Sz_um": scaled(f, "Sz_mm", 1000),
            "cov_roi": scaled(c, "roi", 100), "cov_eval": scaled(c, "evaluated", 100),
            "cov_min": scaled(c, "evaluated_min", 100),
            "box_px": box, "box_mm": _mm_box(box, pitch),
        })  # fmt: skip
    return rows


def _u_rows(report: Mapping[str, Any]) -> list[dict[str, Any]]:
    tol = report.get("tolerance_mm")
    rows = []
    for s in report.get("steps", []):
        if "u_mm" not in s:
            continue
        row = _with_rep3(s)
        row.setdefault("uncertainty_budget", {})
        row["abs_error"] = abs(float(s["error_mm"]))
        big_u = float(s["U_mm"])
        t = math.nan if tol is None else float(tol)
        row["pass_limit"], row["fail_limit"] = t - big_u, t + big_u
        rows.append(row)
    return rows


def _conditions(report: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Label/value(/note/strong) items of the measurement conditions; values are plain text."""
    items: list[dict[str, Any]] = []

    def add(label: str, value: str, note: str = "", strong: str = "") -> None:
        items.append({"label": label, "value": value, "note": note, "strong": strong})

    method = str(report.get("method", ""))
    hue_model = report.get("hue_model")
    if method:
        words = METHOD_WORDS.get(method, {}).get("long", "")
        add("Method", f"{method}: {words}" if words else method,
            "The method names the phase-shifting technique; the hue model below is the RGB → hue formula it "
            "uses to read the code phase from each colour pixel." if hue_model else "")
    if hue_model is not None:
        add("Hue model", f"{hue_model}: {HUE_MODEL_WORDS.get(str(hue_model), 'RGB → hue formula')}",
            "Options: hexcone (default) or hsi (config key hue_model); both feed the same trapezoidal HSI "
            "method and its per-pixel hue tables.")
    if "tolerance_mm" in report:
        add("Tolerance", f"±{_num(report['tolerance_mm'], 'g')} mm on the mean step height")
    if "range_mm" in report:
        add("Measuring range", f"{_num(report['range_mm'], 'g')} mm (denominator of “error % range”)")
    if "edge_exclusion" in report:
        e = float(report["edge_exclusion"])
        add("Edge exclusion", f"{_num(100 * e, '.1f')} % of each top-box side at each edge "
                              f"(central {_num(100 * (1 - 2 * e), '.1f')} % evaluated)")
    if "distance" in report:
        add("Distance to base plane", str(report["distance"]))
    if "min_coverage" in report:
        add("Minimum coverage", f"{_num(100 * float(report['min_coverage']), '.0f')} % valid pixels per evaluated box")
    base = report.get("base")
    if isinstance(base, Mapping) and "residual_rms_mm" in base:
        add("Base plane fit residual (rms)",
            f"{_num(1000 * float(base['residual_rms_mm']), '.2f')} µm mean, "
            f"{_num(1000 * float(base.get('residual_rms_mm_max', math.nan)), '.2f')} µm worst frame")
    if "unwrap" in report:
        add("Phase unwrapping", str(report["unwrap"]))
    cal = report.get("calibration") or {}
    if cal.get("unambiguous_range_mm"):
        lo, hi = cal["unambiguous_range_mm"]
        add("Unambiguous depth", f"{_num(lo, '.2f')} to {_num(hi, '.2f')} mm")
    banding = cal.get("row_banding") or {}
    if banding.get("suspected"):
        mm = banding.get("amplitude_mm")
        add("Row banding", "", strong=f"{_num(float(banding['amplitude_rad']), '.3f')} rad RMS"
            + ("" if mm is None else f" (about {_num(1000 * float(mm), '.1f')} µm)"),
            note="(the calibration planes' phase repeats along the rows: a colour-sequential projector and an "
                 "exposure that is not a whole number of its colour cycles? Not in u; see the capture guide)")
    flicker = cal.get("colour_flicker") or {}
    if flicker.get("suspected"):
        add("Colour flicker", "", strong=f"{_num(float(flicker['amplitude_rad']), '.4f')} rad between repeats",
            note="(a uniform hue band's hue changes from image to image: a colour-sequential projector and an "
                 "exposure that is not a whole number of its colour cycles, flickering light or auto white balance? "
                 "Not in u; see the capture guide)")
    fq = report.get("frame_qa") or {}
    if "phase_ambiguity_suspected" in fq:
        bad = fq["phase_ambiguity_suspected"]
        if bad:
            add("Phase ambiguity", "", strong=f"suspected in frames {', '.join(str(n) for n in bad)}",
                note="(a step may exceed the unambiguous depth)")
        else:
            add("Phase ambiguity", "none suspected")
    return items


def _figure_entry(key: str, path: str | os.PathLike[str]) -> dict[str, str]:
    data = Path(path).read_bytes()
    if not data.startswith(_PNG_MAGIC):
        raise ValueError(f"figure {key!r}: {path} is not a PNG file")
    uri = "data:image/png;base64," + base64.b64encode(data).decode("ascii")
    return {"key": key, "uri": uri, "caption": FIGURE_ORDER.get(key, key.replace("_", " "))}


def _context(report: Mapping[str, Any], figures: Mapping[str, str | os.PathLike[str]],
             provenance: Mapping[str, Any], pixel_pitch_mm: float | None, box_mm: BoxMM | None = None) -> dict[str, Any]:
    """Everything the templates show, derived from the report (numbers formatted in the templates)."""
    report = _plain(report)
    provenance = _plain(dict(provenance))
    steps = [_with_rep3(s) for s in report.get("steps", [])]
    baseline = report.get("baseline")
    bsteps = {s["name"]: _with_rep3(s) for s in baseline["steps"]} if baseline else {}
    keys = [k for k in FIGURE_ORDER if k in figures] + [k for k in figures if k not in FIGURE_ORDER]
    u_steps = _u_rows(report)
    decision = None
    if u_steps:
        zones = [s["conformance"] for s in u_steps]
        word = report.get("verdict_with_uncertainty") or (
            "FAIL" if "fail" in zones else "UNDECIDED" if "undecided" in zones else "PASS")
        decision = {"word": word, "counts": [(z, zones.count(z)) for z in ("pass", "undecided", "fail") if z in zones]}
    pitch = None if pixel_pitch_mm is None else float(pixel_pitch_mm)
    base = report.get("base") if isinstance(report.get("base"), Mapping) else {}
    tol = report.get("tolerance_mm")
    headline = report.get("conformity") or (conformity(report.get("steps", []), float(tol)) if tol is not None else None)
    return {
        "report": report,
        "css": _css(),
        "verdict": _verdict(report),
        "headline": headline,
        "steps": steps,
        "npass": sum(1 for s in steps if s.get("pass")),
        "failing": [s for s in steps if not s.get("pass")],
        "baseline_steps": bsteps,
        "baseline_pass": sum(1 for s in bsteps.values() if s.get("pass")) if bsteps else None,
        "method_words": METHOD_WORDS.get(str(report.get("method", ""))),
        "hue_model": report.get("hue_model"),
        "decision": decision,
        "has_u": bool(u_steps),
        "u_steps": u_steps,
        "u_validation": (report.get("accuracy") or {}).get("trapezoidal-hsi", {}).get("uncertainty"),
        "step_head": _STEP_HEAD,
        "budget_terms": _RIG_BUDGET_TERMS if report.get("geometry") else _BUDGET_TERMS,
        "rig": bool(report.get("geometry")),
        "zone_class": _ZONE_CLASS,
        "conditions": _conditions(report),
        "flat_steps": _flat_rows(report, box_mm if box_mm is not None and pitch is not None else pitch),
        "pitch": pitch,
        "base_rois": [{"px": r, "mm": _mm_box(r, box_mm if box_mm is not None and pitch is not None else pitch)}
                      for r in base.get("rois", [])],
        "figures": [_figure_entry(k, figures[k]) for k in keys],
        "capture": {k: None for k in ("captured_at", "operator", "instrument", "simulated", "notes")}
                   | dict(provenance.get("capture") or {}),
        "provenance": provenance,
    }  # fmt: skip


def render_report_html(
    report: Mapping[str, Any],
    figures: Mapping[str, str | os.PathLike[str]] | None = None,
    provenance: Mapping[str, Any] | None = None,
    *,
    pixel_pitch_mm: float | None = None,
    box_mm: BoxMM | None = None,
) -> str:
    """The HTML text of :func:`write_report_html` (pure: reads only the figure files).

    The page comes from the Jinja2 templates ``huefringe/templates/report.html.j2`` and
    ``partials/*.html.j2`` (package data) with autoescaping on: every value of the report and
    the provenance is escaped.

    Parameters
    ----------
    report : mapping
        A report from :func:`build_report_json`.
    figures : mapping of str to path, optional
        PNG files by key; known keys (:data:`FIGURE_ORDER`: ``profile``, ``height``, ``render``,
        ``per_frame``, ``calibration_qa``) come first in that order, other keys after them in
        the given order, captioned with their key.
    provenance : mapping, optional
        Shown in the collapsible provenance section (e.g. from :func:`collect_provenance`); its
        ``capture`` entry (session.yaml ``provenance``) in the header.
    pixel_pitch_mm : float, optional
        The session's pixel pitch: the evaluated boxes are also shown in mm (``X = u * pitch``).
    box_mm : callable, optional
        With ``pixel_pitch_mm``: a lens model's box in mm instead of ``u * pitch`` (the session's
        ``camera`` block, docs/design.md).

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
    ctx = _context(report, dict(figures or {}), provenance or {}, pixel_pitch_mm, box_mm)
    text: str = _environment().get_template("report.html.j2").render(ctx)
    return text


def write_report_html(
    path: str | os.PathLike[str],
    report: Mapping[str, Any],
    figures: Mapping[str, str | os.PathLike[str]] | None,
    provenance: Mapping[str, Any] | None,
    *,
    pixel_pitch_mm: float | None = None,
    box_mm: BoxMM | None = None,
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
    pixel_pitch_mm : float, optional
        The session's pixel pitch, to show the evaluated boxes in mm as well as in pixels.
    box_mm : callable, optional
        A lens model's box in mm (:func:`render_report_html`).

    Returns
    -------
    Path
        ``path``.
    """
    text = render_report_html(report, figures, provenance, pixel_pitch_mm=pixel_pitch_mm, box_mm=box_mm)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
