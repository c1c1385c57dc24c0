"""What produced a report: software versions, provenance record, and the run summary."""

from __future__ import annotations

import importlib.metadata
import importlib.resources
import json
import os
import platform
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from huefringe.io import sha256_file
from ._contract import _plain, conformity


# --------------------------------------------------------------------------------------------
# provenance helpers
# --------------------------------------------------------------------------------------------


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


def run_summary(reports: Mapping[str, str | os.PathLike[str] | None]) -> str:
    """What the end of a workflow run prints: each session's decision and where its report is.

    Parameters
    ----------
    reports : mapping of str to path or None
        Session id to its ``metrology/report.json`` (None or a missing file: no specimen, or not
        made by this run).

    Returns
    -------
    str
        One block per session: ``<id>: CONFORMS|DOES NOT CONFORM|UNDECIDED (ISO 14253-1) - <reason>``
        and the path of ``report.html``, or the results folder when there is no report.
    """
    lines = []
    for sid, path in reports.items():
        p = None if path is None else Path(path)
        if p is None or not p.is_file():
            where = p.parent.parent if p is not None else None
            lines.append(f"  {sid}: no step-height report (the session has no specimen"
                         f"{'' if p is None else ', or this run did not make it'})"
                         + (f"; results in {where}/" if where is not None else ""))
            continue
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
            c = doc.get("conformity") or conformity(doc["steps"], float(doc["tolerance_mm"]))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            lines.append(f"  {sid}: cannot read {p} ({exc})")
            continue
        lines.append(f"  {sid}: {c['decision'].upper()} (ISO 14253-1) - {c['reason']}")
        lines.append(f"      report: {p.with_suffix('.html')}")
    return "\n".join(lines)
