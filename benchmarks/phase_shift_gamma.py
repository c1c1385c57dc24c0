"""Three-step phase shifting through the files route: plain against pre-compensated sinusoids.

Usage: nice ./run python benchmarks/phase_shift_gamma.py [--size 320 240] [--bands 48] [--keep DIR]
                                                         [--gammas dev|holdout|all] [--table1]

For each projector gamma (``DEV_GAMMAS`` for development, ``HOLDOUT_GAMMAS`` only scored) and bit
depth (``DEPTHS``: pattern files, the bench's DMD, the camera) the flat-board scene (``flat`` preset,
its 80 x 60 mm field at ``--size``, 12 mm period, 0.1 mm projector pixels) is captured through the
route a lab runs: ``huefringe patterns`` -> ``huefringe bench CONFIG CAMERA --patterns`` ->
``huefringe session``, then measured with the workflow's stages (``stages.measure_session``, the
three-step baseline included). Three sessions per case:

- ``plain``: the phase-shift sinusoids written as the spec draws them;
- ``compensated``: ``huefringe patterns --compensated CALIB`` with CALIB the plain session's
  ``table_reference.json`` (what the workflow leaves in ``results/<id>/calib``): the sinusoids
  pre-compensated through the gamma fitted to the plate's hue table;
- ``oracle``: the same files with the sinusoids pre-compensated through the bench's *true* gamma
  (the floor of the method: quantisation, noise, defocus).

Printed per session: the fitted gamma, the RMS of the three-step phase about the true code phase
on the board (rad, every pixel but the two outermost columns at each side, where the bench's lens
blur reads beyond the image; its constant offset removed), the RMS of the row-averaged error (the
systematic part, noise averaged over the rows), the fraction of pixels with modulation > 0.1, and
the RMS of the baseline's height (mm) against the board's true height over its valid pixels.
With ``--table1``: the ``table1`` scene (a 1.0 mm gauge block, vibrating membrane) plain against
compensated: the block's step error and its ROI standard deviation (um), one frame.
The tables go to docs/accuracy-cameras.md.
"""

from __future__ import annotations

import argparse
import copy
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
import yaml

from huefringe import bench, cli, colour, metrology, stages
from huefringe.bench.geometry import code_phase
from huefringe.bench.writer import specimen_document
from huefringe.compensation import linearised_levels
from huefringe.io import write_png_rgb
from huefringe.patterns import TWO_PI, phase_shift_intensity, quantise
from huefringe.phase import three_step_phase, wrap
from huefringe.session import Session, decode_image, load_session
from huefringe.settings import load_config

#: Gammas the approach was developed on; the hold-out set is only scored.
DEV_GAMMAS = ([2.2, 2.2, 2.2], [1.8, 2.5, 2.1])
HOLDOUT_GAMMAS = ([2.6, 2.0, 1.9],)
#: (pattern files, the bench's DMD, the camera) bit depths.
DEPTHS = ((8, 8, 8), (16, 10, 16))
PROJECTOR = (1024, 768)
#: Columns left out at each side of the phase statistics.
BORDER = 2
CONFIG = load_config()


def _config(preset: str, size: tuple[int, int], bands: int, gamma: list[float], dmd_bits: int,
            camera_bits: int) -> dict[str, Any]:
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path(preset)))
    s = cfg["session"]
    pitch = s["width"] * s["pixel_pitch_mm"] / size[0]
    s.update(width=size[0], height=size[1], pixel_pitch_mm=pitch, period_px=s["period_px"] * s["pixel_pitch_mm"] / pitch,
             hue_bands=bands, repeats=2, frames=1, id="ps-gamma", bit_depth=camera_bits)
    cfg["projector"]["gamma"] = list(gamma)
    cfg["projector"]["dmd_bits"] = dmd_bits
    cfg["projector"]["compensation"] = {"enabled": False}
    return cfg


def _chain(root: Path, cfg: dict[str, Any], name: str, file_bits: int, *extra: str,
           patterns: Path | None = None) -> Session:
    """patterns -> bench --patterns -> session; ``patterns`` reuses an existing patterns folder."""
    s = cfg["session"]
    pat, cam, out = patterns or root / f"patterns-{name}", root / f"camera-{name}", root / f"session-{name}"
    spec = root / "spec.yaml"
    root.mkdir(parents=True, exist_ok=True)
    if not spec.exists():
        doc: dict[str, Any] = {"id": s["id"], "pixel_pitch_mm": s["pixel_pitch_mm"], "period_px": s["period_px"],
                               "provenance": {"simulated": True}}
        sp = specimen_document(cfg)
        if sp is not None:
            doc["specimen"] = sp
        spec.write_text(yaml.safe_dump(doc))
        (root / "bench.yaml").write_text(yaml.safe_dump(cfg))
    mag = cfg["projector"]["pixel_mm"] / s["pixel_pitch_mm"]
    if patterns is None:
        assert cli.main(["patterns", str(pat), "--width", str(PROJECTOR[0]), "--height", str(PROJECTOR[1]),
                         "--camera-period-px", f"{s['period_px']:g}", "--magnification", f"{mag:g}",
                         "--bands", str(s["hue_bands"]), "--repeats", str(s["repeats"]),
                         "--planes", ",".join(f"{z:g}" for z in s["planes_mm"]), "--frames", "1",
                         "--bit-depth", str(file_bits), *extra]) == 0
    assert cli.main(["bench", str(root / "bench.yaml"), str(cam), "--patterns", str(pat), "--quiet"]) == 0
    assert cli.main(["session", str(cam), str(pat), str(spec), str(out)]) == 0
    return load_session(out, deep=True)


def oracle_patterns(src: Path, dst: Path, gamma: list[float]) -> Path:
    """A copy of a patterns folder whose phase-shift images are pre-compensated with ``gamma``."""
    shutil.copytree(src, dst)
    meta = yaml.safe_load((dst / "patterns.yaml").read_text())
    w, h, period, bits = meta["width"], meta["height"], meta["period_px"], meta["bit_depth"]
    for f in sorted(dst.glob("*_shift_s*.png")):
        level = phase_shift_intensity(TWO_PI * np.arange(w) / period, int(f.stem[-1]))
        row = quantise(linearised_levels(level, gamma), bits)
        f.unlink()
        write_png_rgb(f, np.broadcast_to(row[None], (h, w, 3)).copy())
    return dst


def phase_scores(session: Session, cfg: dict[str, Any], baseline: str) -> dict[str, float]:
    """Three-step phase on the flat board against the true code phase, and the baseline's height."""
    rig = bench.Bench(cfg).rig
    z = float(cfg["scene"]["height_mm"])
    x = np.arange(session.width) * session.pixel_pitch_mm
    truth = code_phase(x, z, projector_x_mm=rig.projector_x_mm, projector_height_mm=rig.projector_height_mm,
                       period_mm=rig.period_mm, x_origin_mm=rig.x_origin_mm)
    phi, mod = three_step_phase(*(colour.intensity(decode_image(p)) for p in session.phase_shift[0]))
    # the bench's lens blur reads beyond the image at the outermost columns (+-0.09 rad there on
    # every route): they are left out of the phase statistics
    e = wrap(phi.astype(np.float64) - truth[None, :])[:, BORDER:-BORDER]
    offset = float(np.angle(np.mean(np.exp(1j * e))))
    e = wrap(e - offset)
    hb = tifffile.imread(baseline)
    ok = np.isfinite(hb)
    return {"rms_rad": float(np.sqrt(np.mean(e**2))), "row_rms_rad": float(np.sqrt(np.mean(e.mean(axis=0) ** 2))),
            "max_row_rad": float(np.max(np.abs(e.mean(axis=0)))), "offset_rad": offset,
            "modulated": float(np.mean(mod > 0.1)), "height_rms_mm": float(np.sqrt(np.mean((hb[ok] - z) ** 2))),
            "height_coverage": float(ok.mean())}


def flat_case(root: Path, size: tuple[int, int], bands: int, gamma: list[float], depth: tuple[int, int, int]
              ) -> list[tuple[str, dict[str, Any]]]:
    cfg = _config("flat", size, bands, gamma, depth[1], depth[2])
    rows = []
    plain = _chain(root, cfg, "plain", depth[0])
    res_plain = stages.measure_session(plain.root, root / "results-plain", CONFIG, baseline=True)
    rows.append(("plain", {**phase_scores(plain, cfg, res_plain["baseline"][0]), "gamma": None}))
    comp = _chain(root, cfg, "compensated", depth[0], "--compensated", str(root / "results-plain"))
    fitted = yaml.safe_load((root / "patterns-compensated" / "patterns.yaml").read_text())["compensated"]["phase_shift"]
    res_comp = stages.measure_session(comp.root, root / "results-compensated", CONFIG, baseline=True)
    rows.append(("compensated", {**phase_scores(comp, cfg, res_comp["baseline"][0]), "gamma": fitted["gamma"],
                                 "fit_rms_rad": fitted["fit_residual_rad"]["rms"]}))
    orc = _chain(root, cfg, "oracle", depth[0],
                 patterns=oracle_patterns(root / "patterns-compensated", root / "patterns-oracle", gamma))
    res_orc = stages.measure_session(orc.root, root / "results-oracle", CONFIG, baseline=True)
    rows.append(("oracle (true gamma)", {**phase_scores(orc, cfg, res_orc["baseline"][0]), "gamma": list(gamma)}))
    return rows


def table1_case(root: Path, size: tuple[int, int], bands: int, gamma: list[float]) -> list[tuple[str, dict[str, Any]]]:
    cfg = _config("table1", size, bands, gamma, 8, 8)
    cfg["camera"]["supersample"] = 1
    rows = []
    for name, extra in (("plain", ()), ("compensated", ("--compensated", str(root / "results-plain")))):
        s = _chain(root, cfg, name, 8, *extra)
        res = stages.measure_session(s.root, root / f"results-{name}", CONFIG, baseline=True)
        out = {}
        for method, paths in (("three-step", res["baseline"]), ("trapezoidal-hsi", res["heights"])):
            hs = [tifffile.imread(p) for p in paths]
            ev = metrology.evaluate_session(hs, s.specimen, s.pixel_pitch_mm,
                                            range_mm=max(s.planes_mm) - min(s.planes_mm))
            st = ev["steps"][0]
            u0, v0, u1, v1 = s.specimen["steps"][0]["roi"]
            roi = hs[0][v0:v1, u0:u1]
            out[method] = {"error_um": 1e3 * st["error_mm"], "roi_std_um": 1e3 * float(np.nanstd(roi)),
                           "roi_coverage": float(np.isfinite(roi).mean())}
        rows.append((name, out))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, nargs=2, default=(320, 240), metavar=("W", "H"))
    ap.add_argument("--bands", type=int, default=48)
    ap.add_argument("--gammas", choices=("dev", "holdout", "all"), default="all")
    ap.add_argument("--table1", action="store_true", help="also the Table 1 scene (gamma [2.2, 2.2, 2.2])")
    ap.add_argument("--keep", type=Path, default=None, help="write everything here (default: a temporary folder)")
    args = ap.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="ps-gamma-"))
    root.mkdir(parents=True, exist_ok=True)
    gammas = {"dev": DEV_GAMMAS, "holdout": HOLDOUT_GAMMAS, "all": DEV_GAMMAS + HOLDOUT_GAMMAS}[args.gammas]
    size = tuple(args.size)
    print(f"\nflat board, {size[0]} x {size[1]} px, {args.bands} bands x 2, projector {PROJECTOR[0]} x {PROJECTOR[1]}\n")
    print("| projector gamma | bits (files/DMD/camera) | phase-shift files | fitted gamma | phase RMS (rad) "
          "| row-mean RMS (rad) | modulated | baseline height RMS (mm), coverage | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for gamma in gammas:
        tag = "hold-out " if gamma in HOLDOUT_GAMMAS else ""
        for depth in DEPTHS:
            t0 = time.perf_counter()
            d = root / f"g{'-'.join(f'{g:g}' for g in gamma)}-b{'-'.join(map(str, depth))}"
            rows = flat_case(d, size, args.bands, gamma, depth)
            dt = time.perf_counter() - t0
            for name, r in rows:
                fg = "-" if r["gamma"] is None else ", ".join(f"{g:.3f}" for g in r["gamma"])
                print(f"| {tag}{gamma} | {'/'.join(map(str, depth))} | {name} | {fg} | {r['rms_rad']:.4f} "
                      f"| {r['row_rms_rad']:.4f} | {100 * r['modulated']:.1f} % "
                      f"| {r['height_rms_mm']:.4f}, {100 * r['height_coverage']:.1f} % | {dt:.0f} |", flush=True)
    if args.table1:
        rows = table1_case(root / "table1", size, args.bands, [2.2, 2.2, 2.2])
        print("\n| table1 scene, gamma [2.2, 2.2, 2.2] | method | step error (um) | ROI std (um) | ROI coverage |")
        print("|---|---|---|---|---|")
        for name, r in rows:
            for method, v in r.items():
                print(f"| {name} phase-shift files | {method} | {v['error_um']:+.1f} | {v['roi_std_um']:.1f} "
                      f"| {100 * v['roi_coverage']:.1f} % |")
    print(f"\n(sessions in {root})")


if __name__ == "__main__":
    main()
