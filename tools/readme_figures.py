"""Make the README's pictures from a finished demo run (and the dental example).

Usage: ./run python tools/readme_figures.py   (after ./run snakemake --cores 2 and the dental run
shown in the README). Writes docs/img/*.png.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from huefringe.session import load_session, read_rgb

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "img"


def captures(session: Path, out: Path) -> None:
    s = load_session(session)
    band = s.hue_bands // 3
    panels = [
        (read_rgb(s.frames[s.frame_ids[0]]), "one-shot frame (trapezoidal fringe)"),
        (read_rgb(s.object_white), "white image"),
        (read_rgb(s.object_bands[band][0]), f"hue band {band} of {s.hue_bands}"),
    ]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    for ax, (img, title) in zip(axes, panels, strict=True):
        ax.imshow(img)
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    fig.suptitle(f"virtual bench: session '{s.id}'", fontsize=11)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    plt.close(fig)


def main() -> None:
    demo = REPO / "resources/demo/gauge-blocks-demo"
    captures(demo, OUT / "demo_captures.png")
    copies = {
        "results/gauge-blocks-demo/renders/frame_0000_oblique1.png": "demo_render.png",
        "results/dental-model/renders/frame_0000_oblique1.png": "dental_render.png",
        "results/flat-board/calib/qa_hue_cross_section.png": "flat_board_hue.png",
    }
    for src, dst in copies.items():
        if (REPO / src).exists():
            shutil.copy(REPO / src, OUT / dst)
            print("wrote", OUT / dst)


if __name__ == "__main__":
    main()
