"""What the sigma-adaptive phase filter averages: the support (equal-weight pixels per height, the
``support`` map of ``stages.measure_frames``) of each session's first frame at the adaptive
filter's targets 0.006, 0.002 (default) and 0.001 rad, median / p10 / p90 over its valid pixels.

Usage: ./run python benchmarks/adaptive_support.py DIR [DIR ...]

Each ``DIR`` is a case folder written by ``benchmarks/accuracy_matrix.py --keep`` or
``benchmarks/coverage_bins.py --keep`` (its ``session``, ``tables`` and the ``all-on`` run's
``model.npz`` and ``camera.json``); the frame is measured again at config.yaml's defaults with
only the target changed (docs/accuracy-texture.md, "The adaptive filter's target").
"""

from __future__ import annotations

import copy
import sys
import tempfile
from pathlib import Path

import numpy as np
import tifffile

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe import stages  # noqa: E402
from huefringe.session import load_session  # noqa: E402

TARGETS = (0.006, 0.002, 0.001)


def support_row(where: Path) -> list[str]:
    """``median / p10 / p90`` of the first frame's support at each of ``TARGETS``."""
    s = load_session(where / "session")
    cfg = am._config({})
    out = where / "all-on"
    table = am.tables_dir(where / "tables", cfg) / "table_object.json"
    cells = []
    for t in TARGETS:
        m = copy.deepcopy(cfg["measurement"])
        m["denoise_adaptive"] = {**m.get("denoise_adaptive", {}), "target_sigma_rad": t}
        with tempfile.TemporaryDirectory() as td:
            tmp = Path(td)
            stages.measure_frames(str(where / "session"), [s.frame_ids[0]], str(table), str(out / "model.npz"),
                                  cfg["hue_model"], m, cfg["calibration"], heights=[str(tmp / "h.tiff")],
                                  qa=[str(tmp / "q.json")], map_frames=[], camera_json=str(out / "camera.json"),
                                  uncertainties=[str(tmp / "u.tiff")], supports=[str(tmp / "s.tiff")])
            sp = tifffile.imread(tmp / "s.tiff").astype(np.float64)
            v = sp[np.isfinite(tifffile.imread(tmp / "h.tiff")) & (sp > 0)]
        cells.append(f"{np.median(v):.0f} / {np.percentile(v, 10):.0f} / {np.percentile(v, 90):.0f}")
    return cells


def main() -> None:
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    print("| session | " + " | ".join(f"target {t}" for t in TARGETS) + " |")
    print("| --- |" + " --- |" * len(TARGETS))
    for d in sys.argv[1:]:
        print(f"| {Path(d).name} | " + " | ".join(support_row(Path(d))) + " |", flush=True)


if __name__ == "__main__":
    main()
