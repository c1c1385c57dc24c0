"""The rig route from captures, as a lab runs it: bench-rig captures -> structured-light sessions ->
rig-calibrate -> rig-measure, against truth (docs/rig.md, "End to end from a structured-light session").

Usage: ./run python benchmarks/rig_session_route.py [--seed S] [N_POSES ...]   (default 6, seed 4: the
documented pose set; about 20 s per case)
For each pose count: the flat board's form deviation and plane RMS (mm) and the steps' heights
(truth 2, 5, 10 mm) with the calibration from printed-board poses (corners in the captures' mean),
from the same poses with board.png (white-light corner images), and with the true calibration.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from rig_helpers import BOARD, SL_BASE, SL_RIG, SL_TOPS, write_rig_captures  # noqa: E402

from huefringe.bench.rig import RIGS, write_pose_folders  # noqa: E402
from huefringe.cli import main  # noqa: E402
from huefringe.codecs import load_sequence  # noqa: E402
from huefringe.rig import write_calibration  # noqa: E402


def run(*args: str) -> None:
    if main(list(args)) != 0:
        raise SystemExit(f"failed: huefringe {' '.join(args)}")


def measure(r: Path, calib: Path, out: Path) -> tuple[dict, dict]:
    run("rig-measure", str(r / "board"), str(r / "sequence.yaml"), str(calib), str(out / "board"))
    boxes = [a for b in SL_BASE for a in ("--base", ",".join(map(str, b)))]
    boxes += [a for b in SL_TOPS.values() for a in ("--box", ",".join(map(str, b)))]
    run("rig-measure", str(r / "steps"), str(r / "sequence.yaml"), str(calib), str(out / "steps"), *boxes)
    return (json.loads((out / "board/report.json").read_text()), json.loads((out / "steps/report.json").read_text()))


def main_(poses: list[int], seed: int = 4) -> None:
    print("| poses | corners from | stereo RMS px | flat form mm | flat plane RMS mm | steps 2 / 5 / 10 mm (error %) |")
    print("|---|---|---|---|---|---|")
    for n in poses:
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp)
            r = root / "rig"
            write_rig_captures(r, n_poses=n, seed=seed)
            run("sl-session", str(r / "board"), str(r / "sequence.yaml"), str(root / "s"), "--poses", str(r / "poses"))
            run("rig-calibrate", str(root / "s"), str(root / "printed.yml"), "--board", "9x7", "--pitch-mm", "12")
            write_pose_folders(RIGS[SL_RIG], BOARD, load_sequence(r / "sequence.yaml"), n, seed, root / "poses_img")
            run("rig-calibrate", str(root / "poses_img"), str(r / "sequence.yaml"), str(root / "image.yml"),
                "--board", "9x7", "--pitch-mm", "12")
            write_calibration(root / "truth.yml", RIGS[SL_RIG].calibration)
            for name in ("printed", "image", "truth"):
                rep = json.loads((root / f"{name}.report.json").read_text()) if name != "truth" else None
                board, steps = measure(r, root / f"{name}.yml", root / name)
                hs = [(v["mean_height_mm"], h) for (h, v) in zip(SL_TOPS, steps["boxes"].values(), strict=True)]
                label = {"printed": "captures' mean (session)", "image": "board.png", "truth": "true calibration"}[name]
                stereo = f"{rep['rms_px']['stereo']:.3f}" if rep else "-"
                print(f"| {n} | {label} | {stereo} | "
                      f"{board['plane']['form_deviation_mm']:.4f} | {board['plane']['rms_mm']:.4f} | "
                      + " / ".join(f"{m:.4f} ({100 * (m / h - 1):+.2f})" for m, h in hs) + " |", flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    seed = int(args[args.index("--seed") + 1]) if "--seed" in args else 4
    if "--seed" in args:
        del args[args.index("--seed"): args.index("--seed") + 2]
    main_([int(a) for a in args] or [6], seed)
