"""What to measure on a structured-light session: ``features.yaml`` (regions in camera pixels).

A region is the union of its ``box``/``boxes`` (``[x0, y0, x1, y1]``: columns ``x0 .. x1 - 1``, rows
``y0 .. y1 - 1``), or the non-zero pixels of its ``mask`` PNG (intersected with the boxes when both
are given). ``base`` is the datum plane every step height is measured from; ``steps``, ``planes``,
``distances`` and ``spheres`` are the figures the report gives, each with its nominal value and
the ISO 14253-1 tolerance (the file's ``tolerance_mm`` unless the figure has its own).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import cv2
import jsonschema
import numpy as np
import yaml
from numpy.typing import NDArray

from ._model import Problem

__all__ = ["FEATURES_FILE", "Feature", "Features", "Region", "load_features"]

FEATURES_FILE = "features.yaml"


@dataclass(frozen=True)
class Region:
    """Camera pixels of one named region: boxes and/or a mask image."""

    name: str
    boxes: tuple[tuple[int, int, int, int], ...] = ()
    mask_file: Path | None = None

    def mask(self, shape: tuple[int, int]) -> NDArray[np.bool_]:
        """The region as a boolean (H, W) mask of the camera image."""
        out = np.zeros(shape, dtype=bool)
        for x0, y0, x1, y1 in self.boxes:
            out[y0:y1, x0:x1] = True
        if self.mask_file is not None:
            m = cv2.imread(str(self.mask_file), cv2.IMREAD_GRAYSCALE) > 0
            out = m & out if self.boxes else m
        return out


@dataclass(frozen=True)
class Feature:
    """One reported figure: ``kind`` step, plane (flatness), distance (and parallelism) or sphere."""

    kind: str
    name: str
    nominal_mm: float
    tolerance_mm: float
    region: Region | None = None
    planes: tuple[str, str] | None = None
    """For a distance: the two plane names (``base`` or a ``planes`` entry), measured from the second."""


@dataclass(frozen=True)
class Features:
    """The contents of ``features.yaml``."""

    path: Path
    tolerance_mm: float
    base: Region | None
    features: tuple[Feature, ...]

    def of_kind(self, kind: str) -> list[Feature]:
        return [f for f in self.features if f.kind == kind]

    def regions(self) -> dict[str, Region]:
        """Every named region (``base`` included)."""
        out = {f.name: f.region for f in self.features if f.region is not None}
        if self.base is not None:
            out["base"] = self.base
        return out


_NOMINAL = {"steps": ("step", "nominal_mm"), "planes": ("plane", "nominal_flatness_mm"),
            "distances": ("distance", "nominal_mm"), "spheres": ("sphere", "nominal_radius_mm")}


def _schema() -> dict[str, Any]:
    return json.loads(resources.files("huefringe").joinpath("schemas/features.schema.json").read_text())


def load_features(path: str | Path, width: int, height: int) -> tuple[Features | None, list[Problem]]:
    """Read and check ``features.yaml`` against its schema and a ``width`` x ``height`` camera.

    Returns
    -------
    features : Features or None
        None when there are problems.
    problems : list of Problem
        Every problem, each naming the file: schema, boxes outside the image or empty, masks
        missing or of another size, names used twice, a distance naming an unknown plane, a
        region with no pixel.
    """
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        return None, [Problem(path, f"cannot read the features ({exc})")]
    problems = []
    for err in sorted(jsonschema.Draft202012Validator(_schema()).iter_errors(doc), key=lambda e: list(map(str, e.absolute_path))):
        where = "/".join(str(p) for p in err.absolute_path) or "(top level)"
        problems.append(Problem(path, f"at {where}: {err.message}"))
    if problems:
        return None, problems

    def region(entry: dict[str, Any], name: str, where: str) -> Region:
        boxes = [entry["box"]] if "box" in entry else []
        boxes += entry.get("boxes", [])
        for x0, y0, x1, y1 in boxes:
            if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
                problems.append(Problem(path, f"{where}: box [{x0}, {y0}, {x1}, {y1}] is not inside the {width} x {height} "
                                              "camera image with x0 < x1 and y0 < y1"))
        mask = None
        if "mask" in entry:
            mask = path.parent / entry["mask"]
            im = cv2.imread(str(mask), cv2.IMREAD_GRAYSCALE) if mask.is_file() else None
            if im is None:
                problems.append(Problem(mask, f"{where}: missing or unreadable mask image"))
            elif im.shape != (height, width):
                problems.append(Problem(mask, f"{where}: mask is {im.shape[1]} x {im.shape[0]}, the camera {width} x {height}"))
        r = Region(name, tuple(tuple(int(v) for v in b) for b in boxes), mask)
        if not problems and not r.mask((height, width)).any():
            problems.append(Problem(path, f"{where}: the region holds no pixel"))
        return r

    tol = float(doc.get("tolerance_mm", 0.05))
    base = region(doc["base"], "base", "base") if "base" in doc else None
    feats: list[Feature] = []
    names = {"base"} if base is not None else set()
    for key, (kind, nominal) in _NOMINAL.items():
        for i, e in enumerate(doc.get(key, [])):
            where = f"{key}[{i}] ({e['name']})"
            if e["name"] in names:
                problems.append(Problem(path, f"{where}: the name is used twice"))
            names.add(e["name"])
            feats.append(Feature(kind, e["name"], float(e.get(nominal, 0.0)), float(e.get("tolerance_mm", tol)),
                                 None if kind == "distance" else region(e, e["name"], where),
                                 tuple(e["planes"]) if kind == "distance" else None))
    planes = {f.name for f in feats if f.kind == "plane"} | ({"base"} if base is not None else set())
    for f in feats:
        if f.kind == "distance":
            for p in f.planes or ():
                if p not in planes:
                    problems.append(Problem(path, f"distances ({f.name}): {p!r} is not base or a name under planes"))
        if f.kind == "step" and base is None:
            problems.append(Problem(path, f"steps ({f.name}): a step height needs a base region"))
    if problems:
        return None, problems
    return Features(path, tol, base, tuple(feats)), []
