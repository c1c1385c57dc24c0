"""One scene, two geometries: the one-shot rig path against the plane-calibrated (paper) path.

Usage: ./run python benchmarks/oneshot_vs_planes.py [--seed 2] [--poses 6:7] [--degrees 3]
                                                    [--planes 0,3,6] [--json OUT]

The scene: the paper's Fig. 9 gauge blocks (green 3.0, blue 1.0, red 4.0 mm) on the holdout-wide
bench rig's tilted base plane (huefringe.bench.oneshot.gauge_scene), one trapezoid frame of period
36 px, 8-bit, 1 DN read noise, 5 % ambient, the demo camera's crosstalk; the same rendered object
captures (white, 64 hue bands x 3 repeats, the frame) go through both paths:

* **rig**: the rig calibrated from N simulated board poses of pose seed S
  (huefringe.bench.oneshot.calibrated_rig), the order from the base plane's Gray code + 8-step
  phase, huefringe.rig.oneshot.measure_oneshot; the height of a point is its distance from the
  least-squares plane of the base's points (the rig route's datum); u of each height from the
  points' noise along the plane's normal and the calibration's term of the height (the jackknife
  of the height over the leave-one-pose-out calibrations, each fitting the base again, t-scaled);
  beside it the same frame with the rig's true calibration (the one-shot decoding alone), and
  with the plane route's phase filter on the frame's offset from the reference
  (huefringe.rig.oneshot.filter_against_reference, the default denoise_radius and adaptive support);
* **planes**: the capture-session route's own functions on the same rig: the reference table
  from 64 x 3 bands on the bare base plane, the base plane lifted along its normal to the
  ``--planes`` heights under the trapezoid (each plane a capture, its phase through the reference
  table), the phase-error table (huefringe.phase_error.from_calibration, default ``auto``) and
  huefringe.height.calibrate_planes (``plane_smooth_degree`` from ``--degrees``), then
  huefringe.perframe.measure_frame with the object's table and the default measurement settings,
  once with the phase filter (the route's default) and once without (``denoise_radius = 0``, as
  the rig path decodes: no filter), u from huefringe.uncertainty's per-pixel budget.

Truth: each pixel's true point's distance from the true base plane. Scored on the lit pixels of
the base and the three tops, 6 px clear of every edge and shadow, that both paths measure: the
median and 95th percentile of |height error|, |e| <= 2u, and the steps (mean top minus mean base).
With several ``--degrees`` it prints one plane row per degree (tuning); report one degree on a
seed and pose set not tuned on.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from huefringe.bench.oneshot import (BASE_ORIGIN, BASE_TILT, calibrated_rig, face_mask, gauge_scene, render_session,
                                     step_scores)
from huefringe.bench.rig import RIGS, PlaneScene
from huefringe.colour import hue as hue_of
from huefringe.colour import white_balance
from huefringe.height import calibrate_planes
from huefringe.huetable import build_table
from huefringe.perframe import measure_frame, shadow_mask
from huefringe.phase_error import correct as pe_correct
from huefringe.phase_error import from_calibration as pe_from_calibration
from huefringe.rig.oneshot import hue_table_from_frames, measure_oneshot, oneshot_reference
from huefringe.rig.triangulation import triangulate
from huefringe.settings import defaults as load_defaults
from huefringe.uncertainty import pixel_budget

GAUGE = {1: 3.0, 2: 1.0, 3: 4.0}


def base_frame() -> tuple[np.ndarray, np.ndarray]:
    """The true base plane: origin and unit normal towards the camera (camera frame, mm)."""
    n = PlaneScene(point=BASE_ORIGIN, tilt_deg=BASE_TILT).normal()
    return np.asarray(BASE_ORIGIN, float), n


def table_of(white: np.ndarray, bands: np.ndarray, n: int, repeats: int, cfg: dict[str, Any]) -> Any:
    """The capture-session route's table: build_table with the calibration's settings."""
    c = cfg["calibration"]
    paths = [[bands[i * repeats + r] for r in range(repeats)] for i in range(n)]
    return build_table(paths, np.asarray(white, np.float32), model=cfg["hue_model"], read=lambda a: np.asarray(a, np.float32),
                       min_saturation=c["min_saturation"], min_intensity=c["min_intensity"])


def plane_calibration(planes_mm: list[float], degree: int, seed: int, cfg: dict[str, Any]) -> tuple[Any, Any, Any]:
    """Reference table and plane calibration from the base plane lifted to ``planes_mm``: the reference's
    white and bands on the bare base, one trapezoid capture per plane through the reference table."""
    o, n = base_frame()
    c = cfg["calibration"]
    ref = render_session(PlaneScene(point=tuple(o), tilt_deg=BASE_TILT), n_bands=64, repeats=3, seed=seed + 500)
    table = table_of(ref.white, ref.bands, 64, 3, cfg)
    shadow = shadow_mask(ref.white, c["shadow_fraction"])
    phases, valid = {}, {}
    for j, z in enumerate(planes_mm):
        if z == 0.0:
            frame = ref.frames[0]
        else:
            frame = render_session(PlaneScene(point=tuple(o + z * n), tilt_deg=BASE_TILT), n_bands=2, repeats=1,
                                   seed=seed + 600 + j).frames[0]
        h = hue_of(white_balance(frame, ref.white), cfg["hue_model"], min_saturation=c["min_saturation"])
        phi = table.to_phase(h)
        phases[float(z)] = phi
        valid[float(z)] = np.isfinite(phi) & ~shadow
    cc = dict(c, plane_smooth_degree=degree)
    lut = pe_from_calibration(phases, valid, cc)
    phases = {z: pe_correct(p, None if lut is None else lut.error) for z, p in phases.items()}
    cal = calibrate_planes(phases, valid, smooth_degree=degree)
    cal.phase_error = None if lut is None else lut.error
    return cal, table, lut


def heights_over_base(xyz: np.ndarray, base: np.ndarray, towards: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every point's distance from the least-squares plane of the ``base`` points (the rig route's
    datum), positive along ``towards``; and the plane's unit normal."""
    P = xyz[base]
    c0 = P.mean(axis=0)
    nf = np.linalg.svd(P - c0, full_matrices=False)[2][-1]
    nf = nf if nf @ towards > 0 else -nf
    return (xyz - c0) @ nf, nf


def rig_heights(res: Any, jack: Any, base: np.ndarray, towards: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heights over the base's least-squares plane, their u and its calibration part: the points'
    noise along the plane's normal, and the calibration's term of the height itself (each
    leave-one-pose-out calibration triangulates and fits the base again, jackknife, t-scaled; a
    shared move of the base and the point cancels in the height, as it does in every figure)."""
    h, nf = heights_over_base(res.xyz, base & res.valid, towards)
    rays = res.xyz / np.linalg.norm(res.xyz, axis=-1, keepdims=True)
    u_noise = res.sigma_ray * np.abs(rays @ nf)
    hs = []
    for _, c in jack:
        t = triangulate(c, res.coordinate.coord, valid=res.valid, mode="u")
        hs.append(heights_over_base(t.xyz, base & res.valid & t.valid, towards)[0])
    J = len(hs)
    hs_a = np.stack(hs)
    u_cal = np.sqrt((J - 1) / J * np.sum((hs_a - hs_a.mean(axis=0)) ** 2, axis=0) * (J - 1) / (J - 3))
    return h, np.sqrt(u_noise**2 + u_cal**2), u_cal


def scores(height: np.ndarray, u: np.ndarray, truth_h: np.ndarray, mask: np.ndarray, faces: dict[int, np.ndarray]) -> dict[str, Any]:
    """Median and 95th percentile |error|, |e| <= 2u, per-face medians and the steps (mean top - mean base)."""
    e = height[mask] - truth_h[mask]
    out: dict[str, Any] = {"pixels": int(mask.sum()), "median_abs_error_mm": float(np.median(np.abs(e))),
                           "p95_abs_error_mm": float(np.percentile(np.abs(e), 95)),
                           "within_2u": float(np.mean(np.abs(e) <= 2 * u[mask])), "median_u_mm": float(np.median(u[mask]))}
    base = faces[0] & mask
    out["face_median_abs_error_mm"] = {k: float(np.median(np.abs(height[f & mask] - truth_h[f & mask]))) for k, f in faces.items()}
    out["steps"] = {}
    for k, h0 in GAUGE.items():
        top = faces[k] & mask
        step = float(np.mean(height[top]) - np.mean(height[base]))
        true = float(np.mean(truth_h[top]) - np.mean(truth_h[base]))
        out["steps"][h0] = {"height_mm": step, "error_mm": step - true, "relative_error": (step - true) / h0}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=2, help="noise seed of the object's and the planes' captures")
    ap.add_argument("--poses", default="6:7", help="the rig's calibration: N:pose seed")
    ap.add_argument("--degrees", default="3", help="plane_smooth_degree of the plane path, comma separated")
    ap.add_argument("--planes", default="0,3,6", help="calibration plane heights (mm), 0 included")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    cfg = load_defaults()
    m = cfg["measurement"]
    planes = [float(v) for v in a.planes.split(",")]
    t0 = time.perf_counter()
    cap = render_session(gauge_scene(), n_bands=64, repeats=3, seed=a.seed)
    o, n = base_frame()
    truth_h = (cap.truth_xyz - o) @ n
    faces = {k: face_mask(cap, k) for k in (0, *GAUGE)}
    anyface = np.zeros(truth_h.shape, bool)
    for f in faces.values():
        anyface |= f

    # rig path
    npose, pseed = (int(v) for v in a.poses.split(":"))
    cal, jack = calibrated_rig(n_poses=npose, seed=pseed)
    table_r = hue_table_from_frames(cap.white, cap.bands, cap.bands_block, model=cfg["hue_model"])
    ref = oneshot_reference(cap.reference, cal, cap.block)
    res = measure_oneshot(cap.frames[0], cap.white, table_r, cap.block, cal, ref)
    h_rig, u_rig, ucal_rig = rig_heights(res, jack, faces[0], n)
    res_f = measure_oneshot(cap.frames[0], cap.white, table_r, cap.block, cal, ref, denoise_radius=int(m["denoise_radius"]),
                            denoise_adaptive=m["denoise_adaptive"])
    h_rig_f, u_rig_f, ucal_rig_f = rig_heights(res_f, jack, faces[0], n)
    true_cal = RIGS["holdout-wide"].calibration
    res_t = measure_oneshot(cap.frames[0], cap.white, table_r, cap.block, true_cal, oneshot_reference(cap.reference, true_cal, cap.block))
    h_true_cal, nf_t = heights_over_base(res_t.xyz, faces[0] & res_t.valid, n)
    u_true_cal = res_t.sigma_ray * np.abs((res_t.xyz / np.linalg.norm(res_t.xyz, axis=-1, keepdims=True)) @ nf_t)
    st = step_scores(cap, res, jack, GAUGE)
    t1 = time.perf_counter()

    # plane path, per degree
    table_o = table_of(cap.white, cap.bands, 64, 3, cfg)
    shadow = shadow_mask(cap.white, cfg["calibration"]["shadow_fraction"])
    planes_out = {}
    for deg in (int(v) for v in a.degrees.split(",")):
        pcal, _, lut = plane_calibration(planes, deg, a.seed, cfg)
        budget = pixel_budget(table_o, pcal)
        for name, radius in (("filtered", int(m["denoise_radius"])), ("unfiltered", 0)):
            fr = measure_frame(cap.frames[0], cap.white, table_o, pcal, hue_model=cfg["hue_model"],
                               min_saturation=m["min_saturation"], shadow=shadow, unwrap_mode=m["unwrap"], bit_depth=8,
                               denoise_radius=radius, denoise_adaptive=m["denoise_adaptive"] if radius else None,
                               budget=budget)
            planes_out[(deg, name)] = (fr, pcal, lut)
    t2 = time.perf_counter()

    both = anyface & res.valid & res_f.valid & res_t.valid & np.all([fr.valid & np.isfinite(fr.height) for fr, _, _ in planes_out.values()], axis=0)
    rows = {"rig": scores(h_rig, u_rig, truth_h, both, faces)}
    rows["rig"]["steps_U_mm"] = {GAUGE[k]: s["U_mm"] for k, s in zip(GAUGE, st.values(), strict=True)}
    rows["rig filtered"] = scores(h_rig_f, u_rig_f, truth_h, both, faces)
    for name, uc in (("rig", ucal_rig), ("rig filtered", ucal_rig_f)):
        rows[name]["median_u_calibration_mm"] = float(np.median(uc[both]))
    rows["rig, true calibration"] = scores(h_true_cal, u_true_cal, truth_h, both, faces)
    for (deg, name), (fr, pcal, lut) in planes_out.items():
        rows[f"planes degree {deg} {name}"] = scores(fr.height.astype(float), fr.uncertainty.astype(float), truth_h, both, faces)
        rows[f"planes degree {deg} {name}"]["phase_error_applied"] = bool(lut is not None and lut.stats.get("applied"))
        rows[f"planes degree {deg} {name}"]["plane_fit_rms_mm"] = pcal.stats["fit_residual_rms_mm"]
    print(f"seed {a.seed}, rig calibrated from {npose} poses of seed {pseed}, planes {planes} mm; {int(both.sum())} px "
          f"(base and tops, 6 px clear of edges) measured by both; rig {t1 - t0:.0f} s, planes {t2 - t1:.0f} s\n")
    print("| path | median \\|e\\| um | p95 \\|e\\| um | \\|e\\| <= 2u | median u um | base / 3.0 / 1.0 / 4.0 mm faces: median \\|e\\| um "
          "| steps 3.0 / 1.0 / 4.0 mm: error um (%) | ratio rig / path |")
    print("|---|---|---|---|---|---|---|---|")
    rig_med = rows["rig"]["median_abs_error_mm"]
    for name, r in rows.items():
        fm = " / ".join(f"{1e3 * v:.1f}" for v in r["face_median_abs_error_mm"].values())
        ss = " / ".join(f"{1e3 * s['error_mm']:+.1f} ({100 * s['relative_error']:+.2f})" for s in r["steps"].values())
        ratio = "" if name.startswith("rig") else \
            f"{rig_med / r['median_abs_error_mm']:.2f}, filtered {rows['rig filtered']['median_abs_error_mm'] / r['median_abs_error_mm']:.2f}"
        print(f"| {name} | {1e3 * r['median_abs_error_mm']:.1f} | {1e3 * r['p95_abs_error_mm']:.1f} | {r['within_2u']:.3f} | "
              f"{1e3 * r['median_u_mm']:.1f} | {fm} | {ss} | {ratio} |")
    print("\nmedian u of the rig rows' calibration term (jackknife): "
          + ", ".join(f"{name} {1e3 * rows[name]['median_u_calibration_mm']:.1f} um" for name in ("rig", "rig filtered")))
    if a.json:
        a.json.write_text(json.dumps({"seed": a.seed, "poses": a.poses, "planes_mm": planes, "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
