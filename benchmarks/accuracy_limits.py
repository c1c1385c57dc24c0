"""Study: what limits the method's cases (docs/accuracy.md, "What limits the figures").

Usage: ./run python benchmarks/accuracy_limits.py --tail [--cases NAME ...] [--within PX] [--keep DIR]
       ./run python benchmarks/accuracy_limits.py --steps [--frames N] [--keep DIR]
       ./run python benchmarks/accuracy_limits.py --dark [--cases NAME ...] [--keep DIR]

Every case is an ``accuracy_matrix.py`` case measured with its stages (``accuracy_matrix.measure``;
``--keep DIR`` shares that script's folders, so its kept sessions and hue tables are reused).

``--tail`` (default: the five gauge cases of the page): per frame at the defaults ("all on") the
p95 tail is the valid pixels whose |error| is at or above the frame's p95; printed, as means over
the frames, the p95, the tail's share within ``--within`` px (default 2) of a block edge (a change
of the true height by more than 0.1 mm inside the pixel's ``2 * within + 1`` square window:
``accuracy_matrix.zones``' edge zone at that reach, the blocks' and the base plate's edges), its
share within that reach of a block edge or of a shadowed pixel (``perframe.shadow_mask`` of the
object white, ``measurement.shadow_fraction`` and ``shadow_own_light`` as configured), and those
two zones' share of the valid pixels (the tail's share if it were spread evenly). About 15 s a
case (1 min for the five).

``--steps``: the tuning gauge session ("gauge plain p48 96x2 16bit") written with ``--frames``
frames (default 20; the frames differ by noise and the membrane's rigid vibration) and measured at
the defaults; per step the per-frame box-mean step heights of ``metrology.evaluate_session``: their
standard deviation over the frames (the noise of one frame's box means), their mean's error and
the largest single-frame error (um). About 20 s.

``--dark`` (default: the two photo reliefs): the session measured at the defaults and with lowered
thresholds (``DARK_VARIANTS``: ``measurement.shadow_fraction``, default 0.12 of the white image's
99th percentile, at 0.06 and 0.03, ``accuracy_matrix``'s variants; then at 0.03 and 0.01 with the
hue tables' ``calibration.min_intensity``, default 0.03, at 0.01 and 0.003, on tables of their own); over
the pixels valid with the lowered thresholds but not at the defaults (the pixels they bring back),
summed over the frames: their number (share of the field), median |error| and the share with
|error| <= 2u (u as the workflow writes it), beside the same figures of the pixels valid at the
defaults. 1-1.5 min a case.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe import metrology, pipeline  # noqa: E402
from huefringe.perframe import shadow_mask  # noqa: E402
from huefringe.session import load_session, read_rgb  # noqa: E402

GAUGE_CASES = ["gauge plain p48 96x2 16bit", "tex gauge plain p40 96x2", "gauge plain p64 d2.0 64x3 8bit",
               "gauge pre-distorted p40 d1.2", "tex gauge plain p56 72x1"]
PHOTO_CASES = ["photo astronaut p48 96x2", "photo coffee p40 d0.8 256x3"]
#: ``--dark``'s lowered thresholds: the measurement's shadow threshold, and with it the hue tables'
#: ``calibration.min_intensity`` (0.03: a white-image channel below it leaves the table's pixel
#: invalid, "low signal"); the latter gets hue tables of its own
DARK_VARIANTS = {
    "shadow fraction 0.06": am.VARIANTS["shadow fraction 0.06"],
    "shadow fraction 0.03": am.VARIANTS["shadow fraction 0.03"],
    "shadow fraction 0.03, min intensity 0.01": {"measurement": {"shadow_fraction": 0.03},
                                                 "calibration": {"min_intensity": 0.01}},
    "shadow fraction 0.01, min intensity 0.003": {"measurement": {"shadow_fraction": 0.01},
                                                  "calibration": {"min_intensity": 0.003}},
}


def _set(case: str) -> str:
    return "hold-out" if am.CASES[case]["holdout"] else "tuning"


def _read(paths: dict) -> tuple[list, list, list]:
    s = paths["session"]
    maps = [tifffile.imread(h).astype(np.float64) for h in paths["heights"]]
    truths = [tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids]
    us = [tifffile.imread(u).astype(np.float64) for u in paths["uncertainties"]]
    return maps, truths, us


def tail_row(case: str, root: Path, within: int) -> str:
    """One case's row of ``--tail``."""
    session, tables = am._case_dirs(root, am.CASES[case]["cfg"])
    config = am._config(am.VARIANTS["all on"])
    paths = am.measure(session, tables, root / am._slug("all on"), config)
    maps, truths, _ = _read(paths)
    m_cfg = config["measurement"]
    shadow = shadow_mask(read_rgb(paths["session"].object_white), m_cfg["shadow_fraction"],
                         own_light=bool(m_cfg["shadow_own_light"]))
    k = 2 * within + 1
    near_shadow = ndimage.maximum_filter(shadow.astype(np.uint8), k) > 0
    p95, n_tail, edge, either, edge_px, either_px = ([] for _ in range(6))
    for m, t in zip(maps, truths, strict=True):
        tt = np.where(np.isfinite(t), t, 0.0)
        near_edge = ndimage.maximum_filter(tt, k) - ndimage.minimum_filter(tt, k) > 0.1
        e = np.abs(m - t)
        ok = np.isfinite(e)
        q = float(np.percentile(e[ok], 95))
        tail = ok & (e >= q)
        p95.append(q)
        n_tail.append(int(tail.sum()))
        edge.append((tail & near_edge).sum() / tail.sum())
        either.append((tail & (near_edge | near_shadow)).sum() / tail.sum())
        edge_px.append((ok & near_edge).sum() / ok.sum())
        either_px.append((ok & (near_edge | near_shadow)).sum() / ok.sum())
    return (f"| {case} | {_set(case)} | {np.mean(p95):.4f} | {np.mean(n_tail):.0f} | {np.mean(edge):.2f} | "
            f"{np.mean(either):.2f} | {np.mean(edge_px):.3f} | {np.mean(either_px):.3f} |")


def steps_rows(root: Path, frames: int) -> list[str]:
    """``--steps``: the tuning gauge with ``frames`` frames, per step."""
    cfg = am._case("plain_gauge", session={"frames": frames})["cfg"]
    session, tables = am._case_dirs(root, cfg)
    paths = am.measure(session, tables, root / am._slug("all on"), am._config(am.VARIANTS["all on"]))
    s = paths["session"]
    maps = [tifffile.imread(h) for h in paths["heights"]]
    lens = pipeline.session_corrections(s, paths["camera"])[0]
    ev = metrology.evaluate_session(maps, s.specimen, s.pixel_pitch_mm, range_mm=max(s.planes_mm) - min(s.planes_mm),
                                    camera=lens)
    out = []
    for st in ev["steps"]:
        per = 1e3 * (np.asarray(st["per_frame_mm"], np.float64) - float(st["nominal_mm"]))
        out.append(f"| {st['name']} | {st['nominal_mm']:.1f} | {len(per)} | {np.std(per, ddof=1):.1f} | "
                   f"{np.mean(per):+.1f} | {per[np.argmax(np.abs(per))]:+.1f} |")
    return out


def dark_rows(case: str, root: Path) -> list[str]:
    """``--dark``: one photo case at the defaults and with the shadow threshold lowered."""
    session, tables = am._case_dirs(root, am.CASES[case]["cfg"])
    res = {"all on": _read(am.measure(session, tables, root / am._slug("all on"), am._config(am.VARIANTS["all on"])))}
    for v, change in DARK_VARIANTS.items():
        tdir = tables / am._slug(v) if "calibration" in change else tables  # tables of their own thresholds
        tdir.mkdir(parents=True, exist_ok=True)
        res[v] = _read(am.measure(session, tdir, root / am._slug(v), am._config(change)))
    maps0, truths, us0 = res["all on"]
    field = sum(int(np.isfinite(t).sum()) for t in truths)

    def figures(e: np.ndarray, u: np.ndarray) -> str:
        return (f"{e.size} ({e.size / field:.3f}) | {np.median(np.abs(e)):.3f} | "
                f"{np.mean(np.abs(e) <= 2 * u):.2f}")

    e0 = np.concatenate([(m - t)[np.isfinite(m) & np.isfinite(t)] for m, t in zip(maps0, truths, strict=True)])
    u0 = np.concatenate([u[np.isfinite(m) & np.isfinite(t)] for m, t, u in zip(maps0, truths, us0, strict=True)])
    out = [f"| {case} | {_set(case)} | valid at the defaults (0.12) | {figures(e0, u0)} |"]
    for v in DARK_VARIANTS:
        maps, _, us = res[v]
        back = [np.isfinite(m) & ~np.isfinite(m0) & np.isfinite(t) for m, m0, t in zip(maps, maps0, truths, strict=True)]
        e = np.concatenate([(m - t)[b] for m, t, b in zip(maps, truths, back, strict=True)])
        u = np.concatenate([uu[b] for uu, b in zip(us, back, strict=True)])
        out.append(f"| {case} | {_set(case)} | brought back by {v} | {figures(e, u)} |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    what = ap.add_mutually_exclusive_group(required=True)
    what.add_argument("--tail", action="store_true", help="the gauges' p95 tail beside block edges and shadows")
    what.add_argument("--steps", action="store_true", help="the tuning gauge's box means over --frames frames")
    what.add_argument("--dark", action="store_true", help="the pixels a lower shadow threshold brings back")
    ap.add_argument("--cases", nargs="*", default=None, help="accuracy_matrix.py cases (--tail, --dark)")
    ap.add_argument("--within", type=int, default=2, help="--tail: the reach (px) about an edge or a shadow")
    ap.add_argument("--frames", type=int, default=20, help="--steps: frames of the session")
    ap.add_argument("--keep", type=Path, default=None, help="write sessions and results here, reuse sessions found there")
    a = ap.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = a.keep or Path(tmp)
        if a.tail:
            print(f"| case | set | p95 mm | tail px | tail within {a.within} px of a block edge | ... of an edge or a shadow "
                  f"| valid px within {a.within} px of an edge | ... of an edge or a shadow |")
            print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
            for case in a.cases or GAUGE_CASES:
                print(tail_row(case, root / am._slug(case), a.within), flush=True)
        elif a.steps:
            print("| step | nominal mm | frames | sd per frame um | mean error um | largest frame error um |")
            print("| --- | ---: | ---: | ---: | ---: | ---: |")
            for line in steps_rows(root / f"{am._slug(GAUGE_CASES[0])}-{a.frames}-frames", a.frames):
                print(line, flush=True)
        else:
            print("| case | set | pixels | pixels (share of the field) | median abs error mm | 2u |")
            print("| --- | --- | --- | ---: | ---: | ---: |")
            for case in a.cases or PHOTO_CASES:
                for line in dark_rows(case, root / am._slug(case)):
                    print(line, flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
