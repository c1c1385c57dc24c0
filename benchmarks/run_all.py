"""Run every benchmark in one go and print a summary table.

Usage::

    ./run python benchmarks/run_all.py [--quick] [--work DIR] [--skip kernel,calibration,workflow]

Parts (each in its own process, so that one-core settings and peak memory are its own):

``kernel``       ``bench_kernel.py``: per-frame kernel at 768 x 494 and 1280 x 1024 on one core,
                 against cv2.cvtColor RGB->HSV (floor) and the NumPy reference, same frame.
``calibration``  ``bench_calibration.py``: hue tables from 256 bands x 3 repeats at 768 x 494.
``workflow``     ``bench_workflow.py``: 20-, 200- and 1000-frame 640 x 480 bench sessions (plain and
                 pre-distorted) with ``snakemake --cores 2``, marginal frames/s beside the I/O floor.

The full run takes 6-10 minutes on 2 cores (most of it writing the 1000-frame session and
running the current measurement stage); ``--quick`` shrinks everything to a smoke test of a
minute or less (figures then mean nothing). Timings are taken on whatever else runs on the
machine: each benchmark reports ratios measured in the same run and CPU times next to wall
times; read absolute figures with the load average printed next to them.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
PARTS = ("kernel", "calibration", "workflow")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["NUMBA_NUM_THREADS"] = "1"
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


def _run(cmd: list[str], label: str) -> str:
    """Run a benchmark, echoing its output; return the output."""
    print(f"\n=== {label}: {' '.join(Path(c).name if i < 2 else c for i, c in enumerate(cmd))}", flush=True)
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=_env())
    lines = []
    assert proc.stdout is not None
    for line in proc.stdout:
        sys.stdout.write(line)
        sys.stdout.flush()
        lines.append(line)
    if proc.wait() != 0:
        raise SystemExit(f"{label} failed (exit {proc.returncode})")
    print(f"=== {label}: {time.perf_counter() - t:.0f} s", flush=True)
    return "".join(lines)


def kernel_part(work: Path, quick: bool) -> dict[str, Any]:
    out = work / "kernel.json"
    _run([sys.executable, str(HERE / "bench_kernel.py"), "--json", str(out), *(["--quick"] if quick else [])], "kernel")
    return json.loads(out.read_text())


def calibration_part(work: Path, quick: bool) -> dict[str, Any]:
    size = ["--width", "160", "--height", "120", "--bands", "32", "--repeats", "2"] if quick else \
        ["--width", "768", "--height", "494", "--bands", "256", "--repeats", "3"]
    text = _run([sys.executable, str(HERE / "bench_calibration.py"), *size, "--dir", str(work / "calibration")],
                "calibration")
    res: dict[str, Any] = {"size": size}
    m = re.search(r"build_table\s*:\s*([\d.]+) s\s+peak RSS\s+([\d.]+) MB", text)
    if m:
        res["build_s"], res["build_peak_rss_mb"] = float(m.group(1)), float(m.group(2))
    m = re.search(r"read only\s*:\s*([\d.]+) s", text)
    if m:
        res["read_s"] = float(m.group(1))
    m = re.search(r"table \(uint16 N\*H\*W\*2\): ([\d.]+) MB", text)
    if m:
        res["table_mb"] = float(m.group(1))
    return res


def workflow_part(work: Path, quick: bool) -> dict[str, Any]:
    out = work / "workflow.json"
    _run([sys.executable, str(HERE / "bench_workflow.py"), "--json", str(out), "--work", str(work / "workflow"),
          *(["--quick"] if quick else [])], "workflow")
    return json.loads(out.read_text())


def _status(ok: bool | None, quick: bool) -> str:
    if ok is None:
        return "info"
    if quick:
        return "(smoke)"
    return "met" if ok else "MISSED"


def summary(res: dict[str, Any], quick: bool, elapsed: float) -> None:
    rows: list[tuple[str, str, str, str]] = []
    k = res.get("kernel")
    if k:
        for i, r in enumerate(k["results"]):
            w, h = r["size"]
            fps_wall, fps_cpu = r["fps"]["wall_best"], r["fps"]["cpu"]
            target = k["target_fps"] if i == 0 else None
            rows.append((f"kernel {w}x{h}, {r['bands']} bands, 1 core",
                         f"{r['ms']['kernel']['wall_best']:.2f} ms = {fps_wall:.0f} frames/s (CPU {fps_cpu:.0f})",
                         f">= {target:.0f} frames/s" if target else "", _status(fps_wall >= target if target else None,
                                                                                 quick)))
            ratio = r["ratio_kernel_to_cvtcolor"]["wall"]
            rows.append((f"  kernel / cvtColor RGB2HSV {w}x{h}", f"x{ratio:.1f}", "<= x10",
                         _status(ratio <= k["target_cv_ratio"], quick)))
            if "ratio_table_reads_to_cvtcolor" in r:
                rows.append((f"  table reads alone / cvtColor {w}x{h}",
                             f"x{r['ratio_table_reads_to_cvtcolor']['wall']:.1f} (kernel = "
                             f"x{r['ratio_kernel_to_table_reads']['wall']:.2f} its table reads)", "", "info"))
            rows.append((f"  speed-up vs NumPy reference {w}x{h}", f"{r['speedup_vs_numpy']['wall']:.0f}x", "", "info"))
            if "speedup_vs_numpy_dn2" in r:
                rows.append((f"  kernel+denoise 2 {w}x{h}",
                             f"{r['ms']['kernel+dn2']['wall_best']:.1f} ms, {r['speedup_vs_numpy_dn2']['wall']:.1f}x "
                             "the reference", "", "info"))
            c = r["checks"]
            rows.append((f"  max |kernel - reference| {w}x{h}",
                         f"{max(c['dn0']['max_abs_diff_mm'], c['dn2']['max_abs_diff_mm']):.1e} mm",
                         "<= 1e-4 mm", _status(max(c['dn0']['max_abs_diff_mm'], c['dn2']['max_abs_diff_mm']) <= 1e-4
                                              and c["dn0"]["same_valid"] and c["dn2"]["same_valid"], False)))
    c = res.get("calibration")
    if c and "build_s" in c:
        w, h, n, r = c["size"][1::2]
        rows.append((f"hue tables {n} bands x {r} repeats at {w}x{h}", f"{c['build_s']:.1f} s", "< 30 s",
                     _status(c["build_s"] < 30, quick)))
        rows.append(("  tables peak RSS", f"{c['build_peak_rss_mb']:.0f} MB", "< 2048 MB",
                     _status(c["build_peak_rss_mb"] < 2048, quick)))
    wf = res.get("workflow")
    if wf:
        w, h = wf["size"]
        for kind, kr in wf["kinds"].items():
            for key, m in kr.items():
                if not key.startswith("marginal_"):
                    continue
                n1, n2 = key.split("_")[1:]
                rows.append((f"workflow {kind} {w}x{h}, {n1} -> {n2} frames: heights (marginal)",
                             f"{m['heights_fps']:.1f} frames/s = {m['heights_vs_floor']:.2f} x I/O floor ({m['floor_fps']:.0f})",
                             ">= 0.2 x floor (moonshot 0.4)", _status(m["heights_vs_floor"] >= 0.2, quick)))
                rows.append((f"  default target set (marginal)",
                             f"{m['default_fps']:.1f} frames/s = {m['default_vs_floor']:.2f} x I/O floor", ">= 0.2 x floor",
                             _status(m["default_vs_floor"] >= 0.2, quick)))
        rows.append(("  peak memory of one job", f"{wf['peak_job_mb']:.0f} MB", "< 2000 MB",
                     _status(wf["peak_job_mb"] < 2000, quick)))
    width = max(len(r[0]) for r in rows) if rows else 10
    print(f"\n=== summary ({'QUICK smoke run: figures are meaningless' if quick else 'full run'}; "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} now; {elapsed / 60:.1f} min)")
    print(f"{'item':<{width}}  {'measured':<44} {'target':<16} status")
    for r in rows:
        print(f"{r[0]:<{width}}  {r[1]:<44} {r[2]:<16} {r[3]}")
    print("Machine shared with other work: wall figures carry its load; the kernel's CPU-time figure and the "
          "same-run ratios are the steadier ones.")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smoke mode (tiny sizes; used by the tests)")
    ap.add_argument("--work", type=Path, default=None, help="folder for sessions and results (default: temporary)")
    ap.add_argument("--skip", default="", help=f"comma-separated parts to skip: {', '.join(PARTS)}")
    ap.add_argument("--json", type=Path, default=None, help="write all results here")
    a = ap.parse_args(argv)
    skip = {s.strip() for s in a.skip.split(",") if s.strip()}
    unknown = skip - set(PARTS)
    if unknown:
        ap.error(f"unknown parts {sorted(unknown)}")
    tmp = None
    if a.work is None:
        tmp = tempfile.TemporaryDirectory(prefix="hf-bench-")
        a.work = Path(tmp.name)
    a.work.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    res: dict[str, Any] = {"cores": os.cpu_count(), "loadavg_start": list(os.getloadavg()), "quick": a.quick}
    for name, fn in (("kernel", kernel_part), ("calibration", calibration_part), ("workflow", workflow_part)):
        if name not in skip:
            res[name] = fn(a.work, a.quick)
    res["loadavg_end"] = list(os.getloadavg())
    summary(res, a.quick, time.perf_counter() - t)
    if a.json:
        a.json.write_text(json.dumps(res, indent=2))
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
