"""Checking a session's ``session.yaml`` against the capture-session/1 schema and its semantic rules."""

from __future__ import annotations

import datetime as dt
import json
import re
from importlib import resources
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
from ._model import Problem


# --------------------------------------------------------------------------- schema


def _schema() -> dict[str, Any]:
    text = resources.files("huefringe").joinpath("schemas/capture-session.schema.json").read_text()
    return json.loads(text)


def _schema_problems(meta: Any, yaml_path: Path) -> list[Problem]:
    validator = jsonschema.Draft202012Validator(_schema())
    problems = []
    for err in sorted(validator.iter_errors(meta), key=lambda e: list(map(str, e.absolute_path))):
        where = "/".join(str(p) for p in err.absolute_path) or "(top level)"
        msg = err.message
        if err.validator == "additionalProperties":
            msg = f"unknown key(s): {msg.split('(')[-1].rstrip(')')}" if "(" in msg else msg
        problems.append(Problem(yaml_path, f"at {where}: {msg}"))
    return problems


def _normalise_dates(meta: Any) -> Any:
    """YAML reads an unquoted ``captured_at: 2026-11-30T14:05:00Z`` as a datetime: make it ISO text.

    Returns a copy of ``meta`` with ``provenance.captured_at`` as a string (UTC written ``Z``);
    anything else is left for the schema to judge.
    """
    if not isinstance(meta, dict) or not isinstance(meta.get("provenance"), dict):
        return meta
    when = meta["provenance"].get("captured_at")
    if isinstance(when, (dt.datetime, dt.date)):
        text = when.isoformat()
        if isinstance(when, dt.datetime) and when.utcoffset() == dt.timedelta(0):
            text = when.replace(tzinfo=None).isoformat() + "Z"
        meta = {**meta, "provenance": {**meta["provenance"], "captured_at": text}}
    return meta


def parse_captured_at(text: str) -> dt.datetime | dt.date:
    """Parse ``provenance.captured_at``: an ISO 8601 date (``2026-11-30``) or date-time
    (``2026-11-30T14:05:00Z``, ``2026-11-30T15:05:00+01:00``, seconds optional).

    Raises
    ------
    ValueError
        When the text is neither.
    """
    if re.fullmatch(r"\d{4}-\d{2}-\d{2}", text):
        return dt.date.fromisoformat(text)
    if not re.fullmatch(r"\d{4}-\d{2}-\d{2}T\d{2}:\d{2}(:\d{2}(\.\d+)?)?(Z|[+-]\d{2}:\d{2})?", text):
        raise ValueError(text)
    return dt.datetime.fromisoformat(text)


def _semantic_problems(meta: dict[str, Any], yaml_path: Path) -> list[Problem]:
    problems = []
    when = (meta.get("provenance") or {}).get("captured_at")
    if when is not None:
        try:
            parse_captured_at(when)
        except ValueError:
            problems.append(Problem(yaml_path, f"at provenance/captured_at: {when!r} is not an ISO 8601 date or "
                                               "date-time (e.g. 2026-11-30 or 2026-11-30T14:05:00Z)"))
    w, h = meta["camera"]["width"], meta["camera"]["height"]
    problems += _camera_problems(meta["camera"], yaml_path)
    planes = [float(z) for z in meta["planes_mm"]]
    keys = [f"{z:.3f}" for z in planes]
    if len(set(keys)) != len(keys):
        problems.append(Problem(yaml_path, f"planes_mm has repeated planes (to 3 decimals): {planes}"))
    if "0.000" not in keys:
        problems.append(Problem(yaml_path, "planes_mm must contain the reference plane 0.0"))
    nonzero = [abs(z) for z in planes if f"{z:.3f}" != "0.000"]
    if not nonzero:
        problems.append(Problem(yaml_path, "planes_mm needs at least one plane besides 0.0"))
    spec = meta.get("specimen")
    if spec:
        boxes = [("base_roi", b) for b in spec["base_roi"]] + [
            (f"steps/{s['name']}/roi", s["roi"]) for s in spec["steps"]
        ]
        for where, (u0, v0, u1, v1) in boxes:
            if not (0 <= u0 < u1 <= w and 0 <= v0 < v1 <= h):
                problems.append(
                    Problem(
                        yaml_path,
                        f"specimen {where} [{u0}, {v0}, {u1}, {v1}) is empty or outside the "
                        f"{w} x {h} image",
                    )
                )
        names = [s["name"] for s in spec["steps"]]
        if len(set(names)) != len(names):
            problems.append(Problem(yaml_path, f"specimen step names repeat: {names}"))
    return problems


def _camera_problems(cam: dict[str, Any], yaml_path: Path) -> list[Problem]:
    """The lens block of the ``camera`` extension (docs/design.md, "the camera block"): what the
    schema cannot say (finite values, the matrix's last row, the distortion's length, what a
    pinhole camera needs)."""
    problems = []
    kind = cam.get("model", "telecentric")

    def bad(key: str, text: str) -> None:
        problems.append(Problem(yaml_path, f"at camera/{key}: {text}"))

    for key in ("pixel_pitch_mm", "matrix", "distortion", "plate_pose"):
        val = cam.get(key)
        if val is None:
            continue
        vals = [val] if key == "pixel_pitch_mm" else (
            [*val["rvec"], *val["tvec"]] if key == "plate_pose" else np.ravel(np.asarray(val, np.float64)).tolist())
        if not all(np.isfinite(float(x)) for x in vals):
            bad(key, "holds a value that is not finite (nan or inf)")
    k = cam.get("matrix")
    if k is not None:
        m = np.asarray(k, np.float64)
        if m.shape != (3, 3):
            bad("matrix", f"must be 3 x 3 (OpenCV camera matrix), got shape {m.shape}")
        elif np.all(np.isfinite(m)):
            if not np.array_equal(m[2], [0.0, 0.0, 1.0]):
                bad("matrix", f"last row must be [0, 0, 1], got {m[2].tolist()}")
            if not (m[0, 0] > 0 and m[1, 1] > 0):
                bad("matrix", f"focal lengths fx = {m[0, 0]:g}, fy = {m[1, 1]:g} px must be positive")
            if m[1, 0] != 0:
                bad("matrix", "must be upper triangular [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    d = cam.get("distortion")
    if d is not None and len(d) not in (4, 5, 8, 12, 14):
        bad("distortion", f"OpenCV distortion coefficients come as 4, 5, 8, 12 or 14 values "
                          f"(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]]), got {len(d)}")
    if kind == "pinhole":
        for key, what in (("matrix", "the camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (cv2.calibrateCamera)"),
                          ("plate_pose", "the plate's pose {rvec: [..], tvec: [..]} in camera coordinates, mm "
                                         "(cv2.solvePnP of a board lying on the plate)")):
            if cam.get(key) is None:
                bad(key, f"missing: a pinhole camera (camera/model: pinhole) needs {what}")
        pose = cam.get("plate_pose")
        if pose is not None and not problems and float(np.linalg.norm(pose["tvec"])) == 0.0:
            bad("plate_pose", "tvec is zero: the plate cannot pass through the camera centre")
    elif cam.get("plate_pose") is not None:
        bad("plate_pose", "only a pinhole camera (camera/model: pinhole) has a plate pose")
    if cam.get("bayer") is not None and (int(cam["width"]) % 2 or int(cam["height"]) % 2):
        bad("bayer", f"a Bayer sensor has whole 2 x 2 blocks: width and height must be even, got "
                     f"{cam['width']} x {cam['height']}")
    return problems
