"""The rig route's metrology: a structured-light session's features measured on its triangulated
X, Y, Z, each figure with U (k = 2) and the ISO 14253-1 decision, into the same report as capture
sessions (:func:`huefringe.report.build_report_json`, :func:`huefringe.report.write_report_html`).

Every figure's standard uncertainty combines two terms:

- **points**: the decoded coordinates' noise propagated through the triangulation to each point
  (along its camera ray) and through the fit (:mod:`huefringe.metrology`'s ``*_u`` functions);
- **calibration**: the leave-one-pose-out (jackknife) standard error of the figure recomputed
  with the rig calibrated again without each board pose in turn, as the standard deviation of
  the t-distribution with ``n - 1`` degrees of freedom it scales, so that ``U = 2u`` stays a 95 %
  interval with few poses (:func:`huefringe.metrology.jackknife_u` with ``t_scaled``). A session measured with a calibration file that
  comes without its poses has no such term; the report says so for every figure.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe.metrology import combine_u, fit_plane_u, fit_sphere_u, flatness_u, jackknife_u, plane_pair_u, sigma_along, step_height_u
from huefringe.report import build_report_json, collect_provenance, write_report_html
from huefringe.rig.measure import RigError, RigFrame, read_jackknife
from huefringe.rig.model import RigCalibration
from huefringe.rig.oneshot import ONESHOT_GEOMETRY
from huefringe.rig.triangulation import triangulate
from huefringe.uncertainty import conformance

__all__ = ["METHOD", "ONESHOT_METHOD", "base_plane", "feature_values", "noise_scale", "rig_report", "xyz_accuracy"]

F64 = NDArray[np.float64]
METHOD = "coded-light-triangulation"
ONESHOT_METHOD = "oneshot-trapezoid-triangulation"
"""The report's ``method`` of a one-shot frame triangulated with the rig calibration."""
NOISE_MODEL_REL_U = 0.02
"""Least relative standard uncertainty of the noise removed from a form figure (FLTq, a sphere's
form): on the bench rigs the residuals' variance on flat faces exceeds the neighbour-difference
noise by up to 4 % (2 % in sigma), noise correlated over a few pixels."""
_JACKKNIFED = ("height_mm", "rms_form_mm", "distance_mm", "parallelism_mm", "radius_mm")
"""The figures recomputed with each leave-one-pose-out calibration (the calibration term)."""


def base_plane(frame: RigFrame, features: Any) -> Any:
    """The datum plane: fitted to the valid points of the features' ``base`` region, else to every valid point."""
    mask = frame.valid
    if features is not None and features.base is not None:
        mask = mask & features.base.mask(frame.valid.shape)
        if mask.sum() < 3:
            raise RigError(f"{features.path}: base: {int(mask.sum())} valid points in the region; a plane needs 3")
    return fit_plane_u(frame.xyz[mask], frame.sigma[mask])


def _points(xyz: F64, sigma: F64, mask: NDArray[np.bool_]) -> tuple[F64, F64]:
    """The region's points with finite coordinates (``mask`` already holds only valid pixels)."""
    return xyz[mask], sigma[mask]


def noise_scale(xyz: F64, sigma: F64, mask: NDArray[np.bool_], centre: F64, normal: F64 | None = None) -> tuple[float, float]:
    """The decoded noise's scale on a region, from the data: neighbouring pixels' residuals differ by
    the noise alone where the surface is smooth at the pixel scale.

    The residuals are the distances from a plane (``centre``, ``normal``) or, without ``normal``,
    from a sphere's centre (the radial distances, whose mean the difference removes). Over every
    pair of 4-neighbours in ``mask``, ``k^2 = sum (r_i - r_j)^2 / sum (s_i^2 + s_j^2)`` with ``s`` the
    predicted noise along the residual's direction.

    Returns
    -------
    k : float
        The factor the predicted noise is to be scaled by on this region.
    rel_u : float
        Relative standard uncertainty of the noise on the region: the statistical ``sqrt(2 / n) / 2``
        for ``n`` / 2 independent pairs (each pixel serves in up to four), and never below
        :data:`NOISE_MODEL_REL_U` (neighbour differences do not see noise correlated over a few
        pixels, which the residuals' variance holds).
    """
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        return 1.0, 0.5
    box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    xyz, sigma, mask = xyz[box], sigma[box], mask[box]
    ok = mask & np.isfinite(xyz).all(axis=-1) & np.isfinite(sigma).all(axis=-1)
    if normal is not None:
        r = (xyz - centre) @ normal
        direction = normal
    else:
        off = xyz - centre
        r = np.linalg.norm(off, axis=-1)
        direction = off / r[..., None]
    s2 = sigma_along(xyz, sigma, direction) ** 2
    num = den = 0.0
    n = 0
    for sl_a, sl_b in (((slice(None), slice(1, None)), (slice(None), slice(None, -1))),
                       ((slice(1, None), slice(None)), (slice(None, -1), slice(None)))):
        both = ok[sl_a] & ok[sl_b]
        num += float(np.sum((r[sl_a] - r[sl_b])[both] ** 2))
        den += float(np.sum((s2[sl_a] + s2[sl_b])[both]))
        n += int(both.sum())
    if n < 10 or den <= 0:
        return 1.0, 0.5
    return float(np.sqrt(num / den)), max(NOISE_MODEL_REL_U, float(np.sqrt(2.0 / (n / 2.0)) / 2.0))


def feature_values(xyz: F64, sigma: F64, features: Any) -> dict[str, dict[str, Any]]:
    """Every figure of ``features`` on one triangulated frame: name -> the fit's result (the form
    figures with the region's noise scaled to what the data show, :func:`noise_scale`)."""
    shape = xyz.shape[:2]
    finite = np.isfinite(xyz).all(axis=-1) & np.isfinite(sigma).all(axis=-1)
    masks = {name: r.mask(shape) & finite for name, r in features.regions().items()}
    out: dict[str, dict[str, Any]] = {}
    base: Any = None
    for f in features.features:
        try:
            if f.kind == "step":
                if base is None:
                    base = fit_plane_u(*_points(xyz, sigma, masks["base"]))
                out[f.name] = step_height_u(*_points(xyz, sigma, masks["base"]), *_points(xyz, sigma, masks[f.name]), base=base)
            elif f.kind == "plane":
                p, sg = _points(xyz, sigma, masks[f.name])
                pl = fit_plane_u(p, sg)
                k, rel = noise_scale(xyz, sigma, masks[f.name], pl.centroid, pl.normal)
                out[f.name] = {**flatness_u(p, k * sg, noise_rel_u=rel), "noise_scale": k, "noise_scale_rel_u": rel}
            elif f.kind == "distance":
                b, a = f.planes or ("", "")
                out[f.name] = plane_pair_u(*_points(xyz, sigma, masks[a]), *_points(xyz, sigma, masks[b]))
            elif f.kind == "sphere":
                p, sg = _points(xyz, sigma, masks[f.name])
                first = fit_sphere_u(p, sg)
                k, rel = noise_scale(xyz, sigma, masks[f.name], np.asarray(first["centre_mm"]))
                out[f.name] = {**fit_sphere_u(p, k * sg, noise_rel_u=rel), "noise_scale": k, "noise_scale_rel_u": rel}
        except ValueError as exc:
            raise RigError(f"{features.path}: {f.name}: {exc}") from None
    return out


def _retriangulate(calib: RigCalibration, decoded: F64, mode: str, mask: NDArray[np.bool_]) -> tuple[F64, F64]:
    """X, Y, Z (H, W, 3; NaN outside ``mask``) of the decoded maps (u, v, sigma_u, sigma_v) with ``calib``."""
    rows, cols = np.nonzero(mask)
    dec = decoded[rows, cols].astype(np.float64)
    use = {"u": mode in ("u", "both"), "v": mode in ("v", "both")}
    t = triangulate(calib, dec[:, 0] if use["u"] else None, dec[:, 1] if use["v"] else None,
                    sigma_u=dec[:, 2] if use["u"] else None, sigma_v=dec[:, 3] if use["v"] else None,
                    pixels=np.column_stack([cols, rows]).astype(np.float64), mode=mode)  # type: ignore[arg-type]
    xyz = np.full((*mask.shape, 3), np.nan)
    sig = np.full((*mask.shape, 3), np.nan)
    xyz[rows, cols], sig[rows, cols] = t.xyz, t.sigma
    return xyz, sig


def _entry(name: str, value: float, nominal: float, tol: float, u_points: float, u_cal: float | None,
           extra: Mapping[str, Any], u_floor: float | None = None) -> dict[str, Any]:
    u = combine_u(u_points, u_cal or 0.0, u_floor or 0.0)
    err = value - nominal
    return {
        "name": name, "nominal_mm": nominal, "mean_mm": value, "std_mm": None, "error_mm": err,
        "error_pct": 100.0 * err / nominal if nominal else None, "pass": abs(err) <= tol, "per_frame_mm": [value],
        "u_mm": u, "U_mm": 2.0 * u, "tolerance_mm": tol, "conformance": conformance(err, tol, 2.0 * u),
        "uncertainty_budget": {"points_mm": u_points,
                               "calibration_mm": u_cal if u_cal is not None else "not available: the calibration file "
                                                                                   "comes without its board poses",
                               **({} if u_floor is None else {"form_floor_mm": u_floor})},
        **extra,
    }


def rig_report(session: Any, config: Mapping[str, Any], *, calibration: str | os.PathLike[str], xyz: F64, sigma: F64,
               decoded: F64, jackknife: str | os.PathLike[str] = "", calibration_report: str | os.PathLike[str] = "",
               json_path: str | os.PathLike[str], html_path: str | os.PathLike[str],
               figures: Mapping[str, str | os.PathLike[str]] | None = None, oneshot: bool = False) -> dict[str, Any]:
    """Measure a structured-light session's features and write ``report.json`` and ``report.html``.

    Parameters
    ----------
    session : SLSession
        With ``features`` (``features.yaml``).
    config : mapping
        The run's configuration (``rig.triangulation``; recorded in the provenance).
    calibration : path
        The calibration the frame was triangulated with.
    xyz, sigma : ndarray, shape (H, W, 3)
        The triangulated frame and its per-point standard uncertainties (NaN where not valid).
    decoded : ndarray, shape (H, W, 4)
        Decoded ``u, v, sigma_u, sigma_v`` (NaN where not decoded): re-triangulated with each
        leave-one-pose-out calibration of ``jackknife`` for the calibration term.
    jackknife, calibration_report : path, optional
        :func:`huefringe.rig.measure.write_rig_calibration`'s files, when the workflow calibrated the rig.
    json_path, html_path : path
        Where the report goes.
    figures : mapping of str to path, optional
        PNG figures for the page.
    oneshot : bool
        The frame is a one-shot trapezoid frame (:func:`huefringe.rig.oneshot.measure_oneshot_session`):
        ``method`` :data:`ONESHOT_METHOD`, and the geometry
        (:data:`huefringe.rig.oneshot.ONESHOT_GEOMETRY`) in ``geometry`` and ``provenance``.

    Returns
    -------
    dict
        The report (validated by :func:`huefringe.report.build_report_json`).
    """
    feats = session.features
    if feats is None:
        raise RigError(f"{session.root}: no features.yaml: nothing to report")
    valid = np.isfinite(xyz).all(axis=-1)
    values = feature_values(xyz, sigma, feats)
    loo = read_jackknife(jackknife) if jackknife else []
    mode = _mode(decoded, config)
    jack: dict[tuple[str, str], list[float]] = {}
    if loo:
        need = np.zeros(valid.shape, dtype=bool)
        for r in feats.regions().values():
            need |= r.mask(valid.shape)
        need &= valid
        for _, c in loo:
            xj, sj = _retriangulate(c, decoded, mode, need)
            for n, v in feature_values(xj, sj, feats).items():
                for key in _JACKKNIFED:
                    if key in v:
                        jack.setdefault((n, key), []).append(float(v[key]))
                for i, t in enumerate(v.get("tilt", [])):
                    jack.setdefault((n, f"tilt{i}"), []).append(float(t))

    cal_doc = json.loads(Path(calibration_report).read_text(encoding="utf-8")) if calibration_report else {}
    floor = (cal_doc.get("form_floor") or {}).get("rms_form_mm")  # the calibration boards' flatness

    def u_cal(name: str, key: str) -> float | None:
        return jackknife_u(jack[(name, key)], t_scaled=True) if loo else None

    steps, forms = [], {"flatness": [], "distances": [], "parallelism": [], "spheres": []}
    for f in feats.features:
        v = values[f.name]
        if f.kind == "step":
            steps.append(_entry(f.name, v["height_mm"], f.nominal_mm, f.tolerance_mm, v["u_mm"], u_cal(f.name, "height_mm"),
                                {"points": {"base": v["n_base"], "top": v["n_top"]}}))
        elif f.kind == "plane":
            forms["flatness"].append(_entry(f.name, v["rms_form_mm"], f.nominal_mm, f.tolerance_mm, v["u_rms_form_mm"],
                                            u_cal(f.name, "rms_form_mm"), u_floor=floor, extra={
                "figure": "flatness FLTq (RMS of the least-squares residuals, noise removed)",
                "pv_form_mm": v["pv_form_mm"], "u_pv_form_mm": v["u_pv_form_mm"], "rms_mm": v["rms_mm"],
                "pv_mm": v["pv_mm"], "rms_noise_mm": v["rms_noise_mm"], "pv_noise_mm": v["pv_noise_mm"], "points": v["n"],
                "noise_scale": v["noise_scale"]}))
        elif f.kind == "distance":
            a, b = f.planes or ("", "")
            forms["distances"].append(_entry(f.name, v["distance_mm"], f.nominal_mm, f.tolerance_mm, v["u_distance_mm"],
                                             u_cal(f.name, "distance_mm"), {
                "figure": f"distance of {a} from {b}",
                "angle_deg": float(np.degrees(v["angle_rad"])), "u_angle_deg": float(np.degrees(v["u_angle_rad"]))}))
            # the calibration's term of a zone width: the spread of the signed tilt vector (not of its
            # magnitude, which folds every leave-one-out tilt onto one side)
            u_tilt = combine_u(*(u_cal(f.name, f"tilt{i}") or 0.0 for i in range(3))) if loo else None
            forms["parallelism"].append(_entry(f"{f.name}-parallelism", v["parallelism_mm"], 0.0, f.tolerance_mm,
                                               v["u_parallelism_mm"], None if u_tilt is None else u_tilt * v["zone_per_tilt_mm"], {
                "figure": f"parallelism of {a} to {b} (zone width over its extent)"}))
        elif f.kind == "sphere":
            forms["spheres"].append(_entry(f.name, v["radius_mm"], f.nominal_mm, f.tolerance_mm, v["u_radius_mm"],
                                           u_cal(f.name, "radius_mm"), {
                "figure": "radius of the least-squares sphere", "centre_mm": v["centre_mm"],
                "form_rms_mm": v.get("rms_form_mm"), "form_pv_mm": v.get("pv_form_mm"), "points": v["n"]}))
    forms = {k: v for k, v in forms.items() if v}
    specimen = {"tolerance_mm": feats.tolerance_mm, "steps": [{"name": s["name"], "nominal_mm": s["nominal_mm"]} for s in steps]}
    method_result = {"method": ONESHOT_METHOD if oneshot else METHOD, "frames": 1, "steps": steps}
    inputs = [p for p in session.input_files()] + [Path(calibration)]
    route = (f"{ONESHOT_GEOMETRY}: the first one-shot trapezoid frame's hue through the per-pixel hue table to the "
             "projector coordinate, its fringe order from the session's coded blocks on the same scene, triangulated "
             "with the rig calibration" if oneshot else
             "structured light: decoded projector coordinates triangulated with the rig calibration")
    extras: dict[str, Any] = {
        "geometry": {"route": route, "triangulation": mode, "calibration": str(calibration),
                     **({"name": ONESHOT_GEOMETRY} if oneshot else {})},
        "forms": forms,
        "provenance": {**collect_provenance(session.id, dict(config), inputs),
                       "capture": session.meta.get("provenance") or {},
                       **({"geometry": ONESHOT_GEOMETRY} if oneshot else {})},
    }
    if cal_doc:
        extras["rig_calibration"] = cal_doc
    report = build_report_json(session.id, specimen, method_result, extras=extras,
                               figures=[e for k in ("flatness", "distances", "parallelism", "spheres") for e in forms.get(k, [])])
    if not loo:  # said in the headline too: this U lacks a term, and a decision read from it must know that
        report["conformity"]["reason"] += ("; every U lacks the calibration's term (the calibration file comes without its "
                                           "board poses, so its uncertainty is not known here)")
    from huefringe.io import write_json

    write_json(json_path, report)
    write_report_html(html_path, report, {k: v for k, v in (figures or {}).items() if v and Path(v).is_file()},
                      report["provenance"])
    return report


def _mode(decoded: F64, config: Mapping[str, Any]) -> str:
    mode = str(config["rig"]["triangulation"])
    if mode != "auto":
        return mode
    has = [np.isfinite(decoded[..., k]).any() for k in (0, 1)]
    return "both" if all(has) else ("u" if has[0] else "v")


def xyz_accuracy(xyz: F64, u: F64, truth: F64, *, sigma: F64 | None = None, calibration: RigCalibration | None = None,
                 true_uv: Mapping[str, F64] | None = None) -> dict[str, Any]:
    """Errors of triangulated points against the true X, Y, Z (benches).

    Parameters
    ----------
    xyz : ndarray, shape (H, W, 3)
    u : ndarray, shape (H, W, 4)
        Combined standard uncertainties ``u_x, u_y, u_z`` and ``u_ray`` along the camera ray
        (``xyz/frame_NNNN_u.tiff``).
    truth : ndarray, shape (H, W, 3)
        NaN where the projector lights no surface directly.
    sigma, calibration, true_uv : optional
        The decoded coordinates' noise (``xyz/frame_NNNN_sigma.tiff``: per axis and along the
        ray), the calibration the frame
        was triangulated with and the true projector coordinates (``ground_truth/x.tiff``,
        ``y.tiff``): the decoding's own error, ``xyz`` against the true coordinates triangulated
        with the same calibration, is then scored against ``sigma`` (``decoding``).

    Returns
    -------
    dict
        ``pixels`` (valid with truth), ``valid_without_truth`` (valid pixels no projector light
        reaches directly: shadow, background), per-axis RMS, the along-ray error's median and 95th
        percentile, and the share of pixels with ``|e_ray| <= 2 u_ray`` and, per axis,
        ``|e| <= 2 u``.
    """
    valid = np.isfinite(xyz).all(axis=-1)
    true = np.isfinite(truth).all(axis=-1)
    both = valid & true
    e = (xyz - truth)[both]
    ray = truth[both] / np.linalg.norm(truth[both], axis=-1, keepdims=True)
    along = np.abs(np.einsum("ij,ij->i", e, ray))
    uu = u[both]
    out: dict[str, Any] = {
        "pixels": int(both.sum()), "valid_without_truth": int((valid & ~true).sum()),
        "coverage_of_truth": float(both.sum() / max(int(true.sum()), 1)),
        "rms_xyz_mm": np.sqrt(np.mean(e**2, axis=0)).tolist(),
        "median_abs_error_mm": float(np.median(along)) if along.size else None,
        "p95_abs_error_mm": float(np.percentile(along, 95)) if along.size else None,
        "median_u_ray_mm": float(np.median(uu[:, 3])) if along.size else None,
        "within_2u": float(np.mean(along <= 2 * uu[:, 3])) if along.size else None,
        "within_2u_xyz": np.mean(np.abs(e) <= 2 * uu[:, :3], axis=0).tolist() if along.size else None,
        "error_measure": "|e . r|, the error along the camera ray r (where a triangulated point's error lies), "
                         "against u_ray; per axis |e_x|, |e_y|, |e_z| against u_x, u_y, u_z",
    }
    if sigma is not None and calibration is not None and true_uv and {"x", "y"} >= set(true_uv):
        ok = both & np.logical_and.reduce([np.isfinite(v) for v in true_uv.values()])
        rows, cols = np.nonzero(ok)
        t = triangulate(calibration, true_uv["x"][ok] if "x" in true_uv else None, true_uv["y"][ok] if "y" in true_uv else None,
                        pixels=np.column_stack([cols, rows]).astype(np.float64))
        e_dec = np.abs(np.einsum("ij,ij->i", xyz[ok] - t.xyz, t.xyz / np.linalg.norm(t.xyz, axis=-1, keepdims=True)))
        s_dec = sigma[ok][:, 3]
        good = np.isfinite(e_dec)
        out["decoding"] = {
            "what": "the decoded coordinates' error alone: xyz against the true projector coordinates triangulated with "
                    "the same calibration, along the ray, against the decoded coordinates' noise sigma",
            "pixels": int(good.sum()), "median_abs_error_mm": float(np.median(e_dec[good])),
            "median_sigma_mm": float(np.median(s_dec[good])), "within_2sigma": float(np.mean(e_dec[good] <= 2 * s_dec[good])),
        }
    return out
