"""Write small, format-valid capture sessions for reader tests (no physics: see the bench)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import tifffile
import yaml


def write_image(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".png":
        assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))
    else:
        tifffile.imwrite(path, rgb, photometric="rgb")


def make_session(
    root: Path,
    *,
    width: int = 32,
    height: int = 24,
    bit_depth: int = 8,
    ext: str = ".png",
    bands: int = 6,
    repeats: int = 2,
    planes: tuple[float, ...] = (0.0, 1.0, 2.0),
    frames: int = 2,
    phase_shift: bool = True,
    specimen: bool = True,
    seed: int = 0,
) -> Path:
    rng = np.random.default_rng(seed)
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    top = 255 if bit_depth == 8 else 65535

    def img(path: Path) -> None:
        write_image(path.parent / (path.name + ext), rng.integers(0, top, size=(height, width, 3)).astype(dtype))

    for part in ("reference", "object"):
        img(root / part / "white")
        for i in range(bands):
            for r in range(repeats):
                img(root / part / "hue" / f"band_{i:03d}_r{r}")
    for z in planes:
        img(root / "reference" / "planes" / f"z_{z:.3f}")
    for n in range(frames):
        img(root / "object" / "frames" / f"frame_{n:04d}")
        if phase_shift:
            for s in range(3):
                img(root / "object" / "phase_shift" / f"frame_{n:04d}_s{s}")
        gt = root / "ground_truth" / "frames" / f"frame_{n:04d}.tiff"
        gt.parent.mkdir(parents=True, exist_ok=True)
        tifffile.imwrite(gt, np.zeros((height, width), np.float32))
    meta = {
        "format": "capture-session/1",
        "id": "test-session",
        "camera": {"width": width, "height": height, "bit_depth": bit_depth, "pixel_pitch_mm": 0.2},
        "pattern": {"period_px": 8, "hue_bands": bands, "repeats": repeats},
        "planes_mm": list(planes),
    }
    if specimen:
        meta["specimen"] = {
            "kind": "step_heights",
            "base_roi": [[0, 0, width, 4]],
            "steps": [{"name": "blue", "nominal_mm": 1.0, "roi": [4, 8, 12, 16]}],
            "tolerance_mm": 0.05,
        }
    (root / "session.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return root
