"""One-shot frames beyond the unambiguous range: pixels measured right, measured wrong (aliased), flagged.

Usage: ./run python benchmarks/oneshot_alias.py [--bands 32] [--repeats 2]

The holdout-wide bench rig with its true calibration (the order decision alone), the order
reference the base plane's Gray code + phase (`huefringe.bench.oneshot.render_session`), and
blocks of 6, 15, 28 and 36 mm standing on the base: inside the half-period range (about 11 mm
in front of the base at period 36 px), between half a period and one, and 1.3 and 1.6 periods
in front. Per face (the base and each block's top, lit pixels clear of edges): the share of
pixels measured within 2 mm of the truth along the ray, measured more than 2 mm off (a wrong
order: a silent alias), and flagged ``ORDER``, for

* ``plane route``: the order nearest the reference, flagged behind the reference
  (``stands_on_reference=True``, no working volume);
* ``session route``: the order nearest the reference on either side (``stands_on_reference=False``);
* ``volume 0.5 / 40 mm``: the trapezoid block's ``travel_mm: {front: 40, back: 0.5}`` (the
  working volume holding every block), at period 36 px and at period 80 px (whose period spans
  more depth than the volume).
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from huefringe.bench.oneshot import face_mask, render_session
from huefringe.bench.rig import RIGS, CompositeScene
from huefringe.codecs import Reason
from huefringe.rig.oneshot import hue_table_from_frames, measure_oneshot, oneshot_reference

HEIGHTS = (6.0, 15.0, 28.0, 36.0)
SCENE = CompositeScene(tilt_deg=(4.0, -3.0), origin=(0.0, 0.0, 430.0), spheres=(),
                       blocks=((-80.0, -30.0, -50.0, 10.0, HEIGHTS[0]), (-35.0, -30.0, -5.0, 10.0, HEIGHTS[1]),
                               (10.0, -30.0, 40.0, 10.0, HEIGHTS[2]), (55.0, -30.0, 85.0, 10.0, HEIGHTS[3])))
TRAVEL = (40.0, 0.5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bands", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    cal = RIGS["holdout-wide"].calibration
    print("| case | period px | face | lit px | measured right | measured wrong (aliased) | flagged order |")
    print("|---|---|---|---|---|---|---|")
    for period in (36.0, 80.0):
        cap = render_session(SCENE, period_px=period, n_bands=a.bands, repeats=a.repeats, seed=3)
        table = hue_table_from_frames(cap.white, cap.bands, cap.bands_block)
        cases = {"volume 0.5 / 40 mm": (replace(cap.block, travel_mm=TRAVEL), False)}
        if period == 36.0:
            cases = {"plane route": (cap.block, True), "session route": (cap.block, False), **cases}
        for name, (block, on_ref) in cases.items():
            ref = oneshot_reference(cap.reference, cal, block)
            res = measure_oneshot(cap.frames[0], cap.white, table, block, cal, ref, stands_on_reference=on_ref)
            if name == "plane route":
                print(f"<!-- range in front of the base (mm): {ref.summary()} -->")
            if block.travel_mm is not None:
                print(f"<!-- volume: {ref.travel_summary()} -->")
            for k, label in enumerate(("base", *(f"{h:g} mm top" for h in HEIGHTS))):
                face = face_mask(cap, k) & ref.valid
                n = int(face.sum())
                t = cap.truth_xyz[face]
                e = np.abs(np.einsum("ij,ij->i", res.xyz[face] - t, t / np.linalg.norm(t, axis=-1, keepdims=True)))
                ok = res.valid[face]
                right = int(np.sum(ok & (e <= 2.0)))
                wrong = int(np.sum(ok & ~(e <= 2.0)))
                flagged = int(np.sum((res.coordinate.reasons[face] & Reason.ORDER) > 0))
                print(f"| {name} | {period:g} | {label} | {n} | {right / n:.3f} | {wrong / n:.3f} ({wrong} px) | "
                      f"{flagged / n:.3f} |")


if __name__ == "__main__":
    main()
