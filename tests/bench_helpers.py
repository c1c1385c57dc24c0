"""Write bench sessions for tests and run the measuring stages on them (no Snakemake)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml

from huefringe import bench, pipeline

REPO = Path(__file__).resolve().parents[1]
CONFIG = yaml.safe_load((REPO / "config.yaml").read_text())


def bench_config(preset: str, **session: Any) -> dict[str, Any]:
    """A packaged bench preset with ``session`` keys overridden (e.g. width, frames)."""
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path(preset)))
    cfg["session"].update(session)
    return cfg


def write(cfg: dict[str, Any], root: Path) -> Path:
    return bench.write_session(cfg, root / cfg["session"]["id"])


def process(session: Path, out: Path, *, config: dict[str, Any] | None = None, frames: list[int] | None = None,
            baseline: bool = False) -> dict[str, Any]:
    """Run tables, plane calibration and frame measurement; return the output paths."""
    cfg = copy.deepcopy(config or CONFIG)
    out.mkdir(parents=True, exist_ok=True)
    s = pipeline.load_session(session)
    frames = s.frame_ids if frames is None else frames
    for which in ("reference", "object"):
        pipeline.hue_table(str(session), which, cfg["hue_model"], cfg["calibration"],
                           table=str(out / f"table_{which}.json"), stats=str(out / f"table_{which}.stats.json"))
    pipeline.plane_calibration(str(session), str(out / "table_reference.json"), cfg["hue_model"], cfg["calibration"],
                               model=str(out / "model.npz"), stats=str(out / "planes.json"))
    paths = {k: [str(out / k / f"frame_{n:04d}.{ext}") for n in frames]
             for k, ext in (("heights", "tiff"), ("clouds", "ply"), ("phases", "tiff"), ("hues", "tiff"), ("qa", "json"))}
    pipeline.measure_frames(str(session), frames, str(out / "table_object.json"), str(out / "model.npz"),
                            cfg["hue_model"], cfg["measurement"], cfg["calibration"], **paths)
    if baseline:
        paths["baseline"] = [str(out / "baseline" / f"frame_{n:04d}.tiff") for n in frames]
        pipeline.baseline_frames(str(session), frames, str(out / "model.npz"), str(out / "table_object.json"),
                                 cfg["measurement"], heights=paths["baseline"],
                                 qa=[str(out / "baseline" / f"frame_{n:04d}.json") for n in frames])
    paths["session"] = s
    return paths
