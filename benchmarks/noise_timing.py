"""ms per frame of the measure stage on a case of ``accuracy_matrix.py --noise --keep DIR``.

Usage: ./run python benchmarks/noise_timing.py DIR/noise-sensor-astronaut-25e-10ke-p56-72x1 [ROUNDS]

Times ``pipeline.frame_results`` (the fused kernel, the phase filter, the uncertainty with its
texture term, the step-edge test) over the case's frames, with the case's own hue table (the
default settings', ``accuracy_matrix.tables_dir``) and plane calibration (``all-on/model.npz``),
against ``cv2.cvtColor`` (RGB to HSV) of the same frame in interleaved rounds: one thread (``NUMBA_NUM_THREADS=1``,
``cv2.setNumThreads(1)``), thread CPU time, medians over the rounds after one warm-up round.
Prints ms per frame and the ratio to ``cvtColor`` (docs/noise.md, Time).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

os.environ["NUMBA_NUM_THREADS"] = "1"

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe import pipeline, stages  # noqa: E402
from huefringe.height import PlaneCalibration  # noqa: E402
from huefringe.huetable import HueTable  # noqa: E402
from huefringe.session import load_session, read_rgb  # noqa: E402
from huefringe.settings import load_config  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    cv2.setNumThreads(1)
    case = Path(sys.argv[1])
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    s = load_session(case / "session")
    cfg = load_config(REPO / "config.yaml")
    table = am.tables_dir(case / "tables", cfg) / "table_object.json"
    cal = PlaneCalibration.load(str(case / "all-on" / "model.npz"))
    frames = list(s.frame_ids)
    rgb = (read_rgb(s.frames[frames[0]]) * 255).astype(np.uint8)

    def measure() -> float:
        t = HueTable.load(table)
        t0 = time.thread_time()
        for _ in pipeline.frame_results(s, t, cal, frames, cfg["hue_model"], cfg["measurement"], map_frames=set()):
            pass
        return (time.thread_time() - t0) / len(frames)

    def convert() -> float:
        t0 = time.thread_time()
        for _ in range(20):
            cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        return (time.thread_time() - t0) / 20

    measure()
    ms, ratios, ref = [], [], []
    for _ in range(rounds):
        a, c = measure(), convert()
        ms.append(1e3 * a)
        ratios.append(a / c)
        ref.append(1e3 * c)
    print(json.dumps({"ms_per_frame": float(np.median(ms)), "ratio_to_cvtColor": float(np.median(ratios)),
                      "cvtColor_ms": float(np.median(ref)), "frames": len(frames), "shape": list(rgb.shape)}))


if __name__ == "__main__":
    main()
