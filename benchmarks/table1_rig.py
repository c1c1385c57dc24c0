"""The paper's Table 1 on a calibrated rig: one-shot trapezoid vs three-step phase shifting under vibration.

Usage: ./run python benchmarks/table1_rig.py [--periods 36,24,12] [--frames 30] [--amplitude 0.03]
       [--poses 8:4] [--json OUT]

The paper's Table 1 compares, over 30 frames of a blue 1.0 mm gauge block on a vibrating membrane,
the standard deviation (sigma %) and the average error (mean |h - nominal|, e %) of the step at
several fringe periods, for the one-shot trapezoidal method and three-step phase shifting. Here
the same comparison is made on the holdout-wide bench rig calibrated from board poses
(huefringe.bench.oneshot.calibrated_rig, N poses of seed S), both methods triangulated with that
calibration:

* the scene: the paper's Fig. 9 gauge blocks (green 3.0, blue 1.0, red 4.0 mm; the blue step is
  scored) on the tilted base plane, vibrating along the base's normal as the capture demo's
  membrane (amplitude --amplitude mm at 29 Hz, phase 0.4 rad, frames at 60 frames/s, 3.5 ms
  exposure averaged over 3 instants); the projector coordinates of the moving scene are the still
  scene's plus the displacement times their derivative along the normal (exact to well under
  1e-4 px at these amplitudes);
* the order reference and the hue table: the session's coded blocks (8-step phase of 16 px and
  Gray code along x, grey) and 48 x 2 hue bands with a white frame, captured on the still scene
  (huefringe.rig.oneshot.oneshot_reference, hue_table_from_frames);
* one-shot: one trapezoid frame of period P per instant (frame k at t = k / 60 s), decoded by
  huefringe.rig.oneshot.trapezoid_coordinate, its order from the reference;
* three-step: three grey sinusoids of period P shifted by 2 pi / 3, captured at three consecutive
  instants (triple k at t = 3k / 60, (3k + 1) / 60, (3k + 2) / 60 s), the wrapped phase
  atan2(sqrt 3 (I1 - I3), 2 I2 - I1 - I3), its order from the same reference;
* both: triangulated with the calibration (huefringe.rig.triangulate, the ray against the projector
  plane of the coordinate); the blue step (huefringe.metrology.step_height_u) of the block's top
  (eroded 6 px) over the base around it.

The bench projector and camera are linear (no gamma) with 1 DN of read noise, 8-bit, 5 % ambient,
the demo camera's channel crosstalk for the colour frames; the grey frames see each surface's
mean albedo.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from huefringe.bench.oneshot import CROSSTALK, GAUGE_BLOCKS, _albedo, calibrated_rig, gauge_scene, reference_spec
from huefringe.bench.rig import RIGS, CompositeScene
from huefringe.bench.scenes import BLOCK_COLOURS
from huefringe.codecs import DecodeOptions, decode_sequence, generate, generate_rgb
from huefringe.codecs.sequence import FlatBlock, HueBandsBlock, SequenceSpec, TrapezoidBlock
from huefringe.metrology import step_height_u
from huefringe.rig.oneshot import (OneShotPhase, absolute_from_reference, hue_table_from_frames, oneshot_reference,
                                   trapezoid_coordinate)
from huefringe.rig.triangulation import triangulate

F64 = NDArray[np.float64]
BLUE = 2
PAPER = {100: (1.29, 1.05, 3.69, 3.17), 80: (1.33, 1.20, 3.72, 3.14), 60: (1.38, 1.28, 3.78, 3.25),
         40: (1.57, 1.69, 3.85, 3.34), 20: (1.94, 1.98, 3.93, 3.37)}
"""The paper's Table 1 (camera px at 0.2 mm): one-shot sigma %, e %, three-step sigma %, e %."""


def erode(m: NDArray[np.bool_], px: int) -> NDArray[np.bool_]:
    return cv2.erode(m.astype(np.uint8), np.ones((2 * px + 1, 2 * px + 1), np.uint8)).astype(bool)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--periods", default="36,24,12", help="fringe periods, projector px, comma separated")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--amplitude", type=float, default=0.03, help="vibration amplitude, mm")
    ap.add_argument("--poses", default="8:4", help="the calibration: N:seed")
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    t0 = time.perf_counter()
    rig = RIGS["holdout-wide"]
    pw, ph = rig.projector_size
    n_poses, seed = (int(x) for x in args.poses.split(":"))
    cal, _ = calibrated_rig("holdout-wide", n_poses, seed)
    rng = np.random.default_rng(2011)

    # the still scene, and the projector coordinate's derivative along the base's normal
    scene = gauge_scene()
    xyz, seen, labels = scene.cast(rig.rays)
    lit = scene.lit(rig, xyz, seen)
    m0 = rig.coordinates(xyz, lit, rng, 0.0)
    R, o = scene.frame()
    step = 0.1
    moved = CompositeScene(tilt_deg=scene.tilt_deg, origin=tuple(o + step * R[:, 2]), blocks=scene.blocks, spheres=())
    x1, s1, l1 = moved.cast(rig.rays)
    m1 = rig.coordinates(x1, moved.lit(rig, x1, s1), rng, 0.0)
    valid = m0["valid"] & m1["valid"] & (l1 == labels)
    u0 = np.where(valid, m0["u_true"], np.nan)
    v0 = np.where(valid, m0["v_true"], np.nan)
    du, dv = (m1["u_true"] - m0["u_true"]) / step, (m1["v_true"] - m0["v_true"]) / step
    print(f"projector px per mm along the normal: u {np.nanmedian(np.abs(du[valid])):.3f}, v {np.nanmedian(np.abs(dv[valid])):.3f}")
    colours = {k + 1: BLOCK_COLOURS[c] for k, (_, c) in enumerate(GAUGE_BLOCKS)}
    alb = _albedo(labels, colours)
    grey_alb = alb.mean(axis=-1)

    def at(d: float) -> tuple[F64, F64]:
        return u0 + d * du, v0 + d * dv

    def disp(t: float) -> F64:   # the exposure's instants about t
        inst = t + (np.arange(3) + 0.5 - 1.5) / 3 * 3.5e-3
        return args.amplitude * np.sin(2 * np.pi * 29.0 * inst + 0.4)

    def grey(pattern: NDArray[Any], t: float) -> F64:   # the grey pattern on every primary: the signal of rig.capture
        return colour(np.repeat(pattern[..., None], 3, axis=-1), t, grey_alb, None)[..., 0]

    def colour(pattern: NDArray[Any], t: float, albedo: F64 = alb, mix: F64 | None = CROSSTALK) -> F64:
        sig = 0.0
        for d in disp(t):   # the exposure's mean signal, noiseless
            u, v = at(float(d))
            sig = sig + rig.capture_rgb([pattern], np.nan_to_num(u, nan=-10), np.nan_to_num(v, nan=-10), valid, rng,
                                        albedo=albedo, ambient=0.05, crosstalk=mix, signal_only=True)[0]
        return sig / 3

    def noisy(sig: F64) -> F64:
        return np.clip(np.rint(sig + rng.normal(0.0, 1.0, sig.shape)), 0, 255)

    # the reference (coded blocks) and the hue table, on the still scene
    uu, vv = np.nan_to_num(u0, nan=-10), np.nan_to_num(v0, nan=-10)
    rspec = reference_spec(pw, ph, "x", 16.0, 8)
    imgs = rig.capture(generate(rspec), uu, vv, valid, rng, noise_dn=1.0, ambient=0.05, albedo=grey_alb)
    decoded = decode_sequence(list(imgs), rspec, DecodeOptions.from_config())["x"]
    bands_block = HueBandsBlock(48, 2)
    distinct = generate_rgb(SequenceSpec((FlatBlock("white"), HueBandsBlock(48)), pw, ph))
    pats = [distinct[0]] + [distinct[1 + i] for i in range(48) for _ in range(2)]
    cap = rig.capture_rgb(pats, uu, vv, valid, rng, albedo=alb, ambient=0.05, noise_dn=1.0,
                          crosstalk=CROSSTALK).astype(np.float32) / 255.0
    white, bands = cap[0], cap[1:]
    table = hue_table_from_frames(white, bands, bands_block)

    top = erode((labels == BLUE) & valid, 6)
    rows, cols = np.nonzero(top)
    around = np.zeros_like(top)
    around[max(rows.min() - 60, 0):rows.max() + 61, max(cols.min() - 60, 0):cols.max() + 61] = True
    base = erode((labels == 0) & valid, 6) & around
    need = top | base
    print(f"blue top {int(top.sum())} px, base around it {int(base.sum())} px; set-up {time.perf_counter() - t0:.1f} s")

    def blue_step(coord: F64, sigma: F64, ok: NDArray[np.bool_]) -> float:
        use = need & ok
        t = triangulate(cal, np.where(use, coord, np.nan), sigma_u=np.where(use, sigma, np.nan), valid=use, mode="u")
        b, tp = base & t.valid, top & t.valid
        return float(step_height_u(t.xyz[b], t.sigma[b], t.xyz[tp], t.sigma[tp])["height_mm"])

    rows_out = []
    for period in (float(p) for p in args.periods.split(",")):
        t1 = time.perf_counter()
        block = TrapezoidBlock("x", period, 0.0, 1)
        ref = oneshot_reference(decoded, cal, block)
        trap = generate_rgb(SequenceSpec((FlatBlock("white"), HueBandsBlock(2), block), pw, ph))[-1]
        ps = generate(_phase_spec(pw, ph, period))
        conv = _phase_convention(ps, period)
        one, three = [], []
        for k in range(args.frames):
            rgb = noisy(colour(trap, k / 60.0)) / 255.0
            ph1 = trapezoid_coordinate(rgb, white, table, block)
            co = absolute_from_reference(ph1, ref, block, stands_on_reference=False)
            one.append(blue_step(co.coord, co.sigma, co.valid))
            i1, i2, i3 = (noisy(grey(ps[j], (3 * k + j) / 60.0)) for j in range(3))
            w, sig = _three_step(i1, i2, i3, period, conv)
            ok = np.isfinite(w) & valid
            phase = OneShotPhase(np.where(ok, w, np.nan), np.where(ok, sig, np.nan), ok, np.zeros(ok.shape, np.uint8),
                                 np.zeros(ok.shape, np.float32))
            co3 = absolute_from_reference(phase, ref, block, stands_on_reference=False)
            three.append(blue_step(co3.coord, co3.sigma, co3.valid))
        row = {"period_px": period}
        for name, h in (("oneshot", np.asarray(one)), ("three_step", np.asarray(three))):
            row[name] = {"sigma_pct": float(100 * np.std(h, ddof=1)), "mean_abs_error_pct": float(100 * np.mean(np.abs(h - 1.0))),
                         "mean_error_pct": float(100 * (h.mean() - 1.0)), "per_frame_mm": h.tolist()}
        row["seconds"] = time.perf_counter() - t1
        rows_out.append(row)
        print(f"P = {period:g} px: one-shot sigma {row['oneshot']['sigma_pct']:.3f} %, e {row['oneshot']['mean_abs_error_pct']:.3f} % "
              f"(mean {row['oneshot']['mean_error_pct']:+.3f} %); three-step sigma {row['three_step']['sigma_pct']:.3f} %, "
              f"e {row['three_step']['mean_abs_error_pct']:.3f} % (mean {row['three_step']['mean_error_pct']:+.3f} %); "
              f"{row['seconds']:.1f} s", flush=True)
    print()
    print(f"| period (projector px) | fringe on the base (mm) | one-shot σ % | one-shot ē % | three-step σ % | three-step ē % |")
    print("| ---: | ---: | ---: | ---: | ---: | ---: |")
    mm_per_px = 1.0 / np.nanmedian(np.abs(np.gradient(u0, axis=1)[(labels == 0) & valid])) * _pitch_mm(xyz, labels, valid)
    for r in rows_out:
        print(f"| {r['period_px']:g} | {r['period_px'] * mm_per_px:.1f} | {r['oneshot']['sigma_pct']:.3f} | "
              f"{r['oneshot']['mean_abs_error_pct']:.3f} | {r['three_step']['sigma_pct']:.3f} | "
              f"{r['three_step']['mean_abs_error_pct']:.3f} |")
    print(f"\ntotal {time.perf_counter() - t0:.1f} s")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"args": vars(args), "rows": rows_out, "paper": PAPER}, f, indent=1)


def _phase_spec(pw: int, ph: int, period: float) -> SequenceSpec:
    from huefringe.codecs import sequence_from_mapping

    return sequence_from_mapping({"projector": {"width": pw, "height": ph},
                                  "blocks": [{"phase": {"axis": "x", "period_px": period, "steps": 3}}]}, "<bench>", ".")


def _wrapped(i1: F64, i2: F64, i3: F64) -> F64:
    return np.arctan2(np.sqrt(3.0) * (i1 - i3), 2 * i2 - i1 - i3)


def _phase_convention(ps: NDArray[Any], period: float) -> tuple[float, float]:
    """Sign and offset that turn the three-step phase into ``(u - origin) mod P`` of the patterns'
    own columns (projector pixels hold their value at their centres)."""
    a = [p[0].astype(np.float64) for p in ps[:3]]
    x = np.arange(a[0].size, dtype=np.float64)
    phi = _wrapped(*a)
    best = (1.0, 0.0, np.inf)
    for sign in (1.0, -1.0):
        w = np.mod(sign * phi * period / (2 * np.pi), period)
        off = float(np.angle(np.mean(np.exp(2j * np.pi * (x - w) / period))) * period / (2 * np.pi))
        r = np.angle(np.exp(2j * np.pi * (x - w - off) / period)) * period / (2 * np.pi)
        if np.sqrt(np.mean(r**2)) < best[2]:
            best = (sign, off, float(np.sqrt(np.mean(r**2))))
    if best[2] > 0.05 * period:
        raise RuntimeError(f"three-step phase convention not found (residual {best[2]:.3f} px)")
    return best[0], best[1]


def _three_step(i1: F64, i2: F64, i3: F64, period: float, conv: tuple[float, float]) -> tuple[F64, F64]:
    """``(u mod P)`` of three 2 pi / 3 shifted captures and its standard uncertainty (1 DN of noise):
    ``sigma_phi = sigma sqrt(2 / 3) / B``, ``B`` the modulation."""
    sign, off = conv
    phi = _wrapped(i1, i2, i3)
    b = np.sqrt(3 * (i1 - i3) ** 2 + (2 * i2 - i1 - i3) ** 2) / 3.0
    ok = b > 5.0
    w = np.mod(sign * phi * period / (2 * np.pi) + off, period)
    sig = np.sqrt(2.0 / 3.0) / np.maximum(b, 1e-9) * period / (2 * np.pi)
    return np.where(ok, w, np.nan), np.where(ok, sig, np.nan)


def _pitch_mm(xyz: F64, labels: NDArray[np.int64], valid: NDArray[np.bool_]) -> float:
    """Median distance between horizontally neighbouring camera pixels' points on the base (mm)."""
    d = np.linalg.norm(np.diff(xyz, axis=1), axis=-1)
    m = ((labels == 0) & valid)[:, 1:] & ((labels == 0) & valid)[:, :-1]
    return float(np.median(d[m]))


if __name__ == "__main__":
    main()
