"""Study: the adaptive filter's ring pass on the stage benchmark's frame, counted and timed.

Usage::

    ./run python benchmarks/study_adaptive_visits.py [--size 640x480] [--bands 64] [--rounds 5]

On the stage benchmark's rig and frame (``bench_stages.py``: the toy rig of ``_kernel_case.py``,
the capture corrected for a texture blur of 0.4 px^2, the default measurement settings) it takes
the phase filter's inputs as the kernel hands them over (``kernel.frame_maps``), runs the fixed
window, then the adaptive pass (``phase._adaptive_pass``, rings only, as ``box_chi_z: 0``) on one
core and prints:

* the pixels whose first-pass sigma stays above ``target_sigma_rad`` (they grow ring by ring),
* their final window half sides, and those that end at ``max_radius`` below the target (they visit
  every neighbour of the largest window),
* how the grown pixels lie along a row (runs of neighbouring grown pixels per row, their median
  length): the pass takes each row's grown pixels through each window offset together, their
  neighbours gathered; walking short runs as contiguous rows costs more than the gather,
* the neighbour visits (``sum (2 r + 1)^2`` over the grown pixels) and the pass's CPU time per visit.

Each visit is a neighbour tested against the local plane and, when accepted, added to the
pixel's sums in ring order: the result is defined by that order (float32), so a faster pass
with the same bits can only lower the cost per visit; fewer visits (a plane fitted per box from
summed-area tables) change the bits.
"""

from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _kernel_case import make_case  # noqa: E402

from huefringe import kernel, perframe, texture  # noqa: E402
from huefringe.phase import _adaptive_pass, adaptive_kwargs, first_pass  # noqa: E402
from huefringe.settings import defaults  # noqa: E402


def filter_inputs(w: int, h: int, bands: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The phase filter's ``dz, s2, inv`` of the stage benchmark's frame (as ``frame_maps`` passes them)."""
    rig = make_case(w, h, n_bands=bands)
    m = defaults()["measurement"]
    prep = kernel.prepare(rig.table, rig.cal, rig.white, hue_model="hexcone", min_saturation=m["min_saturation"],
                          shadow=perframe.shadow_mask(rig.white, m["shadow_fraction"]), bit_depth=8)
    raw = rig.frame.astype(np.float32) * np.float32(1 / 255)
    rgb = texture.correct(raw, rig.white, 0.4, clipped=perframe.clipped_mask(raw, 8))
    seen: dict[str, tuple[np.ndarray, ...]] = {}
    inner = kernel.denoise_weighted

    def spy(dz: np.ndarray, s2: np.ndarray, inv: np.ndarray, **kw: object) -> np.ndarray:
        seen.setdefault("args", (dz.copy(), s2.copy(), inv.copy()))
        return inner(dz, s2, inv, **kw)

    kernel.denoise_weighted = spy
    try:
        kernel.frame_maps(prep, rgb, denoise_radius=int(m["denoise_radius"]), denoise_adaptive=m["denoise_adaptive"])
    finally:
        kernel.denoise_weighted = inner
    return seen["args"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--bands", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=5)
    a = ap.parse_args(argv)
    w, h = (int(x) for x in a.size.split("x"))
    dz, s2, inv = filter_inputs(w, h, a.bands)
    m = defaults()["measurement"]
    radius = int(m["denoise_radius"])
    ad = adaptive_kwargs(m["denoise_adaptive"])
    k2 = np.float32(9.0)
    first, wfirst = np.empty_like(dz), np.empty_like(dz)
    first_pass(dz, s2, inv, radius, k2, first, wfirst)
    tw, rw = np.float32(1 / ad["target_sigma"] ** 2), np.float32(1 / ad["reject_sigma"] ** 2)
    out, wout, rad = (np.empty_like(dz) for _ in range(3))
    none32 = np.empty((1, 1), np.float32)
    args = (dz, s2, inv, first, wfirst, radius, ad["max_radius"], k2, tw, rw, out, wout, rad, True,
            0.0, none32, False, none32, none32, none32, none32, np.float32(ad["plane_kink_sigma"] ** 2), none32,
            ad["lacking_probe_bias"] == "posterior")
    _adaptive_pass(*args)  # compiled or loaded from the cache
    cpu = []
    for _ in range(a.rounds):
        c = time.process_time()
        _adaptive_pass(*args)
        cpu.append(time.process_time() - c)
    grown = (inv > 0) & (wfirst < tw)
    r = rad[grown].astype(np.int64)
    visits = int(((2 * r + 1) ** 2).sum())
    at_max_below = int((grown & (rad == ad["max_radius"]) & (wout < tw)).sum())
    ms = 1e3 * statistics.median(cpu)
    print(f"{w} x {h}, {a.bands} bands: {int(grown.sum())} pixels grow ({grown.sum() / grown.size:.1%} of the frame)")
    edges = np.diff(np.pad(grown.astype(np.int8), ((0, 0), (1, 1))), axis=1)
    starts, ends = np.nonzero(edges == 1), np.nonzero(edges == -1)
    runs = ends[1] - starts[1]
    print(f"runs per row {runs.size / h:.0f} (median length {np.median(runs):.0f} px)")
    print("final half side: " + ", ".join(f"{int(k)}: {int(n)}" for k, n in zip(*np.unique(r, return_counts=True))))
    print(f"at max_radius {ad['max_radius']} below the target: {at_max_below} pixels, "
          f"{at_max_below * (2 * ad['max_radius'] + 1) ** 2 / visits:.0%} of the visits")
    print(f"neighbour visits {visits / 1e6:.1f} M; pass {ms:.1f} ms CPU (median of {a.rounds}), "
          f"{1e6 * ms / visits:.2f} ns per visit")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
