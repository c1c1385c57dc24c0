"""The configuration: the library's packaged defaults (``defaults.yaml``), overridden key by key.

The workflow reads :data:`DEFAULTS_PATH` first, then the repository's ``config.yaml`` and any
``--configfile``; :func:`huefringe.measure` and scripts call :func:`load_config`.
:func:`software_identity` is huefringe's own name, version and address, read from the installed
distribution's metadata (``[project.urls]`` of ``pyproject.toml``), for the files that record
what made them (archives, X3P).
"""

from __future__ import annotations

import copy
import importlib.metadata
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import yaml

from huefringe import __version__

__all__ = ["DEFAULTS_PATH", "SoftwareIdentity", "defaults", "load_config", "merge", "software_identity"]

DEFAULTS_PATH = Path(__file__).with_name("defaults.yaml")
"""The packaged defaults: every configuration key but ``sessions``, ``bench_sessions`` and ``table1``."""


def defaults() -> dict[str, Any]:
    """A fresh copy of the packaged defaults."""
    return yaml.safe_load(DEFAULTS_PATH.read_text(encoding="utf-8"))


def merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` updated by ``override``, mappings merged key by key (as Snakemake merges config files)."""
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def load_config(*overrides: Mapping[str, Any] | str | os.PathLike[str] | None) -> dict[str, Any]:
    """The packaged defaults overridden by each of ``overrides`` in turn (mappings or YAML files).

    Examples
    --------
    >>> load_config({"measurement": {"denoise_radius": 0}})["measurement"]["denoise_radius"]
    0
    >>> load_config()["hue_model"]
    'hexcone'
    """
    cfg = defaults()
    for o in overrides:
        if o is None:
            continue
        if not isinstance(o, Mapping):
            o = yaml.safe_load(Path(o).read_text(encoding="utf-8")) or {}
        cfg = merge(cfg, o)
    return cfg


class SoftwareIdentity(NamedTuple):
    """huefringe as the software that made a file: ``name``, ``version`` and ``url`` (or None)."""

    name: str
    version: str
    url: str | None


def software_identity(url: str | None = None) -> SoftwareIdentity:
    """huefringe's name, version and home page, from the installed distribution's metadata.

    The address is ``Homepage`` of ``[project.urls]`` in ``pyproject.toml`` (the core metadata's
    ``Project-URL``), so it is written once, in the project's own file; ``url`` (the
    configuration's ``archive.software_url``) overrides it. Without an installed distribution
    (a source tree on ``sys.path``) the version is ``huefringe.__version__`` and the url None.
    """
    try:
        meta = importlib.metadata.metadata("huefringe")
    except importlib.metadata.PackageNotFoundError:
        return SoftwareIdentity("huefringe", __version__, url)
    urls = dict(
        (part.strip() for part in entry.split(",", 1)) for entry in (meta.get_all("Project-URL") or []) if "," in entry
    )
    return SoftwareIdentity(str(meta["Name"]), str(meta["Version"]), url or urls.get("Homepage"))
