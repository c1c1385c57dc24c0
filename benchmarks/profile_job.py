"""Study: what a workflow measurement job spends a frame on, from the stage itself.

Usage::

    ./run python benchmarks/bench_workflow.py --sizes 20 --kinds plain --heights-only --work DIR   # the session, once
    ./run python benchmarks/profile_job.py DIR/plain-n20/workflow [--frames 10] [--top 18]

On a workflow folder that ``bench_workflow.py --work`` kept (its config, session and calibration),
``huefringe.stages.measure_frames`` runs the job's first ``--frames`` frames in this process on
one core (``NUMBA_NUM_THREADS=1``) with the workflow's settings (height, QA, uncertainty and
support maps, the camera corrections): once to warm up, once timed (ms a frame, the batch's ready
phase included), once under ``cProfile`` (the ``--top`` functions by own time). Then the
sigma-adaptive pass on the first frame's inputs, as the job called it, timed alone (CPU ms,
median of 7): as called, without the carried texture change, without the window sizes either, and
without the grown windows' bias either (the pass's arguments found by name).
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse  # noqa: E402
import cProfile  # noqa: E402
import inspect  # noqa: E402
import pstats  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from huefringe.phase import _denoise  # noqa: E402
from huefringe.stages import measure_frames  # noqa: E402


def job_kwargs(wf: Path, frames: list[int], out: Path) -> dict:
    """``measure_frames`` keywords of a job of the workflow folder ``wf`` for ``frames``."""
    cfg = yaml.safe_load((wf / "config.yaml").read_text())
    session = cfg["sessions"][0]
    sid = yaml.safe_load((Path(session) / "session.yaml").read_text())["id"]
    cal = wf / "results" / sid / "calib"
    return dict(session=session, frames=frames, table=str(cal / "table_object.json"),
                model=str(cal / "phase_to_height.npz"), hue_model=cfg["hue_model"], measurement=cfg["measurement"],
                calibration=cfg.get("calibration", {}), heights=[str(out / f"h{k}.tiff") for k in frames],
                qa=[str(out / f"q{k}.json") for k in frames], phases=[], hues=[], map_frames=[],
                uncertainties=[str(out / f"u{k}.tiff") for k in frames],
                supports=[str(out / f"s{k}.tiff") for k in frames], camera_json=str(cal / "camera.json"))


def _cpu_ms(args: tuple, rounds: int = 7) -> float:
    _denoise._adaptive_pass(*args)
    ts = []
    for _ in range(rounds):
        t0 = time.process_time()
        _denoise._adaptive_pass(*args)
        ts.append(time.process_time() - t0)
    return 1e3 * float(np.median(ts))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("workflow", type=Path, help="a workflow folder kept by bench_workflow.py --work")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--top", type=int, default=18)
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="hf-profile-job-") as tmp:
        kw = job_kwargs(a.workflow, list(range(a.frames)), Path(tmp))
        seen: list[tuple] = []
        inner = _denoise._adaptive_pass

        def spy(*args):  # noqa: ANN002, ANN202 - the pass's positional arguments
            if not seen:
                seen.append(tuple(np.array(x) if isinstance(x, np.ndarray) else x for x in args))
            return inner(*args)

        _denoise._adaptive_pass = spy
        try:
            measure_frames(**kw)  # warm-up (numba's cache), and the pass's inputs of the first frame
        finally:
            _denoise._adaptive_pass = inner
        t = time.perf_counter()
        measure_frames(**kw)
        print(f"measure_frames in process: {1e3 * (time.perf_counter() - t) / a.frames:.1f} ms a frame "
              f"({a.frames} frames, the ready phase included)")
        prof = cProfile.Profile()
        prof.enable()
        measure_frames(**kw)
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(a.top)
    args = list(seen[0])
    none = np.empty((1, 1), np.float32)
    at = {name: i for i, name in enumerate(inspect.signature(_denoise._adaptive_pass.py_func).parameters)}
    grown = int(((args[at["inv"]] > 0) & (args[at["wfirst"]] < args[at["target_w"]])).sum())
    bare = list(args)  # without the carried change (the grown windows' bias as called)
    bare[at["carry"]], bare[at["c"]], bare[at["cfirst"]], bare[at["cout"]] = False, none, none, none
    norad = list(bare)
    norad[at["rad"]], norad[at["full"]] = none, False
    nobias = list(norad)
    nobias[at["b2o"]] = none
    print(f"adaptive pass, first frame: {grown} of {args[0].size} pixels grow; CPU ms as called "
          f"{_cpu_ms(tuple(args)):.1f} (carry {args[at['carry']]}), without the carried change {_cpu_ms(tuple(bare)):.1f}, "
          f"without the window sizes either {_cpu_ms(tuple(norad)):.1f}, without the grown windows' bias either "
          f"{_cpu_ms(tuple(nobias)):.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
