"""Study: a case's error split into the frames' noise and what they share, against u's terms.

Usage: ./run python benchmarks/noise_split.py [--cases NAME ...] [--weights default|pooled|own|along] [--keep DIR]

For each case of ``accuracy_matrix.py`` (two frames; default: the flat boards, tuning and
hold-out) the session is measured at the defaults with the lateral term off (``accuracy_matrix``'s
"lateral term off": the same heights; u then holds the per-pixel budget, the texture term and the
edge floor), and on the pixels valid in both frames, 4 px or more from the image border, the
script prints the rms of the frame-to-frame error (the frames' difference over sqrt 2) against
the noise term, and the rms of what the frames share (their mean error, less the noise's share
in quadrature) against the shared terms (table, interpolation, reference, model; in quadrature),
each term split from u by ``uncertainty.split_terms``; beside them the hue noise of one capture
that the table estimated (its per-pixel figure times sqrt of the repeats) and the frames' own
(their hue difference over sqrt 2, white-balanced hexcone hue), each as the rms over the table's
valid pixels (docs/accuracy.md, Known limits). ``--weights pooled`` / ``own`` / ``along`` measure
with the phase filter weighted by the table's pooled figure / each pixel's own figure as captured /
the own figure of the capture smoothed along the fringe (docs/uncertainty.md, "The filter's
weights"). About a minute per case with its session kept.
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

from huefringe import colour, uncertainty  # noqa: E402
from huefringe.height import PlaneCalibration  # noqa: E402
from huefringe.huetable import HueTable  # noqa: E402
from huefringe.session import load_session, read_rgb  # noqa: E402

BORDER_PX = 4


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


#: ``--weights``: the phase filter's weights (docs/uncertainty.md, "The filter's weights"), each
#: with the lateral term off
WEIGHTS = {"default": "lateral term off", "pooled": "lateral term off, weights pooled",
           "own": "lateral term off, weights own unsmoothed", "along": "lateral term off, weights along the fringe"}


def row(case: str, root: Path, weights: str = "default") -> str:
    """The table row of one case (its session and results under ``root``)."""
    session, tables = am._case_dirs(root, am.CASES[case]["cfg"])
    variant = WEIGHTS[weights]
    out = root / am._slug(variant)
    paths = am.measure(session, tables, out, am._config(am.VARIANTS[variant]))
    s = load_session(session)
    truths = [tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids]
    heights = [tifffile.imread(h).astype(np.float64) for h in paths["heights"]]
    us = [tifffile.imread(u).astype(np.float64) for u in paths["uncertainties"]]
    if len(heights) < 2:
        raise SystemExit(f"{case}: the split needs two frames, the session has {len(heights)}")
    errs = [h - t for h, t in zip(heights[:2], truths[:2], strict=True)]
    ok = np.isfinite(errs[0]) & np.isfinite(errs[1])
    ok[:BORDER_PX] = ok[-BORDER_PX:] = False
    ok[:, :BORDER_PX] = ok[:, -BORDER_PX:] = False
    table = HueTable.load(paths["tables"] / "table_object.json")
    cal = PlaneCalibration.load(str(out / "model.npz"))
    terms = uncertainty.split_terms(us[0], heights[0], cal.a, cal.b, uncertainty.pixel_budget(table, cal))
    noise = _rms((errs[0] - errs[1])[ok] / np.sqrt(2.0))
    mean_rms = _rms((0.5 * (errs[0] + errs[1]))[ok])  # what the frames share, plus the noise over sqrt 2
    shared = float(np.sqrt(max(mean_rms**2 - noise**2 / 2.0, 0.0)))
    shared_terms = float(np.sqrt(sum(_rms(terms[k][ok]) ** 2 for k in ("table", "interpolation", "reference", "model"))))
    noise_term = _rms(terms["noise"][ok])
    # the hue noise the table's weights assume (its per-pixel estimate) against the frames' own
    white = read_rgb(s.object_white)
    hues = [colour.hue(colour.white_balance(read_rgb(s.frames[n]), white), "hexcone") for n in s.frame_ids[:2]]
    valid = np.asarray(table.valid, bool)
    frame_hue = _rms(np.angle(np.exp(1j * (hues[0] - hues[1])))[valid] / np.sqrt(2.0))
    repeats = int((table.stats or {}).get("repeats", 1) or 1)  # noise_rad is a band mean's: one capture's is sqrt(R) x
    nr = np.asarray(table.noise_rad, np.float64)[valid] * np.sqrt(repeats)
    table_hue = _rms(nr[np.isfinite(nr)])
    set_name = "hold-out" if am.CASES[case]["holdout"] else "tuning"
    return (f"| {case} | {set_name} | {int(ok.sum())} | {noise:.4f} | {noise_term:.4f} | {noise / noise_term:.2f} | "
            f"{shared:.4f} | {shared_terms:.4f} | {shared / shared_terms:.2f} | {table_hue:.4f} | {frame_hue:.4f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=["flat p40 d1.6 96x2", "flat p20 d0.5 256x1 8bit"])
    ap.add_argument("--keep", type=Path, default=None, help="write sessions and results here, reuse sessions found there")
    ap.add_argument("--weights", choices=sorted(WEIGHTS), default="default",
                    help="the phase filter's weights: the default (the own-signal figure of the smoothed capture), "
                         "the table's pooled figure, each pixel's own figure as captured, or the own figure of the "
                         "capture smoothed along the fringe")
    a = ap.parse_args()
    print("| case | set | pixels | frame-to-frame mm | noise term mm | ratio | shared mm | shared terms mm | ratio "
          "| table's hue noise of a capture rad | frames' hue noise rad |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        for case in a.cases:
            print(row(case, (a.keep or Path(tmp)) / am._slug(case), a.weights), flush=True)


if __name__ == "__main__":
    main()
