"""Study: the uncertainty beside the edge mask's holes, with and without its lateral term.

Usage: ./run python benchmarks/lateral_holes.py [--cases NAME ...] [--keep DIR]

For each case of ``accuracy_matrix.py`` (default: the demo and the plain gauge, both tuning) the
session is measured at the defaults and with the lateral term off (``accuracy_matrix``'s "all on"
and "lateral term off"; the heights are the same bits, only u differs). The valid pixels of the
"edge" zone (within 3 px of a change of the true height by more than 0.1 mm) are binned by their
distance to the nearest invalid pixel (the edge mask's holes, shadows, the image border), and
per bin the script prints the rms error against the truth, the rms u with and without the
lateral term and the share of pixels with ``|e| <= 2u`` for each (docs/uncertainty.md, Known
limits). About a minute per case with its session kept.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe.session import load_session, read_rgb  # noqa: E402

BINS = ((0.0, 1.5), (1.5, 2.5), (2.5, 3.5), (3.5, 99.0))
VARIANTS = ("all on", "lateral term off")


def rows(case: str, root: Path) -> list[str]:
    """The table rows of one case (its session and results under ``root``)."""
    session, tables = am._case_dirs(root, am.CASES[case]["cfg"])
    paths = {v: am.measure(session, tables, root / am._slug(v), am._config(am.VARIANTS[v])) for v in VARIANTS}
    s = load_session(session)
    truths = [tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids]
    edge = am.zones(np.where(np.isfinite(truths[0]), truths[0], 0.0),
                    np.asarray(read_rgb(s.object_white), np.float64))["edge"]
    e, d, u = [], [], {v: [] for v in VARIANTS}
    for k, truth in enumerate(truths):
        h = tifffile.imread(paths["all on"]["heights"][k]).astype(np.float64)
        dist = ndimage.distance_transform_edt(np.isfinite(h))
        e.append((h - truth)[edge])
        d.append(dist[edge])
        for v in VARIANTS:
            u[v].append(tifffile.imread(paths[v]["uncertainties"][k]).astype(np.float64)[edge])
    ee, dd = np.concatenate(e), np.concatenate(d)
    uu = {v: np.concatenate(x) for v, x in u.items()}
    ok = np.isfinite(ee) & np.isfinite(uu["all on"]) & np.isfinite(uu["lateral term off"])
    out = []
    for lo, hi in BINS:
        m = ok & (dd >= lo) & (dd < hi)
        if m.sum() < 20:
            continue
        cells = [f"{np.sqrt(np.mean(ee[m] ** 2)):.4f}"]
        for v in VARIANTS:
            cells += [f"{np.sqrt(np.mean(uu[v][m] ** 2)):.4f}", f"{np.mean(np.abs(ee[m]) <= 2 * uu[v][m]):.3f}"]
        span = f"{lo:g}-{hi:g} px" if hi < 99 else f">= {lo:g} px"
        out.append(f"| {case} | {span} | {int(m.sum())} | " + " | ".join(cells) + " |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=["demo (pre-distorted) p60", "gauge plain p48 96x2 16bit"])
    ap.add_argument("--keep", type=Path, default=None, help="write sessions and results here, reuse sessions found there")
    a = ap.parse_args()
    print("| case | distance to an invalid pixel | pixels | rms e mm | rms u mm | 2u | rms u, lateral term off | 2u |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        for case in a.cases:
            for line in rows(case, (a.keep or Path(tmp)) / am._slug(case)):
                print(line, flush=True)


if __name__ == "__main__":
    main()
