"""Write bench sessions for tests and run the measuring stages on them (no Snakemake)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Callable

import numpy as np

from huefringe import bench, stages
from huefringe.settings import load_config

REPO = Path(__file__).resolve().parents[1]
CONFIG = load_config(REPO / "config.yaml")  # the library defaults, overridden by the repository's


def bench_config(preset: str, **session: Any) -> dict[str, Any]:
    """A packaged bench preset with ``session`` keys overridden (e.g. width, frames)."""
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path(preset)))
    cfg["session"].update(session)
    return cfg


def write(cfg: dict[str, Any], root: Path) -> Path:
    return bench.write_session(cfg, root / cfg["session"]["id"])


def process(session: Path, out: Path, *, config: dict[str, Any] | None = None, frames: list[int] | None = None,
            baseline: bool = False) -> dict[str, Any]:
    """Run tables, plane calibration and frame measurement (:func:`stages.measure_session`)."""
    return stages.measure_session(session, out, config or CONFIG, frames=frames, baseline=baseline)


def still_cfg(frames: int) -> dict[str, Any]:
    """The still bench session (tests/test_uncertainty.py's ``still`` fixture,
    ``benchmarks/still_session.py``): the demo rig, small (100 x 75 px, 0.8 mm pitch, 15 px period,
    32 bands x 3 repeats), no phase shifting, no vibration: ``frames`` frames that differ only by
    noise."""
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("demo")))
    cfg["session"].update(width=100, height=75, pixel_pitch_mm=0.8, period_px=15, hue_bands=32, repeats=3,
                          frames=frames)
    cfg["phase_shift"]["enabled"] = False
    cfg["vibration"]["amplitude_mm"] = 0.0
    return cfg


def texture_edge_case(sigma2: float) -> tuple[np.ndarray, Callable[[float, np.ndarray], np.ndarray]]:
    """The texture term's analytic capture (tests/test_uncertainty.py,
    ``benchmarks/texture_term_edge.py``): a fringe (period 24 px, ``0.5 + 0.4 cos``) on a
    reflectance edge (0.2 : 0.8 at column 80 of 16 x 160 px), blurred by a Gaussian of variance
    ``sigma2`` px^2. Returns the reflectance and ``phase(s2, r)``: the four-step phase of the
    capture of reflectance ``r`` after ``texture.correct`` with blur ``s2``."""
    from scipy import ndimage

    from huefringe import texture

    _, uu = np.mgrid[:16, :160].astype(np.float64)
    refl = np.where(uu < 80, 0.2, 0.8)

    def blur(x: np.ndarray) -> np.ndarray:
        return ndimage.gaussian_filter(x, np.sqrt(sigma2), mode="nearest")

    def phase(s2: float, r: np.ndarray) -> np.ndarray:
        w = np.repeat(blur(r)[..., None], 3, axis=-1)
        caps = []
        for k in range(4):
            f = 0.5 + 0.4 * np.cos(2 * np.pi * uu / 24.0 + k * np.pi / 2)
            b = np.repeat(blur(r * f)[..., None], 3, axis=-1)
            caps.append(texture.correct(b, w, s2)[..., 0].astype(np.float64) / w[..., 0])
        return np.arctan2(caps[3] - caps[1], caps[0] - caps[2])

    return refl, phase
