"""Benchmark: the per-frame kernel (``huefringe.kernel``) on one core, against two references.

Usage::

    ./run python benchmarks/bench_kernel.py [--sizes 768x494,1280x1024] [--bands 256] [--json OUT]
                                            [--quick]

For each sensor size, on the same uint8 frame of a realistic rig (a hue table built with
``huetable.build_table`` from 256 captured bands through a projector-camera model with gamma,
crosstalk, coloured and dark patches and noise: the toy rig; see ``_kernel_case.py``), it measures

``kernel``      ``kernel.frame_to_height(prep, frame_u8)`` (denoise off),
``kernel+dn2``  the same with ``denoise_radius=2`` (the workflow's setting),
``kernel+dn2+u`` the same with the uncertainty map,
``kernel+ad``   ``denoise_radius=2`` with the sigma-adaptive support (the workflow's filter),
``kernel+ad+u`` the same with the uncertainty map (what the measurement stage calls),
``cvtColor``    ``cv2.cvtColor(frame, COLOR_RGB2HSV)``, the floor: one colour conversion pass,
``numpy``       ``perframe.measure_frame(frame_f32, ..., denoise_radius=0)``, the reference
                implementation (NumPy, plus the compiled table lookup it already has),
``numpy+dn2``   the reference with ``denoise_radius=2`` (first size only: it is slow).
``table-reads`` a floor of another kind: reading, for every pixel, the one cache line of its
                table column that the kernel reads for this frame (no other arithmetic): what
                the per-pixel table costs in memory traffic alone.

Self-calibrating: all single-threaded (``NUMBA_NUM_THREADS=1``, ``cv2.setNumThreads(1)``), and
measured in interleaved rounds, so that each round's ratios compare runs made under the same
machine load; the figures reported are medians over rounds of per-round values. Times are given
as wall clock (best round and median) and as thread CPU time (``time.thread_time``, which leaves
out the time the process waited for a core on a busy machine).

The kernel's heights are checked against the reference on every size (max |difference|, same
valid mask) and against the rendered surface (median |error|), so that a fast wrong answer shows.
The larger sensor reuses the first rig's table and frame, tiled (the lookup cost does not depend
on where a column came from; building a 1280 x 1024 table would only cost time).
"""

from __future__ import annotations

import os

for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable  # noqa: E402

import cv2  # noqa: E402
import numba  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _kernel_case import KernelCase, make_case, tile_case  # noqa: E402

from huefringe import kernel, perframe  # noqa: E402

TARGET_FPS = 200.0
TARGET_CV_RATIO = 10.0


@numba.njit(cache=True, nogil=True)
def _table_reads(cols, lines, ncols, hq):  # pragma: no cover - numba
    """Count, for every pixel, the entries <= its hue in the table line ``lines[i]`` (-1: none),
    with the kernel's two 16-wide vector compares."""
    total = 0
    for i in range(lines.size):
        line = lines[i]
        if line < 0:
            continue
        o = i * ncols + 32 * line
        total += kernel._count16_le(cols, o, hq[i]) + kernel._count16_le(cols, o + 16, hq[i])
    return total


def table_lines(prep: Any, hue: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The guessed table line of every usable pixel for this frame's hue (as the kernel's pass 1)."""
    h, w = prep.shape
    hq = np.nan_to_num(hue.astype(np.float64) * (65536.0 / (2 * np.pi)), nan=-1.0)
    vv, uu = np.mgrid[0:h, 0:w]
    tile = (vv // kernel._TILE) * prep.tiles_x + uu // kernel._TILE
    use = (hq >= 0) & prep.ok
    lines = np.where(use, prep.guess[tile, np.clip(hq, 0, 65535).astype(np.int64) >> kernel._SHIFT], -1)
    return lines.astype(np.int64).ravel(), np.floor(np.maximum(hq, 0)).astype(np.uint16).ravel()


def _time(fn: Callable[[], Any], reps: int) -> tuple[float, float]:
    """(wall, cpu) seconds per call over ``reps`` calls."""
    w0, c0 = time.perf_counter(), time.thread_time()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - w0) / reps, (time.thread_time() - c0) / reps


def _reps_for(fn: Callable[[], Any], min_time: float) -> int:
    w, _ = _time(fn, 1)
    return max(1, int(min_time / max(w, 1e-6)))


def bench_size(rig: KernelCase, *, rounds: int, min_time: float, with_dn2_reference: bool) -> dict[str, Any]:
    h, w = rig.table.shape
    cv2.setNumThreads(1)
    t0 = time.perf_counter()
    prep = kernel.prepare(rig.table, rig.cal, rig.white, hue_model="hexcone", min_saturation=0.08, shadow=0.12,
                          bit_depth=8)
    prep_s = time.perf_counter() - t0
    frame = rig.frame
    frame_f32 = frame.astype(np.float32) * np.float32(1 / 255)  # what session.read_rgb returns
    shadow = perframe.shadow_mask(rig.white, 0.12)
    buf = (np.empty((h, w), np.float32), np.empty((h, w), bool))

    def k0() -> Any:
        return kernel.frame_to_height(prep, frame, out=buf)

    def k2() -> Any:
        return kernel.frame_to_height(prep, frame, denoise_radius=2, out=buf)

    def k2a() -> Any:  # the workflow's filter: sigma-adaptive support (measurement.denoise_adaptive)
        return kernel.frame_maps(prep, frame, denoise_radius=2, denoise_adaptive=True, out=buf)

    def k2au() -> Any:  # the measurement stage's call: adaptive filter and the uncertainty map
        return kernel.frame_maps(prep, frame, denoise_radius=2, denoise_adaptive=True, want_uncertainty=True, out=buf)

    def k2u() -> Any:  # the fixed filter with the uncertainty map
        return kernel.frame_maps(prep, frame, denoise_radius=2, want_uncertainty=True, out=buf)

    def cvt() -> Any:
        return cv2.cvtColor(frame, cv2.COLOR_RGB2HSV)

    def ref(radius: int) -> Callable[[], Any]:
        return lambda: perframe.measure_frame(frame_f32, rig.white, rig.table, rig.cal, hue_model="hexcone",
                                              min_saturation=0.08, shadow=shadow, bit_depth=8, unwrap_mode="reference",
                                              denoise_radius=radius)

    # correctness on this frame (and warm-up of every compiled path)
    checks = {}
    for radius in (0, 2):
        r = ref(radius)()
        hk, vk = kernel.frame_to_height(prep, frame, denoise_radius=radius)
        d = np.abs(hk[vk].astype(np.float64) - r.height[vk]) if vk.any() else np.zeros(1)
        checks[f"dn{radius}"] = {"max_abs_diff_mm": float(d.max()), "same_valid": bool(np.array_equal(vk, r.valid)),
                                 "valid_fraction": float(vk.mean())}
    hk, vk = kernel.frame_to_height(prep, frame)
    checks["median_abs_error_vs_surface_mm"] = float(np.median(np.abs(hk[vk] - rig.truth[vk])))

    lines, hq16 = table_lines(prep, kernel.frame_maps(prep, frame, want_maps=True).hue)
    cols_flat = prep.cols.reshape(-1)
    ncols = prep.cols.shape[2]

    def reads() -> Any:
        return _table_reads(cols_flat, lines, ncols, hq16)

    cases: dict[str, Callable[[], Any]] = {"kernel": k0, "kernel+dn2": k2, "kernel+dn2+u": k2u, "kernel+ad": k2a,
                                           "kernel+ad+u": k2au, "cvtColor": cvt,
                                           "numpy": ref(0),
                                           "table-reads": reads}
    if with_dn2_reference:
        cases["numpy+dn2"] = ref(2)
    reps = {k: _reps_for(f, min_time) for k, f in cases.items()}
    per_round: dict[str, list[tuple[float, float]]] = {k: [] for k in cases}
    for _ in range(rounds):
        for k, f in cases.items():
            per_round[k].append(_time(f, reps[k]))
    wall = {k: [x[0] for x in v] for k, v in per_round.items()}
    cpu = {k: [x[1] for x in v] for k, v in per_round.items()}

    def ratio(a: str, b: str, src: dict[str, list[float]]) -> float:
        return statistics.median(x / y for x, y in zip(src[a], src[b], strict=True))

    out: dict[str, Any] = {
        "size": [w, h],
        "bands": rig.table.n_bands,
        "prepare_s": prep_s,
        "prepared_mb": prep.nbytes / 1e6,
        "table_mb": rig.table.table.nbytes / 1e6,
        "reps": reps,
        "rounds": rounds,
        "checks": checks,
        "ms": {k: {"wall_best": 1e3 * min(wall[k]), "wall_median": 1e3 * statistics.median(wall[k]),
                   "cpu_median": 1e3 * statistics.median(cpu[k])} for k in cases},
        "ratio_uncertainty_to_adaptive": {"wall": ratio("kernel+ad+u", "kernel+ad", wall),
                                          "cpu": ratio("kernel+ad+u", "kernel+ad", cpu)},
        "ratio_uncertainty_to_dn2": {"wall": ratio("kernel+dn2+u", "kernel+dn2", wall),
                                     "cpu": ratio("kernel+dn2+u", "kernel+dn2", cpu)},
        "ratio_kernel_to_cvtcolor": {"wall": ratio("kernel", "cvtColor", wall), "cpu": ratio("kernel", "cvtColor", cpu)},
        "speedup_vs_numpy": {"wall": ratio("numpy", "kernel", wall), "cpu": ratio("numpy", "kernel", cpu)},
        "ratio_kernel_to_table_reads": {"wall": ratio("kernel", "table-reads", wall),
                                        "cpu": ratio("kernel", "table-reads", cpu)},
        "ratio_table_reads_to_cvtcolor": {"wall": ratio("table-reads", "cvtColor", wall),
                                          "cpu": ratio("table-reads", "cvtColor", cpu)},
    }
    if with_dn2_reference:
        out["speedup_vs_numpy_dn2"] = {"wall": ratio("numpy+dn2", "kernel+dn2", wall),
                                       "cpu": ratio("numpy+dn2", "kernel+dn2", cpu)}
    out["fps"] = {"wall_best": 1e3 / out["ms"]["kernel"]["wall_best"], "cpu": 1e3 / out["ms"]["kernel"]["cpu_median"]}
    return out


def print_size(r: dict[str, Any]) -> None:
    w, h = r["size"]
    print(f"\n{w} x {h}, {r['bands']} bands: prepare {r['prepare_s']:.2f} s, prepared data {r['prepared_mb']:.0f} MB "
          f"(band-major table {r['table_mb']:.0f} MB); {r['rounds']} interleaved rounds")
    print(f"  {'case':<12} {'wall best':>10} {'wall median':>12} {'cpu median':>11}   (ms per frame)")
    for k, m in r["ms"].items():
        print(f"  {k:<12} {m['wall_best']:10.2f} {m['wall_median']:12.2f} {m['cpu_median']:11.2f}")
    print(f"  kernel: {r['fps']['wall_best']:.0f} frames/s (best wall), {r['fps']['cpu']:.0f} frames/s (CPU time); "
          f"x{r['ratio_kernel_to_cvtcolor']['wall']:.1f} the time of cvtColor RGB->HSV "
          f"(cpu x{r['ratio_kernel_to_cvtcolor']['cpu']:.1f}); "
          f"{r['speedup_vs_numpy']['wall']:.0f}x faster than the NumPy reference")
    print(f"  the table reads alone (one line per pixel, no arithmetic) take x{r['ratio_table_reads_to_cvtcolor']['wall']:.1f} "
          f"the time of cvtColor; the kernel takes x{r['ratio_kernel_to_table_reads']['wall']:.2f} the time of its table reads")
    print(f"  with the uncertainty map (denoise 2): x{r['ratio_uncertainty_to_dn2']['wall']:.3f} the time without "
          f"(cpu x{r['ratio_uncertainty_to_dn2']['cpu']:.3f}; target <= 1.15)")
    print(f"  with the uncertainty map (the workflow's adaptive filter): "
          f"x{r['ratio_uncertainty_to_adaptive']['wall']:.3f} the time without "
          f"(cpu x{r['ratio_uncertainty_to_adaptive']['cpu']:.3f}; target <= 1.15)")
    if "speedup_vs_numpy_dn2" in r:
        print(f"  with denoise radius 2: {r['speedup_vs_numpy_dn2']['wall']:.1f}x faster than the reference")
    c = r["checks"]
    print(f"  check: max |kernel - reference| {c['dn0']['max_abs_diff_mm']:.1e} mm (denoise 2: "
          f"{c['dn2']['max_abs_diff_mm']:.1e} mm), same valid mask {c['dn0']['same_valid'] and c['dn2']['same_valid']}, "
          f"valid {100 * c['dn0']['valid_fraction']:.1f} %, median |error| vs surface "
          f"{c['median_abs_error_vs_surface_mm']:.4f} mm")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="768x494,1280x1024", help="WxH,WxH,... (the first one builds the table)")
    ap.add_argument("--bands", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=2, help="repeats of each band for the table (noise estimate)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--min-time", type=float, default=0.25, help="seconds per case per round")
    ap.add_argument("--quick", action="store_true", help="smoke mode: 192x120, 32 bands, 2 short rounds")
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    a = ap.parse_args(argv)
    if a.quick:
        a.sizes, a.bands, a.rounds, a.min_time = "192x120,256x160", 32, 2, 0.02
    sizes = [tuple(int(x) for x in s.lower().split("x")) for s in a.sizes.split(",")]
    print(f"kernel benchmark: {os.cpu_count()} cores on this machine, measured on 1 "
          f"(NUMBA_NUM_THREADS={os.environ['NUMBA_NUM_THREADS']}); load average {os.getloadavg()[0]:.2f}")
    t = time.perf_counter()
    w0, h0 = sizes[0]
    base = make_case(w0, h0, n_bands=a.bands, repeats=a.repeats)
    print(f"rig {w0} x {h0}: table of {a.bands} bands x {a.repeats} repeats built in {base.build_seconds:.1f} s "
          f"(in memory), valid {100 * base.table.stats['valid_fraction']:.1f} %; total {time.perf_counter() - t:.1f} s")
    results = []
    for i, (w, h) in enumerate(sizes):
        rig = base if (w, h) == (w0, h0) else tile_case(base, w, h)
        r = bench_size(rig, rounds=a.rounds, min_time=a.min_time, with_dn2_reference=(i == 0))
        print_size(r)
        results.append(r)
        del rig
    doc = {"cores": os.cpu_count(), "numba_threads": 1, "loadavg": list(os.getloadavg()), "bands": a.bands,
           "results": results, "target_fps": TARGET_FPS, "target_cv_ratio": TARGET_CV_RATIO}
    if a.json:
        a.json.write_text(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
