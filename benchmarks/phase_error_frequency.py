"""Benchmark: what ``measurement.phase_error_frequency`` costs a frame, against the same frame without it.

Usage: ./run python benchmarks/phase_error_frequency.py [--size 640x480] [--calls 9]

On the stage benchmark's frame (``_kernel_case.py``, 64 bands) with a phase-error table of the
demo's size (0.016 rad peak to peak; the toy rig's planes give none), ``kernel.frame_maps`` as the
workflow calls it (filter at ``denoise_radius``, sigma-adaptive, uncertainty) and without the
filter, each with the table's correction as learned and scaled to the fringe frequency
(``phase_error.correct_frequency``), the two interleaved in one process; and
``correct_frequency`` alone. CPU ms of the process, minimum and median of ``--calls`` calls
(this machine's single-core speed changes within seconds: the minimum is the figure to compare).
The accuracy side: ``accuracy_matrix.py --variants "all on" "phase-error frequency"``.
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _kernel_case import make_case  # noqa: E402

from huefringe import kernel, perframe, phase_error  # noqa: E402
from huefringe.settings import defaults  # noqa: E402


def _ms(fn, calls: int) -> list[float]:  # noqa: ANN001
    out = []
    for _ in range(calls):
        t0 = time.process_time()
        fn()
        out.append(1e3 * (time.process_time() - t0))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--calls", type=int, default=9)
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.split("x"))
    m = defaults()["measurement"]
    rig = make_case(w, h, 64)
    cal = copy.copy(rig.cal)
    c = (np.arange(512) + 0.5) * (2 * np.pi / 512)
    cal.phase_error = 0.006 * np.sin(3 * c) + 0.002 * np.sin(6 * c)
    shadow = perframe.shadow_mask(rig.white, m["shadow_fraction"])
    preps = {on: kernel.prepare(rig.table, cal, rig.white, hue_model="hexcone", min_saturation=m["min_saturation"],
                                shadow=shadow, bit_depth=8, phase_error_frequency=on) for on in (False, True)}
    rgb = rig.frame.astype(np.float32) / np.float32(255)
    full = {"denoise_radius": int(m["denoise_radius"]), "denoise_adaptive": m["denoise_adaptive"], "want_uncertainty": True}
    print(f"{w} x {h}, CPU ms a frame, min / median of {a.calls} calls, interleaved\n")
    print("| call | as learned | scaled to the fringe frequency | difference (min) |")
    print("| --- | ---: | ---: | ---: |")
    for name, kw in (("frame_maps as the workflow calls it", full), ("frame_maps without the filter", {})):
        for p in preps.values():
            kernel.frame_maps(p, rgb, **kw)  # compiled and warm
        t: dict[bool, list[float]] = {False: [], True: []}
        for _ in range(a.calls):
            for on, p in preps.items():
                t[on] += _ms(lambda p=p: kernel.frame_maps(p, rgb, **kw), 1)
        print(f"| {name} | {min(t[False]):.1f} / {np.median(t[False]):.1f} | {min(t[True]):.1f} / "
              f"{np.median(t[True]):.1f} | {min(t[True]) - min(t[False]):+.1f} |")
    d = kernel.frame_maps(preps[False], rgb, want_dphi=True)
    inputs = preps[True].frequency
    alone = _ms(lambda: phase_error.correct_frequency(d.dphi, d.valid, cal.phi_ref, cal.phase_error, inputs), a.calls)
    print(f"| `phase_error.correct_frequency` alone | | {min(alone):.1f} / {np.median(alone):.1f} | |")


if __name__ == "__main__":
    main()
