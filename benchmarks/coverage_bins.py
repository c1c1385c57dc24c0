"""2u coverage per kind of pixel: |e| <= 2u binned by white level, local texture contrast and
distance to a texture edge or a step edge, on the demo and on photo-textured scenes with
realistic sensors.

Usage: ./run python benchmarks/coverage_bins.py [--scenes NAME ...] [--frames-demo 3] [--keep DIR] [--markdown FILE]
                                                [--filter-check] [--box-chi-z Z] [--plane-kink-sigma S]
                                                [--lacking-probe-bias posterior]

Scenes (``SCENES``): the capture-session demo (bench preset ``demo``, the session
``gauge-blocks-demo`` of config.yaml, 400 x 300, its first ``--frames-demo`` frames), and the
noise cases of ``benchmarks/accuracy_matrix.py --noise`` with one hue-band repeat (photographs
printed on a relief over the whole field, 320 x 240, 2 frames, machine-vision sensors of 2-30 e-
read noise and 5,000-30,000 e- full well): the astronaut is a tuning case, coffee, chelsea and
rocket are hold-outs (fixed before any setting was tuned; they only score). Each scene is
measured by the workflow's stages at config.yaml's defaults; e = measured height - bench truth,
u the uncertainty map the measurement writes; valid pixels of every frame count.

Bins (each pixel of the field once; a bin is reported when it holds more than 1 % of the valid
pixels, target 0.95 +- 0.03):

- **white level**: the object white image's channel mean in DN, as a fraction of its 99th
  percentile (the DN range of each bin is printed);
- **texture contrast**: the local standard deviation over the mean of the bench's true
  reflectance (channel mean) in a 5 x 5 window;
- **distance to a texture edge**: Euclidean distance (px, ``scipy.ndimage.distance_transform_edt``)
  to the nearest pixel whose true reflectance changes by more than 1.5 x to a 4-neighbour;
- **distance to a step edge**: the same to the nearest pixel where the true height's second
  difference along a row or column exceeds 0.1 mm (a discontinuity, not a steep smooth flank), or
  the truth's border (NaN).

``--keep DIR`` keeps the sessions and results (a second run reuses them and only scores).
``--box-chi-z Z`` measures with ``measurement.denoise_adaptive.box_chi_z`` set to ``Z`` (plane boxes,
results in a folder of their own beside the default's) and prints, per scene, how the grown pixels
grew (a box, or the rings after the box's band, scatter or mean test), and runs the filter check
with it. ``--plane-kink-sigma S`` measures with ``measurement.denoise_adaptive.plane_kink_sigma`` set to
``S`` (the grown rings' plane kept up to that disagreement of its sides; results in a folder of their
own). ``--lacking-probe-bias posterior`` measures with ``measurement.denoise_adaptive.lacking_probe_bias``
set to it (the grown windows' bias term where the local plane lacked a probe; results in a folder of
their own). Each scene also prints the median and 95th percentile of |e|.

``--filter-check`` adds what the misses come from (docs/uncertainty.md): the phase filter at the
defaults (radius 2, sigma-adaptive to 0.002 rad, up to radius 6, neighbours rejected beyond
``k = 3`` combined sigma) on synthetic phase maps (120 x 100 px, 40 noise draws), flat or on a
ramp of 0.007 rad/px (a relief's slope at the sensor cases' periods), with one sigma (0.05 rad)
or a textured one (lognormal, 0.05 rad x e^N(0, 0.5)): the filtered phase's spread over the
draws against its predicted ``1 / sqrt(sum w)``, median over the pixels, at ``k`` = 3, 5 and
100 (no rejection), and on the textured ramp at ``k`` = 3 with the window's growth capped at
``max_radius`` 2 (the fixed 5 x 5 window), 3, 4 and 6 (the grown rings test their neighbours
against the local plane through the pixel's first-pass estimate, ``phase._adaptive_pass``).
"""

from __future__ import annotations

import argparse
import copy
import inspect
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe import bench  # noqa: E402
from huefringe.session import load_session, read_rgb  # noqa: E402


def _demo(frames: int) -> dict:
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("demo")))
    cfg["session"]["frames"] = frames
    cfg["phase_shift"]["enabled"] = False
    return {"cfg": bench.validate_bench_config(cfg), "holdout": False}


#: name -> (role, case); the roles are said in the table
SCENES = {
    "demo": "tune",
    "sensor astronaut 25e 10ke p56 72x1": "tune",
    "sensor coffee 8e 5ke p48 72x1": "hold-out",
    "sensor chelsea 30e 30ke p64 96x1": "hold-out",
    "sensor rocket 2e 20ke p56 72x1": "hold-out",
    "tex rocket p56 72x1": "hold-out, quiet",
}

WHITE_BINS = (0.0, 0.1, 0.2, 0.35, 0.5, 0.7, 0.85, np.inf)
CONTRAST_BINS = (0.0, 0.02, 0.05, 0.1, 0.2, 0.4, np.inf)
DIST_BINS = (0.0, 1.0, 2.0, 3.0, 5.0, 10.0, np.inf)
#: a bin is reported when it holds more than this fraction of the valid pixels
MIN_SHARE = 0.01
TEXTURE_EDGE_RATIO = 1.5
STEP_EDGE_MM = 0.1


def true_maps(cfg: dict) -> tuple[np.ndarray, np.ndarray]:
    """The bench's true reflectance (channel mean) and height at rest, at the pixel centres."""
    b = bench.Bench(cfg)
    surf = b.object_surface(None, fine=False)
    return np.asarray(surf.reflectance, np.float64).mean(axis=-1), np.asarray(surf.height, np.float64)


def pixel_kinds(white: np.ndarray, refl: np.ndarray, truth: np.ndarray) -> dict[str, np.ndarray]:
    """Per-pixel classifiers: white level (fraction of the 99th percentile), texture contrast,
    distance (px) to a texture edge and to a step edge."""
    level = white / max(float(np.percentile(white, 99)), 1e-12)
    m = ndimage.uniform_filter(refl, 5, mode="nearest")
    m2 = ndimage.uniform_filter(refl * refl, 5, mode="nearest")
    contrast = np.sqrt(np.maximum(m2 - m * m, 0.0)) / np.maximum(m, 1e-9)
    lr = np.log(np.maximum(refl, 1e-6))
    tex = np.zeros(refl.shape, bool)
    for ax in (0, 1):
        d = np.abs(np.diff(lr, axis=ax)) > np.log(TEXTURE_EDGE_RATIO)
        sl_a = [slice(None)] * 2
        sl_b = [slice(None)] * 2
        sl_a[ax] = slice(1, None)
        sl_b[ax] = slice(None, -1)
        tex[tuple(sl_a)] |= d
        tex[tuple(sl_b)] |= d
    t = np.where(np.isfinite(truth), truth, np.nan)
    step = ~np.isfinite(t)
    for ax in (0, 1):
        d2 = np.abs(np.diff(t, n=2, axis=ax))
        big = ~(d2 <= STEP_EDGE_MM)  # NaN (border of the truth) counts as an edge
        sl = [slice(None)] * 2
        sl[ax] = slice(1, -1)
        step[tuple(sl)] |= big
    inf = np.full(refl.shape, np.inf)
    return {
        "white level": level,
        "texture contrast": contrast,
        "distance to texture edge": ndimage.distance_transform_edt(~tex) if tex.any() else inf,
        "distance to step edge": ndimage.distance_transform_edt(~step) if step.any() else inf,
    }


BINS = {"white level": WHITE_BINS, "texture contrast": CONTRAST_BINS,
        "distance to texture edge": DIST_BINS, "distance to step edge": DIST_BINS}


class BoxShare:
    """Counts, over the adaptive pass's calls while measuring, the grown pixels (first-pass weight
    below the target) by how their support grew: a plane box, or the rings after the box's band,
    scatter or mean test (``phase._adaptive_pass``'s ``boxed`` codes; only with ``box_chi_z`` > 0)."""

    def __init__(self) -> None:
        from huefringe.phase import _denoise
        self.counts = np.zeros(5, np.int64)
        self._mod, self._inner = _denoise, _denoise._adaptive_pass

    def __enter__(self) -> "BoxShare":
        at = {name: i for i, name in enumerate(inspect.signature(self._inner.py_func).parameters)}

        def spy(*args):  # noqa: ANN002, ANN202 - the pass's positional arguments
            inv, wfirst, target_w, chi_z = args[at["inv"]], args[at["wfirst"]], args[at["target_w"]], args[at["chi_z"]]
            boxed = np.zeros(inv.shape, np.float32) if chi_z > 0 else args[at["boxed"]]
            self._inner(*args[:at["boxed"]], boxed, *args[at["boxed"] + 1:])
            if chi_z > 0:
                grown = (inv > 0) & (wfirst < target_w)
                self.counts += np.bincount(boxed[grown].astype(np.int64), minlength=5)[:5]
        self._mod._adaptive_pass = spy
        return self

    def __exit__(self, *exc: object) -> None:
        self._mod._adaptive_pass = self._inner

    def line(self) -> str:
        if not self.counts.sum():
            return ""
        n = int(self.counts.sum())
        names = ("no box tried", "plane box", "rings: band", "rings: scatter", "rings: mean")
        return "grown pixels " + str(int(self.counts.sum())) + ": " + ", ".join(
            f"{k} {c / n:.1%}" for k, c in zip(names, self.counts, strict=True) if c)


def measure_scene(name: str, root: Path, frames_demo: int, box_chi_z: float | None = None,
                  kink_sigma: float | None = None, lacking_probe_bias: str | None = None) -> dict:
    """The scene measured at config.yaml's defaults (``box_chi_z``, ``kink_sigma`` or
    ``lacking_probe_bias`` given: with the adaptive support's ``box_chi_z``, ``plane_kink_sigma`` or
    ``lacking_probe_bias`` set to it, in a results folder of its own), its truth and pixel kinds."""
    case = _demo(frames_demo) if name == "demo" else {**am.CASES, **am.NOISE_CASES}[name]
    where = root / am._slug(name if name != "demo" else f"demo-{frames_demo}")
    session, tables = am._case_dirs(where, case["cfg"])
    adaptive: dict = {}
    tag = "all-on"
    if box_chi_z is not None:
        adaptive["box_chi_z"], tag = box_chi_z, f"box-chi-z-{box_chi_z:g}"
    if kink_sigma is not None:
        adaptive["plane_kink_sigma"] = kink_sigma
        tag = ("" if tag == "all-on" else tag + "-") + f"plane-kink-{kink_sigma:g}"
    if lacking_probe_bias is not None:
        adaptive["lacking_probe_bias"] = lacking_probe_bias
        tag = ("" if tag == "all-on" else tag + "-") + f"lacking-probe-{lacking_probe_bias}"
    out = where / tag
    variant = {"measurement": {"denoise_adaptive": adaptive}} if adaptive else {}
    share = BoxShare()
    heights = sorted(out.glob("frame_*[0-9].tiff"))
    if heights and all(Path(str(h).replace(".tiff", ".u.tiff")).exists() for h in heights):
        s = load_session(session)
        paths = {"session": s, "heights": [str(out / f"frame_{n:04d}.tiff") for n in s.frame_ids]}
        paths["uncertainties"] = [h.replace(".tiff", ".u.tiff") for h in paths["heights"]]
    else:
        with share:
            paths = am.measure(session, tables, out, am._config(variant))
    s = paths["session"]
    hs = np.stack([tifffile.imread(h).astype(np.float64) for h in paths["heights"]])
    us = np.stack([tifffile.imread(u).astype(np.float64) for u in paths["uncertainties"]])
    truths = np.stack([tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids])
    bit_depth = int(case["cfg"]["session"]["bit_depth"])
    white = np.asarray(read_rgb(s.object_white), np.float64) * float(2**bit_depth - 1)  # DN
    white = white.mean(axis=-1) if white.ndim == 3 else white
    refl, rest = true_maps(case["cfg"])
    return {"e": hs - truths, "u": us, "white": white, "dn": float(2**bit_depth - 1),
            "kinds": pixel_kinds(white, refl, np.where(np.isfinite(truths[0]), rest, np.nan)),
            "shape": case["cfg"]["session"], "frames": len(s.frame_ids), "share": share.line()}


def bin_table(r: dict) -> dict[str, list[dict]]:
    """Per classifier, per bin: pixels (valid, over all frames), their share, the 2u coverage, the
    rms of e / u and the median u."""
    e, u = r["e"], r["u"]
    ok = np.isfinite(e) & np.isfinite(u)
    n_all = int(ok.sum())
    out: dict[str, list[dict]] = {"all": [{"label": "all", "n": n_all, "share": 1.0,
                                           "cov": float(np.mean(np.abs(e[ok]) <= 2 * u[ok])),
                                           "z": float(np.sqrt(np.mean((e[ok] / u[ok]) ** 2))),
                                           "u": float(np.median(u[ok]))}]}
    for kind, edges in BINS.items():
        x = r["kinds"][kind]
        rows = []
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            inside = (x >= lo) & ((x < hi) | (~np.isfinite(hi) & np.isinf(x)))
            sel = ok & inside[None]
            n = int(sel.sum())
            if kind == "white level":
                label = f"{lo:.2f}-{hi:.2f}" if np.isfinite(hi) else f">= {lo:.2f}"
                if inside.any():
                    label += f" ({r['white'][inside].min():.0f}-{r['white'][inside].max():.0f} DN)"
            elif kind == "texture contrast":
                label = f"{lo:.2f}-{hi:.2f}" if np.isfinite(hi) else f">= {lo:.2f}"
            else:
                label = f"{lo:.0f}-{hi:.0f} px" if np.isfinite(hi) else f">= {lo:.0f} px"
            row = {"label": label, "n": n, "share": n / max(n_all, 1)}
            if n:
                row["cov"] = float(np.mean(np.abs(e[sel]) <= 2 * u[sel]))
                row["z"] = float(np.sqrt(np.mean((e[sel] / u[sel]) ** 2)))
                row["u"] = float(np.median(u[sel]))
            rows.append(row)
        out[kind] = rows
    return out


def error_parts(r: dict) -> dict[str, float]:
    """On the pixels valid in every frame: rms of e, of the frames' mean of e (the part they share
    plus noise / sqrt(F)), of the frame-to-frame part (sample sd over the frames: noise), of u, and the
    median and 95th percentile of |e|."""
    e, u = r["e"], r["u"]
    ok = np.all(np.isfinite(e) & np.isfinite(u), axis=0)
    ee = e[:, ok]
    return {"rms_e": float(np.sqrt(np.mean(ee**2))), "rms_mean": float(np.sqrt(np.mean(ee.mean(axis=0) ** 2))),
            "rms_noise": float(np.sqrt(np.mean(ee.var(axis=0, ddof=1)))) if e.shape[0] > 1 else float("nan"),
            "rms_u": float(np.sqrt(np.mean(u[:, ok] ** 2))),
            "median_e": float(np.median(np.abs(ee))), "p95_e": float(np.percentile(np.abs(ee), 95))}


def _cell(row: dict) -> str:
    if row["share"] <= MIN_SHARE:
        return f"({row['cov']:.3f}, {100 * row['share']:.1f} %)" if row["n"] else "-"
    flag = "" if abs(row["cov"] - 0.95) <= 0.03 else " **"
    return f"{row['cov']:.3f} ({100 * row['share']:.0f} %){flag}"


def markdown(results: dict[str, dict], tables: dict[str, dict]) -> list[str]:
    names = list(results)
    head = "| bin | " + " | ".join(f"{n} ({SCENES[n]})" for n in names) + " |"
    sep = "| --- | " + " | ".join("---:" for _ in names) + " |"
    lines = ["2u coverage (share of the scene's valid pixels); `**` a bin with more than 1 % of the "
             "pixels outside 0.95 +- 0.03; in parentheses with its share, a bin of 1 % or less.", ""]
    lines += [head, sep, "| all | " + " | ".join(f"{tables[n]['all'][0]['cov']:.3f} ({tables[n]['all'][0]['n']} px)"
                                            for n in names) + " |"]
    for kind, edges in BINS.items():
        lines.append(f"| **{kind}** |" + " |" * len(names))
        for i in range(len(edges) - 1):
            lab = tables[names[0]][kind][i]["label"]
            if kind == "white level":
                lab = lab.split(" (")[0]
            lines.append(f"| {lab} | " + " | ".join(_cell(tables[n][kind][i]) for n in names) + " |")
    lines += ["", "| scene | set | rms e mm | rms frame mean of e | rms frame-to-frame (noise) | rms u mm |",
              "| --- | --- | ---: | ---: | ---: | ---: |"]
    for n in names:
        p = error_parts(results[n])
        lines.append(f"| {n} | {SCENES[n]} | {p['rms_e']:.4f} | {p['rms_mean']:.4f} | {p['rms_noise']:.4f} | {p['rms_u']:.4f} |")
    return lines


def filter_check(draws: int = 40, seed: int = 1, box_chi_z: float = 0.0) -> list[str]:
    """Filtered phase spread over noise draws against ``1 / sqrt(sum w)`` (``--filter-check``;
    the adaptive support's ``box_chi_z`` as given)."""
    from huefringe.phase import denoise_phase

    rng = np.random.default_rng(seed)
    h, w = 100, 120
    valid = np.ones((h, w), bool)
    ramp = (np.add.outer(np.arange(h), np.arange(w)) * 0.007).astype(np.float32)
    sigmas = {"one sigma": np.full((h, w), 0.05, np.float32),
              "textured sigma": np.exp(rng.normal(np.log(0.05), 0.5, (h, w))).astype(np.float32)}
    lines = ["| phase | sigma | k = 3 | k = 5 | k = 100 |", "| --- | --- | ---: | ---: | ---: |"]
    for bname, base in (("flat", np.zeros((h, w), np.float32)), ("ramp 0.007 rad/px", ramp)):
        for sname, sig in sigmas.items():
            cells = []
            for k in (3.0, 5.0, 100.0):
                outs, sums = [], []
                for _ in range(draws):
                    ws = np.zeros((h, w), np.float32)
                    d = base + rng.normal(0.0, 1.0, (h, w)).astype(np.float32) * sig
                    outs.append(denoise_phase(d, sig, valid, radius=2, k=k, max_radius=6, target_sigma=0.002,
                                              reject_sigma=0.03, weight_sum=ws, box_chi_z=box_chi_z) - base)
                    sums.append(ws)
                o, ws = np.array(outs)[:, 8:-8, 8:-8], np.array(sums)[:, 8:-8, 8:-8]
                cells.append(float(np.nanmedian(np.nanstd(o, axis=0) / np.sqrt(np.nanmean(1.0 / ws, axis=0)))))
            lines.append(f"| {bname} | {sname} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
    # the same on the textured ramp at k = 3 with the window's growth capped (max_radius 2 = fixed)
    sig, cells = sigmas["textured sigma"], []
    for max_r in (2, 3, 4, 6):
        outs, sums = [], []
        for _ in range(draws):
            ws = np.zeros((h, w), np.float32)
            d = ramp + rng.normal(0.0, 1.0, (h, w)).astype(np.float32) * sig
            outs.append(denoise_phase(d, sig, valid, radius=2, k=3.0, max_radius=max_r, target_sigma=0.002,
                                      reject_sigma=0.03, weight_sum=ws, box_chi_z=box_chi_z) - ramp)
            sums.append(ws)
        o, ws = np.array(outs)[:, 8:-8, 8:-8], np.array(sums)[:, 8:-8, 8:-8]
        cells.append(float(np.nanmedian(np.nanstd(o, axis=0) / np.sqrt(np.nanmean(1.0 / ws, axis=0)))))
    lines += ["", "| textured ramp, k = 3 | max_radius 2 (fixed 5 x 5) | 3 | 4 | 6 (default) |",
              "| --- | ---: | ---: | ---: | ---: |",
              "| spread / predicted | " + " | ".join(f"{c:.2f}" for c in cells) + " |"]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--frames-demo", type=int, default=3)
    ap.add_argument("--keep", type=Path, default=None, help="keep sessions and results here; reuse them")
    ap.add_argument("--markdown", type=Path, default=None, help="also write the Markdown table to this file")
    ap.add_argument("--filter-check", action="store_true", help="also the filter's spread against 1 / sqrt(sum w)")
    ap.add_argument("--box-chi-z", type=float, default=None,
                    help="measure with measurement.denoise_adaptive.box_chi_z set to this (results in a folder of "
                         "their own; default: config.yaml's value)")
    ap.add_argument("--plane-kink-sigma", type=float, default=None,
                    help="measure with measurement.denoise_adaptive.plane_kink_sigma set to this (results in a "
                         "folder of their own; default: config.yaml's value)")
    ap.add_argument("--lacking-probe-bias", choices=("posterior", "unbiased"), default=None,
                    help="measure with measurement.denoise_adaptive.lacking_probe_bias set to this (results in a "
                         "folder of their own; default: config.yaml's value)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    results, tables = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        for name in args.scenes:
            r = measure_scene(name, root, args.frames_demo, args.box_chi_z, args.plane_kink_sigma,
                              args.lacking_probe_bias)
            results[name], tables[name] = r, bin_table(r)
            sh = r["shape"]
            print(f"\n## {name} ({SCENES[name]}; {sh['width']} x {sh['height']}, {r['frames']} frames, "
                  f"{time.perf_counter() - t0:.0f} s so far)")
            p = error_parts(r)
            print(f"rms e {p['rms_e']:.4f} mm: frames' mean {p['rms_mean']:.4f}, frame-to-frame {p['rms_noise']:.4f}; "
                  f"rms u {p['rms_u']:.4f}; |e| median {p['median_e']:.4f}, p95 {p['p95_e']:.4f} mm")
            if r["share"]:
                print(r["share"])
            print(f"{'bin':28} {'pixels':>8} {'share':>6} {'2u cov':>7} {'rms e/u':>8} {'median u':>9}")
            for kind, rows in tables[name].items():
                print(f"-- {kind}")
                for row in rows:
                    if not row["n"]:
                        continue
                    mark = "" if row["share"] <= MIN_SHARE or abs(row["cov"] - 0.95) <= 0.03 else "  MISS"
                    print(f"{row['label']:28} {row['n']:8d} {row['share']:6.3f} {row['cov']:7.3f} {row['z']:8.2f} "
                          f"{row['u']:9.4f}{mark}", flush=True)
    md = markdown(results, tables)
    print("\n" + "\n".join(md))
    if args.markdown:
        args.markdown.write_text("\n".join(md) + "\n")
    if args.filter_check:
        fc = filter_check(box_chi_z=args.box_chi_z or 0.0)
        print("\nfiltered phase spread / predicted 1 / sqrt(sum w), median over pixels:\n" + "\n".join(fc))
        if args.markdown:
            with args.markdown.open("a") as fh:
                fh.write("\n" + "\n".join(fc) + "\n")
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
