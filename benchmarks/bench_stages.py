"""Benchmark: per-frame milliseconds of the measurement chain, stage by stage, against references
measured in the same run.

Usage::

    ./run python benchmarks/bench_stages.py [--sizes 640x480,1280x1024] [--bands 64] [--rounds 5]
                                            [--threads 1] [--markdown OUT.md] [--json OUT.json] [--quick]
                                            [--page docs/throughput.md] [--box-chi-z Z]

On the kernel benchmark's toy rig (``_kernel_case.py``: a hue table built from captured bands, a
known surface with steps and a dome, coloured and dark reflectance patches, so that the texture
correction and the adaptive filter have edges to work on) it runs one frame through what
``pipeline.measure_one`` runs for it with the default measurement settings, a texture blur of
0.4 px^2 and its uncertainty 0.1 px^2 (the demo's order), and times each stage:

``read``         decoding the frame's PNG (``session.read_rgb_codes``),
``texture``      the texture-edge correction (``texture.correct``, with the light without fringe the bands give) of the capture,
``kernel``       the fused kernel without the filter (``kernel.frame_maps``, phase difference),
``filter``       the phase filter at ``denoise_radius`` (the kernel with it, minus without),
``adaptive``     its sigma-adaptive support (with minus without),
``uncertainty``  the uncertainty map (with minus without),
``texture u``    the texture term of the uncertainty (``frame_maps``'s ``texture_rgb`` where the library
                 has it, otherwise the second corrected capture through the filtered chain),
``flags``        the frame statistics, the step-edge mask (with the shadow-side pixels dropped after it)
                 and the lateral term,
``write``        the height, uncertainty and support TIFFs,

and two references on the same frame: ``cv2.cvtColor(RGB2HSV)`` (one colour pass) and the **I/O
floor** (decoding the PNG plus writing the float32 height TIFF: what a chain that computed
nothing would cost).

Beside it (``--tables plane,oneshot``, the default; ``--tables oneshot`` alone) the **one-shot rig
path**: one trapezoid frame of the bench's holdout-wide rig (``huefringe.bench.oneshot``: the
paper's gauge blocks on a tilted base, a hue table of ``--bands`` bands x 2 repeats built from the scene's
captures, the order from the base plane's Gray code + phase, a calibration from 6 simulated board
poses with its 6 leave-one-pose-out calibrations; at other sizes the same rig and calibrations
with the camera's focal length and principal point scaled, so the view is the same) through what
``huefringe.rig.oneshot.measure_oneshot`` and the rig route's calibration term run for it:

``read``         decoding the colour PNG to float RGB (as ``oneshot_captures`` reads it),
``decode``       ``trapezoid_coordinate``: white balance, hue, the table's inverse and slope, sigma,
``order``        ``absolute_from_reference``: the order nearest the reference, the flags,
``triangulate``  ``huefringe.rig.triangulate`` with ``sigma_u`` (ray against the projector plane),
``calibration u`` ``huefringe.rig.measure.calibration_spread``: the leave-one-pose-out calibrations' term,
``write``        the X, Y, Z, sigma and u TIFFs,

with its own cvtColor and I/O floor on its frame, timed the same way. Stages are timed in interleaved rounds (medians over rounds;
with ``--reps R`` of each stage's best of R calls in a round), one core
(``NUMBA_NUM_THREADS``, ``cv2.setNumThreads`` = ``--threads``), as CPU time of the process (so
that time spent waiting for a core on a busy machine is left out; the best wall times are in the
JSON). The table gives ms per frame and
each stage's ratio to ``cvtColor``; the chain's frames/s on 2 cores is twice the one-core rate of
two independent jobs (the workflow's plan).

``--box-chi-z Z`` also times the adaptive support and the uncertainty with
``measurement.denoise_adaptive.box_chi_z`` set to ``Z`` (plane boxes), interleaved with the
default's calls in the same rounds, and prints their rows and the compute row they give.

It prints and never fails on a slow machine: nothing is compared with a limit.
``--quick`` runs 160 x 120 with 16 bands and 2 rounds (seconds; figures mean nothing).
"""

from __future__ import annotations

import argparse
import os
import sys

_pre = argparse.ArgumentParser(add_help=False)
_pre.add_argument("--threads", type=int, default=1)
_THREADS = max(1, _pre.parse_known_args()[0].threads)
for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(_THREADS)

import inspect  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _kernel_case import KernelCase, make_case, tile_case  # noqa: E402

from huefringe import kernel, perframe, texture  # noqa: E402
from huefringe.io import write_tiff  # noqa: E402
from huefringe.session import read_rgb_codes  # noqa: E402
from huefringe.settings import defaults as load_defaults  # noqa: E402
from huefringe.uncertainty import add_lateral, texture_term  # noqa: E402

ONESHOT_STAGES = ("read", "decode", "order", "triangulate", "calibration u", "write")

BLUR_PX2 = 0.4
BLUR_U_PX2 = 0.1
STAGES = ("read", "texture", "kernel", "filter", "adaptive", "uncertainty", "texture u", "flags", "write")


def _clock(fn: Callable[[], Any]) -> tuple[float, float]:
    """(CPU seconds of the process, all threads; wall seconds) of one call."""
    c, t = time.process_time(), time.perf_counter()
    fn()
    return time.process_time() - c, time.perf_counter() - t


def chain(rig: KernelCase, work: Path, box_chi_z: float | None = None) -> dict[str, Callable[[], Any]]:
    """The timed calls of one frame (each a closure over the frame's prepared inputs); with
    ``box_chi_z`` also the adaptive support and the uncertainty with the adaptive support's
    ``box_chi_z`` set to it (``k2 box``, ``k3 box``), timed in the same rounds."""
    m_cfg = load_defaults()["measurement"]
    adaptive = m_cfg["denoise_adaptive"]
    boxed = {**adaptive, "box_chi_z": box_chi_z}
    radius = int(m_cfg["denoise_radius"])
    h, w = rig.table.shape
    png = work / "frame.png"
    cv2.imwrite(str(png), cv2.cvtColor(rig.frame, cv2.COLOR_RGB2BGR))
    shadow = perframe.shadow_mask(rig.white, m_cfg["shadow_fraction"])
    # the pixels on a shadow's side of its edge, dropped after the edge test (measurement.shadow_own_light;
    # an older tree without it times the edge test alone)
    drop: dict[str, Any] = {}
    if m_cfg.get("shadow_own_light") and "drop" in inspect.signature(perframe.remove_step_edges).parameters:
        spill = perframe.shadow_mask(rig.white, m_cfg["shadow_fraction"], own_light=True) & ~shadow
        drop = {"drop": spill} if spill.any() else {}
    prep = kernel.prepare(rig.table, rig.cal, rig.white, hue_model="hexcone", min_saturation=m_cfg["min_saturation"],
                          shadow=shadow, bit_depth=8)
    raw = rig.frame.astype(np.float32) * np.float32(1 / 255)
    clip = perframe.clipped_mask(raw, 8)
    rgb = texture.correct(raw, rig.white, BLUR_PX2, clipped=clip, offset=rig.offset)
    buf = (np.empty((h, w), np.float32), np.empty((h, w), bool))

    def maps(**kw: Any) -> Any:
        return kernel.frame_maps(prep, rgb, want_dphi=True, out=buf, **kw)

    full = maps(denoise_radius=radius, denoise_adaptive=adaptive, want_uncertainty=True)
    height, u_map, support = full.height.copy(), full.uncertainty, full.support

    carried = "texture_rgb" in inspect.signature(kernel.frame_maps).parameters
    if carried:  # the texture term carried through the filter: the moved capture's phase alone
        _, moved = texture.correct_pair(raw, rig.white, BLUR_PX2, BLUR_PX2 + BLUR_U_PX2, clipped=clip,
                                        offset=rig.offset)

        def tex_u() -> Any:
            return maps(denoise_radius=radius, denoise_adaptive=adaptive, want_uncertainty=True, texture_rgb=moved)
    else:  # the second corrected capture through the whole filtered chain

        def tex_u() -> Any:
            mv = texture.correct(raw, rig.white, BLUR_PX2 + BLUR_U_PX2, clipped=clip, offset=rig.offset)
            mh = kernel.frame_maps(prep, mv, denoise_radius=radius, denoise_adaptive=adaptive).height
            return maps(denoise_radius=radius, denoise_adaptive=adaptive, want_uncertainty=True), texture_term(height, mh)

    def flags() -> Any:
        px = full.valid.size
        st = perframe.reference_frame_stats(full.dphi, full.valid, height, clipped_fraction=full.counts["clipped"] / px,
                                            hue_undefined_fraction=full.counts["hue_undefined"] / px,
                                            table_invalid_fraction=0.0, shadow_fraction=0.0, hue_model="hexcone",
                                            flag_valid=np.isfinite(full.dphi))
        hh, (uu,), (ss,), _ = perframe.remove_step_edges(
            height, float(m_cfg["edge_jump_mm"]), nan_maps=(u_map,), zero_maps=(support,),
            test=str(m_cfg["edge_test"]), tol_mm=float(m_cfg["edge_plane_tol_mm"]), **drop)
        return st, add_lateral(hh, uu, lateral_px=float(m_cfg["lateral_uncertainty_px"]),
                               step_px=float(m_cfg["lateral_step_px"]))

    def write() -> None:
        write_tiff(work / "h.tiff", height)
        write_tiff(work / "u.tiff", u_map)
        write_tiff(work / "s.tiff", np.rint(support).astype(np.uint16))

    boxes = {} if box_chi_z is None else {
        "k2 box": lambda: maps(denoise_radius=radius, denoise_adaptive=boxed),
        "k3 box": lambda: maps(denoise_radius=radius, denoise_adaptive=boxed, want_uncertainty=True),
    }
    return {
        **boxes,
        "read": lambda: read_rgb_codes(png),
        "texture": ((lambda: texture.correct_pair(raw, rig.white, BLUR_PX2, BLUR_PX2 + BLUR_U_PX2, clipped=clip,
                                                  offset=rig.offset))
                    if carried else (lambda: texture.correct(raw, rig.white, BLUR_PX2, clipped=clip, offset=rig.offset))),
        "k0": lambda: maps(),
        "k1": lambda: maps(denoise_radius=radius),
        "k2": lambda: maps(denoise_radius=radius, denoise_adaptive=adaptive),
        "k3": lambda: maps(denoise_radius=radius, denoise_adaptive=adaptive, want_uncertainty=True),
        "texture u": tex_u,
        "flags": flags,
        "write": write,
        "cvtColor": lambda: cv2.cvtColor(rig.frame, cv2.COLOR_RGB2HSV),
        "floor": lambda: (read_rgb_codes(png), write_tiff(work / "f.tiff", height)),
    }


def _timed(calls_of: Callable[[Path], dict[str, Callable[[], Any]]], rounds: int,
           prefix: str, reps: int = 1) -> tuple[dict[str, float], dict[str, float]]:
    """Median CPU ms and best wall ms of each call over ``rounds`` interleaved rounds (after one
    warm-up call each: compiled paths, caches; in each round a call's best of ``reps`` calls, the
    quick references' best of 5)."""
    cv2.setNumThreads(_THREADS)
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        calls = calls_of(Path(tmp))
        for fn in calls.values():
            fn()
        per: dict[str, list[float]] = {k: [] for k in calls}
        wall: dict[str, list[float]] = {k: [] for k in calls}
        for _ in range(rounds):
            for k, fn in calls.items():
                n = 5 if k in ("cvtColor", "read", "floor") else reps
                best = min((_clock(fn) for _ in range(n)), key=lambda x: x[0])
                per[k].append(best[0])
                wall[k].append(best[1])
    return ({k: 1e3 * statistics.median(v) for k, v in per.items()},
            {k: 1e3 * min(v) for k, v in wall.items()})


def bench_size(rig: KernelCase, rounds: int, box_chi_z: float | None = None, reps: int = 1) -> dict[str, Any]:
    med, wall_ms = _timed(lambda work: chain(rig, work, box_chi_z), rounds, "hf-bench-stages-", reps)
    ms = {"read": med["read"], "texture": med["texture"], "kernel": med["k0"],
          "filter": max(med["k1"] - med["k0"], 0.0), "adaptive": max(med["k2"] - med["k1"], 0.0),
          "uncertainty": max(med["k3"] - med["k2"], 0.0), "texture u": max(med["texture u"] - med["k3"], 0.0),
          "flags": med["flags"],
          "write": med["write"]}
    compute = sum(v for k, v in ms.items() if k not in ("read", "write"))
    total = sum(ms.values())
    box = {}
    if box_chi_z is not None:  # the same frame with plane boxes: adaptive and uncertainty rows, compute
        ad_b, un_b = max(med["k2 box"] - med["k1"], 0.0), max(med["k3 box"] - med["k2 box"], 0.0)
        box = {"box_chi_z": box_chi_z, "adaptive_ms": ad_b, "uncertainty_ms": un_b,
               "compute_ms": compute - ms["adaptive"] - ms["uncertainty"] + ad_b + un_b}
    return {"size": list(rig.frame.shape[1::-1]), "ms": ms, "compute_ms": compute, "total_ms": total, "box": box,
            "cvtColor_ms": med["cvtColor"], "floor_ms": med["floor"],
            "fps_1core": 1e3 / total, "fps_2cores": 2e3 / total, "floor_fps_2cores": 2e3 / med["floor"],
            "vs_floor": med["floor"] / total, "threads": _THREADS, "wall_best_ms": wall_ms}


def oneshot_case(w: int, h: int, n_bands: int) -> dict[str, Any]:
    """A one-shot frame of the bench's holdout-wide rig at ``w`` x ``h`` with everything the rig
    path needs prepared once per session: hue table, order reference, calibration, jackknife."""
    from dataclasses import replace

    from huefringe.bench.oneshot import calibrated_rig, gauge_scene, render_session
    from huefringe.bench.rig import RIGS
    from huefringe.rig.oneshot import hue_table_from_frames, oneshot_reference

    base = RIGS["holdout-wide"]
    s = w / base.camera_size[0]
    dy = (h - base.camera_size[1] * s) / 2.0
    rig = replace(base, camera_size=(w, h), camera_f=base.camera_f * s,
                  camera_pp=(base.camera_pp[0] * s, base.camera_pp[1] * s + dy))

    def scaled(c: Any) -> Any:
        K = c.camera_matrix.copy()
        K[:2, :] *= s
        K[2, :] = (0.0, 0.0, 1.0)
        K[1, 2] += dy
        return replace(c, camera_matrix=K, camera_size=(w, h))

    cal, jack = calibrated_rig(n_poses=6, seed=7)
    cal, jack = scaled(cal), [(n, scaled(c)) for n, c in jack]
    cap = render_session(gauge_scene(), n_bands=n_bands, repeats=2, seed=1, rig=rig)
    table = hue_table_from_frames(cap.white, cap.bands, cap.bands_block)
    ref = oneshot_reference(cap.reference, cal, cap.block)
    frame8 = np.clip(np.rint(cap.frames[0] * 255.0), 0, 255).astype(np.uint8)
    return {"cap": cap, "table": table, "ref": ref, "cal": cal, "jack": jack, "frame8": frame8}


def oneshot_chain(case: dict[str, Any], work: Path) -> dict[str, Callable[[], Any]]:
    """The timed calls of one one-shot frame on the rig (each a closure over the prepared inputs)."""
    from huefringe.rig.measure import RigFrame, calibration_spread
    from huefringe.rig.oneshot import absolute_from_reference, trapezoid_coordinate
    from huefringe.rig.triangulation import triangulate

    cap, cal = case["cap"], case["cal"]
    png = work / "oneshot.png"
    cv2.imwrite(str(png), cv2.cvtColor(case["frame8"], cv2.COLOR_RGB2BGR))
    rgb = case["frame8"].astype(np.float32) / np.float32(255.0)
    extent = cal.projector_size[0]
    ph = trapezoid_coordinate(rgb, cap.white, case["table"], cap.block)
    co = absolute_from_reference(ph, case["ref"], cap.block, extent=extent)
    t = triangulate(cal, co.coord, sigma_u=co.sigma, valid=co.valid, mode="u")
    frame = RigFrame(t.xyz, t.sigma, t.valid, {"u": co.coord, "v": None}, "u", t.sigma_ray)
    u_axes, u_ray = calibration_spread(frame, case["jack"])

    def read() -> Any:
        im = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        return cv2.cvtColor(im, cv2.COLOR_BGR2RGB).astype(np.float32) / np.float32(255.0)

    def write() -> None:
        write_tiff(work / "xyz.tiff", t.xyz.astype(np.float32))
        write_tiff(work / "sigma.tiff", np.concatenate([t.sigma, t.sigma_ray[..., None]], axis=-1).astype(np.float32))
        write_tiff(work / "u.tiff", np.concatenate([u_axes, u_ray[..., None]], axis=-1).astype(np.float32))

    return {
        "read": read,
        "decode": lambda: trapezoid_coordinate(rgb, cap.white, case["table"], cap.block),
        "order": lambda: absolute_from_reference(ph, case["ref"], cap.block, extent=extent),
        "triangulate": lambda: triangulate(cal, co.coord, sigma_u=co.sigma, valid=co.valid, mode="u"),
        "calibration u": lambda: calibration_spread(frame, case["jack"]),
        "write": write,
        "cvtColor": lambda: cv2.cvtColor(case["frame8"], cv2.COLOR_RGB2HSV),
        "floor": lambda: (read_rgb_codes(png), write_tiff(work / "f.tiff", t.xyz[..., 2].astype(np.float32))),
    }


def bench_oneshot(case: dict[str, Any], rounds: int, reps: int = 1) -> dict[str, Any]:
    """Median CPU ms per stage of the one-shot rig path over ``rounds`` interleaved rounds (each a
    stage's best of ``reps`` calls)."""
    med, wall_ms = _timed(lambda work: oneshot_chain(case, work), rounds, "hf-bench-oneshot-", reps)
    ms = {k: med[k] for k in ONESHOT_STAGES}
    compute = sum(v for k, v in ms.items() if k not in ("read", "write"))
    total = sum(ms.values())
    h, w = case["frame8"].shape[:2]
    return {"size": [w, h], "ms": ms, "compute_ms": compute, "total_ms": total, "cvtColor_ms": med["cvtColor"],
            "floor_ms": med["floor"], "fps_1core": 1e3 / total, "fps_2cores": 2e3 / total,
            "floor_fps_2cores": 2e3 / med["floor"], "vs_floor": med["floor"] / total, "threads": _THREADS,
            "valid_px": int(case["ref"].valid.sum()), "wall_best_ms": wall_ms}


def _stage_table(results: list[dict[str, Any]], stages: tuple[str, ...], head: str, compute: str,
                 per_floor: bool) -> str:
    """A stage table: ms per frame and x cvtColor per size (``per_floor``: also x the I/O floor)."""
    sizes = [f"{r['size'][0]} × {r['size'][1]}" for r in results]
    cols = "ms | × cvtColor | × floor" if per_floor else "ms | × cvtColor"
    lines = [f"| {head} | " + " | ".join(f"{s}: {cols}" for s in sizes) + " |",
             "| --- | " + " | ".join("---: | ---: | ---:" if per_floor else "---: | ---:" for _ in sizes) + " |"]

    def row(name: str, vals: list[float]) -> None:
        cells = [f"{v:.1f} | {v / r['cvtColor_ms']:.1f}" + (f" | {v / r['floor_ms']:.2f}" if per_floor else "")
                 for v, r in zip(vals, results, strict=True)]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")

    for st in stages:
        row(st, [r["ms"][st] for r in results])
    row(f"**compute** ({compute})", [r["compute_ms"] for r in results])
    row("**frame** (all stages)", [r["total_ms"] for r in results])
    row("*cv2.cvtColor RGB→HSV*", [r["cvtColor_ms"] for r in results])
    row("*I/O floor (PNG read + TIFF write)*", [r["floor_ms"] for r in results])
    last = [f"{r['fps_2cores']:.2f} | | {r['vs_floor']:.3f} × floor" if per_floor
            else f"{r['fps_2cores']:.1f} | {r['vs_floor']:.2f} × floor" for r in results]
    lines.append("| frames/s, 2 cores (two jobs) | " + " | ".join(last) + " |")
    return "\n".join(lines) + "\n"


def oneshot_markdown(results: list[dict[str, Any]]) -> str:
    """The one-shot rig path's table: ms per frame, x cvtColor and x the I/O floor, per size."""
    return _stage_table(results, ONESHOT_STAGES, "one-shot rig stage", "decode … calibration u", per_floor=True)


#: docs/throughput.md's target: the plane path's compute at 640 x 480 on one core (ms a frame)
TARGET_COMPUTE_MS = 30.0


def target_line(results: list[dict[str, Any]]) -> str:
    """Whether the plane path's 640 x 480 compute meets :data:`TARGET_COMPUTE_MS` ("" without that size)."""
    r = next((r for r in results if tuple(r["size"]) == (640, 480)), None)
    if r is None:
        return ""
    got = r["compute_ms"]
    verdict = "met" if got <= TARGET_COMPUTE_MS else f"missed by {got / TARGET_COMPUTE_MS:.1f} ×"
    return (f"\n**Target** (640 × 480, {r['threads']} thread): compute ≤ {TARGET_COMPUTE_MS:g} ms a frame: "
            f"{got:.1f} ms, {verdict}.\n")


def markdown(results: list[dict[str, Any]], command: str) -> str:
    """The plane path's table (ms per frame and x cvtColor per size) and the target's line."""
    return _stage_table(results, STAGES, "stage", "texture … flags", per_floor=False) + target_line(results)


def _replace_between(page: Path, begin: str, end: str, body: str) -> None:
    text = page.read_text(encoding="utf-8")
    i, j = text.index(begin) + len(begin), text.index(end)
    page.write_text(text[:i] + body + text[j:], encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="640x480,1280x1024")
    ap.add_argument("--bands", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--reps", type=int, default=1,
                    help="in each round, a stage's best of this many calls (CPU time): on a machine whose speed "
                         "changes within seconds the medians of single calls mix its speeds")
    ap.add_argument("--threads", type=int, default=1, help="numba and OpenCV threads (default: one core)")
    ap.add_argument("--tables", default="plane,oneshot",
                    help="which chains: plane (the capture-session frame), oneshot (the one-shot rig path), or both")
    ap.add_argument("--markdown", type=Path, default=None, help="also write the table(s) here")
    ap.add_argument("--page", type=Path, default=None,
                    help="a manual page whose tables between the stages:begin / stages:end (plane) and "
                         "oneshot-stages:begin / oneshot-stages:end markers are replaced (those it has)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--quick", action="store_true", help="smoke mode: 160 x 120, 16 bands, 2 rounds")
    ap.add_argument("--box-chi-z", type=float, default=None,
                    help="also time the adaptive support and the uncertainty with measurement.denoise_adaptive.box_chi_z "
                         "set to this, interleaved in the same rounds (printed below the plane chain's line)")
    a = ap.parse_args(argv)
    if a.quick:
        a.sizes, a.bands, a.rounds = "160x120", 16, 2
    tables = {t.strip() for t in a.tables.split(",") if t.strip()}
    if not tables or tables - {"plane", "oneshot"}:
        ap.error(f"--tables {a.tables}: plane, oneshot or both")
    sizes = [tuple(int(x) for x in s.split("x")) for s in a.sizes.split(",")]
    t0 = time.perf_counter()
    print(f"stage benchmark: {a.sizes}, {a.bands} bands, {a.rounds} rounds, {a.threads} thread(s), {a.tables}; "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores", flush=True)
    results: list[dict[str, Any]] = []
    oneshot: list[dict[str, Any]] = []
    if "plane" in tables:
        base = make_case(*sizes[0], n_bands=a.bands)
        for w, h in sizes:
            rig = base if (w, h) == sizes[0] else tile_case(base, w, h)
            r = bench_size(rig, a.rounds, a.box_chi_z, a.reps)
            results.append(r)
            print(f"\n{w} x {h}: " + ", ".join(f"{k} {v:.1f}" for k, v in r["ms"].items()) + " ms", flush=True)
            if r["box"]:
                b = r["box"]
                print(f"  box_chi_z {b['box_chi_z']:g}: adaptive {b['adaptive_ms']:.1f} ms, uncertainty "
                      f"{b['uncertainty_ms']:.1f} ms, compute {b['compute_ms']:.1f} ms (the rest as above)", flush=True)
            print(f"  compute {r['compute_ms']:.1f} ms, frame {r['total_ms']:.1f} ms; cvtColor {r['cvtColor_ms']:.2f} ms, "
                  f"I/O floor {r['floor_ms']:.2f} ms; 2 cores: {r['fps_2cores']:.1f} frames/s = {r['vs_floor']:.2f} of "
                  f"the floor ({r['floor_fps_2cores']:.0f} frames/s)", flush=True)
    if "oneshot" in tables:
        for w, h in sizes:
            c0 = time.perf_counter()
            case = oneshot_case(w, h, a.bands)
            r = bench_oneshot(case, a.rounds, a.reps)
            oneshot.append(r)
            print(f"\none-shot rig {w} x {h} ({r['valid_px']} px with an order reference; set-up "
                  f"{time.perf_counter() - c0:.0f} s): " + ", ".join(f"{k} {v:.1f}" for k, v in r["ms"].items()) + " ms",
                  flush=True)
            print(f"  compute {r['compute_ms']:.1f} ms, frame {r['total_ms']:.1f} ms; cvtColor {r['cvtColor_ms']:.2f} ms, "
                  f"I/O floor {r['floor_ms']:.2f} ms; 2 cores: {r['fps_2cores']:.2f} frames/s", flush=True)
    cmd = "./run python benchmarks/bench_stages.py " + " ".join(argv if argv is not None else sys.argv[1:])
    table = markdown(results, cmd.strip()) if results else ""
    otable = oneshot_markdown(oneshot) if oneshot else ""
    print("\n" + table + ("\n" if table and otable else "") + otable)
    load = os.getloadavg()[0]
    print(f"load average {load:.2f}; {time.perf_counter() - t0:.0f} s")
    if a.markdown:
        a.markdown.write_text(table + ("\n" if table and otable else "") + otable)
    if a.page:
        text = a.page.read_text(encoding="utf-8")
        if results and "<!-- stages:begin -->" in text:
            note = (f"*{results[0]['threads']} thread, CPU ms per frame, medians of {a.rounds} rounds"
                    + (f" of each stage's best of {a.reps} calls" if a.reps > 1 else "") + f", {a.bands} bands; "
                    f"load average {load:.1f} on {os.cpu_count()} cores.*\n\n")
            _replace_between(a.page, "<!-- stages:begin -->\n", "<!-- stages:end -->", note + table)
        if oneshot and "<!-- oneshot-stages:begin -->" in text:
            note = (f"*{oneshot[0]['threads']} thread, CPU ms per frame, medians of {a.rounds} rounds"
                    + (f" of each stage's best of {a.reps} calls" if a.reps > 1 else "") + f", {a.bands} bands; "
                    f"load average {load:.1f} on {os.cpu_count()} cores.*\n\n")
            _replace_between(a.page, "<!-- oneshot-stages:begin -->\n", "<!-- oneshot-stages:end -->", note + otable)
    if a.json:
        a.json.write_text(json.dumps({"plane": results, "oneshot": oneshot} if oneshot else results, indent=2))
    return 0

if __name__ == "__main__":
    raise SystemExit(main())
