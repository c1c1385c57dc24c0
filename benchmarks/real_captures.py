"""The real captures of ../shared/real decoded at full resolution: the figures and maps of
docs/real-captures.md (docs/img/real-*.png).

    ./run python benchmarks/real_captures.py

kamino410 plate (gamma_correction): decoded display coordinates against a smooth 2-D fit
(degree 6) over the plate, RMS and p95 per direction, with the projector gamma ignored (1), the
repository's own estimate (gamma_result.txt) and huefringe's (against the Gray code).
kamino410 object2: valid fractions, the projector gamma from its two periods, and Gray-code /
two-period agreement. nzhagen lens: four-step modulation. Decode time per frame at 1936 x 1216
is printed against a reference measured in the same run (the N-step fit of one block alone).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import cv2
import numpy as np

from huefringe import codecs as C
from huefringe.codecs.checks import smooth_fit, smooth_region
from huefringe.codecs.graycode import decode_gray
from huefringe.codecs.output import quality_figure
from huefringe.io import write_figure_png

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "real"
KAMINO = REAL / "kamino410-phase-shifting"
IMG = REPO / "docs" / "img"
REPO_GAMMA = float(
    next(l for l in (KAMINO / "gamma_correction" / "gamma_result.txt").read_text().splitlines() if "gamma p" in l).split(":")[1]
)


def plate() -> None:
    spec = C.kamino410_sequence(KAMINO / "gamma_correction" / "config.xml", "gamma_correction")
    ims = np.stack(C.read_captures(KAMINO / "gamma_correction", spec))
    first = C.decode_sequence(ims, spec)
    est = C.estimate_projector_gamma(ims, spec, first["x"].valid & first["y"].valid)
    print(f"plate: projector gamma, repository {REPO_GAMMA:.3f}; huefringe against the Gray code {est.gray:.3f} "
          f"(blocks {', '.join(f'{g:.3f}' for g in est.gray_blocks)})")
    print("| projector gamma | region px | x RMS | x p95 | y RMS | y p95 |")
    print("| --- | --- | --- | --- | --- | --- |")
    keep = None
    for label, g in (("1 (ignored)", 1.0), (f"{REPO_GAMMA:.3f} (repository)", REPO_GAMMA), (f"{est.gray:.3f} (huefringe)", est.gray)):
        out = C.decode_sequence(ims, dataclasses.replace(spec, projector_gamma=g))
        region = smooth_region([out["x"].coord, out["y"].coord], out["x"].valid & out["y"].valid, 5.0, 8)
        fx, fy = (smooth_fit(out[a].coord, region, 6) for a in "xy")
        print(f"| {label} | {fx.pixels} | {fx.rms:.3f} | {fx.p95:.3f} | {fy.rms:.3f} | {fy.p95:.3f} |")
        keep = (out, fx, fy, g)
    out, fx, fy, g = keep
    fig = quality_figure(out, f"kamino410 gamma_correction (flat plate), projector gamma {g:.3f}")
    write_figure_png(fig, IMG / "real-plate.png", dpi=70)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3))
    for ax, f, a in zip(axes, (fx, fy), "xy", strict=True):
        im = ax.imshow(f.residual[::4, ::4], cmap="RdBu_r", vmin=-3, vmax=3)
        ax.set_title(f"{a} minus smooth fit: RMS {f.rms:.2f} px, p95 {f.p95:.2f} px", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, fraction=0.046)
    fig.tight_layout()
    write_figure_png(fig, IMG / "real-plate-residual.png", dpi=70)
    plt.close("all")


def mugs() -> None:
    spec = C.kamino410_sequence(KAMINO / "object2" / "config.xml", "phase_shifting")
    ims = np.stack(C.read_captures(KAMINO / "object2", spec))
    t = time.perf_counter()
    first = C.decode_sequence(ims, spec)
    t_decode = time.perf_counter() - t
    blk, sl = next((b, s) for b, s in spec.slices() if isinstance(b, C.PhaseBlock))
    t = time.perf_counter()
    C.wrapped_phase(ims[sl], blk.shifts_rad, C.DecodeOptions.from_config().noise(255.0))
    t_ref = time.perf_counter() - t
    print(f"object2 decode: {t_decode / spec.n_frames * 1e3:.0f} ms per frame at {ims.shape[2]} x {ims.shape[1]} "
          f"({spec.n_frames} frames, both axes) = {t_decode / spec.n_frames / (t_ref / 3):.1f}x the three-step fit's own ms per frame")
    est = C.estimate_projector_gamma(ims, spec, first["x"].valid & first["y"].valid)
    out = C.decode_sequence(ims, dataclasses.replace(spec, projector_gamma=est.periods))
    print(f"object2: projector gamma from its two periods {est.periods:.3f}")
    for a in "xy":
        b, gsl = next((b, s) for b, s in spec.slices() if isinstance(b, C.GrayBlock) and b.axis == a)
        dec = decode_gray(ims[gsl][0::2], 0.0, inverse=ims[gsl][1::2])
        c, v = out[a].coord, out[a].valid
        q = (c + 0.5) / b.cell_px
        away = v & (np.abs(q - np.round(q)) * b.cell_px > 3)
        agree = np.mean(dec.index[away] == np.floor(q[away]))
        print(f"object2 {a}: {v.mean():.1%} valid, median u {np.nanmedian(out[a].sigma):.3f} px, Gray code = two-period "
              f"decode on {agree:.3%} of valid pixels (3 px from cell edges)")
    fig = quality_figure(out, f"kamino410 object2, projector gamma {est.periods:.3f} (from its two periods)")
    write_figure_png(fig, IMG / "real-object2.png", dpi=70)


def lens() -> None:
    d = REAL / "nzhagen-fpp-tools-lens"
    frames = np.stack([cv2.imread(str(d / f"lens_orig_{a:03d}.jpg"), cv2.IMREAD_GRAYSCALE) for a in (0, 90, 180, 270)])
    w = C.wrapped_phase(frames, C.equal_shifts(4), C.DecodeOptions.from_config().noise(255.0))
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 4))
    for ax, img, cmap, title in ((axes[0], w.phase, "twilight", "wrapped phase [rad]"), (axes[1], w.modulation, "gray", "modulation [DN]")):
        im = ax.imshow(img[::2, ::2], cmap=cmap)
        ax.set_title(f"nzhagen lens, four-step: {title}", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, fraction=0.046)
    fig.tight_layout()
    write_figure_png(fig, IMG / "real-lens.png", dpi=70)
    plt.close("all")
    print(f"lens: median modulation {np.median(w.modulation):.1f} DN, median u(phi) {np.median(w.sigma):.4f} rad")


if __name__ == "__main__":
    plate()
    mugs()
    lens()
