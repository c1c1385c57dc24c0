"""Study: the interpolation term's shared part in the corner bins, on plain and on textured pixels.

Usage: ./run python benchmarks/interpolation_corners.py [--cases NAME ...] [--keep DIR]

Where a phase-error table is applied, the interpolation term adds what its smoothing leaves of the
plate's shared chord error (``interp_common_resid_rad``, ``uncertainty.common_interpolation``),
as one pixel would read it. That residual lives in the six code-phase bins of the twelve next to
the starts of a rising channel (codes 0, 2 pi / 3, 4 pi / 3: "corner" bins). For each case of
``accuracy_matrix.py`` (measured at config.yaml's defaults, two frames; with ``--keep`` the
matrix's own folder layout, so ``accuracy_matrix.py --keep DIR`` results are reused), on the
pixels valid in both frames, 4 px or more from the border:

1. in the corner bins and the others: the frames' shared error (their mean error less the noise's
   share), and the residual's term (through ``G``) as written and as a sketch averages it over the
   phase filter's fixed window (``measurement.denoise_radius``; :func:`windowed_residual`: the
   residual is the same function of the code phase at every pixel, and the window's pixels read it
   at the pixel's phase plus ``du g_u + dv g_v``, ``g`` the reference phase's change per pixel);
2. per zone of the matrix (``edge`` within 3 px of a step, ``texture`` within 3 px of a
   reflectance change of 1.5 x, ``rest``), corner and other bins: the frames' shared error, the
   2u coverage of u as written
   and of u with the sketch's residual in place of the written one (``u^2 - G^2 (c_0^2 - c_w^2)``,
   the heights unchanged).

``--blur-check``: the tuning reliefs (``tex astronaut``, ``tex chelsea``) again with the camera's
lens blur off and with the projector's defocus off (the second table's rows for each).
``--frequency-check``: on the tuning reliefs, per zone and corner / other bins, the correlation of
the frames' mean error with ``((g / g_0)^2 - 1) e(phi) G``: what the phase-error table's
correction ``e`` leaves if the error it corrects scales with the local fringe frequency squared (a
blur's phase error does), ``g`` the code phase's change per pixel at the true height, ``g_0`` the
reference plane's (the table's), ``G = dz / dphi``.

Scores only; about a minute for the eight cases (two more with ``--blur-check``).
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
from pathlib import Path

import numpy as np
import tifffile
from scipy.ndimage import gaussian_filter1d

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe import bench, phase_error  # noqa: E402
from huefringe.height import PlaneCalibration  # noqa: E402
from huefringe.session import load_session, read_rgb  # noqa: E402

CORNER_BINS = (0, 3, 4, 7, 8, 11)
BINS = 12
BORDER_PX = 4
DEFAULT = ["flat p40 d1.6 96x2", "gauge plain p48 96x2 16bit", "demo (pre-distorted) p60", "tex astronaut p56 72x1",
           "tex chelsea p56 72x1", "gauge plain p64 d2.0 64x3 8bit", "tex rocket p56 72x1", "tex coffee p48 72x1 blur1.1"]


def windowed_residual(common: np.ndarray, smoothing_rad: float, phi_ref: np.ndarray, radius: int,
                      samples: int = 16) -> np.ndarray:
    """A sketch, not the library's term: ``(H, W, 12)`` rms per code-phase bin of the plate's shared
    chord error ``-f (1 - f) r step / 2`` (``r`` per interval: ``common``) less its periodic Gaussian
    of ``smoothing_rad`` (what ``uncertainty.common_interpolation`` calls the residual), averaged
    with equal weights over the ``(2 radius + 1)^2`` window's code phases; radius 0 is the written
    residual's rms per bin. Interval ``k`` belongs to bin ``12 k // N`` as in the library."""
    common = np.asarray(common, np.float64)
    n = common.size
    step = 2.0 * np.pi / n
    f = (np.arange(samples) + 0.5) / samples
    chord = (-(f * (1.0 - f) / 2.0)[None, :] * common[:, None] * step).ravel()
    left = chord - gaussian_filter1d(chord, smoothing_rad / (step / samples), mode="wrap") if smoothing_rad > 0 else chord
    grid = (np.arange(n * samples) + 0.5) * (step / samples)
    which = ((np.arange(n) * BINS) // n)[np.arange(n * samples) // samples]
    count = np.bincount(which, minlength=BINS).astype(np.float64)
    p = np.asarray(phi_ref, np.float64)
    gu, gv = np.zeros_like(p), np.zeros_like(p)
    gu[:, 1:-1] = np.angle(np.exp(1j * (p[:, 2:] - p[:, :-2]))) / 2.0
    gv[1:-1] = np.angle(np.exp(1j * (p[2:] - p[:-2]))) / 2.0
    quantum = step / 64.0  # pixels whose gradients agree to 1/64 of a band step share one computation
    key = np.stack([np.rint(np.nan_to_num(gu) / quantum), np.rint(np.nan_to_num(gv) / quantum)], -1).reshape(-1, 2)
    key, inverse = np.unique(key, axis=0, return_inverse=True)
    offs = np.arange(-radius, radius + 1, dtype=np.float64)
    out = np.empty((key.shape[0], BINS))
    for j, (ku, kv) in enumerate(key):
        o = (offs[:, None] * ku + offs[None, :] * kv).ravel() * quantum
        avg = np.mean([np.interp(np.mod(grid + x, 2.0 * np.pi), grid, left, period=2.0 * np.pi) for x in o], axis=0)
        out[j] = np.sqrt(np.bincount(which, avg**2, minlength=BINS) / np.maximum(count, 1.0))
    return out[np.asarray(inverse).ravel()].reshape(p.shape + (BINS,))


BLUR_CHECK = {"lens blur off": {"camera": {"lens_blur_sigma_px": 0.0}},
              "defocus off": {"projector": {"defocus_sigma_px": 0.0}}}


def _variant(case: str, name: str, over: dict) -> str:
    """``case`` with ``over``'s bench sections changed, registered in the matrix's cases as
    ``case, name``."""
    cfg = copy.deepcopy(am.CASES[case]["cfg"])
    for section, values in over.items():
        cfg[section].update(values)
    key = f"{case}, {name}"
    am.CASES[key] = {"cfg": bench.validate_bench_config(cfg), "holdout": am.CASES[case]["holdout"], "variants": None}
    return key


def study(case: str, where: Path) -> tuple[str, list[str]]:
    cfg = am._config({})
    session, tables = am._case_dirs(where, am.CASES[case]["cfg"])
    out = where / "all-on"
    if not (out / "model.npz").exists() or not sorted(out.glob("frame_*[0-9].u.tiff")):
        am.measure(session, tables, out, cfg)
    s = load_session(session)
    ids = list(s.frame_ids)[:2]
    cal = PlaneCalibration.load(str(out / "model.npz"))
    hs = np.stack([tifffile.imread(out / f"frame_{n:04d}.tiff").astype(np.float64) for n in ids])
    us = np.stack([tifffile.imread(out / f"frame_{n:04d}.u.tiff").astype(np.float64) for n in ids])
    truth = np.stack([tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in ids])
    es = hs - truth
    ok = np.all(np.isfinite(es) & np.isfinite(us), axis=0)
    ok[:BORDER_PX] = ok[-BORDER_PX:] = False
    ok[:, :BORDER_PX] = ok[:, -BORDER_PX:] = False
    zs = am.zones(np.where(np.isfinite(truth[0]), truth[0], 0.0), np.asarray(read_rgb(s.object_white), np.float64))
    a, b = np.asarray(cal.a, np.float64), np.asarray(cal.b, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = a * hs / (1.0 - b * hs)
        g = np.abs(a) / (a + b * d) ** 2
    code = np.mod(np.asarray(cal.phi_ref, np.float64) + np.nan_to_num(d), 2 * np.pi)
    kbin = np.minimum((code / (2 * np.pi) * BINS).astype(int), BINS - 1)
    corner = np.isin(kbin, CORNER_BINS)
    bud = cal.budget or {}
    radius = int(cfg["measurement"]["denoise_radius"])
    set_name = "hold-out" if am.CASES[case]["holdout"] else "tuning"
    if "interp_common" in bud:
        smoothing = float(cfg["calibration"]["phase_error"]["smooth_bins"]) * 2 * np.pi / float(cfg["calibration"]["phase_error"]["bins"])
        parts = [windowed_residual(bud["interp_common"], smoothing, cal.phi_ref, r) for r in (0, radius)]
        c0, cw = (g * np.take_along_axis(p[None], kbin[..., None], axis=-1)[..., 0] for p in parts)
    else:  # no phase-error table applied: no shared residual in u
        c0 = cw = np.zeros_like(us)
    u_w = np.sqrt(np.maximum(us**2 - c0**2 + cw**2, 0.0))
    shared = es.mean(axis=0)
    noise2 = (0.5 * (es[0] - es[1])) ** 2

    def rms(x: np.ndarray, sel: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x[sel] ** 2)))
    cells = []
    for sel in (ok & corner[0], ok & ~corner[0]):
        sh = float(np.sqrt(max(np.mean(shared[sel] ** 2) - np.mean(noise2[sel]), 0.0)))
        cells.append(f"{sh:.4f}")
    sel2 = np.broadcast_to(ok, es.shape) & corner
    head = (f"| {case} | {set_name} | {cells[0]} | {cells[1]} | {rms(c0, sel2):.4f} | {rms(cw, sel2):.4f} |")
    zone_rows = []
    for zname in ("edge", "texture", "rest"):
        z = np.broadcast_to(ok & zs[zname], es.shape)
        if z.sum() < 200:
            continue
        vals = []
        for sel, sel1 in ((z & corner, ok & zs[zname] & corner[0]), (z & ~corner, ok & zs[zname] & ~corner[0])):
            sh = float(np.sqrt(max(np.mean(shared[sel1] ** 2) - np.mean(noise2[sel1]), 0.0)))
            vals.append(f"{int(sel.sum())} | {sh:.4f} | {np.mean(np.abs(es[sel]) <= 2 * us[sel]):.3f} | "
                        f"{np.mean(np.abs(es[sel]) <= 2 * u_w[sel]):.3f}")
        zone_rows.append(f"| {case} | {set_name} | {zname} | " + " | ".join(vals) + " |")
    return head, zone_rows


def _gradient(p: np.ndarray) -> np.ndarray:
    """The code phase's change per pixel (magnitude, central wrapped differences)."""
    gu = np.angle(np.exp(1j * (np.roll(p, -1, 1) - np.roll(p, 1, 1)))) / 2.0
    gv = np.angle(np.exp(1j * (np.roll(p, -1, 0) - np.roll(p, 1, 0)))) / 2.0
    return np.hypot(gu, gv)


def frequency_check(case: str, where: Path) -> list[str]:
    """``--frequency-check``'s rows for one case (measured by :func:`study` first)."""
    s = load_session(where / "session")
    ids = list(s.frame_ids)[:2]
    out = where / "all-on"
    cal = PlaneCalibration.load(str(out / "model.npz"))
    if cal.phase_error is None:
        return [f"| {case} | no phase-error table applied | | | | |"]
    hs = np.stack([tifffile.imread(out / f"frame_{n:04d}.tiff").astype(np.float64) for n in ids])
    truth = np.stack([tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in ids])
    a, b = np.asarray(cal.a, np.float64), np.asarray(cal.b, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = a * truth[0] / (1.0 - b * truth[0])
        g = a / (a + b * d) ** 2  # signed: dz / dphi
    ref = np.asarray(cal.phi_ref, np.float64)
    code = ref + np.nan_to_num(d)
    e = phase_error.table_at(np.mod(code, 2 * np.pi), np.asarray(cal.phase_error, np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        pred = ((_gradient(code) / _gradient(ref)) ** 2 - 1.0) * e * g  # corrected by e, the blur's error is (g / g0)^2 e
    mean = (hs - truth).mean(axis=0)
    ok = np.isfinite(mean) & np.isfinite(pred) & (np.abs(mean) < 0.5)
    ok[:BORDER_PX] = ok[-BORDER_PX:] = False
    ok[:, :BORDER_PX] = ok[:, -BORDER_PX:] = False
    zs = am.zones(np.where(np.isfinite(truth[0]), truth[0], 0.0), np.asarray(read_rgb(s.object_white), np.float64))
    corner = np.isin(np.minimum((np.mod(code, 2 * np.pi) / (2 * np.pi) * BINS).astype(int), BINS - 1), CORNER_BINS)
    rows = []
    for zname in ("edge", "texture", "rest"):
        cells = []
        for sel in (ok & zs[zname] & corner, ok & zs[zname] & ~corner):
            cells.append(f"{np.corrcoef(pred[sel], mean[sel])[0, 1]:+.2f} | {np.sqrt(np.mean(pred[sel] ** 2)):.4f}"
                         if sel.sum() >= 200 else "- | -")
        rows.append(f"| {case} | {zname} | " + " | ".join(cells) + " |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=DEFAULT)
    ap.add_argument("--keep", type=Path, default=None,
                    help="sessions and results here (accuracy_matrix.py --keep's layout), reused when found")
    ap.add_argument("--blur-check", action="store_true", help="also the tuning reliefs with each blur off")
    ap.add_argument("--frequency-check", action="store_true",
                    help="also the tuning reliefs' errors against the phase-error table scaled by the local fringe frequency")
    a = ap.parse_args()
    cases = list(a.cases)
    if a.blur_check:
        cases += [_variant(c, n, over) for c in ("tex astronaut p56 72x1", "tex chelsea p56 72x1")
                  for n, over in BLUR_CHECK.items()]
    heads, zones = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            h, z = study(case, (a.keep or Path(tmp)) / am._slug(case))
            heads.append(h)
            zones += z
            print(f"<!-- {case} -->", flush=True)
    print("\n| case | set | shared error, corner bins mm | shared error, other bins mm | "
          "the residual's term, corner bins mm: as written | averaged over the filter's window (sketch) |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    print("\n".join(heads))
    print("\n| case | set | zone | corner bins: pixel values | shared error mm | 2u as written | 2u, the residual "
          "averaged (sketch) | other bins: pixel values | shared error mm | 2u as written | 2u, the residual averaged "
          "(sketch) |")
    print("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    print("\n".join(zones))
    if a.frequency_check:
        print("\n| case | zone | corner bins: correlation | prediction rms mm | other bins: correlation | prediction rms mm |")
        print("| --- | --- | ---: | ---: | ---: | ---: |")
        with tempfile.TemporaryDirectory() as tmp:
            for case in ("tex astronaut p56 72x1", "tex chelsea p56 72x1"):
                where = (a.keep or Path(tmp)) / am._slug(case)
                study(case, where)
                print("\n".join(frequency_check(case, where)), flush=True)


if __name__ == "__main__":
    main()
