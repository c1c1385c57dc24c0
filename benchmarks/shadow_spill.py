"""Shadow spill: the pixels a cast shadow or a dark print hides that the lens blur lights with a
neighbour's fringe, measured with the shadow test on the white image as read and with the
shadow-side test (``measurement.shadow_own_light``, :func:`huefringe.perframe.shadow_side`).

Usage: ./run python benchmarks/shadow_spill.py [--cases NAME ...] [--keep DIR] [--markdown FILE]

The photo-relief and gauge-block cases of ``benchmarks/accuracy_matrix.py`` with a step (the printed
rectangle's border, the blocks), one repeat or two, 16 bit, quiet bench camera, and five tuning
cases of this study's own (the retina photograph; chelsea at 48 px and the astronaut at 64 px with
other seeds; the astronaut and the retina at 48 px seen through a lens blur of 1.1 px): tuning
cases and hold-outs (the matrix's, fixed before any setting was tuned; they only score). Each is
measured twice at config.yaml's defaults by the workflow's stages, ``shadow_own_light`` false and true (the same hue
tables and plane calibration). Per case and setting, over the valid pixel values of every frame:
their number, those more than 0.5 mm off the bench's truth (and the share of them within 1 px of a
step of the truth, as ``coverage_bins.py`` finds steps), the 2u coverage of those and of all, the
rms and 95th percentile of |e|; for the shadow-side test, the values it drops that were no gross
error (their rms error and 2u coverage as read). Last, the share of pixels the test adds on a real
capture's white image (../shared/real, mugs on a table; no truth). About 3 minutes on one core.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import tifffile

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402
import coverage_bins as cb  # noqa: E402

from huefringe.perframe import shadow_masks  # noqa: E402
from huefringe.settings import defaults as load_defaults  # noqa: E402

#: tuning cases of this study's own: other photographs, periods and seeds on the same bench
OWN = {"tex retina p56 72x1": am._case("photo_relief", session={**am._TEX, "seed": 63}, scene={"image": "retina"}),
       "tex chelsea p48 72x1 seed": am._case("photo_relief", session={**am._TEX, "seed": 65, "period_px": 48},
                                             scene={"image": "chelsea"}),
       "tex astronaut p64 72x1 seed": am._case("photo_relief", session={**am._TEX, "seed": 67, "period_px": 64}),
       "tex astronaut p48 72x1 blur1.1 seed": am._case("photo_relief", session={**am._TEX, "period_px": 48, "seed": 73},
                                                       camera={"lens_blur_sigma_px": 1.1}),
       "tex retina p48 72x1 blur1.1 seed": am._case("photo_relief", session={**am._TEX, "period_px": 48, "seed": 75},
                                                    camera={"lens_blur_sigma_px": 1.1}, scene={"image": "retina"})}
CASES = {**{k: am.CASES[k] for k in ("tex astronaut p56 72x1", "tex chelsea p56 72x1", "tex gauge plain p40 96x2")}, **OWN,
         **{k: am.CASES[k] for k in ("tex rocket p56 72x1", "tex immunohistochemistry p56 72x1",
                                      "tex coffee p48 72x1 blur1.1", "tex gauge plain p56 72x1")}}
#: |e| beyond this (mm) is a gross error: a height from the other side of a step
GROSS_MM = 0.5
#: a real capture's white image (mugs on a table, ../shared/real), for the share of pixels the test adds
SHADOW_FRACTION = float(load_defaults()["measurement"]["shadow_fraction"])
REAL_WHITE = Path(__file__).resolve().parents[2] / "shared" / "real" / "kamino410-phase-shifting" / "object2" / "pat30.png"


def measure(name: str, root: Path, own: bool) -> dict[str, Any]:
    """One case at the defaults with ``measurement.shadow_own_light`` = ``own``: the figures above
    (and, under ``"maps"``, the errors, u and valid masks of every frame, for :func:`table`)."""
    case = CASES[name]
    where = root / am._slug(name)
    session, tables = am._case_dirs(where, case["cfg"])
    out = where / f"own-light-{str(own).lower()}"
    heights = sorted(out.glob("frame_*[0-9].tiff"))
    if heights and all(Path(str(h).replace(".tiff", ".u.tiff")).exists() for h in heights):
        hs, us = [str(h) for h in heights], [str(h).replace(".tiff", ".u.tiff") for h in heights]
        s = am.load_session(session)
    else:
        paths = am.measure(session, tables, out, am._config({"measurement": {"shadow_own_light": own}}))
        s, hs, us = paths["session"], paths["heights"], paths["uncertainties"]
    h = np.stack([tifffile.imread(p).astype(np.float64) for p in hs])
    u = np.stack([tifffile.imread(p).astype(np.float64) for p in us])
    t = np.stack([tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids])
    e = h - t
    ok = np.isfinite(e)
    refl, rest = cb.true_maps(case["cfg"])
    # the white level is not binned here (ones)
    step = cb.pixel_kinds(np.ones(refl.shape), refl, np.where(np.isfinite(t[0]), rest, np.nan))["distance to step edge"]
    near = np.broadcast_to(step < 1.0, e.shape)
    gross = ok & (np.abs(e) > GROSS_MM)
    ae, ue = np.abs(e[ok]), u[ok]
    return {"valid": int(ok.sum()), "gross": int(gross.sum()),
            "gross near step": float(near[gross].mean()) if gross.any() else float("nan"),
            "gross 2u": float(np.mean(np.abs(e[gross]) <= 2 * u[gross])) if gross.any() else float("nan"),
            "2u": float(np.mean(ae <= 2 * ue)), "rms": float(np.sqrt(np.mean(ae * ae))),
            "p95": float(np.percentile(ae, 95)), "holdout": bool(case["holdout"]), "maps": (e, u, ok)}


def dropped_sound(as_read: dict[str, Any], side: dict[str, Any]) -> tuple[int, float, float]:
    """The values the shadow-side test drops that were within ``GROSS_MM`` of the truth as read:
    their number, rms error (mm) and 2u coverage, measured with the white image as read."""
    e, u, ok = as_read["maps"]
    lost = ok & ~side["maps"][2] & (np.abs(np.where(ok, e, 0.0)) <= GROSS_MM)
    if not lost.any():
        return 0, float("nan"), float("nan")
    ae = np.abs(e[lost])
    return int(lost.sum()), float(np.sqrt(np.mean(ae * ae))), float(np.mean(ae <= 2 * u[lost]))


def table(results: dict[str, dict[bool, dict[str, Any]]]) -> list[str]:
    """The Markdown table: a row per case and test; the shadow-side row also gives the values it
    drops that were no gross error (as read: their rms error and 2u coverage)."""
    rows = ["| case | set | shadow test | valid values | dropped | > 0.5 mm | of them within 1 px of a step | of them 2u "
            "| 2u all | rms mm | p95 mm | dropped values not > 0.5 mm: rms mm / 2u (as read) |",
            "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for name, by in results.items():
        for own in (False, True):
            r = by[own]
            drop = 1 - r["valid"] / by[False]["valid"]
            sound = ""
            if own:
                n, rms, cov = dropped_sound(by[False], r)
                sound = f"{rms:.3f} / {cov:.2f}" if n else "-"
            rows.append(f"| {name} | {'hold-out' if r['holdout'] else 'tuning'} | {'shadow side' if own else 'as read'} | "
                        f"{r['valid']} | {'' if not own else f'{drop:.2%}'} | {r['gross']} | "
                        f"{r['gross near step']:.2f} | {r['gross 2u']:.2f} | {r['2u']:.3f} | {r['rms']:.4f} | {r['p95']:.4f} "
                        f"| {sound} |")
    return rows


def real_white() -> str:
    """The shadow-side test on a real capture's white image (no truth: the pixels it adds, and
    their level against the image's 99th percentile)."""
    if not REAL_WHITE.is_file():
        return f"real capture: {REAL_WHITE} not found"
    level = cv2.imread(str(REAL_WHITE), cv2.IMREAD_GRAYSCALE).astype(np.float64) / 255.0
    rgb = np.repeat(level[..., None], 3, axis=-1)
    read, side = shadow_masks(rgb, SHADOW_FRACTION)
    top = float(np.max(level[side]) / np.percentile(level, 99)) if side.any() else float("nan")
    return (f"real capture ({REAL_WHITE.parent.parent.name}/{REAL_WHITE.parent.name}, white image "
            f"{level.shape[1]} x {level.shape[0]}): shadowed as read {read.mean():.2%}, the shadow-side test adds "
            f"{side.mean():.2%} ({int(side.sum())} pixels), at most {top:.2f} of the 99th percentile")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--keep", help="keep sessions and results here; reuse them")
    ap.add_argument("--markdown", help="also write the Markdown table to this file")
    args = ap.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.keep) if args.keep else Path(tmp)
        results: dict[str, dict[bool, dict[str, Any]]] = {}
        for name in args.cases:
            results[name] = {own: measure(name, root, own) for own in (False, True)}
            print(f"{name}: done ({time.perf_counter() - t0:.0f} s)", flush=True)
    lines = table(results)
    print("\n".join(lines))
    print("\n" + real_white())
    if args.markdown:
        Path(args.markdown).write_text("\n".join(lines) + "\n")
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
