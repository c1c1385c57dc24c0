"""The surface and metrology stages (``workflow/rules/surfaces.smk``, ``metrology.smk``): meshes, renders, the metrology report, Table 1."""

from __future__ import annotations

import json as jsonlib
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from huefringe import uncertainty
from huefringe.height import PlaneCalibration, accuracy
from huefringe.huetable import HueTable
from huefringe.io import read_tiff, write_json
from huefringe.mesh import attach_sigma, clean_mesh, decimate, export_mesh, height_to_mesh, place_vertices, stats_path
from huefringe.metrology import MetrologyError, evaluate_session
from huefringe.pipeline import session_corrections
from huefringe.render import camera_for_field, height_map_figure, profile_figure, render_views, uncertainty_map_figure, wrapped_phase_figure
from huefringe.report import build_report_json, collect_provenance, per_frame_figure, write_report_html
from huefringe.session import Session, load_session
from huefringe.table1 import table1_rows, write_table1
from ._archive import add_step_uncertainty

log = logging.getLogger("huefringe")


# ------------------------------------------------ workflow/rules/surfaces.smk


def _height_limits(s: Session) -> tuple[float, float]:
    """Colour limits shared by every frame of a session: the calibrated depth range."""
    return (min(0.0, min(s.planes_mm)), max(s.planes_mm))


def mesh(session: str, height: str, mesh: Mapping[str, Any], ply: str, stl: str, stats: str,
         uncertainty: str | None = None, camera_json: str = "") -> None:
    """Triangle mesh of one height map (no bridging of jumps), cleaned, exported as PLY + STL; the
    PLY's vertices carry ``sigma_mm`` from the uncertainty map (:func:`huefringe.mesh.attach_sigma`)."""
    s = load_session(session)
    model, reader = session_corrections(s, camera_json)
    h = read_tiff(height)
    m = height_to_mesh(h, s.pixel_pitch_mm, colours=reader.rgb(s.object_white))
    m = clean_mesh(m, min_island_faces=mesh["min_island_faces"])
    if mesh["decimate_faces"]:
        m = decimate(m, mesh["decimate_faces"])
    if uncertainty is not None:
        attach_sigma(m, read_tiff(uncertainty), s.pixel_pitch_mm)
    if not model.plain:  # last: the steps above find pixels from u * pitch
        place_vertices(m, model.xy_at, s.pixel_pitch_mm)
    export_mesh(m, ply, stl)
    if stats_path(ply) != Path(stats):
        raise RuntimeError(f"mesh statistics went to {stats_path(ply)}, the workflow expects {stats}")


def render(session: str, mesh: str, height: str, phase: str, render: Mapping[str, Any], frame: str,
           top: str, oblique1: str, oblique2: str, height_map: str, phase_map: str,
           uncertainty: str = "", uncertainty_map: str = "", camera_json: str = "") -> None:
    """Off-screen renders (top and two oblique views) and the height and phase figures of one frame
    (and, given the frame's ``uncertainty`` TIFF, the uncertainty figure beside the height's)."""
    s = load_session(session)
    size = (int(render["width"]), int(render["height"]))
    clim = _height_limits(s)
    model = session_corrections(s, camera_json)[0]
    if model.plain:
        cams = camera_for_field((s.width - 1) * s.pixel_pitch_mm, (s.height - 1) * s.pixel_pitch_mm, clim,
                                          size=size)
    else:  # the lens model's field on the plate (the mesh's vertices are in its X, Y)
        x0, x1, y0, y1 = model.field_mm()
        cams = camera_for_field(x1 - x0, y1 - y0, clim, origin=(x0, y0), size=size)
    m = trimesh.load(mesh, process=False, force="mesh")
    out_dir = Path(top).parent
    written = render_views(m, out_dir, f"frame_{frame}", clim=clim, camera=cams, size=size,
                                     title=f"{s.id} frame {frame}")
    expected = {Path(top), Path(oblique1), Path(oblique2)}
    if not expected <= set(written):
        raise RuntimeError(f"render wrote {written}, expected {sorted(map(str, expected))}")
    height_map_figure(read_tiff(height), s.pixel_pitch_mm, height_map, clim=clim,
                                title=f"{s.id} frame {frame}: height (mm)")
    wrapped_phase_figure(read_tiff(phase), phase_map, pitch_mm=s.pixel_pitch_mm,
                                   title=f"{s.id} frame {frame}: corrected code phase")
    if uncertainty and uncertainty_map:
        uncertainty_map_figure(read_tiff(uncertainty), s.pixel_pitch_mm, uncertainty_map,
                                         title=f"{s.id} frame {frame}: height uncertainty u")


# ----------------------------------------------- workflow/rules/metrology.smk


def metrology(session: str, heights: Sequence[str], qa: Sequence[str], baseline: Sequence[str], planes: str, tables: str,
                     cross_section: str, render: str, height_map: str, accuracy: Sequence[str],
                     config: Mapping[str, Any], json: str, html: str, profile: str, per_frame: str,
                     uncertainties: Sequence[str] = (), model: str = "", object_table: str = "",
                     supports: Sequence[str] = (), threads: int = 1, camera_json: str = "") -> None:
    """Step-height metrology of every frame: report.json (results contract) and report.html.

    With ``uncertainties`` (one map per height map), the phase-to-height ``model`` and the
    ``object_table``, each step also gets ``u_mm``, ``U_mm``, its ISO 14253-1 ``conformance``
    and its ``uncertainty_budget`` (:func:`add_step_uncertainty`); ``supports`` (the filter's
    support maps, one per frame) give the budget each pixel's actual support (without them:
    the fixed window's). ``threads``: frames whose step budgets are computed at once.
    """
    s = load_session(session)
    spec = s.specimen
    if spec is None:
        raise ValueError(f"{s.root / 'session.yaml'}: no specimen block, nothing to evaluate")
    range_mm = max(s.planes_mm) - min(s.planes_mm)
    edge = float(config["metrology"]["edge_exclusion"])
    lens = session_corrections(s, camera_json)[0]

    def evaluate(paths: Sequence[str], **kw: Any) -> dict[str, Any]:
        try:
            # a generator: one height map in memory at a time (1000 frames held at once were
            # 1.2 GB, twice over with the profile's list: 2.5 GB peak)
            return evaluate_session((read_tiff(p) for p in paths), spec, s.pixel_pitch_mm,
                                              range_mm=range_mm, edge_exclusion=edge, camera=lens, **kw)
        except MetrologyError as exc:
            where = paths[exc.frame] if exc.frame is not None and exc.frame < len(paths) else s.root / "session.yaml"
            raise MetrologyError(f"{where}: {exc} (specimen in {s.root / 'session.yaml'})") from exc

    method = evaluate(heights)
    if uncertainties:
        add_step_uncertainty(method, _TiffMaps(heights), _TiffMaps(uncertainties), spec, s.pixel_pitch_mm,
                             PlaneCalibration.load(model), HueTable.load(object_table), edge_exclusion=edge,
                             denoise_radius=int(config["measurement"]["denoise_radius"]),
                             supports=_TiffMaps(supports) if supports else None, workers=threads, camera=lens,
                             lateral_px=float(config["measurement"]["lateral_uncertainty_px"]),
                             lateral_step_px=float(config["measurement"]["lateral_step_px"]))
    base = evaluate(baseline, method="three-step-phase-shift") if baseline else None
    plane_stats = jsonlib.loads(Path(planes).read_text())
    table_stats = jsonlib.loads(Path(tables).read_text())
    provenance = collect_provenance(s.id, dict(config), s.input_files(), root=s.root)
    provenance["capture"] = s.provenance  # session.yaml provenance: report header, simulated notice
    extras: dict[str, Any] = {
        "hue_model": config["hue_model"],
        "unwrap": config["measurement"]["unwrap"],
        "calibration": {
            "plane_fit_residual_rms_mm": plane_stats.get("fit_residual_rms_mm"),
            "unambiguous_range_mm": plane_stats.get("unambiguous_range_mm"),
            "object_table_valid_fraction": table_stats.get("valid_fraction"),
        },
    }
    banding = plane_stats.get("row_banding")
    if banding is not None:  # the planes' row banding (huefringe.row_banding), without the per-plane records
        extras["calibration"]["row_banding"] = {k: v for k, v in banding.items() if k != "planes"}
        if banding.get("suspected"):
            log.warning("%s: the calibration planes' phase bands along the rows (%.3f rad RMS, about %s mm): the "
                        "heights carry a row-periodic error that their u does not hold (docs/capture.md, "
                        "'Colour-sequential projectors')", s.id, banding["amplitude_rad"],
                        "?" if banding.get("amplitude_mm") is None else f"{banding['amplitude_mm']:.4f}")
    flicker = plane_stats.get("colour_flicker")
    if flicker is not None:  # the reference bands' hue between repeats (huefringe.row_banding)
        extras["calibration"]["colour_flicker"] = dict(flicker)
        if flicker.get("suspected"):
            log.warning("%s: the repeats of a uniform hue band differ in hue by %.4f rad: each image has its own "
                        "colour balance, an error the heights' u does not hold (docs/capture.md, "
                        "'Colour-sequential projectors')", s.id, flicker["amplitude_rad"])
    if accuracy:
        extras["accuracy"] = jsonlib.loads(Path(accuracy[0]).read_text())
    frame_qa = [jsonlib.loads(Path(p).read_text()) for p in qa]
    extras["frame_qa"] = {
        "phase_ambiguity_suspected": [q["frame"] for q in frame_qa if q["phase_ambiguity_suspected"]],
        "valid_fraction_min": min(q["valid_fraction"] for q in frame_qa),
        "clipped_fraction_max": max(q["clipped_fraction"] for q in frame_qa),
    }
    if extras["frame_qa"]["phase_ambiguity_suspected"]:
        log.warning("frames %s: phase ambiguity suspected (a step may be too tall for the fringe period)",
                    extras["frame_qa"]["phase_ambiguity_suspected"])
    doc = build_report_json(s.id, spec, method, base, extras=extras)
    # a profile through the middle of the steps' ROIs (paper Fig. 9 d)
    rows = [(st["roi"][1] + st["roi"][3]) // 2 for st in spec["steps"]]
    profile_figure(read_tiff(heights[0]), int(np.median(rows)), s.pixel_pitch_mm, profile,
                             title=f"{s.id} frame {s.frame_ids[0]:04d}: cross-section")
    per_frame_figure(doc, per_frame)
    figures = {"profile": Path(profile), "height": Path(height_map), "render": Path(render),
               "per_frame": Path(per_frame), "calibration_qa": Path(cross_section)}
    write_json(json, doc)
    write_report_html(html, doc, figures, provenance, pixel_pitch_mm=s.pixel_pitch_mm,
                             box_mm=None if lens.plain else lens.box_mm)


class _TiffMaps(Sequence):
    """TIFF maps as a sequence that reads each one when it is taken (one map in memory at a time
    while it is iterated: 1000 frames held at once are 1.2 GB per kind)."""

    def __init__(self, paths: Sequence[str]):
        self.paths = list(paths)

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, i):  # type: ignore[override]
        if isinstance(i, slice):
            return _TiffMaps(self.paths[i])
        return read_tiff(self.paths[i])


def table1(reports: Sequence[str], periods: Sequence[float], step: str, nominal_mm: float,
           markdown: str, csv: str, figure: str, uncertainty_ratio: str = "") -> None:
    """The paper's Table 1 from the metrology reports of a period sweep, beside the published values.

    ``uncertainty_ratio`` (JSON): per period, the step's observed std over the frames against the
    predicted independent part of one frame's u (``uncertainty_budget.independent_per_frame_mm``).
    """
    results = {}
    for period, path in zip(periods, reports, strict=True):
        doc = jsonlib.loads(Path(path).read_text())
        results[int(period)] = {"method": {"steps": doc["steps"]}}
        if doc.get("baseline"):
            results[int(period)]["baseline"] = doc["baseline"]
    rows = table1_rows(results, step_name=step, nominal=nominal_mm)
    write_table1(rows, markdown, csv, figure)
    if uncertainty_ratio:
        ratios = {}
        for period, res in results.items():
            st = next((x for x in res["method"]["steps"] if x["name"] == step), None)
            bud = (st or {}).get("uncertainty_budget")
            if st is None or bud is None or st.get("std_mm") is None:
                continue
            ind = float(bud["independent_per_frame_mm"])
            ratios[str(period)] = {"frames": len(st["per_frame_mm"]), "std_mm": st["std_mm"],
                                   "independent_per_frame_mm": ind, "ratio": st["std_mm"] / ind if ind > 0 else None,
                                   "u_mm": st.get("u_mm"), "error_mm": st["error_mm"]}
            log.info("period %s px: std %.4f mm, predicted independent u %.4f mm, ratio %.2f (target 0.7-1.4)",
                     period, st["std_mm"], ind, ratios[str(period)]["ratio"] or float("nan"))
        write_json(uncertainty_ratio, {"step": step, "target": [0.7, 1.4], "periods": ratios})
