"""How well the phase filter's weights read each pixel's noise: the Gaussian's shape against the period.

Usage: ./run python benchmarks/weights_blur_shape.py [--keep DIR] [--no-timing]

The filter's weights read the frame's own-signal hue noise (``perframe.frame_hue_noise``) from the
capture smoothed by a Gaussian (``measurement.weight_blur_px``, ``weight_blur_shape``;
docs/uncertainty.md, "The filter's weights"). Each case is rendered twice by the bench with the
same seed, as is and without shot or read noise; on the first frame, over the object table's
valid pixels, the script prints the ratio of the figure read from the noisy capture smoothed each
way to the figure of the noise-free capture as it is (what the weights should read): its median,
mean, mean ``|log|`` (how far a pixel's figure strays) and 5th / 95th percentiles. The camera's
fringe period and direction are read from the noise-free capture's hue. Cases: the still rig of
``tests/test_uncertainty.py`` (the demo bench at 100 x 75 px, 32 bands x 3) at a 15 and a 30 px
period, the flat boards of ``accuracy_matrix.py`` (p40, tuning; p20 8 bit, hold-out), its tuning
photo relief ``tex astronaut`` and the demo. Nothing is tuned on the output.

Then (unless ``--no-timing``) the stage benchmark's 640 x 480 frame (``_kernel_case.make_case``,
64 bands; one thread, CPU ms, medians of 5 interleaved rounds): the smoothing alone and the
fused kernel's rows (kernel, filter, adaptive support, uncertainty, as ``bench_stages.py``) with
each shape, and the filtered pixels' mean support. About 3 minutes with the sessions written
(``--keep`` reuses them).
"""

from __future__ import annotations

import argparse
import copy
import glob
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe import bench, colour, kernel, perframe, texture  # noqa: E402
from huefringe.huetable import HueTable  # noqa: E402
from huefringe.session import load_session, read_rgb  # noqa: E402
from huefringe.settings import defaults as load_defaults  # noqa: E402

QUIET = {"full_well_e": None, "read_noise_e": None, "read_noise_dn": 0.0}
#: (label, smoothing) of each way of reading the signal: None the capture as it is, else
#: (sigma px, shape)
WAYS: tuple[tuple[str, tuple[float, str] | None], ...] = (
    ("as captured", None), ("isotropic 1 px", (1.0, "isotropic")), ("isotropic 2 px (default)", (2.0, "isotropic")),
    ("isotropic 3 px", (3.0, "isotropic")), ("along the fringe 2 px", (2.0, "along_fringe")),
    ("along the fringe 4 px", (4.0, "along_fringe")))


def _still(period: int) -> dict:
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("demo")))
    cfg["session"].update(width=100, height=75, pixel_pitch_mm=0.8, period_px=period, hue_bands=32, repeats=3, frames=2)
    cfg["phase_shift"]["enabled"] = False
    cfg["vibration"]["amplitude_mm"] = 0.0
    return bench.validate_bench_config(cfg)


def cases() -> dict[str, dict]:
    tex = next(c for c in am.CASES if c.startswith("tex astronaut"))
    return {"still rig p15": _still(15), "still rig p30": _still(30),
            "flat p20 d0.5 256x1 8bit (hold-out)": am.CASES["flat p20 d0.5 256x1 8bit"]["cfg"],
            "flat p40 d1.6 96x2": am.CASES["flat p40 d1.6 96x2"]["cfg"], tex: am.CASES[tex]["cfg"],
            "demo": bench.validate_bench_config(bench.load_bench_config(bench.preset_path("demo")))}


def _session(root: Path, cfg: dict, quiet: bool) -> tuple[Path, Path]:
    c = copy.deepcopy(cfg)
    if quiet:
        c["camera"].update(QUIET)
    return am._case_dirs(root / ("noise-free" if quiet else "as-is"), bench.validate_bench_config(c))


def figure_rows(name: str, cfg: dict, root: Path) -> list[str]:
    """The table rows of one case."""
    session, tables = _session(root, cfg, False)
    quiet, _ = _session(root, cfg, True)
    if not glob.glob(str(tables / "*" / "table_object.json")):
        am.measure(session, tables, root / "measured", am._config({}))
    table = HueTable.load(glob.glob(str(tables / "*" / "table_object.json"))[0])
    s, sq = load_session(session), load_session(quiet)
    white = np.asarray(read_rgb(s.object_white), np.float32)
    gains = colour.white_gains(white)
    n = s.frame_ids[0]
    rgb = np.asarray(read_rgb(s.frames[n]), np.float32)
    clean = np.asarray(read_rgb(sq.frames[n]), np.float32)
    truth = perframe.frame_hue_noise(table, clean, gains, table.model)
    hue = colour.hue(colour.white_balance(clean, white), "hexcone").astype(np.float64)
    ok0 = np.asarray(table.valid, bool) & np.isfinite(truth) & (truth > 0)
    gx = np.angle(np.exp(1j * np.diff(hue, axis=1)))[:-1][ok0[:-1, :-1]]
    gy = np.angle(np.exp(1j * np.diff(hue, axis=0)))[:, :-1][ok0[:-1, :-1]]
    gxm, gym = float(np.nanmedian(gx)), float(np.nanmedian(gy))
    angle = float(np.arctan2(gym, gxm))
    period = 2 * np.pi / float(np.hypot(gxm, gym))
    rows = []
    for label, way in WAYS:
        x = rgb if way is None else perframe.smoothed_signal(rgb, way[0], angle=angle if way[1] == "along_fringe" else None)
        fig = perframe.frame_hue_noise(table, np.ascontiguousarray(x, np.float32), gains, table.model)
        ok = ok0 & np.isfinite(fig)
        q = fig[ok] / truth[ok]
        rows.append(f"| {name} | {period:.1f} | {label} | {np.median(q):.3f} | {np.mean(q):.3f} | "
                    f"{np.mean(np.abs(np.log(q))):.3f} | {np.percentile(q, 5):.3f} | {np.percentile(q, 95):.3f} |")
    return rows


def timing(rounds: int = 5) -> None:
    """The 640 x 480 frame's rows with each shape, interleaved."""
    from _kernel_case import make_case
    from bench_stages import BLUR_PX2

    cv2.setNumThreads(1)
    rig = make_case(640, 480, n_bands=64)
    m = load_defaults()["measurement"]
    ad, r = m["denoise_adaptive"], int(m["denoise_radius"])
    shadow = perframe.shadow_mask(rig.white, m["shadow_fraction"])
    raw = rig.frame.astype(np.float32) * np.float32(1 / 255)
    rgb = texture.correct(raw, rig.white, BLUR_PX2, clipped=perframe.clipped_mask(raw, 8), offset=rig.offset)
    shapes = ("isotropic", "along_fringe")
    preps = {s: kernel.prepare(rig.table, rig.cal, rig.white, hue_model="hexcone", min_saturation=m["min_saturation"],
                               shadow=shadow, bit_depth=8, weight_blur_shape=s) for s in shapes}
    calls: dict[tuple[str, str], Any] = {}
    for s, p in preps.items():
        calls[(s, "smoothing")] = lambda p=p: perframe.smoothed_signal(rgb, p.weight_blur_px, angle=p.weight_angle)
        calls[(s, "k0")] = lambda p=p: kernel.frame_maps(p, rgb)
        calls[(s, "k1")] = lambda p=p: kernel.frame_maps(p, rgb, denoise_radius=r)
        calls[(s, "k2")] = lambda p=p: kernel.frame_maps(p, rgb, denoise_radius=r, denoise_adaptive=ad)
        calls[(s, "k3")] = lambda p=p: kernel.frame_maps(p, rgb, denoise_radius=r, denoise_adaptive=ad,
                                                         want_uncertainty=True)
    for fn in calls.values():
        fn()
    per: dict[tuple[str, str], list[float]] = {k: [] for k in calls}
    for _ in range(rounds):
        for k, fn in calls.items():
            c = time.process_time()
            fn()
            per[k].append(time.process_time() - c)
    med = {k: 1e3 * statistics.median(v) for k, v in per.items()}
    print(f"\n640 x 480, 64 bands, 1 thread, CPU ms (medians of {rounds} interleaved rounds); fringe angle "
          f"{np.degrees(preps['along_fringe'].weight_angle or 0.0):.1f} deg, kernel "
          f"{perframe.fringe_kernel(2.0, preps['along_fringe'].weight_angle or 0.0).shape}\n")
    print("| weights' Gaussian | smoothing | kernel | filter | adaptive | uncertainty | kernel to uncertainty | mean support px |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for s, p in preps.items():
        k = {n: med[(s, n)] for n in ("smoothing", "k0", "k1", "k2", "k3")}
        full = kernel.frame_maps(p, rgb, denoise_radius=r, denoise_adaptive=ad, want_uncertainty=True)
        print(f"| {s} | {k['smoothing']:.1f} | {k['k0']:.1f} | {k['k1'] - k['k0']:.1f} | {k['k2'] - k['k1']:.1f} | "
              f"{k['k3'] - k['k2']:.1f} | {k['k3']:.1f} | {float(np.mean(full.support[full.valid])):.1f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", type=Path, default=None, help="write sessions here, reuse sessions found there")
    ap.add_argument("--no-timing", action="store_true", help="the figures only")
    a = ap.parse_args()
    print("| case | camera period px | signal read | median | mean | mean abs log | p5 | p95 |")
    print("| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        root = a.keep or Path(tmp)
        for name, cfg in cases().items():
            for row in figure_rows(name, cfg, root / am._slug(name)):
                print(row, flush=True)
    if not a.no_timing:
        timing()


if __name__ == "__main__":
    main()
