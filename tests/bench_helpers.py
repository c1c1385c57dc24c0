"""Write bench sessions for tests and run the measuring stages on them (no Snakemake)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any


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
