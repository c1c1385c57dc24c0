"""A session's metrology: each frame's steps and flatness against the specimen's nominal, summarised over the frames."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from huefringe.camera import CameraModel
from ._fit import Box, DEFAULT_EDGE_EXCLUSION, DEFAULT_MIN_COVERAGE, MetrologyError, _check_pitch, _height_map, central_box, check_box, coverage, fit_plane, flatness, step_height


# --------------------------------------------------------------------------------------------
# session
# --------------------------------------------------------------------------------------------


def _specimen_parts(specimen: Mapping[str, Any]) -> tuple[list[Any], list[Mapping[str, Any]], float]:
    if not isinstance(specimen, Mapping):
        raise MetrologyError(f"specimen must be a mapping, got {type(specimen).__name__}")
    kind = specimen.get("kind", "step_heights")
    if kind != "step_heights":
        raise MetrologyError(f"specimen kind {kind!r} is not supported (only 'step_heights')")
    for key in ("base_roi", "steps", "tolerance_mm"):
        if key not in specimen:
            raise MetrologyError(f"specimen has no {key!r}")
    base = list(specimen["base_roi"])
    steps = list(specimen["steps"])
    if not base:
        raise MetrologyError("specimen.base_roi is empty: at least one base box is needed")
    if not steps:
        raise MetrologyError("specimen.steps is empty: nothing to measure")
    tol = specimen["tolerance_mm"]
    if isinstance(tol, bool) or not isinstance(tol, int | float) or not math.isfinite(tol) or tol < 0:
        raise MetrologyError(f"specimen.tolerance_mm must be a number >= 0, got {tol!r}")
    names: set[str] = set()
    for i, s in enumerate(steps):
        if not isinstance(s, Mapping) or not {"name", "nominal_mm", "roi"} <= set(s):
            raise MetrologyError(f"specimen.steps[{i}] must have name, nominal_mm and roi, got {s!r}")
        nom = s["nominal_mm"]
        if isinstance(nom, bool) or not isinstance(nom, int | float) or not math.isfinite(nom) or nom == 0:
            raise MetrologyError(f"nominal_mm must be a finite non-zero number, got {nom!r}", roi=str(s["name"]))
        if s["name"] in names:
            raise MetrologyError("duplicate step name", roi=str(s["name"]))
        names.add(s["name"])
    return base, steps, float(tol)


def evaluate_session(
    heights: Iterable[ArrayLike],
    specimen: Mapping[str, Any],
    pitch_mm: float,
    *,
    range_mm: float,
    method: str = "trapezoidal-hsi",
    edge_exclusion: float = DEFAULT_EDGE_EXCLUSION,
    min_coverage: float = DEFAULT_MIN_COVERAGE,
    normal: bool = False,
    camera: CameraModel | None = None,
) -> dict[str, Any]:
    """Evaluate every step of a specimen on every frame, then across frames.

    ``camera``: X, Y of every frame from :meth:`huefringe.camera.CameraModel.xy` (each pixel at
    its own height); default (or a plain telecentric model) ``u * pitch_mm``.

    Parameters
    ----------
    heights : iterable of array_like, each (H, W)
        Per-frame height maps in mm (NaN = invalid), all of the same shape. Taken one at a
        time: a generator that reads each map from disk keeps one map in memory.
    specimen : mapping
        The ``specimen`` block of ``session.yaml``: ``base_roi``, ``steps`` (``name``,
        ``nominal_mm``, ``roi``) and ``tolerance_mm``.
    pitch_mm : float
        Pixel pitch in mm.
    range_mm : float
        Measuring (calibrated depth) range in mm for ``error_pct_of_range``, e.g.
        ``max(planes_mm) - min(planes_mm)``.
    method : str
        Name of the method that produced the heights (``"trapezoidal-hsi"``,
        ``"three-step-phase-shift"``).
    edge_exclusion : float
        Fraction of each top box side excluded at each edge (see :func:`central_box`).
    min_coverage : float
        Smallest accepted fraction of valid pixels per evaluated box and frame.
    normal : bool
        Normal instead of vertical distance to the base plane (see :func:`step_height`).

    Returns
    -------
    dict
        The per-method block (JSON-ready: Python scalars and lists only)::

            {"method", "frames", "tolerance_mm", "range_mm", "edge_exclusion", "min_coverage",
             "distance": "vertical" | "normal", "verdict": "PASS" | "FAIL",
             "base": {"rois", "coverage", "coverage_min", "plane_per_frame",
                      "residual_rms_mm", "residual_rms_mm_max"},
             "steps": [{"name", "nominal_mm", "mean_mm", "std_mm", "repeatability_3sigma_mm",
                        "error_mm", "error_pct", "error_pct_of_range", "pass", "per_frame_mm",
                        "roi", "evaluated_roi", "coverage": {"roi", "evaluated", "evaluated_min"},
                        "flatness": {"Sa_mm", "Sq_mm", "Sp_mm", "Sv_mm", "Sz_mm"}}]}

        ``std_mm`` and ``repeatability_3sigma_mm`` are ``None`` for a single frame. Coverage
        values are means over frames (``*_min``: the worst frame); flatness values are means
        over frames of the per-frame values.

    Raises
    ------
    MetrologyError
        Empty input, maps of different shapes, a NaN-only map, a bad box, or a box with too few
        valid pixels (the message names the frame and the ROI).
    """
    base, steps, tol = _specimen_parts(specimen)
    pitch = _check_pitch(pitch_mm)
    rng = float(range_mm)
    if not (math.isfinite(rng) and rng > 0):
        raise ValueError(f"range_mm must be a positive number, got {range_mm!r}")
    central_box((0, 0, 3, 3), edge_exclusion)  # validates edge_exclusion early
    # one frame at a time (a generator of maps read from disk keeps one map in memory: 1000
    # frames of 640 x 480 would be 1.2 GB held at once)
    maps = _height_maps(heights)
    _, z0 = next(maps)
    shape = z0.shape

    base_boxes = [check_box(b, shape, f"base_roi[{i}]") for i, b in enumerate(base)]
    step_boxes = [check_box(s["roi"], shape, str(s["name"])) for s in steps]
    eval_boxes = [central_box(b, edge_exclusion) for b in step_boxes]

    planes_l: list[NDArray[np.float64]] = []
    rms_l: list[float] = []
    base_cov_l: list[list[float]] = []
    per_frame_l: list[list[float]] = []
    cov_roi_l: list[list[float]] = []
    cov_eval_l: list[list[float]] = []
    flat_l: list[list[list[float]]] = []
    lens = camera is not None and not camera.plain
    for f, z in itertools.chain([(0, z0)], maps):
        xy = camera.xy(z) if lens else None  # type: ignore[union-attr]
        plane_f, res = fit_plane(z, base_boxes, pitch, min_coverage=min_coverage, frame=f, xy=xy)
        plane = np.empty(3)
        plane[:] = plane_f
        planes_l.append(plane)
        rms_l.append(res)
        base_cov_l.append([coverage(z, b) for b in base_boxes])
        pf, cr, ce, fls = _frame_steps(z, plane, steps, step_boxes, eval_boxes, pitch, edge_exclusion,
                                       min_coverage=min_coverage, normal=normal, frame=f, xy=xy)
        per_frame_l.append(pf)
        cov_roi_l.append(cr)
        cov_eval_l.append(ce)
        flat_l.append(fls)
        del z

    n = len(rms_l)
    planes = np.array(planes_l, dtype=np.float64).reshape(n, 3)
    rms = np.array(rms_l, dtype=np.float64)
    base_cov = np.array(base_cov_l, dtype=np.float64).reshape(n, len(base_boxes))
    per_frame = np.array(per_frame_l, dtype=np.float64).reshape(n, len(steps)).T
    cov_roi = np.array(cov_roi_l, dtype=np.float64).reshape(n, len(steps)).T
    cov_eval = np.array(cov_eval_l, dtype=np.float64).reshape(n, len(steps)).T
    flat = np.array(flat_l, dtype=np.float64).reshape(n, len(steps), 5).transpose(1, 0, 2)

    step_out = [_step_summary(s, per_frame[k], step_boxes[k], eval_boxes[k], cov_roi[k], cov_eval[k], flat[k],
                              tolerance_mm=tol, range_mm=rng) for k, s in enumerate(steps)]
    return {
        "method": str(method),
        "frames": n,
        "tolerance_mm": tol,
        "range_mm": rng,
        "edge_exclusion": float(edge_exclusion),
        "min_coverage": float(min_coverage),
        "distance": "normal" if normal else "vertical",
        "verdict": "PASS" if all(s["pass"] for s in step_out) else "FAIL",
        "base": {
            "rois": [list(b) for b in base_boxes],
            "coverage": [float(c) for c in base_cov.mean(axis=0)],
            "coverage_min": [float(c) for c in base_cov.min(axis=0)],
            "plane_per_frame": [[float(c) for c in p] for p in planes],
            "residual_rms_mm": float(rms.mean()),
            "residual_rms_mm_max": float(rms.max()),
        },
        "steps": step_out,
    }


#: The flatness parameters of each step's evaluated box (:func:`flatness`), in the report's order.
_FLAT_KEYS = ("Sa_mm", "Sq_mm", "Sp_mm", "Sv_mm", "Sz_mm")


def _height_maps(heights: Iterable[ArrayLike]) -> Iterator[tuple[int, NDArray[np.floating[Any]]]]:
    """``(frame, map)`` of each height map, checked as read: one at a time, each the first's shape."""
    maps = iter(heights)
    first = next(maps, None)
    if first is None:
        raise MetrologyError("no height map given: nothing to evaluate")
    z0 = _height_map(first, 0)
    yield 0, z0
    for i, h in enumerate(maps, start=1):
        z = _height_map(h, i)
        if z.shape != z0.shape:
            raise MetrologyError(f"height map shape {z.shape} differs from frame 0's {z0.shape}", frame=i)
        yield i, z


def _frame_steps(z: NDArray[np.floating[Any]], plane: NDArray[np.float64], steps: Sequence[Mapping[str, Any]],
                 step_boxes: Sequence[Box], eval_boxes: Sequence[Box], pitch: float, edge_exclusion: float, *,
                 min_coverage: float, normal: bool, frame: int, xy: Any
                 ) -> tuple[list[float], list[float], list[float], list[list[float]]]:
    """One frame's step heights, ROI and evaluated-box coverage, and flatness parameters, step by step."""
    pf, cr, ce, fls = [], [], [], []
    for s, box, ebox in zip(steps, step_boxes, eval_boxes, strict=True):
        name = str(s["name"])
        pf.append(step_height(
            z, plane, box, pitch, edge_exclusion,
            name=name, min_coverage=min_coverage, normal=normal, frame=frame, xy=xy,
        ))  # fmt: skip
        cr.append(coverage(z, box))
        ce.append(coverage(z, ebox))
        fl = flatness(z, box, pitch, edge_exclusion, name=name, min_coverage=min_coverage, frame=frame, xy=xy)
        fls.append([fl[key] for key in _FLAT_KEYS])
    return pf, cr, ce, fls


def _step_summary(s: Mapping[str, Any], per_frame: NDArray[np.float64], box: Box, ebox: Box,
                  cov_roi: NDArray[np.float64], cov_eval: NDArray[np.float64], flat: NDArray[np.float64], *,
                  tolerance_mm: float, range_mm: float) -> dict[str, Any]:
    """One step's block of :func:`evaluate_session` from its per-frame figures (``flat``: frames x 5)."""
    n = per_frame.size
    nominal = float(s["nominal_mm"])
    mean = float(np.mean(per_frame))
    std = float(np.std(per_frame, ddof=1)) if n > 1 else None
    error = mean - nominal
    return {
        "name": str(s["name"]),
        "nominal_mm": nominal,
        "mean_mm": mean,
        "std_mm": std,
        "repeatability_3sigma_mm": None if std is None else 3.0 * std,
        "error_mm": error,
        "error_pct": 100.0 * (mean - nominal) / nominal,
        "error_pct_of_range": 100.0 * error / range_mm,
        "pass": bool(abs(error) <= tolerance_mm),
        "per_frame_mm": [float(v) for v in per_frame],
        "roi": list(box),
        "evaluated_roi": list(ebox),
        "coverage": {
            "roi": float(cov_roi.mean()),
            "evaluated": float(cov_eval.mean()),
            "evaluated_min": float(cov_eval.min()),
        },
        "flatness": {key: float(flat[:, j].mean()) for j, key in enumerate(_FLAT_KEYS)},
    }
