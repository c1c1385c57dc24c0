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
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe.metrology import combine_u, fit_plane_u, fit_sphere_u, flatness_u, jackknife_u, plane_pair_u, sigma_along, step_height_u
from huefringe.report import build_report_json, collect_provenance, per_frame_figure, write_report_html
from huefringe.rig.measure import RigError, RigFrame, read_jackknife
from huefringe.rig.model import RigCalibration
from huefringe.rig.oneshot import ONESHOT_GEOMETRY
from huefringe.rig.triangulation import triangulate
from huefringe.uncertainty import conformance

__all__ = ["METHOD", "ONESHOT_METHOD", "base_plane", "feature_values", "flatness_as_reported", "noise_scale", "rig_report",
           "xyz_accuracy"]

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


def flatness_as_reported(xyz: F64, sigma: F64, mask: NDArray[np.bool_]) -> dict[str, Any]:
    """A region's flatness as the report gives it: :func:`~huefringe.metrology.flatness_u` of the
    region's points with their noise scaled to what the data show (:func:`noise_scale`: ``k``
    times ``sigma``) and that scale's relative uncertainty in ``u_rms_form_mm`` (``noise_rel_u``),
    so that a noise figure off by a per cent or two is not read as form; ``noise_scale`` and
    ``noise_scale_rel_u`` beside the fit's keys."""
    p, sg = _points(xyz, sigma, mask)
    pl = fit_plane_u(p, sg)
    k, rel = noise_scale(xyz, sigma, mask, pl.centroid, pl.normal)
    return {**flatness_u(p, k * sg, noise_rel_u=rel), "noise_scale": k, "noise_scale_rel_u": rel}


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
                out[f.name] = flatness_as_reported(xyz, sigma, masks[f.name])
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


def _series(values: Sequence[float]) -> tuple[float, float | None, list[float]]:
    """A figure over the frames: its mean, the sample standard deviation (``ddof = 1``; None for
    one frame) and the per-frame values, as the capture route's steps carry them
    (:func:`huefringe.metrology.evaluate_session`)."""
    x = [float(v) for v in values]
    if len(x) == 1:
        return x[0], None, x
    return float(np.mean(x)), float(np.std(x, ddof=1)), x


def _rms(values: Sequence[float]) -> float:
    """The frames' standard uncertainties in quadrature mean (the value itself for one frame)."""
    return float(values[0]) if len(values) == 1 else float(np.sqrt(np.mean(np.square(values))))


def _entry(name: str, values: Sequence[float], nominal: float, tol: float, u_points: float, u_cal: float | None,
           extra: Mapping[str, Any], u_floor: float | None = None) -> dict[str, Any]:
    value, std, per_frame = _series(values)
    u = combine_u(u_points, u_cal or 0.0, u_floor or 0.0)
    err = value - nominal
    rep = {} if std is None else {"repeatability_3sigma_mm": 3.0 * std}
    return {
        "name": name, "nominal_mm": nominal, "mean_mm": value, "std_mm": std, **rep, "error_mm": err,
        "error_pct": 100.0 * err / nominal if nominal else None, "pass": abs(err) <= tol, "per_frame_mm": per_frame,
        "u_mm": u, "U_mm": 2.0 * u, "tolerance_mm": tol, "conformance": conformance(err, tol, 2.0 * u),
        "uncertainty_budget": {"points_mm": u_points,
                               "calibration_mm": u_cal if u_cal is not None else "not available: the calibration file "
                                                                                   "comes without its board poses",
                               **({} if u_floor is None else {"form_floor_mm": u_floor})},
        **extra,
    }


def _frames(maps: F64 | Sequence[F64], what: str) -> list[F64]:
    """One frame's map (H, W, C) or a sequence of them, as a list of frames."""
    if isinstance(maps, np.ndarray) and maps.ndim == 3:
        return [maps]
    out = [np.asarray(m) for m in maps]
    if not out:
        raise RigError(f"no {what} map given: nothing to report")
    return out


def rig_report(session: Any, config: Mapping[str, Any], *, calibration: str | os.PathLike[str],
               xyz: F64 | Sequence[F64], sigma: F64 | Sequence[F64], decoded: F64 | Sequence[F64],
               jackknife: str | os.PathLike[str] = "", calibration_report: str | os.PathLike[str] = "",
               json_path: str | os.PathLike[str], html_path: str | os.PathLike[str],
               figures: Mapping[str, str | os.PathLike[str]] | None = None, oneshot: bool = False) -> dict[str, Any]:
    """Measure a structured-light session's features and write ``report.json`` and ``report.html``.

    Every figure is measured on each frame given; the report carries, as the capture route's
    (:func:`huefringe.metrology.evaluate_session`), its per-frame values (``per_frame_mm``), their
    mean (``mean_mm``, the figure the error and the decision are of) and sample standard deviation
    (``std_mm``, ``repeatability_3sigma_mm``; None and absent for one frame). The mean's standard
    uncertainty combines, as for one frame:

    - **points**: the quadrature mean of the frames' own points terms, not divided by the number of
      frames (each pixel's ``sigma`` holds the hue table's noise, the same in every frame, beside
      the capture's, and the files do not separate them), so an upper figure for several frames;
    - **calibration**: the jackknife over the leave-one-pose-out calibrations of the figure on the
      first frame, re-triangulated with each: a calibration's error moves every frame of the scene
      alike, so it is neither reduced by the frames nor recomputed for each (which would cost the
      leave-one-out triangulations once per frame).

    Parameters
    ----------
    session : SLSession
        With ``features`` (``features.yaml``).
    config : mapping
        The run's configuration (``rig.triangulation``; recorded in the provenance).
    calibration : path
        The calibration the frames were triangulated with.
    xyz, sigma : ndarray, shape (H, W, 3), or a sequence of them (one per frame)
        The triangulated frames and their per-point standard uncertainties (NaN where not valid).
    decoded : ndarray, shape (H, W, 4), or a sequence of them
        Decoded ``u, v, sigma_u, sigma_v`` of each frame (NaN where not decoded): re-triangulated
        with each leave-one-pose-out calibration of ``jackknife`` for the calibration term.
    jackknife, calibration_report : path, optional
        :func:`huefringe.rig.measure.write_rig_calibration`'s files, when the workflow calibrated the rig.
    json_path, html_path : path
        Where the report goes.
    figures : mapping of str to path, optional
        PNG figures for the page; with several frames the per-frame figure
        (:func:`huefringe.report.per_frame_figure`) is added as ``per_frame``.
    oneshot : bool
        The frames are one-shot trapezoid frames (:func:`huefringe.rig.oneshot.measure_oneshot_session`):
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
    xyzs, sigmas, decs = _frames(xyz, "xyz"), _frames(sigma, "sigma"), _frames(decoded, "decoded")
    if not len(xyzs) == len(sigmas) == len(decs):
        raise RigError(f"{session.root}: {len(xyzs)} xyz, {len(sigmas)} sigma and {len(decs)} decoded maps: one of "
                       "each per frame expected")
    nf = len(xyzs)
    per_frame = [feature_values(x, sg, feats) for x, sg in zip(xyzs, sigmas, strict=True)]
    loo = read_jackknife(jackknife) if jackknife else []
    mode = _mode(decs[0], config)
    jack: dict[tuple[str, str], list[float]] = {}
    if loo:  # on the first frame: a calibration's error is the same in every frame of the scene
        valid = np.isfinite(xyzs[0]).all(axis=-1)
        need = np.zeros(valid.shape, dtype=bool)
        for r in feats.regions().values():
            need |= r.mask(valid.shape)
        need &= valid
        for _, c in loo:
            xj, sj = _retriangulate(c, decs[0], mode, need)
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

    def each(name: str, key: str) -> list[float]:
        return [float(v[name][key]) for v in per_frame]

    def first(name: str, key: str) -> Any:
        return per_frame[0][name][key]

    steps, forms = [], {"flatness": [], "distances": [], "parallelism": [], "spheres": []}
    for f in feats.features:
        n = f.name
        if f.kind == "step":
            steps.append(_entry(n, each(n, "height_mm"), f.nominal_mm, f.tolerance_mm, _rms(each(n, "u_mm")),
                                u_cal(n, "height_mm"), {"points": {"base": first(n, "n_base"), "top": first(n, "n_top")}}))
        elif f.kind == "plane":
            v = per_frame[0][n] if nf == 1 else {k: float(np.mean(each(n, k))) for k in (
                "pv_form_mm", "u_pv_form_mm", "rms_mm", "pv_mm", "rms_noise_mm", "pv_noise_mm", "noise_scale")}
            forms["flatness"].append(_entry(n, each(n, "rms_form_mm"), f.nominal_mm, f.tolerance_mm,
                                            _rms(each(n, "u_rms_form_mm")), u_cal(n, "rms_form_mm"), u_floor=floor, extra={
                "figure": "flatness FLTq (RMS of the least-squares residuals, noise removed)",
                "pv_form_mm": v["pv_form_mm"], "u_pv_form_mm": v["u_pv_form_mm"], "rms_mm": v["rms_mm"],
                "pv_mm": v["pv_mm"], "rms_noise_mm": v["rms_noise_mm"], "pv_noise_mm": v["pv_noise_mm"],
                "points": first(n, "n"), "noise_scale": v["noise_scale"]}))
        elif f.kind == "distance":
            a, b = f.planes or ("", "")
            angle = (first(n, "angle_rad"), first(n, "u_angle_rad")) if nf == 1 else (
                float(np.mean(each(n, "angle_rad"))), _rms(each(n, "u_angle_rad")))
            forms["distances"].append(_entry(n, each(n, "distance_mm"), f.nominal_mm, f.tolerance_mm,
                                             _rms(each(n, "u_distance_mm")), u_cal(n, "distance_mm"), {
                "figure": f"distance of {a} from {b}",
                "angle_deg": float(np.degrees(angle[0])), "u_angle_deg": float(np.degrees(angle[1]))}))
            # the calibration's term of a zone width: the spread of the signed tilt vector (not of its
            # magnitude, which folds every leave-one-out tilt onto one side)
            zone = first(n, "zone_per_tilt_mm") if nf == 1 else float(np.mean(each(n, "zone_per_tilt_mm")))
            u_tilt = combine_u(*(u_cal(n, f"tilt{i}") or 0.0 for i in range(3))) if loo else None
            forms["parallelism"].append(_entry(f"{n}-parallelism", each(n, "parallelism_mm"), 0.0, f.tolerance_mm,
                                               _rms(each(n, "u_parallelism_mm")), None if u_tilt is None else u_tilt * zone, {
                "figure": f"parallelism of {a} to {b} (zone width over its extent)"}))
        elif f.kind == "sphere":
            v = per_frame[0][n]
            centre = v["centre_mm"] if nf == 1 else np.mean([p[n]["centre_mm"] for p in per_frame], axis=0).tolist()
            form = (v.get("rms_form_mm"), v.get("pv_form_mm")) if nf == 1 else tuple(
                None if v.get(k) is None else float(np.mean(each(n, k))) for k in ("rms_form_mm", "pv_form_mm"))
            forms["spheres"].append(_entry(n, each(n, "radius_mm"), f.nominal_mm, f.tolerance_mm, _rms(each(n, "u_radius_mm")),
                                           u_cal(n, "radius_mm"), {
                "figure": "radius of the least-squares sphere", "centre_mm": centre,
                "form_rms_mm": form[0], "form_pv_mm": form[1], "points": v["n"]}))
    forms = {k: v for k, v in forms.items() if v}
    specimen = {"tolerance_mm": feats.tolerance_mm, "steps": [{"name": s["name"], "nominal_mm": s["nominal_mm"]} for s in steps]}
    method_result = {"method": ONESHOT_METHOD if oneshot else METHOD, "frames": nf, "steps": steps}
    ref_root = getattr(session, "oneshot_reference", None) if oneshot else None
    ref_doc: dict[str, Any] = {}
    inputs = [p for p in session.input_files()] + [Path(calibration)]
    if ref_root is not None:
        from huefringe.session import load_sl_session

        ref = load_sl_session(ref_root)
        inputs += ref.input_files()
        ref_doc = {"oneshot_reference": {"session": ref.id, "path": str(ref_root),
                                         "what": "the coded captures of a plane under the object, captured apart from the "
                                                 "one-shot frames: their fringe-order reference"}}
    order_from = (f"the reference session {ref_doc['oneshot_reference']['session']}'s coded captures (a plane under the "
                  "object)" if ref_doc else "the session's coded blocks on the same scene")
    which = "the first one-shot trapezoid frame's" if nf == 1 else f"each of the {nf} one-shot trapezoid frames'"
    route = (f"{ONESHOT_GEOMETRY}: {which} hue through the per-pixel hue table to the "
             f"projector coordinate, its fringe order from {order_from}, triangulated "
             "with the rig calibration" + ("" if nf == 1 else "; every figure the mean over the frames") if oneshot else
             "structured light: decoded projector coordinates triangulated with the rig calibration")
    extras: dict[str, Any] = {
        "geometry": {"route": route, "triangulation": mode, "calibration": str(calibration),
                     **({"name": ONESHOT_GEOMETRY} if oneshot else {}), **ref_doc},
        "forms": forms,
        "provenance": {**collect_provenance(session.id, dict(config), inputs),
                       "capture": session.meta.get("provenance") or {},
                       **({"geometry": ONESHOT_GEOMETRY} if oneshot else {}), **ref_doc},
    }
    if nf > 1:
        extras["uncertainty_over_frames"] = (
            "each figure is the mean over the frames; its points term the quadrature mean of the frames' (not divided by "
            "the number of frames: each pixel's sigma holds the hue table's noise, the same in every frame), its "
            "calibration term the jackknife over the leave-one-pose-out calibrations on the first frame (a calibration's "
            "error moves every frame alike)")
    if cal_doc:
        extras["rig_calibration"] = cal_doc
    report = build_report_json(session.id, specimen, method_result, extras=extras,
                               figures=[e for k in ("flatness", "distances", "parallelism", "spheres") for e in forms.get(k, [])])
    if not loo:  # said in the headline too: this U lacks a term, and a decision read from it must know that
        report["conformity"]["reason"] += ("; every U lacks the calibration's term (the calibration file comes without its "
                                           "board poses, so its uncertainty is not known here)")
    from huefringe.io import write_json

    write_json(json_path, report)
    figs = {k: v for k, v in (figures or {}).items() if v and Path(v).is_file()}
    with tempfile.TemporaryDirectory() as tmp:
        if nf > 1:  # the capture route's per-frame figure, embedded in the page
            figs["per_frame"] = per_frame_figure(report, Path(tmp) / "per_frame.png")
        write_report_html(html_path, report, figs, report["provenance"])
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
