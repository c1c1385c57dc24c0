"""Benchmark: what ``measurement.phase_error_frequency`` costs a frame, against the same frame without it.

Usage: ./run python benchmarks/phase_error_frequency.py [--size 640x480] [--calls 9]
       ./run python benchmarks/phase_error_frequency.py --steps DIR   (where a gauge case's steps move)

On the stage benchmark's frame (``_kernel_case.py``, 64 bands) with a phase-error table of the
demo's size (0.016 rad peak to peak; the toy rig's planes give none), ``kernel.frame_maps`` as the
workflow calls it (filter at ``denoise_radius``, sigma-adaptive, uncertainty) and without the
filter, each with the table's correction as learned and scaled to the fringe frequency
(``phase_error.correct_frequency``), the two interleaved in one process; and
``correct_frequency`` alone. CPU ms of the process on one thread (``NUMBA_NUM_THREADS=1`` unless
set), minimum and median of ``--calls`` calls
(this machine's single-core speed changes within seconds: the minimum is the figure to compare).
The accuracy side: ``accuracy_matrix.py --variants "all on" "phase-error frequency"``.

``--steps DIR``: a gauge case's folder of ``accuracy_matrix.py --keep`` (its ``session``,
``all-on`` and ``phase-error-frequency`` results, both variants run) instead: per step, its error
with and without the option (``metrology.evaluate_session``) and, per frame, the height change the
option makes inside the step's evaluated box (``metrology.central_box``: mean, rms, the fraction
of its pixels changed by more than 1 nm) beside each variant's mean error there; then the change
and the rms errors per distance to the nearest change of the true height. Seconds.
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # one core, as the stage benchmark (the passes run rows in parallel)

import argparse  # noqa: E402
import copy  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _kernel_case import make_case  # noqa: E402

from huefringe import kernel, metrology, perframe, phase_error  # noqa: E402
from huefringe.session import load_session  # noqa: E402
from huefringe.settings import defaults  # noqa: E402

DISTANCES = ((0, 2), (2, 4), (4, 6), (6, 9), (9, 14), (14, None))


def _ms(fn, calls: int) -> list[float]:  # noqa: ANN001
    out = []
    for _ in range(calls):
        t0 = time.process_time()
        fn()
        out.append(1e3 * (time.process_time() - t0))
    return out


def steps(case: Path) -> None:
    """``--steps``: where the option moves a gauge case's steps (module docstring)."""
    import tifffile
    from scipy import ndimage

    s = load_session(case / "session")
    if s.specimen is None:
        raise SystemExit(f"{case / 'session'}: no specimen (a gauge case's folder is needed)")
    runs = {}
    for name in ("all-on", "phase-error-frequency"):
        paths = [case / name / f"frame_{n:04d}.tiff" for n in s.frame_ids]
        missing = [str(p) for p in paths if not p.exists()]
        if missing:
            raise SystemExit(f"not measured: {', '.join(missing)} (run accuracy_matrix.py --keep with both variants)")
        runs[name] = [tifffile.imread(p).astype(np.float64) for p in paths]
    truth = [tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids]
    off, on = runs["all-on"], runs["phase-error-frequency"]
    ev = {k: metrology.evaluate_session([m.astype(np.float32) for m in v], s.specimen, s.pixel_pitch_mm,
                                        range_mm=max(s.planes_mm) - min(s.planes_mm)) for k, v in runs.items()}
    print(f"{case.name}: step error um without / with the option; per frame inside the evaluated box: the change's "
          "mean and rms um, the fraction of pixels changed, the mean error um without / with\n")
    for k, st in enumerate(s.specimen["steps"]):
        u0, v0, u1, v1 = metrology.central_box(st["roi"])
        cells = []
        for a, b, t in zip(off, on, truth, strict=True):
            d = 1e3 * (b - a)[v0:v1, u0:u1]
            cells.append(f"{np.nanmean(d):+.2f} / {np.nanstd(d):.2f} / {np.nanmean(np.abs(d) > 1e-6):.2f}, "
                         f"{1e3 * np.nanmean((a - t)[v0:v1, u0:u1]):+.2f} / {1e3 * np.nanmean((b - t)[v0:v1, u0:u1]):+.2f}")
        print(f"{st['name']}: {1e3 * ev['all-on']['steps'][k]['error_mm']:+.2f} / "
              f"{1e3 * ev['phase-error-frequency']['steps'][k]['error_mm']:+.2f}; " + "; ".join(cells))
    t0 = np.round(np.nan_to_num(truth[0], nan=-9.0), 3)
    edge = np.zeros(t0.shape, bool)
    edge[:, 1:] |= t0[:, 1:] != t0[:, :-1]
    edge[1:, :] |= t0[1:, :] != t0[:-1, :]
    dist = ndimage.distance_transform_edt(~edge)
    print("\n| px from a step | pixels | change rms um | change mean um | rms error without / with um |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for lo, hi in DISTANCES:
        band = (dist >= lo) & (dist < (np.inf if hi is None else hi))
        d = np.concatenate([1e3 * (b - a)[band] for a, b in zip(off, on, strict=True)])
        ea = np.concatenate([1e3 * (a - t)[band] for a, t in zip(off, truth, strict=True)])
        eb = np.concatenate([1e3 * (b - t)[band] for b, t in zip(on, truth, strict=True)])
        ok = np.isfinite(d) & np.isfinite(ea) & np.isfinite(eb)
        label = f"{lo}-{hi}" if hi is not None else f">= {lo}"
        print(f"| {label} | {ok.sum()} | {np.sqrt(np.mean(d[ok] ** 2)):.2f} | {np.mean(d[ok]):+.2f} | "
              f"{np.sqrt(np.mean(ea[ok] ** 2)):.1f} / {np.sqrt(np.mean(eb[ok] ** 2)):.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--calls", type=int, default=9)
    ap.add_argument("--steps", type=Path, default=None,
                    help="a gauge case's accuracy_matrix.py --keep folder: where the option moves its steps")
    a = ap.parse_args()
    if a.steps is not None:
        steps(a.steps)
        return
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
