"""Metrology report: ``metrology/report.json`` (results contract 1) and ``report.html``.

``report.json``
    :func:`build_report_json` assembles the contract's keys (``session``, ``method``, ``frames``,
    ``steps[{name, nominal_mm, mean_mm, std_mm, error_mm, error_pct, pass, per_frame_mm}]`` and
    ``baseline{method: "three-step-phase-shift", steps}`` only when a baseline is given) from the
    per-method blocks of :func:`huefringe.metrology.evaluate_session`. Backward-compatible
    extensions (documented in ``schemas/report.schema.json``):

    - top level: ``tolerance_mm``, ``range_mm``, ``edge_exclusion``, ``min_coverage``,
      ``distance`` (``"vertical"``/``"normal"``), ``verdict`` (``"PASS"`` when every step of
      ``method`` is within the tolerance, U ignored; the baseline does not vote), ``conformity``
      (the ISO 14253-1 decision with U for the whole specimen, with its reason: :func:`conformity`,
      the report's headline), ``base`` (base ROIs, coverage, per-frame
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
    any browser. Rendered from the Jinja2 templates in ``huefringe/templates/`` (package data,
    autoescaped). Order: header (capture date, operator, instrument, simulated-data notice),
    the headline: the ISO 14253-1 decision (conforms, does not conform, undecided) with its
    reason, then the tolerance test without U, step-height table (baseline side by side,
    the ISO 14253-1 zone beside the contract's pass), uncertainty and conformance, measurement
    conditions (the method and the hue model in words), flatness/coverage with the evaluated
    boxes in pixels and mm, figures, provenance (collapsible).
"""

from __future__ import annotations

from ._contract import (  # noqa: F401
    BASELINE_METHOD,
    CONTRACT_TOP_KEYS,
    CONTRACT_STEP_KEYS,
    ReportError,
    load_schema,
    _plain,
    _ordered_steps,
    build_report_json,
    CONFORMITY_DECISIONS,
    conformity,
    unmodelled_errors,
    _close,
    _check_steps,
    validate_report,
)
from ._provenance import (  # noqa: F401
    software_versions,
    collect_provenance,
    run_summary,
)
from ._html import (  # noqa: F401
    FIGURE_ORDER,
    _PNG_MAGIC,
    per_frame_figure,
    METHOD_WORDS,
    HUE_MODEL_WORDS,
    _STEP_HEAD,
    _BUDGET_TERMS,
    _ZONE_CLASS,
    _num,
    _box,
    _is_flat,
    _tojson_pretty,
    _environment,
    _css,
    _verdict,
    _with_rep3,
    BoxMM,
    _mm_box,
    _flat_rows,
    _u_rows,
    _conditions,
    _figure_entry,
    _context,
    render_report_html,
    write_report_html,
)

__all__ = [
    "BASELINE_METHOD",
    "CONTRACT_STEP_KEYS",
    "CONFORMITY_DECISIONS",
    "CONTRACT_TOP_KEYS",
    "FIGURE_ORDER",
    "HUE_MODEL_WORDS",
    "METHOD_WORDS",
    "ReportError",
    "build_report_json",
    "collect_provenance",
    "conformity",
    "unmodelled_errors",
    "run_summary",
    "load_schema",
    "per_frame_figure",
    "render_report_html",
    "software_versions",
    "validate_report",
    "write_report_html",
]
