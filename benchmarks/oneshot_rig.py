"""One-shot colour frames on a calibrated bench rig: steps, per-pixel errors, flatness, range, timing.

Usage: ./run python benchmarks/oneshot_rig.py [--poses 6:7,8:4,8:5,8:6] [--frames 5] [--aim 0.06,0.05]

The holdout-wide bench rig (huefringe.bench.rig.RIGS), calibrated from simulated board poses
(huefringe.bench.oneshot.calibrated_rig: N poses of pose seed S for each N:S, boards aimed within
--aim times their distance off the camera's axis: the default near the middle of the image,
0.14,0.11 over the field), measures with one
trapezoid frame per instant (period 36 px, hue table of 64 bands x 3 repeats, 8-bit, 1 DN read
noise, the demo camera's crosstalk), the order from the base plane's Gray code + 8-step phase:

* the Fig. 9 gauge blocks (3.0 / 1.0 / 4.0 mm, coloured green / blue / red) on the base plane:
  each step's error (%) and U (k = 2, points and calibration jackknife); |e_ray| <= 2u over the
  valid pixels; the same with the rig's true calibration (the one-shot decoding alone);
* a flat board 4 mm in front of the base, tilted 2 degrees against it: FLTq (noise-corrected,
  with U, as the report gives it: the noise scaled to the data,
  huefringe.rig.metrology.flatness_as_reported) and the raw RMS of the plane residuals; FLTq again
  on the board's pixels inside the calibrated field (huefringe.rig.calibrated_field: the poses' corner hulls) and that share;
* blocks of 6 and 15 mm: the unambiguous range in front of the base at their pixels, the share
  of their lit tops measured and flagged ORDER;
* per-frame compute of the one-shot rig path at 640 x 480 (perf_counter, median of --frames
  frames): decode (white balance, hue, table) + order, and triangulation.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from huefringe.bench.oneshot import (calibrated_rig, calibrated_rig_report, face_mask, flatness_scores, gauge_scene, pixel_scores, render_session,
                                     step_scores)
from huefringe.bench.rig import RIGS, CompositeScene, PlaneScene
from huefringe.codecs import Reason
from huefringe.metrology import step_height_u
from huefringe.rig import field_mask
from huefringe.rig.metrology import flatness_as_reported
from huefringe.rig.oneshot import (absolute_from_reference, hue_table_from_frames, measure_oneshot, oneshot_reference,
                                   trapezoid_coordinate)
from huefringe.rig.triangulation import triangulate

GAUGE = {1: 3.0, 2: 1.0, 3: 4.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", default="6:7,8:4,8:5,8:6", help="calibrations as N:seed, comma separated")
    ap.add_argument("--frames", type=int, default=5, help="trapezoid frames timed")
    ap.add_argument("--aim", default="0.06,0.05", help="board centres off the camera's axis, x,y times the distance")
    args = ap.parse_args()
    aim = tuple(float(v) for v in args.aim.split(","))
    truth = RIGS["holdout-wide"].calibration
    t0 = time.perf_counter()
    gauge = render_session(gauge_scene(), n_bands=64, repeats=3, seed=1, frames=args.frames)
    board = render_session(PlaneScene(point=(0.0, 0.0, 426.0), tilt_deg=(6.0, -5.0)), n_bands=64, repeats=3, seed=2)
    tall = render_session(CompositeScene(tilt_deg=(4.0, -3.0), origin=(0.0, 0.0, 430.0), spheres=(),
                                         blocks=((-70.0, -25.0, -35.0, 25.0, 6.0), (35.0, -25.0, 70.0, 25.0, 15.0))),
                          n_bands=64, repeats=3, seed=3)
    t1 = time.perf_counter()
    tables = {k: hue_table_from_frames(c.white, c.bands, c.bands_block) for k, c in
              (("gauge", gauge), ("board", board), ("tall", tall))}
    t2 = time.perf_counter()
    print(f"rendering {t1 - t0:.1f} s; three hue tables {t2 - t1:.1f} s ({(t2 - t1) / 3:.2f} s each, 64 x 3 bands)")

    # the decoding alone: the rig's true calibration
    ref = oneshot_reference(gauge.reference, truth, gauge.block)
    res = measure_oneshot(gauge.frames[0], gauge.white, tables["gauge"], gauge.block, truth, ref)
    base = face_mask(gauge, 0) & res.valid
    errs = []
    for k, h0 in GAUGE.items():
        top = face_mask(gauge, k) & res.valid
        s = step_height_u(res.xyz[base], res.sigma[base], res.xyz[top], res.sigma[top])
        errs.append(f"{100 * (s['height_mm'] - h0) / h0:+.3f} (u {1e3 * s['u_mm']:.1f} um)")
    ok = res.valid & np.isfinite(gauge.truth_xyz).all(axis=-1)
    t = gauge.truth_xyz[ok]
    e = np.abs(np.einsum("ij,ij->i", res.xyz[ok] - t, t / np.linalg.norm(t, axis=-1, keepdims=True)))
    print("\ntrue calibration (the one-shot decoding alone)")
    print(f"  steps 3.0 / 1.0 / 4.0 mm error %: {' / '.join(errs)}")
    print(f"  |e_ray| <= 2 sigma: {np.mean(e <= 2 * res.sigma_ray[ok]):.3f} of {ok.sum()} px; median |e| "
          f"{1e3 * np.median(e):.1f} um, median sigma {1e3 * np.median(res.sigma_ray[ok]):.1f} um")
    print("  range in front / behind the base (mm, median [p05, p95]): " + ", ".join(
        f"{k} {v:.2f}" for k, v in ref.summary().items()))
    bref = oneshot_reference(board.reference, truth, board.block)
    bres = measure_oneshot(board.frames[0], board.white, tables["board"], board.block, truth, bref)
    m = face_mask(board, 0) & bres.valid
    f = flatness_as_reported(bres.xyz, bres.sigma, m)
    print(f"  board: FLTq {1e3 * f['rms_form_mm']:.1f} um (U {2e3 * f['u_rms_form_mm']:.1f}), raw RMS "
          f"{1e3 * f['rms_mm']:.1f} um, noise {1e3 * f['rms_noise_mm']:.1f} um, {f['n']} px")

    print("\ncalibrated rig | steps 3.0 / 1.0 / 4.0 mm: error % (U um) | truth inside U | |e_ray| <= 2u | "
          "board FLTq (U: form and calibration) um, raw RMS um | board FLTq (U) um inside the calibrated field, its share of the board | range front mm at 6 / 15 mm blocks | 6 mm top measured | 15 mm top flagged ORDER, measured")
    for case in args.poses.split(","):
        n, seed = (int(v) for v in case.split(":"))
        cal, jack, report = calibrated_rig_report(n_poses=n, seed=seed, aim=aim)
        field = field_mask(report.calibrated_field, gauge.labels.shape)
        ref = oneshot_reference(gauge.reference, cal, gauge.block)
        res = measure_oneshot(gauge.frames[0], gauge.white, tables["gauge"], gauge.block, cal, ref)
        st = step_scores(gauge, res, jack, GAUGE)
        px = pixel_scores(gauge, res, jack)
        bref = oneshot_reference(board.reference, cal, board.block)
        bres = measure_oneshot(board.frames[0], board.white, tables["board"], board.block, cal, bref)
        f = flatness_scores(board, bres, jack)
        fin = flatness_scores(board, bres, jack, within=field)
        share = fin["n"] / max(f["n"], 1)
        tref = oneshot_reference(tall.reference, cal, tall.block)
        tres = measure_oneshot(tall.frames[0], tall.white, tables["tall"], tall.block, cal, tref)
        tops = {k: face_mask(tall, k) & tref.valid for k in (1, 2)}
        fr = [float(np.nanmedian(tref.range_front_mm[tops[k]])) for k in (1, 2)]
        meas6 = float(tres.valid[tops[1]].mean())
        flag15 = float(np.mean((tres.coordinate.reasons[tops[2]] & Reason.ORDER) > 0))
        meas15 = int(tres.valid[tops[2]].sum())
        steps = " / ".join(f"{100 * s['relative_error']:+.3f} ({1e3 * s['U_mm']:.1f})" for s in st.values())
        inside = all(s["inside_U"] for s in st.values())
        print(f"holdout-wide {n} poses seed {seed}, aim {args.aim} | {steps} | {'yes' if inside else 'NO'} | {px['within_2u']:.3f} | "
              f"{1e3 * f['rms_form_mm']:.1f} ({1e3 * f['U_mm']:.1f}), {1e3 * f['rms_mm']:.1f} | "
              f"{1e3 * fin['rms_form_mm']:.1f} ({1e3 * fin['U_mm']:.1f}), {share:.2f} "
              f"(field {report.calibrated_field['image_fraction']:.2f} of the image) | {fr[0]:.2f} / {fr[1]:.2f} | {meas6:.3f} | {flag15:.3f}, {meas15} px")

    # per-frame compute of the one-shot rig path (640 x 480)
    cal, _ = calibrated_rig()
    ref = oneshot_reference(gauge.reference, cal, gauge.block)
    dec, tri = [], []
    for rgb in gauge.frames:
        a = time.perf_counter()
        ph = trapezoid_coordinate(rgb, gauge.white, tables["gauge"], gauge.block)
        co = absolute_from_reference(ph, ref, gauge.block, extent=cal.projector_size[0])
        b = time.perf_counter()
        triangulate(cal, co.coord, sigma_u=co.sigma, valid=co.valid, mode="u")
        c = time.perf_counter()
        dec.append(b - a)
        tri.append(c - b)
    d, tr = 1e3 * float(np.median(dec)), 1e3 * float(np.median(tri))
    print(f"\nper frame, 640 x 480, median of {len(dec)}: decode + order {d:.0f} ms, triangulation with sigma_u "
          f"{tr:.0f} ms, total {d + tr:.0f} ms")


if __name__ == "__main__":
    main()
