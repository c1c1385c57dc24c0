"""The colour-flicker QA from the hue table's own hue, and what building the reference table costs.

Usage: ./run python benchmarks/flicker_qa_hue.py [SESSION...] [--preset NAME...] [--dark-ramp F] [--rounds N]

For each session (``repeats >= 2``; ``--preset NAME`` writes the bench preset with two repeats and
one frame to a temporary folder first), builds the reference hue table as the workflow does
(:func:`huefringe.pipeline.session_hue_table`, the repository's ``config.yaml``) and prints:

- the colour-flicker QA (``amplitude_rad``, ``max_rad``) from the means the table carries
  (``stats["colour_flicker_means"]``), which the plane calibration reports;
- the same QA from the hue of two white balances, computed here from the same bands: the table's
  (``colour.balanced_hue`` with the table's floor, :func:`huefringe.huetable.white_balance_floor`,
  ``0.5 * calibration.min_intensity``) and the one-count floor of
  :func:`huefringe.colour.white_balance` (``1 / 255``) with :func:`huefringe.colour.hue`; the two
  differ only on pixels whose white image is below the table's floor in some channel (their
  share is printed);
- the process CPU time of ``session_hue_table`` (median of ``--rounds`` rounds after one warm-up).

``--dark-ramp F`` reads every reference image (white and bands) times a geometric ramp across the
columns from 1 to ``F``: a scene whose right part is darker than the table's floor.
Run it with another library on ``PYTHONPATH`` to time that library's table build on the same
sessions (docs/capture.md, "How the QA tells").
"""

from __future__ import annotations

import argparse
import copy
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe import bench, row_banding
from huefringe.camera import CaptureReader
from huefringe.colour import balanced_hue, white_balance, white_gains
from huefringe.colour import hue as hue_of
from huefringe.pipeline import flicker_bands, session_hue_table
from huefringe.session import load_session
from huefringe.settings import load_config

REPO = Path(__file__).resolve().parents[1]


class RampReader(CaptureReader):
    """Every image times a geometric ramp across the columns, from 1 to ``end``."""

    def __init__(self, end: float) -> None:
        super().__init__()
        self.end = end

    def rgb(self, path: Any) -> NDArray[np.float32]:
        img = super().rgb(path)
        return (img * np.geomspace(1.0, self.end, img.shape[1], dtype=np.float32)[None, :, None]).astype(np.float32)


def qa(means: list[list[float | None]], threshold: float) -> tuple[float, float]:
    fl = row_banding.flicker_from_means(means, threshold_rad=threshold)
    return float(fl.amplitude_rad), float(fl.max_rad)


def write_preset(name: str, root: Path) -> Path:
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path(name)))
    cfg["session"].update(repeats=max(2, int(cfg["session"]["repeats"])), frames=1, id=f"{name}-r2".replace("_", "-"))
    return bench.write_session(bench.validate_bench_config(cfg), root / f"{name}-r2", workers=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sessions", nargs="*", type=Path)
    ap.add_argument("--preset", nargs="*", default=[])
    ap.add_argument("--dark-ramp", type=float, default=None)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    config = load_config(REPO / "config.yaml")
    cal, model = config["calibration"], config["hue_model"]
    threshold = float(cal["colour_flicker_max_rad"])
    with tempfile.TemporaryDirectory() as tmp:
        folders = [*args.sessions, *(write_preset(p, Path(tmp)) for p in args.preset)]
        for folder in folders:
            s = load_session(folder)
            reader = CaptureReader() if args.dark_ramp is None else RampReader(args.dark_ramp)
            times = []
            for k in range(args.rounds + 1):
                t0 = time.process_time()
                table = session_hue_table(s, "reference", model, cal, reader=reader)
                if k:
                    times.append(time.process_time() - t0)
            rec = table.stats["colour_flicker_means"]
            white = reader.rgb(s.reference_white)
            table_floor = 0.5 * float(cal["min_intensity"])
            gains = white_gains(white, table_floor)
            ms = float(cal["min_saturation"])
            own: list[list[float | None]] = []
            one_count: list[list[float | None]] = []
            for i in flicker_bands(len(s.reference_bands)):
                own.append([])
                one_count.append([])
                for p in s.reference_bands[i]:
                    img = reader.rgb(p)
                    own[-1].append(row_banding.mean_hue(balanced_hue(img, gains, model, min_saturation=ms)))
                    one_count[-1].append(row_banding.mean_hue(hue_of(white_balance(img, white), model, min_saturation=ms)))
            dark = float((np.min(white, axis=2) < table_floor).mean())
            a_rec, m_rec = qa(rec["mean_hue_rad"], threshold)
            a_own, m_own = qa(own, threshold)
            a_one, m_one = qa(one_count, threshold)
            ramp = "" if args.dark_ramp is None else f", dark ramp to {args.dark_ramp:g}"
            print(f"{s.id}{ramp}: {len(rec['bands'])} bands x {s.repeats} repeats; white below the table's floor "
                  f"{table_floor:g} in some channel: {100 * dark:.2f} % of the pixels")
            print(f"  QA as reported (table's means): amplitude {a_rec:.4e} rad, max {m_rec:.4e} rad")
            print(f"  table's floor:                  amplitude {a_own:.4e} rad, max {m_own:.4e} rad")
            print(f"  one-count floor (1/255):        amplitude {a_one:.4e} rad, max {m_one:.4e} rad "
                  f"(difference {a_own - a_one:+.2e} / {m_own - m_one:+.2e} rad)")
            print(f"  session_hue_table CPU s: median {statistics.median(times):.3f} "
                  f"({', '.join(f'{t:.3f}' for t in times)})", flush=True)


if __name__ == "__main__":
    main()
