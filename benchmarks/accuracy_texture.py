"""Accuracy on textured surfaces (issue 24): the accuracy matrix as the texture branch measured it.

The same cases as accuracy_matrix.py plus issue 24's texture cases (--texture, --holdout); kept
beside accuracy_matrix.py (which has the camera cases) until the two are folded into one script.

Usage: ./run python benchmarks/accuracy_texture.py [--cases NAME ...] [--tuning] [--variants NAME ...] [--keep DIR]

Each case is a bench preset plus overrides (plain and pre-distorted projection, periods 20-64 px,
defocus 0.5-2 camera px, 64/96/256 bands x 1-3 repeats, per-channel gamma 1.8-2.5, crosstalk,
multi-colour coatings with dark ones, a relief printed with a real photograph, 8 and 16 bit,
vibration). Cases marked HOLD-OUT were never looked at while choosing the methods' settings:
they only score. Every case is measured with the workflow's stages (``hue_table`` once per case,
then ``plane_calibration`` and ``measure_frames`` per variant, as ``stages.measure_session``)
under the variants in ``VARIANTS``; errors are against the bench's ground truth (which only
scores), averaged over the frames; ``coverage`` is the valid fraction of the pixels where the
ground truth is defined (lit, unshadowed); gauge-block cases also print the worst step error
(um) and the mean |step error| (%) from ``metrology.evaluate_session``. About 10 min on a
shared 2-core machine (6.2 min tuning, 4.3 min hold-outs at load 6-9).
"""

from __future__ import annotations

import argparse
import copy
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile
import yaml
from scipy import ndimage

from huefringe import bench, metrology, stages
from huefringe.session import read_rgb
from huefringe.settings import load_config
from huefringe.height import accuracy

REPO = Path(__file__).resolve().parents[1]


def _case(preset: str, holdout: bool = False, **over: dict) -> dict:
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path(preset)))
    for section, values in over.items():
        cfg[section].update(values)
    return {"cfg": cfg, "holdout": holdout}


#: issue 24's photographed reliefs and tooth: one repeat, 16 bit, plain pattern
_TEX = {"period_px": 56, "hue_bands": 72, "repeats": 1, "bit_depth": 16, "frames": 2}
_TOOTH = {"period_px": 64, "hue_bands": 128, "repeats": 1, "bit_depth": 16, "frames": 2}

CASES = {
    # tuning set
    "flat p40 d1.6 96x2": _case("flat", session={"period_px": 40, "hue_bands": 96, "repeats": 2, "frames": 2},
                                projector={"defocus_sigma_px": 1.6}),
    "gauge plain p48 96x2 16bit": _case("plain_gauge"),
    "photo astronaut p48 96x2": _case("photo_relief"),
    "demo (pre-distorted) p60": _case("demo", session={"frames": 2}, phase_shift={"enabled": False}),
    # hold-out: only scores
    "flat p20 d0.5 256x1 8bit": _case("flat", True, session={"period_px": 20, "hue_bands": 256, "repeats": 1,
                                                             "frames": 2, "width": 320, "height": 240},
                                      projector={"defocus_sigma_px": 0.5, "gamma": [1.8, 2.5, 2.1]}),
    "gauge plain p64 d2.0 64x3 8bit": _case("plain_gauge", True, session={"period_px": 64, "hue_bands": 64, "repeats": 3,
                                                                            "bit_depth": 8, "seed": 99},
                                            projector={"defocus_sigma_px": 2.0, "gamma": [2.4, 1.9, 2.2]}),
    "photo coffee p40 d0.8 256x3": _case("photo_relief", True, session={"period_px": 40, "hue_bands": 256,
                                                                         "repeats": 3, "seed": 5},
                                         projector={"defocus_sigma_px": 0.8, "gamma": [2.5, 2.0, 1.8]},
                                         scene={"image": "coffee"}),
    "gauge pre-distorted p40 d1.2": _case("plain_gauge", True, session={"period_px": 40, "seed": 7},
                                          projector={"compensation": {"enabled": True}}),
    # issue 24: colour-textured and freeform surfaces as others capture them (plain pattern, one
    # repeat, 16 bit). The hold-outs were fixed here before any setting was tuned.
    "tex astronaut p56 72x1": _case("photo_relief", session=_TEX),
    "tex chelsea p56 72x1": _case("photo_relief", session={**_TEX, "seed": 21}, scene={"image": "chelsea"}),
    "tex dental two-tone p64 128x1": _case("dental", session=_TOOTH, projector={"compensation": {"enabled": False}}),
    "tex gauge plain p40 96x2": _case("plain_gauge", session={"period_px": 40, "seed": 31}),
    "tex rocket p56 72x1": _case("photo_relief", True, session={**_TEX, "seed": 41}, scene={"image": "rocket"}),
    "tex immunohistochemistry p56 72x1": _case("photo_relief", True, session={**_TEX, "seed": 43},
                                               scene={"image": "immunohistochemistry"}),
    "tex coffee p48 72x1 blur1.1": _case("photo_relief", True, session={**_TEX, "period_px": 48, "seed": 45},
                                         camera={"lens_blur_sigma_px": 1.1}, scene={"image": "coffee"}),
    "tex dental two-tone p56 128x1 seed": _case("dental", True, session={**_TOOTH, "period_px": 56, "seed": 47},
                                                projector={"compensation": {"enabled": False}}),
    "tex gauge plain p56 72x1": _case("plain_gauge", True, session={"period_px": 56, "hue_bands": 72, "repeats": 1,
                                                                    "seed": 49}),
}

#: name -> changes to config.yaml's calibration / measurement sections
VARIANTS = {
    "all on": {},
    "phase-error table off": {"calibration": {"phase_error": {"enabled": False}}},
    # the variants below apply the table without the leave-one-plane-out test (it decided "apply"
    # on every case of "all on"; skipping it saves its time)
    "edge mask off": {"calibration": {"phase_error": {"enabled": True}}, "measurement": {"edge_jump_mm": 0.0}},
    "adaptive filter off": {"calibration": {"phase_error": {"enabled": True}},
                            "measurement": {"denoise_adaptive": {"enabled": False}}},
    "round 1 (sharp table, no edge mask)": {"calibration": {"phase_error": {"enabled": True, "smooth_bins": 1.5}},
                                            "measurement": {"edge_jump_mm": 0.0}},
}
VARIANTS.update({
    "texture blur 0.81 (true)": {"calibration": {"texture_blur_px2": 0.81}},
    "texture blur 0.81, edge mask off": {"calibration": {"texture_blur_px2": 0.81}, "measurement": {"edge_jump_mm": 0.0}},
    "texture blur 1.2": {"calibration": {"texture_blur_px2": 1.2}},
    "texture blur 1.6": {"calibration": {"texture_blur_px2": 1.6}},
    "texture correction off": {"calibration": {"texture_blur_px2": 0}},
})
#: variants measured on some cases only (the adaptive filter acts on weak signal: the photo reliefs)
ONLY = {"adaptive filter off": "photo"}


def _config(variant: dict) -> dict:
    cfg = load_config(REPO / "config.yaml")
    for section, values in variant.items():
        for k, v in values.items():
            cfg[section][k] = {**cfg[section].get(k, {}), **v} if isinstance(v, dict) else v
    return cfg


def zones(truth: np.ndarray, white: np.ndarray) -> dict[str, np.ndarray]:
    """benchmarks/uncertainty_validation.py's zones: "edge" within 3 px of a change of the true
    height by more than 0.1 mm, "texture" within 3 px of a reflectance change by more than 1.5 x in
    the white image (not edge), "rest" the others."""
    white = white.mean(axis=-1) if white.ndim == 3 else white
    jump = ndimage.maximum_filter(truth, 7) - ndimage.minimum_filter(truth, 7) > 0.1
    lw = np.log(np.maximum(white / max(white.max(), 1e-9), 1e-3))
    texture = (ndimage.maximum_filter(lw, 7) - ndimage.minimum_filter(lw, 7) > np.log(1.5)) & ~jump
    return {"edge": jump, "texture": texture, "rest": ~jump & ~texture}


def score(paths: dict) -> dict:
    s = paths["session"]
    maps = [tifffile.imread(h) for h in paths["heights"]]
    truths = [tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids]
    accs = [accuracy(m, t) for m, t in zip(maps, truths, strict=True)]
    out = {k: float(np.mean([a[k] for a in accs])) for k in ("median_abs_mm", "p95_abs_mm", "coverage")}
    if paths.get("uncertainties"):  # |error| <= 2u over the valid pixels, and by zone
        us = [tifffile.imread(u).astype(np.float64) for u in paths["uncertainties"]]
        zs = zones(np.where(np.isfinite(truths[0]), truths[0], 0.0), np.asarray(read_rgb(s.object_white), np.float64))
        errs = [m.astype(np.float64) - t for m, t in zip(maps, truths, strict=True)]
        for zname, zm in {"all": None, **zs}.items():
            e = np.concatenate([(x if zm is None else x[zm]).ravel() for x in errs])
            uu = np.concatenate([(x if zm is None else x[zm]).ravel() for x in us])
            ok = np.isfinite(e) & np.isfinite(uu)
            out[f"cov2u_{zname}"] = float(np.mean(np.abs(e[ok]) <= 2 * uu[ok])) if ok.any() else float("nan")
    if s.specimen is not None:
        try:
            ev = metrology.evaluate_session(maps, s.specimen, s.pixel_pitch_mm, range_mm=max(s.planes_mm) - min(s.planes_mm))
        except metrology.MetrologyError as exc:
            print(f"  (steps not evaluated: {exc})")
            return out
        errs = [st["error_mm"] for st in ev["steps"]]
        out["step_worst_um"] = 1e3 * float(np.max(np.abs(errs)))
        out["step_mean_pct"] = float(np.mean([abs(st["error_pct"]) for st in ev["steps"]]))
    return out


def measure(session: Path, tables: Path, out: Path, config: dict) -> dict:
    """``stages.measure_session`` with the hue tables of ``tables`` (built once per case: the variants
    change only the plane calibration and the per-frame chain)."""
    out.mkdir(parents=True, exist_ok=True)
    s = stages.load_session(session)
    model, cal = config["hue_model"], config["calibration"]
    for which in ("reference", "object"):
        if not (tables / f"table_{which}.json").exists():
            stages.hue_table(str(session), which, model, cal, table=str(tables / f"table_{which}.json"),
                             stats=str(tables / f"table_{which}.stats.json"))
    stages.plane_calibration(str(session), str(tables / "table_reference.json"), model, cal,
                             model=str(out / "model.npz"), stats=str(out / "planes.json"),
                             phase_error_summary=str(out / "phase_error.json"), object_table=str(tables / "table_object.json"))
    heights = [str(out / f"frame_{n:04d}.tiff") for n in s.frame_ids]
    us = [h.replace(".tiff", ".u.tiff") for h in heights]
    stages.measure_frames(str(session), s.frame_ids, str(tables / "table_object.json"), str(out / "model.npz"), model,
                          config["measurement"], cal, heights=heights, qa=[h.replace(".tiff", ".json") for h in heights],
                          map_frames=[], uncertainties=us)
    return {"session": s, "heights": heights, "uncertainties": us}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--tuning", action="store_true", help="the tuning cases only (no hold-out)")
    ap.add_argument("--holdout", action="store_true", help="the hold-out cases only")
    ap.add_argument("--texture", action="store_true", help="issue 24's cases only (names starting 'tex ')")
    ap.add_argument("--variants", nargs="*", default=list(VARIANTS))
    ap.add_argument("--keep", type=Path, default=None, help="write sessions and results here, reuse sessions found there")
    args = ap.parse_args()
    cases = [c for c in args.cases if not (args.tuning and CASES[c]["holdout"])
             and not (args.holdout and not CASES[c]["holdout"]) and not (args.texture and not c.startswith("tex "))]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        print("| case | set | variant | median mm | p95 mm | coverage | worst step um | mean step % "
              "| 2u all | 2u edge | 2u texture | 2u rest |")
        print("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
        for name in cases:
            case = CASES[name]
            slug = "".join(c if c.isalnum() else "-" for c in name)
            session = root / slug / "session"
            if not (session / "session.yaml").exists():
                bench.write_session(case["cfg"], session)
            tables = root / slug / "tables"
            tables.mkdir(parents=True, exist_ok=True)
            for vname in args.variants:
                if vname in ONLY and ONLY[vname] not in name:
                    continue
                out = root / slug / "".join(c if c.isalnum() else "-" for c in vname)
                r = score(measure(session, tables, out, _config(VARIANTS[vname])))
                pe = json.loads((out / "phase_error.json").read_text())
                if vname == "all on" and not pe["applied"]:
                    name_v = f"{vname} (table not applied: hold-out planes)"
                else:
                    name_v = vname
                steps = (f"{r['step_worst_um']:.1f} | {r['step_mean_pct']:.2f}" if "step_worst_um" in r else "- | -")
                cov2u = " | ".join(f"{r[f'cov2u_{z}']:.3f}" for z in ("all", "edge", "texture", "rest"))
                print(f"| {name} | {'hold-out' if case['holdout'] else 'tuning'} | {name_v} | {r['median_abs_mm']:.4f} | "
                      f"{r['p95_abs_mm']:.4f} | {r['coverage']:.3f} | {steps} | {cov2u} |", flush=True)
            print(f"<!-- {name}: {time.perf_counter() - t0:.0f} s so far -->", flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
