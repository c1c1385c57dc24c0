"""Study: how many of the adaptive support's grown pixels take a plane box, and what the pass costs
with and without boxes, on three frames.

Usage::

    ./run python benchmarks/study_box_share.py [--chi-z 0,3,10,30] [--rounds 5] [--keep DIR]

The frames: the stage benchmark's 640 x 480 rig frame (``bench_stages.py``, as
``study_adaptive_visits.py`` builds it), the first frame of the capture-session demo (bench preset
``demo``, 400 x 300, 8 bit) and a frame of the workflow benchmark's plain 640 x 480 8-bit session
(``bench_workflow.py``'s bench configuration, 64 bands x 2 repeats). Each demo and workflow frame is
measured once by the workflow's stages at config.yaml's defaults (``accuracy_matrix.measure``);
the phase filter's inputs of its first call are kept. Then, per frame and per ``box_chi_z``
(0 = rings only), the adaptive pass (``phase._adaptive_pass``, as ``denoise_weighted`` calls it)
runs ``--rounds`` interleaved rounds: CPU ms (median), the grown pixels (first-pass weight below
the target) and the share of them that took a box or went to the rings after the box's band,
scatter or mean test, and the neighbour visits left to the rings (``(2 r + 1)^2`` per ring pixel).
One thread (``NUMBA_NUM_THREADS=1``).
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402
from bench_workflow import bench_config  # noqa: E402
from study_adaptive_visits import filter_inputs  # noqa: E402

from huefringe import bench  # noqa: E402
from huefringe.phase import _denoise, adaptive_kwargs, band_floor, first_pass  # noqa: E402
from huefringe.settings import defaults  # noqa: E402

CODES = ("no box tried", "box", "band", "scatter", "mean")


def captured_inputs(cfg: dict, where: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``dz, s2, inv`` of the phase filter's first call while the session of ``cfg`` is measured."""
    seen: list[tuple[np.ndarray, ...]] = []
    inner = _denoise._adaptive_pass

    def spy(*args):  # noqa: ANN002, ANN202 - the pass's positional arguments
        if not seen:
            seen.append(tuple(np.array(a) for a in args[:3]))
        return inner(*args)

    session, tables = am._case_dirs(where, cfg)
    _denoise._adaptive_pass = spy
    try:
        am.measure(session, tables, where / "measured", am._config({}))
    finally:
        _denoise._adaptive_pass = inner
    return seen[0]


def study(name: str, dz: np.ndarray, s2: np.ndarray, inv: np.ndarray, chi_zs: list[float], rounds: int) -> None:
    m = defaults()["measurement"]
    radius = int(m["denoise_radius"])
    ad = adaptive_kwargs(m["denoise_adaptive"])
    big = int(ad["max_radius"])
    k2 = np.float32(9.0)
    first, wfirst = np.empty_like(dz), np.empty_like(dz)
    first_pass(dz, s2, inv, radius, k2, first, wfirst)
    tw, rw = np.float32(1 / ad["target_sigma"] ** 2), np.float32(1 / ad["reject_sigma"] ** 2)
    none = np.empty((1, 1), np.float32)
    grown = (inv > 0) & (wfirst < tw)
    runs = {}
    for z in chi_zs:
        out, wout, rad, boxed = (np.empty_like(dz) for _ in range(4))
        s2min = band_floor(s2, big) if z > 0 else none
        args = (dz, s2, inv, first, wfirst, radius, big, k2, tw, rw, out, wout, rad, True, z, s2min, False,
                none, none, none, boxed, np.float32(ad["plane_kink_sigma"] ** 2), none)
        _denoise._adaptive_pass(*args)  # compiled or loaded from the cache
        runs[z] = (args, [], out, rad, boxed)
    for _ in range(rounds):
        for z, (args, cpu, *_rest) in runs.items():
            c = time.process_time()
            if z > 0:  # as denoise_weighted: the band's floor is part of the cost
                band_floor(args[1], big)
            _denoise._adaptive_pass(*args)
            cpu.append(time.process_time() - c)
    h, w = dz.shape
    print(f"\n{name}, {w} x {h}: {int(grown.sum())} grown pixels ({grown.mean():.1%} of the frame)")
    for z, (args, cpu, out, rad, boxed) in runs.items():
        codes = np.bincount(boxed[grown].astype(np.int64), minlength=5)[:5] / max(int(grown.sum()), 1)
        ring = grown & (boxed != 1)
        visits = int(((2 * rad[ring].astype(np.int64) + 1) ** 2).sum())
        share = ", ".join(f"{n} {c:.1%}" for n, c in zip(CODES, codes, strict=True) if c) if z > 0 else "rings only"
        print(f"  box_chi_z {z:g}: {1e3 * statistics.median(cpu):.1f} ms CPU; {share}; ring visits {visits / 1e6:.2f} M")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--chi-z", default="0,3,10,30")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--keep", type=Path, default=None, help="keep (and reuse) the measured sessions here")
    a = ap.parse_args(argv)
    chi_zs = [float(x) for x in a.chi_z.split(",")]
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    study("bench_stages rig frame", *filter_inputs(640, 480, 64), chi_zs, a.rounds)
    with tempfile.TemporaryDirectory() as tmp:
        root = a.keep or Path(tmp)
        demo = bench.load_bench_config(bench.preset_path("demo"))
        demo["session"]["frames"] = 1
        demo["phase_shift"]["enabled"] = False
        study("demo frame", *captured_inputs(bench.validate_bench_config(demo), root / "demo-1"), chi_zs, a.rounds)
        wf = bench_config(640, 480, 1, 64, 2, predistorted=False)
        study("workflow 8-bit frame", *captured_inputs(bench.validate_bench_config(wf), root / "workflow-plain-1"),
              chi_zs, a.rounds)
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
