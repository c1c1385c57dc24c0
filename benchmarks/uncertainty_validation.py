"""Does the predicted height uncertainty hold? Coverage and step ratios on bench presets.

Usage: ./run python benchmarks/uncertainty_validation.py [--frames 5] [--presets demo flat dental ...] [--lateral-px 0] [--terms]

For each preset the bench writes a session, the whole chain measures it (the uncertainty maps
from the kernel's pass), and against the bench's ground truth it prints: the fraction of the
valid pixels with |error| <= 2u (target 0.95 +- 0.03), the rms error and rms u, and, for
sessions with a specimen, each step's std over the frames against the predicted independent
part of one frame's u (target ratio 0.7-1.4; with few frames the std is itself uncertain:
its relative standard error is about 1 / sqrt(2 (frames - 1))).

``--terms`` also measures each session with the lateral term off (u as it stands before it) and
prints, on the first frame's valid pixels, the median and 95th percentile of each term split from
that u by ``uncertainty.split_terms`` (the split gives the remainder, the edge floor's and the
texture term's part among it, to the noise term) and of the combined u (docs/uncertainty.md,
"Terms per pixel"), and the share of those pixels whose u the edge floor raised
(``uncertainty.edge_floor``; the first frame again through the NumPy reference chain, the kernel's
u bit for bit, with the floor's input and output compared; also the share of the pixels valid
before the step-edge mask).
"""

from __future__ import annotations

import argparse
import copy
import tempfile
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

from huefringe import bench, metrology, pipeline, stages, uncertainty
from huefringe.perframe import _measure
from huefringe.settings import load_config
from huefringe.huetable import HueTable
from huefringe.height import PlaneCalibration
from huefringe.session import load_session, read_rgb

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--presets", nargs="+", default=["demo", "flat", "dental", "plain_gauge", "photo_relief"])
    ap.add_argument("--lateral-px", type=float, default=None,
                    help="measurement.lateral_uncertainty_px (default: config.yaml's; 0 = the lateral term off)")
    ap.add_argument("--terms", action="store_true", help="also each term's median / p95 on the first frame, before the lateral term")
    ap.add_argument("--lateral-step-px", type=float, default=None,
                    help="measurement.lateral_step_px (default: config.yaml's; 0 = the lateral term's step part off)")
    args = ap.parse_args()
    cfg = load_config(REPO / "config.yaml")
    if args.lateral_px is not None:
        cfg["measurement"]["lateral_uncertainty_px"] = args.lateral_px
    if args.lateral_step_px is not None:
        cfg["measurement"]["lateral_step_px"] = args.lateral_step_px
    print(f"{'preset':8} {'|e|<=2u':>8} {'rms e mm':>9} {'rms u mm':>9} {'median u mm':>11}  coverage by zone; "
          "steps: std / independent u")
    with tempfile.TemporaryDirectory() as tmp:
        for preset in args.presets:
            bcfg = copy.deepcopy(bench.load_bench_config(bench.preset_path(preset)))
            bcfg["session"]["frames"] = args.frames
            bcfg.setdefault("phase_shift", {})["enabled"] = False
            session = bench.write_session(bcfg, Path(tmp) / preset)
            out = Path(tmp) / f"{preset}-out"
            p = stages.measure_session(session, out, cfg)
            s = p["session"]
            hs = [tifffile.imread(h) for h in p["heights"]]
            us = [tifffile.imread(u) for u in p["uncertainties"]]
            errs = [h.astype(np.float64) - tifffile.imread(s.ground_truth[n]) for h, n in zip(hs, s.frame_ids, strict=True)]
            rel = uncertainty.reliability(np.concatenate([e.ravel() for e in errs]), np.concatenate([u.ravel() for u in us]))
            # where the misses are: near a height edge of the truth, near a reflectance edge of the
            # white image (lens blur mixes colours there), or elsewhere
            truth = tifffile.imread(s.ground_truth[s.frame_ids[0]]).astype(np.float64)
            white = np.asarray(read_rgb(s.object_white), np.float64)
            white = white.mean(axis=-1) if white.ndim == 3 else white
            jump = ndimage.maximum_filter(truth, 7) - ndimage.minimum_filter(truth, 7) > 0.1
            lw = np.log(np.maximum(white / max(white.max(), 1e-9), 1e-3))
            texture = (ndimage.maximum_filter(lw, 7) - ndimage.minimum_filter(lw, 7) > np.log(1.5)) & ~jump
            zones = {"edge": jump, "texture": texture, "rest": ~jump & ~texture}
            cov = {}
            for name, m in zones.items():
                e = np.concatenate([x[m] for x in errs])
                uu = np.concatenate([x[m] for x in us])
                ok = np.isfinite(e) & np.isfinite(uu)
                cov[name] = (float(np.mean(np.abs(e[ok]) <= 2 * uu[ok])) if ok.any() else float("nan"), int(ok.sum()))
            line = (f"{preset:8} {rel['coverage_2u']:8.3f} {rel['rms_error_mm']:9.4f} {rel['rms_u_mm']:9.4f} "
                    f"{rel['median_u_mm']:11.4f}  " + " ".join(f"{k} {v[0]:.3f} ({v[1] / len(errs):.0f} px)"
                                                         for k, v in cov.items()))
            if s.specimen:
                method = metrology.evaluate_session(hs, s.specimen, s.pixel_pitch_mm,
                                                    range_mm=max(s.planes_mm) - min(s.planes_mm),
                                                    edge_exclusion=cfg["metrology"]["edge_exclusion"])
                stages.add_step_uncertainty(method, hs, us, s.specimen, s.pixel_pitch_mm,
                                              PlaneCalibration.load(str(out / "model.npz")),
                                              HueTable.load(out / "table_object.json"),
                                              edge_exclusion=cfg["metrology"]["edge_exclusion"],
                                              denoise_radius=cfg["measurement"]["denoise_radius"],
                                              supports=[tifffile.imread(x) for x in p["supports"]],
                                              lateral_px=cfg["measurement"]["lateral_uncertainty_px"],
                                              lateral_step_px=cfg["measurement"]["lateral_step_px"])
                parts = []
                for st in method["steps"]:
                    ind = st["uncertainty_budget"]["independent_per_frame_mm"]
                    parts.append(f"{st['name']} {st['std_mm']:.4f}/{ind:.4f}={st['std_mm'] / ind:.2f} "
                                 f"(error {st['error_mm']:+.4f}, U {st['U_mm']:.4f}, {st['conformance']})")
                line += "  " + "; ".join(parts)
            print(line, flush=True)
            if args.terms:
                print("  " + _terms(session, Path(tmp) / f"{preset}-terms", cfg), flush=True)


def _terms(session: Path, out: Path, cfg: dict) -> str:
    """Each term's median / p95 (mm) on the first frame, split from u before the lateral term."""
    c = copy.deepcopy(cfg)
    c["measurement"]["lateral_uncertainty_px"] = 0.0
    c["measurement"]["lateral_step_px"] = 0.0
    p = stages.measure_session(session, out, c)
    h = tifffile.imread(p["heights"][0]).astype(np.float64)
    u = tifffile.imread(p["uncertainties"][0]).astype(np.float64)
    cal = PlaneCalibration.load(str(out / "model.npz"))
    terms = uncertainty.split_terms(u, h, cal.a, cal.b,
                                    uncertainty.pixel_budget(HueTable.load(out / "table_object.json"), cal))
    ok = np.isfinite(u) & np.isfinite(h)
    cells = []
    for name, v in [*terms.items(), ("combined", u)]:
        x = np.asarray(v, np.float64)[ok]
        x = x[np.isfinite(x)]
        cells.append(f"{name} {np.median(x):.4f} / {np.percentile(x, 95):.4f}")
    raised, before, same = _edge_floor_share(session, out, c, u)
    return ("terms, first frame, before the lateral term (median / p95 mm): " + "; ".join(cells)
            + f"; the edge floor raises u on {raised:.1%} of these pixels ({before:.1%} of the pixels valid "
            "before the step-edge mask; the reference chain's u " + ("is the kernel's, bit for bit)" if same
                                                                     else "DIFFERS from the kernel's)"))


def _edge_floor_share(session: Path, out: Path, cfg: dict, u_kernel: np.ndarray) -> tuple[float, float, bool]:
    """The first frame through the reference chain, ``edge_floor``'s input and output compared: the
    share of the delivered valid pixels it raised, and of the pixels valid where it runs (before
    the step-edge mask); and whether the chain's u is the kernel's (``u_kernel``)."""
    s = load_session(session)
    meas = copy.deepcopy(cfg["measurement"])
    meas["kernel"] = False
    rec: dict = {}
    real = _measure.edge_floor

    def recorder(height, valid, u):
        before = np.array(u, copy=True)
        res = real(height, valid, u)
        rec.update(raised=np.asarray(valid, bool) & (res > before), valid=np.array(valid, bool))
        return res

    _measure.edge_floor = recorder
    try:
        fp = pipeline.prepare_frames(s, HueTable.load(out / "table_object.json"),
                                     PlaneCalibration.load(str(out / "model.npz")), cfg["hue_model"], meas,
                                     reader=pipeline.session_corrections(s, str(out / "camera.json"))[1])
        r = pipeline.measure_one(fp, s.frame_ids[0])
    finally:
        _measure.edge_floor = real
    same = bool(np.array_equal(r.uncertainty, u_kernel.astype(np.float32), equal_nan=True))
    ok = np.isfinite(r.height)
    return float(np.mean(rec["raised"][ok])), float(np.mean(rec["raised"][rec["valid"]])), same


if __name__ == "__main__":
    main()
