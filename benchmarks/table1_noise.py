"""Table 1's frame-to-frame noise on the blue top, pixel by pixel, against the uncertainty's noise term.

Usage: ./run python benchmarks/table1_noise.py [--periods 100 80 60 40 20] [--hue]

Reads what ``./run snakemake --cores 2 table1`` wrote (``results/table1-pNN/``: heights,
uncertainty and support maps, the calibration; ``resources/table1/table1-pNN/``: the frames and
the bench's truth). On the evaluated top box of the blue step, per pixel: the temporal standard
deviation over the 30 frames of the error ``e = h - truth`` (the truth follows the membrane)
against the noise term of the written u (``uncertainty.split_terms`` after the lateral term is
taken out, as the step budget does; rms over the frames), its median over the box and by the
filter's mean support (169 = the full 13 x 13 window of the adaptive pass; fewer: neighbours
rejected). ``--hue``: per column of the box (every second), the hue's temporal spread against
the table's pooled figure (``perframe.capture_noise``) and the frame's own one
(``perframe.frame_hue_noise``, mean over the frames), the code phase, and the same ratio for the
unfiltered heights (``perframe.measure_frame`` with ``denoise_radius = 0``). 20-60 s per period.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import tifffile

from huefringe.colour import hue as hue_of
from huefringe.colour import white_balance, white_gains
from huefringe.height import PlaneCalibration
from huefringe.huetable import HueTable
from huefringe.perframe import capture_noise, frame_hue_noise, measure_frame
from huefringe.session import load_session, read_rgb
from huefringe.settings import load_config
from huefringe.uncertainty import pixel_budget
from huefringe.uncertainty.frame import lateral_term, split_terms

SUPPORT_BINS = ((168, 170), (160, 168), (150, 160), (0, 150))


def _circ_std(a: np.ndarray) -> np.ndarray:
    d = np.angle(np.exp(1j * (a - np.nanmedian(a, axis=0))))
    return np.nanstd(d, axis=0, ddof=1)


def period(p: int, cfg: dict, hue: bool) -> None:
    res, ses = f"results/table1-p{p}", f"resources/table1/table1-p{p}"
    step = json.load(open(f"{res}/metrology/report.json"))["steps"][0]
    u0, v0, u1, v1 = step["evaluated_roi"]
    box = (slice(v0, v1), slice(u0, u1))
    cal = PlaneCalibration.load(f"{res}/calib/phase_to_height.npz")
    table = HueTable.load(f"{res}/calib/table_object.json")
    bud = pixel_budget(table, cal)
    s = load_session(ses)
    ids = s.frame_ids
    meas = cfg["measurement"]
    err, noise, sup = [], [], []
    for n in ids:
        h = tifffile.imread(f"{res}/height/frame_{n:04d}.tiff").astype(np.float64)
        u = tifffile.imread(f"{res}/uncertainty/frame_{n:04d}.tiff").astype(np.float64)
        lat = lateral_term(h.astype(np.float32), u.astype(np.float32), lateral_px=meas["lateral_uncertainty_px"],
                           step_px=meas["lateral_step_px"]).astype(np.float64)
        terms = split_terms(np.sqrt(np.maximum(u**2 - lat**2, 0.0)), h, cal.a, cal.b, bud)
        truth = tifffile.imread(s.ground_truth[n]).astype(np.float64)
        err.append((h - truth)[box])
        noise.append(terms["noise"][box])
        sup.append(tifffile.imread(f"{res}/support/frame_{n:04d}.tiff")[box].astype(np.float64))
    err, noise, sup = np.array(err), np.array(noise), np.array(sup)
    ratio = np.nanstd(err, axis=0, ddof=1) / np.sqrt(np.nanmean(noise**2, axis=0))
    ms = sup.mean(axis=0)
    parts = []
    for lo, hi in SUPPORT_BINS:
        m = (ms >= lo) & (ms < hi) & np.isfinite(ratio)
        if m.any():
            parts.append(f"{lo}-{hi - 1}: {m.mean():.2f} of the box, {np.median(ratio[m]):.2f}")
    bud_step = step["uncertainty_budget"]
    print(f"| {p} | {step['std_mm'] * 1e3:.2f} | {bud_step['independent_per_frame_mm'] * 1e3:.2f} "
          f"| {np.nanmedian(ratio):.2f} | {'; '.join(parts)} |")
    if not hue:
        return
    white = np.asarray(read_rgb(s.object_white), np.float32)
    gains = white_gains(white)
    hues, codes, owns, raw_h, raw_n = [], [], [], [], []
    for n in ids:
        rgb = np.asarray(read_rgb(s.frames[n]), np.float32)
        hh = hue_of(white_balance(rgb, white), cfg["hue_model"], min_saturation=meas["min_saturation"])
        emitted, _ = table.to_phase_and_slope(hh)
        codes.append((emitted if s.predistortion is None else s.predistortion.decode(emitted))[box])
        hues.append(hh[box])
        owns.append(frame_hue_noise(table, rgb, gains, cfg["hue_model"])[box])
        r = measure_frame(rgb, white, table, cal, hue_model=cfg["hue_model"], min_saturation=meas["min_saturation"],
                          unwrap_mode=meas["unwrap"], denoise_radius=0, predistortion=s.predistortion, budget=bud)
        raw_h.append((r.height.astype(np.float64) - tifffile.imread(s.ground_truth[n]))[box])
        raw_n.append(split_terms(r.uncertainty, r.height, cal.a, cal.b, bud)["noise"][box])
    hs, pooled, own = _circ_std(np.array(hues, np.float64)), capture_noise(table)[box], np.nanmean(owns, axis=0)
    code = np.nanmedian(np.array(codes, np.float64), axis=0)
    raw = np.nanstd(np.array(raw_h), axis=0, ddof=1) / np.sqrt(np.nanmean(np.array(raw_n) ** 2, axis=0))
    print(f"\n{p} px, per column of the top: | column | code phase rad | hue spread rad | pooled | own | "
          "unfiltered std / noise term | filtered |")
    for j in range(0, u1 - u0, 2):
        print(f"| {u0 + j} | {np.nanmedian(code[:, j]):.2f} | {np.nanmedian(hs[:, j]):.4f} | {np.median(pooled[:, j]):.4f} "
              f"| {np.nanmedian(own[:, j]):.4f} | {np.nanmedian(raw[:, j]):.2f} | {np.nanmedian(ratio[:, j]):.2f} |")
    print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--periods", type=int, nargs="+", default=[100, 80, 60, 40, 20])
    ap.add_argument("--hue", action="store_true")
    args = ap.parse_args()
    cfg = load_config("config.yaml")
    print("| period px | step std um | budget's independent part um | per-pixel std / noise term, median "
          "| by the filter's mean support |")
    print("| ---: | ---: | ---: | ---: | --- |")
    for p in args.periods:
        period(p, cfg, args.hue)


if __name__ == "__main__":
    main()
