"""What a colour-sequential (single-chip DLP) projector and the camera's shutter cost the one-shot heights.

Usage: ./run python benchmarks/dlp_colour_sequence.py [--frames N] [--keep DIR]

The demo's gauge-block scene (bench preset ``demo``: vibrating membrane, pre-distorted pattern,
64 bands x 3 repeats; here without the phase-shift captures) captured with a 12.5 ms exposure by:

- a 3-CCD camera and a projector that shows R, G and B at once (the paper's rig, the reference);
- a single-chip DLP with a 3x colour wheel at 60 Hz (R, G, B segments of a third each, a colour
  cycle of 5.56 ms) and an exposure of exactly two cycles (11.11 ms), rolling shutter;
- the same DLP, exposure 12.5 ms = 2.25 cycles, global shutter (each image its own colour balance);
- the same DLP, 12.5 ms, rolling shutter of 50 us per row (15 ms readout: the balance changes along
  the rows, a band every 111 rows);
- the same DLP and rolling shutter, exposure 10.25 cycles (56.9 ms: exposure much longer than a
  cycle; the membrane's motion blurs more).

Every image's colour-cycle start phase is drawn from the session seed and the image's name
(``camera.shutter.start_phase: random``). Each session is measured with the workflow's stages
(:func:`huefringe.stages.measure_session`) and scored against the bench's ground truth: RMS height
error over the valid pixels and its row-periodic component
(:func:`huefringe.row_banding.row_periodic_rms` of the error map), the worst step error, the
fraction of valid pixels with ``|e| <= 2u``, the object table's valid fraction, and what the QA
says (``calib/planes.json``: ``row_banding``, amplitude in rad and mm; ``colour_flicker``, the
reference bands' hue spread between repeats; which of them warn). Frame means.
About 4 min on one shared core with ``--frames 2``.
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

from huefringe import bench, metrology, pipeline, stages
from huefringe.row_banding import row_periodic_rms
from huefringe.settings import load_config

REPO = Path(__file__).resolve().parents[1]
WHEEL = {"segments": "RGB", "refresh_hz": 60.0, "cycles_per_refresh": 3.0}
CYCLE_MS = 1000.0 / 180.0
ROLLING = {"kind": "rolling", "line_time_us": 50.0}

CASES: dict[str, dict] = {
    "3-CCD, global": {"exposure_ms": 12.5},
    "DLP, 2 cycles, rolling": {"exposure_ms": 2 * CYCLE_MS, "sequence": WHEEL, "shutter": ROLLING},
    "DLP, 2.25 cycles, global": {"exposure_ms": 12.5, "sequence": WHEEL},
    "DLP, 2.25 cycles, rolling": {"exposure_ms": 12.5, "sequence": WHEEL, "shutter": ROLLING},
    "DLP, 10.25 cycles, rolling": {"exposure_ms": 10.25 * CYCLE_MS, "sequence": WHEEL, "shutter": ROLLING},
}


def case_config(name: str, frames: int) -> dict:
    """The demo preset with a case's projector and shutter."""
    case = CASES[name]
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("demo")))
    cfg["session"].update(frames=frames, id="dlp-" + "".join(c if c.isalnum() else "-" for c in name.lower()))
    cfg["phase_shift"]["enabled"] = False
    cfg["camera"]["exposure_ms"] = float(case["exposure_ms"])
    if "sequence" in case:
        cfg["projector"]["colour_sequence"] = dict(case["sequence"])
    if "shutter" in case:
        cfg["camera"]["shutter"] = dict(case["shutter"])
    return bench.validate_bench_config(cfg)


def score(paths: dict, out: Path) -> dict:
    """Errors against the ground truth, frame means; the QA's row-banding record."""
    s = paths["session"]
    lens = pipeline.session_corrections(s, paths["camera"])[0]
    maps = [tifffile.imread(h).astype(np.float64) for h in paths["heights"]]
    rms, band, cov = [], [], []
    for n, (m, up) in enumerate(zip(maps, paths["uncertainties"], strict=True)):
        e = m - tifffile.imread(s.ground_truth[s.frame_ids[n]]).astype(np.float64)
        u = tifffile.imread(up).astype(np.float64)
        ok = np.isfinite(e) & np.isfinite(u)
        rms.append(float(np.sqrt(np.mean(e[ok] ** 2))))
        band.append(row_periodic_rms(e, ok)[0])
        cov.append(float(np.mean(np.abs(e[ok]) <= 2 * u[ok])))
    ev = metrology.evaluate_session(maps, s.specimen, s.pixel_pitch_mm, range_mm=max(s.planes_mm) - min(s.planes_mm),
                                    camera=lens)
    planes = json.loads((out / "planes.json").read_text())
    table = json.loads((out / "table_object.stats.json").read_text())
    return {
        "rms_um": 1e3 * float(np.mean(rms)),
        "row_periodic_um": 1e3 * float(np.mean(band)),
        "steps_um": {st["name"]: 1e3 * float(st["error_mm"]) for st in ev["steps"]},
        "cov2u": float(np.mean(cov)),
        "table_valid": float(table["valid_fraction"]),
        "qa": planes["row_banding"],
        "flicker": planes["colour_flicker"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--keep", type=Path, default=None, help="write the sessions and results here")
    args = ap.parse_args()
    config = load_config(REPO / "config.yaml")
    t0 = time.perf_counter()
    print("| camera and projector | RMS error um | row-periodic um | step errors um (green, blue, red) | |e| <= 2u "
          "| object table valid | QA row banding rad (mm) | QA colour flicker rad | QA warns |")
    print("| --- | ---: | ---: | --- | ---: | ---: | ---: | ---: | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        for name in args.cases:
            cfg = case_config(name, args.frames)
            session = bench.write_session(cfg, root / cfg["session"]["id"])
            out = root / "results" / cfg["session"]["id"]
            r = score(stages.measure_session(session, out, config), out)
            steps = ", ".join(f"{v:+.0f}" for v in r["steps_um"].values())
            qa, fl = r["qa"], r["flicker"]
            warns = [w for w, rec in (("row banding", qa), ("colour flicker", fl)) if rec["suspected"]]
            print(f"| {name} | {r['rms_um']:.1f} | {r['row_periodic_um']:.1f} | {steps} | {r['cov2u']:.3f} "
                  f"| {r['table_valid']:.3f} | {qa['amplitude_rad']:.3f} ({qa['amplitude_mm']:.3f}) "
                  f"| {fl['amplitude_rad']:.4f} | {', '.join(warns) or 'no'} |", flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
