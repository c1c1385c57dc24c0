"""Study: the interpolation term against the error the frames share, by code-phase bin.

Usage: ./run python benchmarks/interpolation_term.py [--cases NAME ...] [--keep DIR]

For each case of ``accuracy_matrix.py`` (default: the tuning cases with two repeats or more
and two textured reliefs of one repeat; two frames each), measured at the defaults, on the
pixels valid in both frames, 4 px or more from the image border: the rms of the interpolation term as the budget has it
(``uncertainty.split_terms``: the chord error of the curvature the table's noise does not
explain, less the plate's shared curvature that the phase-error table takes out) and as the
table's raw second differences give it (``uncertainty.interpolation_bins``, the bin of each
pixel's phase); the frames' shared error (their mean error, less the noise's share) in the
six code-phase bins of the twelve next to the starts of a rising channel (codes 0, 2 pi / 3,
4 pi / 3: where gamma flattens the hue curve and the term is largest) and in the other six;
there, the correlation of the shared error with the raw signed chord error each pixel's own
table predicts at its phase (``-f (1 - f) r step / 2`` through ``G``, ``r`` the interval's mean
second difference over its first, ``f`` the phase's place in the interval); and the 2u coverage
with u as written. Scores only; about a minute per case with its session kept.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import tifffile

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe import uncertainty  # noqa: E402
from huefringe.height import PlaneCalibration  # noqa: E402
from huefringe.huetable import HueTable  # noqa: E402
from huefringe.session import load_session  # noqa: E402

CORNER_BINS = (0, 3, 4, 7, 8, 11)
BORDER_PX = 4
DEFAULT = ["flat p40 d1.6 96x2", "gauge plain p48 96x2 16bit", "photo astronaut p48 96x2", "demo (pre-distorted) p60",
           "tex astronaut p56 72x1", "tex chelsea p56 72x1"]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def row(case: str, root: Path) -> str:
    session, tables = am._case_dirs(root, am.CASES[case]["cfg"])
    out = root / "defaults"
    paths = am.measure(session, tables, out, am._config({}))
    s = load_session(session)
    table = HueTable.load(paths["tables"] / "table_object.json")
    cal = PlaneCalibration.load(str(out / "model.npz"))
    hs = [tifffile.imread(p).astype(np.float64) for p in paths["heights"][:2]]
    us = [tifffile.imread(p).astype(np.float64) for p in paths["uncertainties"][:2]]
    es = [h - tifffile.imread(s.ground_truth[i]).astype(np.float64) for h, i in zip(hs, s.frame_ids[:2], strict=True)]
    ok = np.isfinite(es[0]) & np.isfinite(es[1]) & np.isfinite(us[0])
    ok[:BORDER_PX] = ok[-BORDER_PX:] = False
    ok[:, :BORDER_PX] = ok[:, -BORDER_PX:] = False
    budget = uncertainty.pixel_budget(table, cal)
    a, b = np.asarray(cal.a, np.float64), np.asarray(cal.b, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = a * hs[0] / (1.0 - b * hs[0])
        g = np.abs(a) / (a + b * d) ** 2
    code = np.mod(np.asarray(cal.phi_ref, np.float64) + np.nan_to_num(d), 2 * np.pi)
    kbin = np.minimum((code / (2 * np.pi) * 12).astype(int), 11)
    term = uncertainty.split_terms(us[0], hs[0], cal.a, cal.b, budget)["interpolation"]
    raw_bins = uncertainty.interpolation_bins(table).astype(np.float64)
    raw = g * np.take_along_axis(raw_bins, kbin[..., None], axis=-1)[..., 0]
    # each pixel's own signed chord error at its phase
    n = table.n_bands
    step = 2 * np.pi / n
    d1, curv = uncertainty.interval_curvature(table.table)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(d1 > 0, curv / d1, 0.0)
    x = code / step
    k = np.minimum(x.astype(int), n - 1)
    f = x - k
    chord = -f * (1 - f) / 2 * np.take_along_axis(ratio, k[None], axis=0)[0] * step * g
    shared = 0.5 * (es[0] + es[1])
    noise2 = (0.5 * (es[0] - es[1])) ** 2
    corner = np.isin(kbin, CORNER_BINS)
    cells = []
    for sel in (ok & corner, ok & ~corner):
        sh = float(np.sqrt(max(np.mean(shared[sel] ** 2) - np.mean(noise2[sel]), 0.0)))
        cells.append(f"{sh:.4f}")
    sel = ok & corner
    corr = float(np.corrcoef(chord[sel], shared[sel])[0, 1])
    cover = float(np.mean(np.concatenate([np.abs(e[ok]) <= 2 * u[ok] for e, u in zip(es, us, strict=True)])))
    set_name = "hold-out" if am.CASES[case]["holdout"] else "tuning"
    return (f"| {case} | {set_name} | {_rms(term[ok]):.4f} | {_rms(raw[ok]):.4f} | {cells[0]} | {cells[1]} | "
            f"{_rms(chord[sel]):.4f} | {corr:+.3f} | {cover:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=DEFAULT)
    ap.add_argument("--keep", type=Path, default=None, help="write sessions and results here, reuse sessions found there")
    a = ap.parse_args()
    print("| case | set | interpolation term mm | raw second differences mm | shared error, corner bins mm | "
          "shared error, other bins mm | predicted chord error, corner bins mm | its correlation with the shared error | 2u |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        for case in a.cases:
            print(row(case, (a.keep or Path(tmp)) / am._slug(case)), flush=True)


if __name__ == "__main__":
    main()
