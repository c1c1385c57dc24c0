"""Where a photo relief's dark pixels' error comes from: the error split per white level against the terms of u.

Usage: ./run python benchmarks/dark_pixels_split.py [--frames 4] [--draws 16] [--keep DIR]

A tuning scene only (the hold-outs score, they are not looked into): the astronaut photo relief
seen by the coffee hold-out's sensor class, as ``benchmarks/filter_centroid.py`` makes it (8 e- /
5,000 e-, 48 px period, 72 hue bands x 1 repeat, 320 x 240, 16 bit, seed 71), measured by the
workflow's stages at config.yaml's defaults (``all-on``) and three times more with the terms that
add to u after the kernel switched off (texture term, lateral term), the heights the same bits:
``core`` (the default filter), ``fixed`` (the filter's fixed 5 x 5 window, no sigma-adaptive
growth) and ``raw`` (no filter, no edge mask). Pixels valid in every frame, binned by the white
level (the object white's channel mean over its 99th percentile), as in ``coverage_bins.py``.

1. Per bin: the 2u coverage of the written u; the frame-to-frame part of the error (per pixel
   the sample std over the frames, rms) against the noise term (``uncertainty.split_terms`` of
   the core u, which counts the grown windows' bias term with the noise); the shared part (the
   frames' mean of ``e``, its noise part ``f2f^2 / F`` removed) against the terms the frames
   share: table (``u_noise sqrt(f_table)``), interpolation, reference + model, the filter's
   centroid (``g . c``, ``c`` of the first pass's fixed window, on every pixel: the written u leaves
   the grown windows out of it), the rest of the lateral term and
   the texture term (what the all-on u holds beyond the core u and the lateral term).
2. The frame-to-frame part over the noise term (median per pixel) for ``raw``, ``fixed`` and
   ``core`` (its noise term with the grown windows' bias): which stage of the chain the excess
   comes from.
3. The share of the pixels by their true phase slope over their own noise (per pixel), per white
   level: where ``benchmarks/filter_slope_sweep.py`` finds the filter's spread above ``1 / sum w``.
4. The phase filter alone on the relief: the true phase difference (from the bench's truth) plus
   Gaussian noise of each pixel's own sigma (the raw run's noise term over the height
   sensitivity), ``--draws`` draws, through ``phase.denoise_phase`` (the defaults: radius 2,
   sigma-adaptive to 0.002 rad up to radius 6, k = 3; the same with the plane kept up to a 10 sigma
   kink (``plane_kink_sigma``); with k = 100; the fixed window):
   the filtered spread over the draws against ``sqrt(1 / sum w)`` (median per pixel), the
   filter's error the draws share (mean over the draws less the truth, its noise part removed),
   in mm through the height sensitivity, and the grown windows' bias term the filter reports
   (``bias2``, rms over the draws and pixels, in mm) with its correlation with the size of the
   shared error per pixel.
5. The same draws through the defaults, the fixed window and a sketch of another filter (a local
   linear fit, :func:`local_linear_sketch`): spread over each one's prediction, the shared error
   and the frame-to-frame spread in mm.

6. Per white level and by whether the sigma-adaptive pass's local plane had its probes (the
   pixels ``max_radius`` px either side along each axis valid in every frame and inside the image):
   the 2u coverage, the frame-to-frame and shared error and the rms u of the written u at the
   defaults and with ``measurement.denoise_adaptive.lacking_probe_bias: posterior`` (``posterior``,
   the same heights): where a probe lacks, the plane is dropped and the grown window's bias term
   is all u has for its slope.

About 1 min on one core with ``--keep`` holding the session (2 min without).
"""

from __future__ import annotations

import argparse
import glob
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402
import filter_centroid as fc  # noqa: E402

from huefringe import colour, uncertainty  # noqa: E402
from huefringe.height import PlaneCalibration  # noqa: E402
from huefringe.huetable import HueTable  # noqa: E402
from huefringe.perframe import phase_sigma  # noqa: E402
from huefringe.phase import denoise_phase  # noqa: E402
from huefringe.session import load_session, read_rgb  # noqa: E402

BINS = ((0.1, 0.2), (0.2, 0.35), (0.35, 0.5), (0.5, 0.7), (0.7, 0.85), (0.85, np.inf))
OFF = {"texture_uncertainty": False, "lateral_uncertainty_px": 0.0, "lateral_step_px": 0.0}
RUNS = {"core": OFF, "fixed": {**OFF, "denoise_adaptive": {"enabled": False}},
        "raw": {**OFF, "denoise_radius": 0, "edge_jump_mm": 0.0},
        "posterior": {"denoise_adaptive": {"lacking_probe_bias": "posterior"}}}
PROBES = {"both axes' probes there": None, "a probe lacking along u": "u", "along v": "v", "along both": "uv"}
FILTERS = {"adaptive, k = 3 (defaults)": {"k": 3.0, "max_radius": 6, "target_sigma": 0.002, "reject_sigma": 0.03},
           "adaptive, k = 3, plane kink 10": {"k": 3.0, "max_radius": 6, "target_sigma": 0.002, "reject_sigma": 0.03,
                                              "plane_kink_sigma": 10.0},
           "adaptive, k = 100": {"k": 100.0, "max_radius": 6, "target_sigma": 0.002, "reject_sigma": 0.03},
           "fixed 5 x 5, k = 3": {"k": 3.0}}


def local_linear_sketch(d: np.ndarray, sig: np.ndarray, ok: np.ndarray, radius: int = 2, k: float = 3.0,
                        iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A sketch of another filter, not the library's: each pixel's value from a weighted least-squares
    plane (intercept and slope, weights ``1 / sigma^2``) fitted to its ``2 radius + 1`` window, the
    neighbours first taken by the level test (``r^2 <= 2 k^2 min(s_i^2, s_j^2)``, the filter's
    own-side test) and then by their residual from the plane (``<= k^2 (s_j^2 + var(intercept))``),
    refitted ``iterations - 1`` times; returns the filtered phase (the intercept) and
    ``1 / var(intercept)`` (``[(A^T W A)^-1]_00``), the weight sum's counterpart."""
    h, w = d.shape
    offs = [(dv, du) for dv in range(-radius, radius + 1) for du in range(-radius, radius + 1)]
    dd = np.where(ok, d.astype(np.float64), np.nan)
    pad = np.pad(dd, radius, constant_values=np.nan)
    ps = np.pad(np.where(ok, sig.astype(np.float64), np.nan), radius, constant_values=np.nan)
    nb = np.stack([pad[radius + dv:radius + dv + h, radius + du:radius + du + w] for dv, du in offs])
    s2 = np.stack([ps[radius + dv:radius + dv + h, radius + du:radius + du + w] for dv, du in offs]) ** 2
    ou = np.broadcast_to(np.array([du for _, du in offs], np.float64)[:, None, None], nb.shape)
    ov = np.broadcast_to(np.array([dv for dv, _ in offs], np.float64)[:, None, None], nb.shape)
    with np.errstate(invalid="ignore"):
        diff = nb - dd[None]
    valid = np.isfinite(diff)
    r0 = np.where(valid, diff, 0.0)
    s2 = np.where(valid, s2, 1.0)
    si2 = np.where(ok, sig.astype(np.float64), 1.0)[None] ** 2
    take = valid & (r0**2 <= 2.0 * k * k * np.minimum(si2, s2))
    a = np.stack([np.ones_like(ou), ou, ov])
    for it in range(iterations):
        wt = np.where(take, 1.0 / s2, 0.0)
        m = np.einsum("anhw,bnhw,nhw->hwab", a, a, wt)
        good = np.abs(np.linalg.det(m)) > 1e-12
        mi = np.linalg.inv(np.where(good[..., None, None], m, np.eye(3)))
        coef = np.einsum("hwab,hwb->hwa", mi, np.einsum("anhw,nhw->hwa", a, wt * r0))
        var0 = np.where(good, mi[..., 0, 0], np.inf)
        if it < iterations - 1:
            res = r0 - (coef[..., 0][None] + coef[..., 1][None] * ou + coef[..., 2][None] * ov)
            take = valid & (res**2 <= k * k * (s2 + var0[None]))
    return np.where(ok & good, dd + coef[..., 0], np.nan), np.where(ok & good, 1.0 / var0, 0.0)


def _label(lo: float, hi: float) -> str:
    return f">= {lo:.2f}" if not np.isfinite(hi) else f"{lo:.2f}-{hi:.2f}"


def _read(out: Path, ids: list[int], suffix: str) -> np.ndarray:
    return np.stack([tifffile.imread(out / f"frame_{n:04d}{suffix}.tiff").astype(np.float64) for n in ids])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--draws", type=int, default=16)
    ap.add_argument("--keep", type=Path, default=None, help="keep the session and results here; reuse them")
    args = ap.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        where = (args.keep or Path(tmp)) / f"astronaut-8e-5ke-p48-72x1-{args.frames}f"
        session, tables = am._case_dirs(where, fc.scene(args.frames))
        runs = {"all-on": {}, **RUNS}
        for name, meas in runs.items():
            if not sorted((where / name).glob("frame_*[0-9].u.tiff")):
                am.measure(session, tables, where / name, am._config({"measurement": meas}))
        s = load_session(session)
        ids = list(s.frame_ids)
        nf = len(ids)
        table = HueTable.load(glob.glob(str(tables / "*" / "table_object.json"))[0])
        cal = PlaneCalibration.load(str(where / "all-on" / "model.npz"))
        bud = uncertainty.pixel_budget(table, cal)
        white_rgb = np.asarray(read_rgb(s.object_white), np.float32)
        gains = colour.white_gains(white_rgb)
        white = white_rgb.astype(np.float64).mean(axis=-1)
        level = white / np.percentile(white, 99)
        truth = np.stack([tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in ids])
        h, u = _read(where / "all-on", ids, ""), _read(where / "all-on", ids, ".u")
        hc, uc = _read(where / "core", ids, ""), _read(where / "core", ids, ".u")
        assert np.array_equal(np.isnan(h), np.isnan(hc)) and np.nanmax(np.abs(h - hc)) == 0.0
        e = h - truth
        terms = [uncertainty.split_terms(uc[f], h[f], cal.a, cal.b, bud) for f in range(nf)]
        lat, cen = [], []
        for f, n in enumerate(ids):
            rgb = np.asarray(read_rgb(s.frames[n]), np.float32)
            _, slope = table.to_phase_and_slope(colour.balanced_hue(rgb, gains, table.model))
            sig = phase_sigma(table, slope)
            w = np.where(np.isfinite(h[f]) & np.isfinite(sig), 1.0 / sig**2, 0.0).astype(np.float32)
            hf, uf = h[f].astype(np.float32), uc[f].astype(np.float32)
            cen.append(uncertainty.lateral_term(hf, uf, lateral_px=0.0, weight=w, filter_radius=fc.RADIUS))
            lat.append(uncertainty.lateral_term(hf, uf, lateral_px=uncertainty.LATERAL_PX, step_px=uncertainty.LATERAL_STEP_PX,
                                                weight=w, filter_radius=fc.RADIUS))
        lat, cen = np.asarray(lat, np.float64), np.asarray(cen, np.float64)
        tex2 = np.maximum(u**2 - uc**2 - lat**2, 0.0)
        valid = np.all(np.isfinite(e) & np.isfinite(u) & np.isfinite(uc), axis=0)
        mean, sd = e.mean(axis=0), e.std(axis=0, ddof=1)
        tk = {k: np.stack([t[k] for t in terms]) for k in ("noise", "table", "interpolation", "reference", "model")}
        print(f"astronaut, 8 e- / 5,000 e-, p48, 72 x 1, {nf} frames (tuning scene); {int(valid.sum())} pixels valid "
              f"in every frame ({time.perf_counter() - t0:.0f} s)\n")
        print("| white level | pixels | 2u | frame-to-frame mm | noise term (with the grown windows' bias) | ratio "
              "| shared mm | table | interpolation "
              "| reference + model | centroid | lateral (rest) | texture | shared terms | ratio |")
        print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
        for lo, hi in BINS:
            b = valid & (level >= lo) & (level < hi)
            if b.sum() < 200:
                continue

            def rms(x: np.ndarray) -> float:
                return float(np.sqrt(np.mean(x[:, b] ** 2)))
            f2f = float(np.sqrt(np.mean(sd[b] ** 2)))
            shared = float(np.sqrt(max(np.mean(mean[b] ** 2) - f2f**2 / nf, 0.0)))
            nz, tb, it = rms(tk["noise"]), rms(tk["table"]), rms(tk["interpolation"])
            rm = float(np.sqrt(np.mean(tk["reference"][:, b] ** 2 + tk["model"][:, b] ** 2)))
            ce = rms(cen)
            lo_ = float(np.sqrt(max(np.mean(lat[:, b] ** 2) - np.mean(cen[:, b] ** 2), 0.0)))
            tx = float(np.sqrt(np.mean(tex2[:, b])))
            pred = float(np.sqrt(tb**2 + it**2 + rm**2 + ce**2 + lo_**2 + tx**2))
            cov = float(np.mean(np.abs(e[:, b]) <= 2.0 * u[:, b]))
            print(f"| {_label(lo, hi)} | {int(b.sum())} | {cov:.3f} | {f2f:.4f} | {nz:.4f} | {f2f / nz:.2f} | {shared:.4f} "
                  f"| {tb:.4f} | {it:.4f} | {rm:.4f} | {ce:.4f} | {lo_:.4f} | {tx:.4f} | {pred:.4f} | {shared / pred:.2f} |")

        print("\nframe-to-frame spread over the noise term, median per pixel:\n")
        print("| run | " + " | ".join(_label(lo, hi) for lo, hi in BINS) + " | all |")
        print("| --- |" + " ---: |" * (len(BINS) + 1))
        raw_h = raw_u = None
        for name in ("raw", "fixed", "core"):
            hh, uu = _read(where / name, ids, ""), _read(where / name, ids, ".u")
            if name == "raw":
                raw_h, raw_u = hh, uu
            nz = np.stack([uncertainty.split_terms(uu[f], hh[f], cal.a, cal.b, bud)["noise"] for f in range(nf)])
            ok = np.all(np.isfinite(hh) & np.isfinite(uu) & np.isfinite(truth), axis=0)
            r = (hh - truth).std(axis=0, ddof=1) / np.sqrt(np.mean(nz**2, axis=0))
            cells = []
            for lo, hi in (*BINS, (0.0, np.inf)):
                b = ok & (level >= lo) & (level < hi) & np.isfinite(r)
                cells.append(f"{np.median(r[b]):.2f}" if b.sum() >= 200 else "-")
            print(f"| {name} | " + " | ".join(cells) + " |")

        # the filter alone on the relief: the truth's phase plus each pixel's own noise
        a, bb = cal.a.astype(np.float64), cal.b.astype(np.float64)
        ok = np.isfinite(raw_h[0]) & np.isfinite(truth[0]) & np.isfinite(raw_u[0])
        d_true = np.where(ok, a * truth[0] / (1.0 - bb * truth[0]), 0.0)
        d0 = a * raw_h[0] / (1.0 - bb * raw_h[0])
        gsens = np.abs(a) / (a + bb * d0) ** 2
        sig = uncertainty.split_terms(raw_u[0], raw_h[0], cal.a, cal.b, bud)["noise"] / gsens
        sig = np.where(ok, np.minimum(sig, np.nanpercentile(sig[ok], 99)), 1.0).astype(np.float32)
        # the true phase slope per pixel in units of the pixel's own noise (benchmarks/filter_slope_sweep.py)
        gy, gx = np.gradient(np.where(ok, d_true, np.nan))
        ratio = np.hypot(gx, gy) / sig
        print("\nshare of the pixels by the true phase slope over the pixel's noise (per pixel):\n")
        spans = ((0.0, 1.0), (1.0, 2.0), (2.0, 8.0), (8.0, np.inf))
        print("| white level | < 1 | 1-2 | 2-8 | >= 8 |")
        print("| --- |" + " ---: |" * len(spans))
        for lo, hi in (*BINS, (0.0, np.inf)):
            b = ok & np.isfinite(ratio) & (level >= lo) & (level < hi)
            if b.sum() < 200:
                continue
            cells = [f"{np.mean((ratio[b] >= a) & (ratio[b] < z)):.3f}" for a, z in spans]
            print(f"| {'all' if lo == 0.0 and not np.isfinite(hi) else _label(lo, hi)} | " + " | ".join(cells) + " |")
        rng = np.random.default_rng(0)
        draws = [(d_true + sig * rng.standard_normal(sig.shape)).astype(np.float32) for _ in range(args.draws)]
        print(f"\nthe phase filter alone on the relief ({args.draws} draws of each pixel's own noise): spread over "
              "sqrt(1 / sum w), median per pixel; the error the draws share, mm rms:\n")
        print("| filter | quantity | " + " | ".join(_label(lo, hi) for lo, hi in BINS) + " | all |")
        print("| --- | --- |" + " ---: |" * (len(BINS) + 1))
        filtered: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # each filter's phases and weight sums over the draws
        for name, kw in FILTERS.items():
            outs, sws, b2s = [], [], []
            for d in draws:
                sw, b2 = np.zeros(d.shape, np.float32), np.zeros(d.shape, np.float32)
                outs.append(denoise_phase(d, sig, ok, radius=fc.RADIUS, weight_sum=sw, bias2=b2, **kw))
                sws.append(sw)
                b2s.append(np.nan_to_num(b2))
            o, swa = np.asarray(outs, np.float64), np.asarray(sws, np.float64)
            filtered[name] = o, swa
            term = np.sqrt(np.mean(np.asarray(b2s, np.float64), axis=0))  # the grown windows' bias term, rad
            spread, pred, bias, fine = _draw_stats(o, swa, d_true, ok)
            c1, c2, c3, c4 = _per_bin(fine, level, (
                lambda b: f"{np.median(spread[b] / pred[b]):.2f}",
                lambda b: _shared(bias, spread, gsens, b, args.draws),
                lambda b: f"{np.sqrt(np.mean((term[b] * gsens[b]) ** 2)):.4f}",
                lambda b: f"{np.corrcoef(np.abs(bias[b]), term[b])[0, 1]:.2f}" if term[b].any() else "-"))
            print(f"| {name} | spread / predicted | " + " | ".join(c1) + " |")
            print("| | shared error mm | " + " | ".join(c2) + " |")
            print("| | grown windows' bias term mm | " + " | ".join(c3) + " |")
            print("| | its correlation with the shared error's size | " + " | ".join(c4) + " |")
        # a sketch of a local linear fit beside the library's filters (not the library's filter)
        print("\nthe library's filters and a local linear fit (a sketch) on the same draws: spread over its "
              "prediction, the error the draws share and the frame-to-frame spread, mm rms:\n")
        print("| filter | quantity | " + " | ".join(_label(lo, hi) for lo, hi in BINS) + " | all |")
        print("| --- | --- |" + " ---: |" * (len(BINS) + 1))
        sketch = [local_linear_sketch(d, sig, ok, radius=fc.RADIUS) for d in draws]
        filtered["local linear fit, 5 x 5 (sketch)"] = (np.asarray([r[0] for r in sketch], np.float64),
                                                        np.asarray([r[1] for r in sketch], np.float64))
        for name in ("adaptive, k = 3 (defaults)", "fixed 5 x 5, k = 3", "local linear fit, 5 x 5 (sketch)"):
            o, swa = filtered[name]
            spread, pred, bias, fine = _draw_stats(o, swa, d_true, ok)
            c1, c2, c3 = _per_bin(fine, level, (
                lambda b: f"{np.median(spread[b] / pred[b]):.2f}",
                lambda b: _shared(bias, spread, gsens, b, args.draws),
                lambda b: f"{np.sqrt(np.mean((spread[b] * gsens[b]) ** 2)):.4f}"))
            print(f"| {name} | spread / predicted | " + " | ".join(c1) + " |")
            print("| | shared error mm | " + " | ".join(c2) + " |")
            print("| | frame-to-frame mm | " + " | ".join(c3) + " |")
        probe_table(where, ids, h, u, truth, level)
        print(f"\n({time.perf_counter() - t0:.0f} s)")


def probe_table(where: Path, ids: list[int], h: np.ndarray, u: np.ndarray, truth: np.ndarray,
                level: np.ndarray) -> None:
    """Table 6 (module docstring): coverage by whether the grown windows' local plane had its probes."""
    up = _read(where / "posterior", ids, ".u")
    hp = _read(where / "posterior", ids, "")
    assert np.array_equal(h, hp, equal_nan=True)  # the same heights
    e = h - truth
    ok = np.all(np.isfinite(e) & np.isfinite(u) & np.isfinite(up), axis=0)
    r = 6  # measurement.denoise_adaptive.max_radius, the probes' distance
    pad = np.pad(np.all(np.isfinite(h), axis=0), r, constant_values=False)
    has_u = pad[r:-r, :-2 * r] & pad[r:-r, 2 * r:]
    has_v = pad[:-2 * r, r:-r] & pad[2 * r:, r:-r]
    masks = {None: has_u & has_v, "u": ~has_u & has_v, "v": has_u & ~has_v, "uv": ~has_u & ~has_v}
    print("\n2u coverage by whether the local plane had its probes (6 px either side, valid in every frame): "
          "defaults / lacking_probe_bias posterior; frame-to-frame and shared error, rms u (defaults / posterior), mm:\n")
    print("| probes | white level | pixels | 2u | frame-to-frame | shared | rms u |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: |")
    for name, key in PROBES.items():
        for lo, hi in ((0.1, 0.35), (0.35, 0.7), (0.7, np.inf)):
            b = ok & masks[key] & (level >= lo) & (level < hi)
            if b.sum() < 100:
                continue
            eb = e[:, b]
            f2f = float(np.sqrt(np.mean(eb.std(axis=0, ddof=1) ** 2)))
            shared = float(np.sqrt(max(np.mean(eb.mean(axis=0) ** 2) - f2f**2 / len(ids), 0.0)))
            cov = [float(np.mean(np.abs(eb) <= 2.0 * x[:, b])) for x in (u, up)]
            ru = [float(np.sqrt(np.mean(x[:, b] ** 2))) for x in (u, up)]
            print(f"| {name} | {_label(lo, hi)} | {int(b.sum())} | {cov[0]:.3f} / {cov[1]:.3f} | {f2f:.4f} | {shared:.4f} "
                  f"| {ru[0]:.4f} / {ru[1]:.4f} |")


def _draw_stats(o: np.ndarray, swa: np.ndarray, d_true: np.ndarray,
                ok: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel over the draws: the filtered phase's spread, its prediction ``sqrt(mean(1 / sum w))``,
    the draws' mean error, and the pixels filtered in every draw."""
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = np.std(o, axis=0, ddof=1)
        pred = np.sqrt(np.mean(1.0 / swa, axis=0))
        bias = o.mean(axis=0) - d_true
    return spread, pred, bias, ok & np.all(np.isfinite(o), axis=0) & np.all(swa > 0, axis=0)


def _shared(bias: np.ndarray, spread: np.ndarray, gsens: np.ndarray, b: np.ndarray, draws: int) -> str:
    """The error the draws share on the pixels ``b`` (mm rms), its noise part removed."""
    v = np.mean((bias[b] * gsens[b]) ** 2) - np.mean((spread[b] * gsens[b]) ** 2) / draws
    return f"{np.sqrt(max(v, 0.0)):.4f}"


def _per_bin(fine: np.ndarray, level: np.ndarray, fns: tuple) -> list[list[str]]:
    """One column of cells per function: each white-level bin (and all) of at least 200 pixels."""
    cols: list[list[str]] = [[] for _ in fns]
    for lo, hi in (*BINS, (0.0, np.inf)):
        b = fine & (level >= lo) & (level < hi)
        for col, f in zip(cols, fns, strict=True):
            col.append(f(b) if b.sum() >= 200 else "-")
    return cols


if __name__ == "__main__":
    main()
