"""Bench configuration: one YAML file, validated against ``bench.schema.json``.

The schema is the single source of truth for keys and defaults. :func:`load_bench_config`
reads a file (or a packaged preset by name), validates it, fills the defaults and resolves the
scene's file paths relative to the YAML file; :func:`validate_bench_config` does the same for a
dictionary built in code (paths relative to the working directory).
"""

from __future__ import annotations

import copy
import json
from functools import cache
from pathlib import Path
from typing import Any

import jsonschema
import yaml

__all__ = [
    "BenchConfigError",
    "available_presets",
    "bench_schema",
    "load_bench_config",
    "preset_path",
    "validate_bench_config",
]

_HERE = Path(__file__).resolve().parent
_PRESETS = _HERE / "presets"
_SCHEMA = _HERE / "bench.schema.json"


class BenchConfigError(ValueError):
    """A bench configuration that cannot be used.

    Parameters
    ----------
    path : str
        The file (or ``"<dict>"``) the configuration came from.
    problem : str
        What is wrong, naming the offending key.
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


@cache
def bench_schema() -> dict[str, Any]:
    """The JSON schema of the bench YAML (draft 2020-12)."""
    return json.loads(_SCHEMA.read_text(encoding="utf-8"))


def available_presets() -> list[str]:
    """Names of the packaged presets (``demo``, ``flat``, ...)."""
    return sorted(p.stem for p in _PRESETS.glob("*.yaml"))


def preset_path(name: str) -> Path:
    """Path of a packaged bench preset.

    Parameters
    ----------
    name : str
        Preset name, with or without ``.yaml`` (e.g. ``"demo"``).

    Raises
    ------
    FileNotFoundError
        If there is no such preset; the message lists the available ones.
    """
    stem = name[:-5] if name.endswith(".yaml") else name
    path = _PRESETS / f"{stem}.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"no bench preset {name!r}; available: {', '.join(available_presets())}")
    return path


def load_bench_config(path: str | Path) -> dict[str, Any]:
    """Read, validate and complete a bench YAML file.

    Parameters
    ----------
    path : str or Path
        A YAML file, or the bare name of a packaged preset (``"demo"``) when no such file exists.

    Returns
    -------
    dict
        The configuration with every default filled in and scene paths made absolute.

    Raises
    ------
    BenchConfigError
        If the file cannot be read or parsed, or breaks the schema (unknown keys included);
        the message names the file and the problem.
    """
    p = Path(path)
    if not p.exists() and p.parent == Path(".") and (_PRESETS / f"{p.stem}.yaml").is_file():
        p = _PRESETS / f"{p.stem}.yaml"
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise BenchConfigError(p, f"cannot read the file ({exc.strerror or exc})") from exc
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise BenchConfigError(p, f"not valid YAML: {exc}") from exc
    return validate_bench_config(raw, source=p, base_dir=p.resolve().parent)


def validate_bench_config(
    raw: Any, source: str | Path = "<dict>", base_dir: str | Path | None = None
) -> dict[str, Any]:
    """Validate a bench configuration and return a completed copy.

    Idempotent: a completed configuration validates to itself.

    Parameters
    ----------
    raw : Any
        The parsed YAML (must be a mapping).
    source : str or Path
        Name used in error messages.
    base_dir : str or Path, optional
        Folder relative scene paths are resolved against (default: the working directory).

    Raises
    ------
    BenchConfigError
        On any schema violation or inconsistent setting.
    """
    if not isinstance(raw, dict):
        raise BenchConfigError(source, "the bench configuration must be a YAML mapping")
    schema = bench_schema()
    validator = jsonschema.Draft202012Validator(schema)
    errors = sorted(validator.iter_errors(raw), key=lambda e: (len(e.absolute_path), list(map(str, e.absolute_path))))
    if errors:
        raise BenchConfigError(source, "; ".join(_describe(e) for e in errors[:3]))
    cfg = copy.deepcopy(raw)
    kind = cfg["scene"]["kind"]
    if "specimen" in cfg and kind != "gauge_blocks":
        raise BenchConfigError(source, "specimen is only meaningful for a gauge_blocks scene")
    if kind == "gauge_blocks":
        cfg.setdefault("specimen", {})
    _fill_defaults(cfg, schema, schema)
    _fill_defaults(cfg["scene"], schema["$defs"][f"scene_{kind}"], schema)
    _check_semantics(cfg, source)
    base = Path(base_dir) if base_dir is not None else Path.cwd()
    for key in ("path", "reflectance_path"):
        value = cfg["scene"].get(key)
        if value:
            resolved = (base / value).resolve() if not Path(value).is_absolute() else Path(value)
            if not resolved.is_file():
                raise BenchConfigError(source, f"scene.{key}: file not found: {resolved}")
            cfg["scene"][key] = str(resolved)
    return cfg


def _describe(err: jsonschema.ValidationError) -> str:
    """One readable sentence for a schema error; ``oneOf`` errors list why each form failed."""
    where = ".".join(str(p) for p in err.absolute_path) or "top level"
    if err.validator in ("oneOf", "anyOf") and err.context:
        branches: dict[Any, jsonschema.ValidationError] = {}
        for sub in err.context:
            key = sub.relative_schema_path[0]
            if key not in branches or len(sub.absolute_path) > len(branches[key].absolute_path):
                branches[key] = sub
        reasons = []
        for sub in branches.values():
            sub_where = ".".join(str(p) for p in sub.absolute_path)
            reasons.append(f"{sub_where}: {sub.message}" if sub_where != where else sub.message)
        return f"at {where}: {err.instance!r} is not allowed (" + "; or ".join(reasons) + ")"
    return f"at {where}: {err.message}"


def _fill_defaults(node: dict[str, Any], schema: dict[str, Any], root: dict[str, Any]) -> None:
    """Fill ``default`` values of ``schema['properties']`` into ``node``, recursively."""
    for key, sub in schema.get("properties", {}).items():
        if "$ref" in sub and "default" not in sub:
            sub = _resolve(sub["$ref"], root)
        if key not in node and "default" in sub:
            node[key] = copy.deepcopy(sub["default"])
        if isinstance(node.get(key), dict) and "properties" in sub:
            _fill_defaults(node[key], sub, root)


def _resolve(ref: str, root: dict[str, Any]) -> dict[str, Any]:
    node: Any = root
    for part in ref.lstrip("#/").split("/"):
        node = node[part]
    return node


def _check_semantics(cfg: dict[str, Any], source: str | Path) -> None:
    """Consistency checks the schema cannot express."""
    s = cfg["session"]
    if not any(abs(z) < 5e-4 for z in s["planes_mm"]):
        raise BenchConfigError(source, "session.planes_mm must contain 0 (the reference plane z_0.000)")
    if len({f"{z:.3f}" for z in s["planes_mm"]}) != len(s["planes_mm"]):
        raise BenchConfigError(source, "session.planes_mm has two planes with the same 3-decimal name")
    proj = cfg["projector"]
    if proj["defocus_sigma_px"] > 0 and proj["pixel_mm"] is None:
        raise BenchConfigError(source, "projector.defocus_sigma_px needs projector.pixel_mm")
    top = max(max(s["planes_mm"]), 0.0)
    if proj["height_mm"] <= top + 1.0:
        raise BenchConfigError(source, "projector.height_mm must be well above the highest plane")
    _check_camera(cfg, source, top)
    blocks = cfg["scene"].get("blocks")
    if isinstance(blocks, list):
        names = [b["name"] for b in blocks]
        if len(set(names)) != len(names):
            raise BenchConfigError(source, "scene.blocks: block names must be unique")
        for i, b in enumerate(blocks):
            x0, y0, x1, y1 = b["rect_mm"]
            if not (x1 > x0 and y1 > y0):
                raise BenchConfigError(source, f"scene.blocks.{i}.rect_mm must satisfy x1 > x0 and y1 > y0")


def _check_camera(cfg: dict[str, Any], source: str | Path, top_mm: float) -> None:
    """The camera keys (sensor, lens) that the schema cannot check."""
    cam, s = cfg["camera"], cfg["session"]
    sensor = cam.get("sensor") or {}
    if sensor.get("kind") == "bayer" and (int(s["width"]) % 2 or int(s["height"]) % 2):
        raise BenchConfigError(source, f"camera.sensor: a Bayer sensor needs an even width and height, "
                                       f"got {s['width']} x {s['height']}")
    seq, shutter = cfg["projector"].get("colour_sequence"), cam.get("shutter") or {}
    if seq is not None:
        if float(cam["exposure_ms"]) <= 0.0:
            raise BenchConfigError(source, "projector.colour_sequence needs camera.exposure_ms > 0 (an instant "
                                           "exposure sees one colour segment)")
        if sum(float(d) for d in seq["duty"]) > 1.0 + 1e-9:
            raise BenchConfigError(source, f"projector.colour_sequence.duty: the shares of R, G and B sum to "
                                           f"{sum(seq['duty']):.4f}, more than one cycle")
        missing = [c for c in "RGB" if c not in seq["segments"]]
        if missing:
            raise BenchConfigError(source, f"projector.colour_sequence.segments {seq['segments']!r} never shows "
                                           f"{', '.join(missing)}")
    if shutter.get("kind") == "rolling" and shutter.get("line_time_us") is None:
        raise BenchConfigError(source, "camera.shutter: a rolling shutter needs line_time_us")
    if shutter.get("kind") != "rolling" and shutter.get("line_time_us") is not None:
        raise BenchConfigError(source, "camera.shutter.line_time_us is only meaningful with kind: rolling")
    model = cam.get("model", "telecentric")
    wd = cam.get("working_distance_mm")
    if model == "pinhole":
        if wd is None:
            raise BenchConfigError(source, "camera.model: pinhole needs camera.working_distance_mm")
        if float(wd) <= top_mm + 10.0:
            raise BenchConfigError(source, "camera.working_distance_mm must be well above the highest plane")
    elif wd is not None:
        raise BenchConfigError(source, "camera.working_distance_mm is only meaningful with camera.model: pinhole")
    dist = cam.get("distortion")
    if dist is not None and len(dist) not in (4, 5, 8, 12, 14):
        raise BenchConfigError(source, f"camera.distortion: OpenCV takes 4, 5, 8, 12 or 14 coefficients "
                                       f"(k1, k2, p1, p2[, k3 ...]), got {len(dist)}")


def sweep_config(config: dict[str, Any], period_px: float) -> dict[str, Any]:
    """A copy of a validated configuration at another fringe period, id suffixed ``-p<period>``."""
    cfg = copy.deepcopy(config)
    cfg["session"]["period_px"] = period_px
    tag = f"{period_px:g}".replace(".", "-")
    cfg["session"]["id"] = f"{config['session']['id']}-p{tag}"
    return cfg
