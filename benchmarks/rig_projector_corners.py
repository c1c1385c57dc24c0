"""Projector corners on the session route's poses against truth: inverse-variance weighted and
equally weighted local homographies, printed-board poses (corners in the captures' mean) and
evenly lit poses with board.png (docs/rig.md, "End to end from a structured-light session").

Usage: ./run python benchmarks/rig_projector_corners.py [N_POSES [RIG ...]]   (default 8 holdout-wide; about 20 s a rig)
Prints, per route and weighting, the mean and RMS (px) of the projector corners' offsets from the
exact projector pixel at each detected camera corner, and the detected camera corners' offsets
from the true corners.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import yaml
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from rig_helpers import BOARD, HALF_WINDOW_PX, MIN_PIXELS, SL_RIG, SL_SEQUENCE  # noqa: E402

from huefringe.bench.rig import RIGS, write_pose_folders  # noqa: E402
from huefringe.codecs import load_sequence  # noqa: E402
from huefringe.rig import detect_corners, projector_corners  # noqa: E402
from huefringe.codecs import read_captures  # noqa: E402
from huefringe.rig.measure import decode_frame  # noqa: E402
from huefringe.settings import load_config  # noqa: E402


def main(n: int, rigs: list[str]) -> None:
    print("| rig | poses | corners from | projector corners weighted: mean / RMS px | equal weights: mean / RMS px | camera corners: mean / RMS px |")
    print("|---|---|---|---|---|---|")
    for name in rigs:
        one(name, n)


def one(name: str, n: int) -> None:
    rig, cal = RIGS[name], RIGS[name].calibration
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "sequence.yaml").write_text(yaml.safe_dump(SL_SEQUENCE, sort_keys=False))
        spec = load_sequence(root / "sequence.yaml")
        for printed in (True, False):
            poses = write_pose_folders(rig, BOARD, spec, n, 4, root / str(printed), corner_image=not printed, printed=printed)
            err: dict[str, list[np.ndarray]] = {"w": [], "u": [], "cam": []}
            for i, (R, t) in enumerate(poses):
                f = root / str(printed) / f"pose_{i:02d}"
                d = decode_frame(read_captures(f, spec), spec, load_config())
                c = detect_corners(d["mean"] if printed else cv2.imread(str(f / "board.png"), cv2.IMREAD_GRAYSCALE), BOARD)
                ray = np.column_stack([cv2.undistortPoints(c.reshape(-1, 1, 2), cal.camera_matrix, cal.camera_distortion,
                                                           None, None, None, (3, 300, 1e-15)).reshape(-1, 2), np.ones(len(c))])
                truth = rig.to_projector(ray * ((R[:, 2] @ t) / (ray @ R[:, 2]))[:, None])
                valid = d["valid_u"] & d["valid_v"]
                pw, _ = projector_corners(c, d["u"], d["v"], valid, HALF_WINDOW_PX, MIN_PIXELS,
                                          sigma_u=d["sigma_u"], sigma_v=d["sigma_v"])
                pu, _ = projector_corners(c, d["u"], d["v"], valid, HALF_WINDOW_PX, MIN_PIXELS)
                ct = rig.to_camera(BOARD.object_points().astype(np.float64) @ R.T + t)
                err["w"].append(pw - truth)
                err["u"].append(pu - truth)
                err["cam"].append(c - ct[cKDTree(ct).query(c)[1]])
            cells = []
            for k in ("w", "u", "cam"):
                e = np.concatenate(err[k])
                cells.append(f"({e[:, 0].mean():+.4f}, {e[:, 1].mean():+.4f}) / {np.sqrt(np.mean(np.sum(e**2, axis=1))):.4f}")
            print(f"| {name} | {n} | {'captures mean (printed board)' if printed else 'board.png'} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 8, sys.argv[2:] or [SL_RIG])
