"""What a photo relief's dark pixels' error is made of, by switching the bench's camera effects off.

Usage: ./run python benchmarks/dark_pixels_blur.py [--frames 4] [--keep DIR] [--bands]

A tuning scene only (the hold-outs score, they are not looked into): the astronaut photo relief seen
by the coffee hold-out's sensor class (``benchmarks/filter_centroid.py``'s scene: 8 e- / 5,000 e-,
48 px period, 72 hue bands x 1 repeat, 320 x 240, 16 bit, seed 71), rendered five times with one
cause at a time removed:

- ``as is``: the scene (the sensor's noise, the lens blur of 0.9 px, ambient and stray light);
- ``noise-free``: no shot or read noise;
- ``noise-free, no lens blur``: and ``camera.lens_blur_sigma_px`` 0;
- ``noise-free, no ambient or stray light``: and ``light.ambient`` = ``light.stray`` = 0;
- ``noise-free, neither``: both.

Each is measured at config.yaml's defaults by the workflow's stages (its own hue tables, plane
calibration and texture-blur estimate). Per white level (the object white's channel mean over its
99th percentile, as ``coverage_bins.py``), pixels valid in every frame: the rms error, the 2u
coverage of the written u, and the rms over the frames' phase (36 bins of the unfiltered wrapped
phase, from the object table) of the error's mean per phase bin: the part of the error locked to
the fringe. Under a minute on one core (about 20 s here: each rendering is 320 x 240, 4 frames).

``--bands`` adds a table per rendering with a lens blur: how large a blur the first-order
texture-edge correction wants where its lean is weak or strong. The session's own blur estimate
(``texture.blur_from_phases``: the instrumental-variable slope between two frames' fine structure
of the raw phase measured as captured and after the correction at ``sigma^2 = 1``, over the pixels
whose ``|g|`` lies between its 0.5 and 0.9 quantiles) taken again in other quantile bands of
``|g|`` (the same frames, camera corrections and shadow mask as ``pipeline.session_texture_blur``),
each with its jackknife standard error over 8 strips, beside the bench's true blur (its lens's
variance; the pixel's own integration not counted). Where the lean is strongest the correction's
first order over-predicts, and the blur that fits is smaller.
"""

from __future__ import annotations

import argparse
import copy
import glob
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402
import filter_centroid as fc  # noqa: E402

from huefringe import bench, colour, texture  # noqa: E402
from huefringe.height import PlaneCalibration  # noqa: E402
from huefringe.huetable import HueTable  # noqa: E402
from huefringe.pipeline import session_corrections, session_texture_phases  # noqa: E402
from huefringe.session import load_session, read_rgb  # noqa: E402
from huefringe.settings import defaults  # noqa: E402

BINS = ((0.1, 0.2), (0.2, 0.35), (0.35, 0.5), (0.5, 0.7), (0.7, np.inf))
PHASE_BINS = 36
QUIET = {"full_well_e": None, "read_noise_e": None, "read_noise_dn": 0.0}
DARK = {"ambient": [0.0, 0.0, 0.0], "stray": [0.0, 0.0, 0.0]}
VARIANTS = {"as is": ({}, {}), "noise-free": (QUIET, {}),
            "noise-free, no lens blur": ({**QUIET, "lens_blur_sigma_px": 0.0}, {}),
            "noise-free, no ambient or stray light": (QUIET, DARK),
            "noise-free, neither": ({**QUIET, "lens_blur_sigma_px": 0.0}, DARK)}


#: the quantile bands of |g| of ``--bands`` (the estimate's own is the second)
G_BANDS = ((0.2, 0.5), (0.5, 0.9), (0.9, 0.97), (0.97, 0.99), (0.99, 0.999))


def blur_bands(where: Path, offset: bool = False) -> tuple[float, list[dict]]:
    """The blur the measured session used and ``texture.blur_from_phases`` in each band of :data:`G_BANDS`
    (no significance test), on the phases ``pipeline.session_texture_blur`` reads
    (``pipeline.session_texture_phases``); with ``offset`` the correction takes out the light without
    fringe first, as the measurement's does (the estimate's does not)."""
    s = load_session(where / "session")
    cal = PlaneCalibration.load(str(where / "all-on" / "model.npz"))
    table = HueTable.load(glob.glob(str(where / "tables" / "*" / "table_object.json"))[0])
    cam = where / "all-on" / "camera.json"
    reader = session_corrections(s, cam if cam.exists() else None)[1]
    plain, unit = session_texture_phases(s, table, cal, defaults()["hue_model"], defaults()["calibration"],
                                         reader.rgb(s.object_white), reader=reader,
                                         offset=cal.projector_off if offset else None)
    return float(cal.texture_blur_px2 or 0.0), [texture.blur_from_phases(plain, unit, band=b, min_t=0.0) for b in G_BANDS]


def _label(lo: float, hi: float) -> str:
    return f">= {lo:.2f}" if not np.isfinite(hi) else f"{lo:.2f}-{hi:.2f}"


def measure(where: Path, frames: int, camera: dict, light: dict) -> dict[str, np.ndarray]:
    """The variant's session measured at the defaults: errors, u, white level, unfiltered phase."""
    cfg = copy.deepcopy(fc.scene(frames))
    cfg["camera"].update(camera)
    cfg["light"].update(light)
    session, tables = am._case_dirs(where, bench.validate_bench_config(cfg))
    out = where / "all-on"
    if not sorted(out.glob("frame_*[0-9].u.tiff")):
        am.measure(session, tables, out, am._config({}))
    s = load_session(session)
    ids = list(s.frame_ids)
    h = np.stack([tifffile.imread(out / f"frame_{n:04d}.tiff").astype(np.float64) for n in ids])
    u = np.stack([tifffile.imread(out / f"frame_{n:04d}.u.tiff").astype(np.float64) for n in ids])
    truth = np.stack([tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in ids])
    white_rgb = np.asarray(read_rgb(s.object_white), np.float32)
    white = white_rgb.astype(np.float64).mean(axis=-1)
    table = HueTable.load(glob.glob(str(tables / "*" / "table_object.json"))[0])
    gains = colour.white_gains(white_rgb)
    phase = np.stack([np.mod(table.to_phase_and_slope(colour.balanced_hue(
        np.asarray(read_rgb(s.frames[n]), np.float32), gains, table.model))[0], 2.0 * np.pi) for n in ids])
    return {"e": h - truth, "u": u, "level": white / np.percentile(white, 99), "phase": phase}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--keep", type=Path, default=None, help="keep the sessions and results here; reuse them")
    ap.add_argument("--bands", action="store_true", help="and the blur the correction wants per band of its lean")
    args = ap.parse_args()
    t0 = time.perf_counter()
    print("| rendering | quantity | " + " | ".join(_label(lo, hi) for lo, hi in BINS) + " | all |")
    print("| --- | --- |" + " ---: |" * (len(BINS) + 1))
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        for name, (camera, light) in VARIANTS.items():
            r = measure(root / am._slug(f"astronaut-8e-5ke-p48-72x1-{args.frames}f-{name}"), args.frames, camera, light)
            e, u, level, phase = r["e"], r["u"], r["level"], r["phase"]
            valid = np.all(np.isfinite(e) & np.isfinite(u), axis=0)
            rows: dict[str, list[str]] = {"rms e mm": [], "2u": [], "fringe-locked mm": []}
            for lo, hi in (*BINS, (0.0, np.inf)):
                b = valid & (level >= lo) & (level < hi)
                if b.sum() < 200:
                    for v in rows.values():
                        v.append("-")
                    continue
                eb = e[:, b]
                k = np.floor(phase[:, b] / (2.0 * np.pi) * PHASE_BINS).astype(int) % PHASE_BINS
                prof = np.array([eb[k == i].mean() if np.any(k == i) else 0.0 for i in range(PHASE_BINS)])
                rows["rms e mm"].append(f"{np.sqrt(np.mean(eb**2)):.4f}")
                rows["2u"].append(f"{np.mean(np.abs(eb) <= 2.0 * u[:, b]):.3f}")
                rows["fringe-locked mm"].append(f"{np.sqrt(np.mean(prof**2)):.4f}")
            for i, (q, cells) in enumerate(rows.items()):
                print(f"| {name if i == 0 else ''} | {q} | " + " | ".join(cells) + " |")
            sys.stdout.flush()
        if args.bands:
            print("\nthe blur (px^2) the first-order correction wants per quantile band of its lean |g| (instrumental-"
                  "variable slope, +- its jackknife standard error over 8 strips); the estimate's own band is 0.5-0.9:\n")
            print("| rendering | correction | true blur | used | " + " | ".join(f"{lo:g}-{hi:g}" for lo, hi in G_BANDS) + " |")
            print("| --- | --- | ---: | ---: |" + " ---: |" * len(G_BANDS))
            for name, (camera, light) in VARIANTS.items():
                true = float(camera.get("lens_blur_sigma_px", fc.scene(args.frames)["camera"]["lens_blur_sigma_px"])) ** 2
                if true == 0.0:
                    continue
                for offset, how in ((False, "the estimate's (no offset)"), (True, "the measurement's (offset out)")):
                    used, rows = blur_bands(root / am._slug(f"astronaut-8e-5ke-p48-72x1-{args.frames}f-{name}"), offset)
                    cells = [f"{r['raw_px2']:.2f} +- {r['stderr_px2']:.2f}" if r.get("stderr_px2") is not None else "-"
                             for r in rows]  # -: the frames' predicted corrections do not correlate there
                    print(f"| {name} | {how} | {true:.2f} | {used:.2f} | " + " | ".join(cells) + " |")
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
