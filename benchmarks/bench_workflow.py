"""Benchmark: whole-workflow throughput, a long bench session through height maps with Snakemake.

Usage::

    ./run python benchmarks/bench_workflow.py [--frames 1000 --width 640 --height 480] [--cores 2]
                                              [--work DIR] [--json OUT] [--quick]

Steps (each timed):

1. ``session``  the virtual bench writes a session of ``--frames`` frames (the ``demo`` rig: gauge
   blocks, pre-distorted fringe; field of view kept at 80 x 60 mm; no phase-shift captures or
   ground truth, single-sample rendering, so that writing 1000 frames stays short). Reused when
   ``--work`` already holds the same session.
2. ``calibration``  ``snakemake --cores N`` on the calibration targets only (session check, hue
   tables, plane calibration) in a workflow folder of its own (``--directory``) with a config file
   listing the session.
3. ``heights``  ``snakemake --cores N`` with the height maps of every frame as explicit targets
   (the measurement rule also writes phase and hue maps and a QA file per frame: that is the
   workflow as it stands; the point clouds are ``cloud_*`` jobs of their own, made from the
   height maps, so they are not part of this step). frames/s = frames / wall time of this step.
   The measurement jobs use the fused kernel (``measurement.kernel: true``, the default).

Peak memory: the largest sum of the resident set sizes of the process tree (sampled every 0.1 s
with psutil) and the largest single process (``ru_maxrss`` of the children). Every job runs with
``NUMBA_NUM_THREADS=1`` (one core per job).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import psutil
import yaml

from huefringe.settings import load_config

REPO = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
TARGET_FPS = 50.0
TARGET_MB = 4096.0


def _env() -> dict[str, str]:
    env = dict(os.environ)
    for var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = "1"
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


class TreeMemory:
    """Peak of the summed RSS of a process tree, sampled in a thread."""

    def __init__(self, period: float = 0.1) -> None:
        self.period = period
        self.peak = 0
        self._stop = threading.Event()
        self._pids: list[int] = []
        self._thread = threading.Thread(target=self._run, daemon=True)

    def watch(self, pid: int) -> None:
        self._pids.append(pid)

    def _sample(self) -> int:
        total = 0
        for pid in list(self._pids):
            try:
                p = psutil.Process(pid)
                procs = [p, *p.children(recursive=True)]
            except psutil.Error:
                continue
            for q in procs:
                try:
                    total += q.memory_info().rss
                except psutil.Error:
                    pass
        return total

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, self._sample())
            self._stop.wait(self.period)

    def __enter__(self) -> TreeMemory:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def bench_config(width: int, height: int, frames: int, bands: int, repeats: int) -> dict[str, Any]:
    from huefringe import bench

    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("demo")))
    pitch = 80.0 / width  # keep the demo's 80 mm wide field (its blocks fit) and 12 mm period
    cfg["session"].update(width=width, height=height, pixel_pitch_mm=pitch, period_px=12.0 / pitch, hue_bands=bands,
                          repeats=repeats, frames=frames, ground_truth=False, id=f"wf-bench-{width}x{height}")
    cfg["phase_shift"]["enabled"] = False
    cfg["camera"].update(supersample=1, motion_blur_subframes=1)
    return cfg


def write_session(cfg: dict[str, Any], where: Path) -> tuple[Path, float, bool]:
    from huefringe import bench

    stamp = where.with_suffix(".json")
    if (where / "session.yaml").exists() and stamp.exists() and json.loads(stamp.read_text()) == cfg:
        return where, 0.0, True
    t = time.perf_counter()
    bench.write_session(cfg, where)
    stamp.write_text(json.dumps(cfg))
    return where, time.perf_counter() - t, False


def run_snakemake(workdir: Path, config: Path, targets: list[str], cores: int, log: Path) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(workdir),
           "--configfile", str(config), "--cores", str(cores), "--nolock", *targets]
    t = time.perf_counter()
    with log.open("w") as fh, TreeMemory() as mem:
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=_env(), cwd=REPO)
        mem.watch(proc.pid)
        rc = proc.wait()
    dt = time.perf_counter() - t
    if rc != 0:
        sys.stdout.write(log.read_text()[-4000:])
        raise RuntimeError(f"snakemake failed ({rc}); log: {log}")
    return {"seconds": dt, "peak_tree_mb": mem.peak / 1e6}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--bands", type=int, default=64, help="hue bands of the bench session")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--work", type=Path, default=None, help="keep (and reuse) the session and results here")
    ap.add_argument("--quick", action="store_true", help="smoke mode: 6 frames at 160 x 120, 32 bands")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    if a.quick:
        a.frames, a.width, a.height, a.bands = 6, 160, 120, 32
    tmp = None
    if a.work is None:
        tmp = tempfile.TemporaryDirectory(prefix="hf-bench-wf-")
        a.work = Path(tmp.name)
    a.work.mkdir(parents=True, exist_ok=True)
    print(f"workflow benchmark: {a.frames} frames {a.width} x {a.height}, snakemake --cores {a.cores} "
          f"({os.cpu_count()} cores here, load average {os.getloadavg()[0]:.2f}); work folder {a.work}")

    bcfg = bench_config(a.width, a.height, a.frames, a.bands, a.repeats)
    session, t_session, reused = write_session(bcfg, a.work / "session")
    print(f"session: {'reused' if reused else f'written in {t_session:.1f} s'} ({a.bands} bands x {a.repeats})")

    wcfg = load_config(REPO / "config.yaml")
    wcfg["sessions"] = [str(session)]
    wcfg.pop("bench_sessions", None)
    wcfg["results_dir"] = "results"
    wf = a.work / "workflow"
    shutil.rmtree(wf / "results", ignore_errors=True)
    wf.mkdir(parents=True, exist_ok=True)
    (wf / "config.yaml").write_text(yaml.safe_dump(wcfg, sort_keys=False))
    sid = bcfg["session"]["id"]
    calib_rel = Path("results") / sid / "calib"  # targets: relative to the workflow folder
    res: dict[str, Any] = {"frames": a.frames, "size": [a.width, a.height], "bands": a.bands, "cores": a.cores,
                           "machine_cores": os.cpu_count(), "session_seconds": t_session, "session_reused": reused}

    c = run_snakemake(wf, wf / "config.yaml", [str(calib_rel / "table_object.json"), str(calib_rel / "phase_to_height.npz")],
                      a.cores, a.work / "snakemake_calibration.log")
    res["calibration"] = c
    print(f"calibration (check, 2 hue tables, planes): {c['seconds']:.1f} s, peak {c['peak_tree_mb']:.0f} MB")

    targets = [f"results/{sid}/height/frame_{n:04d}.tiff" for n in range(a.frames)]
    h = run_snakemake(wf, wf / "config.yaml", targets, a.cores, a.work / "snakemake_heights.log")
    h["fps"] = a.frames / h["seconds"]
    res["heights"] = h
    res["end_to_end_fps"] = a.frames / (c["seconds"] + h["seconds"])
    res["max_single_process_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    per_job = int(wcfg["measurement"]["frames_per_job"])
    print(f"heights ({-(-a.frames // per_job)} jobs of {per_job} frames): {h['seconds']:.1f} s = {h['fps']:.1f} frames/s, "
          f"peak {h['peak_tree_mb']:.0f} MB (whole tree); calibration + heights {res['end_to_end_fps']:.1f} frames/s")

    res["max_single_process_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    res["target_fps"], res["target_mb"] = TARGET_FPS, TARGET_MB
    if a.json:
        a.json.write_text(json.dumps(res, indent=2))
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
