"""Areal step-height metrology in the practice of ISO 5436-1 (type A, step heights).

The specimen (the ``specimen`` block of ``session.yaml``, capture-session format 1) gives pixel
boxes ``[u0, v0, u1, v1)`` (``u1``/``v1`` exclusive) on the height map: one or more *base* boxes
on the surface the steps stand on, and one *top* box per step. Heights are ``float32`` mm above
the reference plane, NaN (or any non-finite value) where invalid; the lateral coordinates are
``X = u * pitch_mm`` and ``Y = v * pitch_mm`` (telecentric camera).

Evaluation, per frame
---------------------
1. **Base plane.** A least-squares plane ``z = c0 + c1 X + c2 Y`` is fitted to the valid pixels
   of all base boxes together (:func:`fit_plane`). The base boxes are used as given: the user
   places them away from the steps' edges.
2. **Edge exclusion of the top** (:func:`central_box`). ISO 5436-1 type A evaluates only the
   central third of a feature of width ``W`` and ignores ``W/3`` next to each edge, where the
   instrument's edge response (here: fringe smearing, shadows, phase unwrapping at the jump)
   corrupts the data. In areal form the top box is shrunk along *both* axes: with
   ``edge_exclusion = e`` (default 1/3), a box side of ``W`` pixels loses
   ``m = ceil(e * W)`` pixels at each end, capped at ``(W - 1) // 2`` so that at least one
   pixel remains; the evaluated box is ``[u0 + mu, v0 + mv, u1 - mu, v1 - mv)``. Rounding up
   makes the excluded band never narrower than requested; the evaluated box stays centred.
   ``e = 0`` uses the whole box.
3. **Step height** (:func:`step_height`): the mean signed distance of the valid pixels of the
   evaluated top box to the base plane. The distance is *vertical* (``z - plane(X, Y)``) by
   default; for a plane of slope ``s`` the normal distance is smaller by the factor
   ``1 / sqrt(1 + c1**2 + c2**2)``, i.e. by ``s**2 / 2`` relatively: 5e-7 for a 1 mrad tilt,
   negligible for near-level specimens (``normal=True`` gives the normal distance).
4. **Flatness of the top** (:func:`flatness`): a least-squares plane is fitted to the evaluated
   top box and removed (levelling, F-operator = plane; no S- or L-filter); of the residuals
   ``r``: ``Sa = mean |r|``, ``Sq = sqrt(mean r**2)``, ``Sp = max r``, ``Sv = -min r`` and
   ``Sz = Sp + Sv`` (ISO 25178-2 definitions over the evaluation area).
5. **Coverage**: the fraction of valid pixels in a box. A box whose coverage is below
   ``min_coverage`` (default 0.5), or with fewer than 3 valid pixels, is refused with a
   :class:`MetrologyError` naming the box and the frame.

Across frames (:func:`evaluate_session`)
----------------------------------------
``mean_mm`` of the per-frame step heights, ``std_mm`` (sample standard deviation, ``ddof=1``;
``None`` for a single frame, where it is undefined), ``repeatability_3sigma_mm = 3 * std_mm``
(the ``+-3 sigma`` band), ``error_mm = mean_mm - nominal_mm``,
``error_pct = 100 * (mean_mm - nominal_mm) / nominal_mm`` (results contract),
``error_pct_of_range = 100 * error_mm / range_mm`` with ``range_mm`` the calibrated depth
range (e.g. ``max(planes_mm)``), and ``pass = |error_mm| <= tolerance_mm``. The session's
``verdict`` is ``"PASS"`` when every step passes.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from huefringe.camera import CameraModel

XY = tuple[NDArray[np.float64], NDArray[np.float64]]
"""X and Y maps in mm of a height map (:meth:`huefringe.camera.CameraModel.xy`)."""

__all__ = [
    "DEFAULT_EDGE_EXCLUSION",
    "DEFAULT_MIN_COVERAGE",
    "MetrologyError",
    "central_box",
    "check_box",
    "coverage",
    "evaluate_session",
    "fit_plane",
    "flatness",
    "plane_height",
    "step_height",
]

DEFAULT_EDGE_EXCLUSION: float = 1.0 / 3.0
"""Fraction of a top box's side excluded at each edge (ISO 5436-1 type A: keep the central third)."""

DEFAULT_MIN_COVERAGE: float = 0.5
"""Smallest accepted fraction of valid pixels in an evaluated box."""

MIN_PIXELS: int = 3
"""Smallest accepted number of valid pixels in an evaluated box (a plane has 3 parameters)."""

Box = tuple[int, int, int, int]


class MetrologyError(ValueError):
    """A height map or a region of interest cannot be evaluated.

    Parameters
    ----------
    message : str
        What is wrong, in words a user can act on.
    roi : str or None
        Name of the region of interest concerned (``"base_roi[0]"``, a step name), if any.
    frame : int or None
        Index of the frame concerned, if any.
    """

    def __init__(self, message: str, *, roi: str | None = None, frame: int | None = None) -> None:
        prefix = ""
        if frame is not None:
            prefix += f"frame {frame}: "
        if roi is not None:
            prefix += f"ROI {roi!r}: "
        super().__init__(prefix + message)
        self.roi = roi
        self.frame = frame


# --------------------------------------------------------------------------------------------
# boxes and coverage
# --------------------------------------------------------------------------------------------


def check_box(roi: Sequence[Any], shape: tuple[int, ...], name: str = "roi") -> Box:
    """Validate a pixel box ``[u0, v0, u1, v1)`` against an image shape.

    Parameters
    ----------
    roi : sequence of 4 int
        ``[u0, v0, u1, v1]``; ``u`` is the column, ``v`` the row; ``u1`` and ``v1`` exclusive.
    shape : tuple of int
        ``(H, W)`` of the height map.
    name : str
        Name used in error messages.

    Returns
    -------
    tuple of int
        The box as four Python ints.

    Raises
    ------
    MetrologyError
        If the box is not four integers, is empty, or does not lie inside the image.
    """
    try:
        values = list(roi)
    except TypeError:
        raise MetrologyError(f"box must be [u0, v0, u1, v1], got {roi!r}", roi=name) from None
    if len(values) != 4:
        raise MetrologyError(f"box must have 4 values [u0, v0, u1, v1], got {values!r}", roi=name)
    ints: list[int] = []
    for x in values:
        if isinstance(x, bool) or not isinstance(x, int | np.integer | float | np.floating):
            raise MetrologyError(f"box values must be integers, got {values!r}", roi=name)
        if not float(x).is_integer():
            raise MetrologyError(f"box values must be integers, got {values!r}", roi=name)
        ints.append(int(x))
    u0, v0, u1, v1 = ints
    h, w = int(shape[0]), int(shape[1])
    if not (u0 < u1 and v0 < v1):
        raise MetrologyError(f"empty box {ints} (need u0 < u1 and v0 < v1)", roi=name)
    if u0 < 0 or v0 < 0 or u1 > w or v1 > h:
        raise MetrologyError(f"box {ints} is not inside the {w} x {h} (W x H) height map", roi=name)
    return u0, v0, u1, v1


def central_box(roi: Sequence[int], edge_exclusion: float = DEFAULT_EDGE_EXCLUSION) -> Box:
    """Shrink a box to its central part (areal ISO 5436-1 edge exclusion).

    Parameters
    ----------
    roi : sequence of 4 int
        ``[u0, v0, u1, v1)``.
    edge_exclusion : float
        Fraction ``e`` in ``[0, 0.5)`` of each side removed at *each* end; the default 1/3 keeps
        the central third of the width and of the height of the box.

    Returns
    -------
    tuple of int
        ``(u0 + mu, v0 + mv, u1 - mu, v1 - mv)`` with ``m = min(ceil(e * W), (W - 1) // 2)``
        for a side of ``W`` pixels (a tolerance of 1e-9 pixel absorbs round-off in ``e * W``).

    Examples
    --------
    >>> central_box([100, 150, 220, 330])
    (140, 210, 180, 270)
    """
    e = float(edge_exclusion)
    if not (0.0 <= e < 0.5):
        raise ValueError(f"edge_exclusion must be in [0, 0.5), got {edge_exclusion!r}")
    u0, v0, u1, v1 = (int(x) for x in roi)

    def margin(width: int) -> int:
        return max(0, min(math.ceil(e * width - 1e-9), (width - 1) // 2))

    mu, mv = margin(u1 - u0), margin(v1 - v0)
    return u0 + mu, v0 + mv, u1 - mu, v1 - mv


def coverage(height: ArrayLike, roi: Sequence[int]) -> float:
    """Fraction of valid (finite) pixels of ``height`` inside the box ``roi``.

    Parameters
    ----------
    height : array_like, shape (H, W)
        Height map.
    roi : sequence of 4 int
        ``[u0, v0, u1, v1)``.

    Returns
    -------
    float
        In [0, 1].
    """
    z = np.asarray(height)
    u0, v0, u1, v1 = check_box(roi, z.shape)
    return float(np.isfinite(z[v0:v1, u0:u1]).mean())


def _height_map(height: ArrayLike, frame: int | None = None) -> NDArray[np.floating[Any]]:
    z = np.asarray(height)
    if z.ndim != 2:
        raise MetrologyError(f"a height map must be a 2-D array (H, W), got shape {z.shape}", frame=frame)
    if not np.issubdtype(z.dtype, np.floating):
        raise MetrologyError(f"a height map must be floating point (mm, NaN = invalid), got {z.dtype}", frame=frame)
    if not np.isfinite(z).any():
        raise MetrologyError(
            "the height map has no valid pixel (all NaN): nothing can be measured; "
            "check the phase and height stages for this frame",
            frame=frame,
        )
    return z


def _box_samples(
    z: NDArray[np.floating[Any]],
    box: Box,
    pitch_mm: float,
    *,
    name: str,
    min_coverage: float,
    frame: int | None,
    xy: XY | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """X, Y (mm) and z (float64) of the valid pixels of a box, after the coverage check; X, Y
    from the maps ``xy`` (:meth:`huefringe.camera.CameraModel.xy`) when given, else ``u * pitch``."""
    u0, v0, u1, v1 = box
    sub = z[v0:v1, u0:u1]
    valid = np.isfinite(sub)
    n = int(valid.sum())
    frac = n / valid.size
    if n == 0:
        raise MetrologyError(f"no valid pixel in box {list(box)} (all NaN)", roi=name, frame=frame)
    if n < MIN_PIXELS or frac < min_coverage:
        raise MetrologyError(
            f"too few valid pixels in box {list(box)}: {n} of {valid.size} ({100 * frac:.1f} %), "
            f"need at least {MIN_PIXELS} and {100 * min_coverage:.1f} %",
            roi=name,
            frame=frame,
        )
    if xy is not None:
        return xy[0][v0:v1, u0:u1][valid], xy[1][v0:v1, u0:u1][valid], sub[valid].astype(np.float64)
    vv, uu = np.nonzero(valid)
    x = (uu + u0).astype(np.float64) * pitch_mm
    y = (vv + v0).astype(np.float64) * pitch_mm
    return x, y, sub[valid].astype(np.float64)


def _check_pitch(pitch_mm: float) -> float:
    p = float(pitch_mm)
    if not (math.isfinite(p) and p > 0):
        raise ValueError(f"pitch_mm must be a positive number, got {pitch_mm!r}")
    return p


def _lstsq_plane(
    x: NDArray[np.float64], y: NDArray[np.float64], z: NDArray[np.float64], *, name: str, frame: int | None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares plane through (x, y, z), centred for conditioning; returns coeffs, residuals."""
    xm, ym = float(x.mean()), float(y.mean())
    a = np.column_stack([np.ones_like(x), x - xm, y - ym])
    sol, _, rank, _ = np.linalg.lstsq(a, z, rcond=None)
    if rank < 3:
        raise MetrologyError(
            "the valid pixels are collinear: a plane cannot be fitted (use boxes spanning both axes)",
            roi=name,
            frame=frame,
        )
    resid = z - a @ sol
    coeffs = np.array([sol[0] - sol[1] * xm - sol[2] * ym, sol[1], sol[2]], dtype=np.float64)
    return coeffs, resid


# --------------------------------------------------------------------------------------------
# per-frame measurements
# --------------------------------------------------------------------------------------------


def fit_plane(
    height: ArrayLike,
    boxes: Sequence[Sequence[int]],
    pitch_mm: float,
    *,
    min_coverage: float = DEFAULT_MIN_COVERAGE,
    names: Sequence[str] | None = None,
    frame: int | None = None,
    xy: XY | None = None,
) -> tuple[NDArray[np.float64], float]:
    """Least-squares base plane over the valid pixels of one or more boxes.

    ``xy``: the map's X, Y in mm (:meth:`huefringe.camera.CameraModel.xy` of ``height``; a
    pinhole camera sees each pixel at its own height); default ``u * pitch_mm``, ``v * pitch_mm``.

    Parameters
    ----------
    height : array_like, shape (H, W)
        Height map in mm, NaN where invalid.
    boxes : sequence of [u0, v0, u1, v1)
        Base boxes; their valid pixels are fitted together.
    pitch_mm : float
        Pixel pitch: ``X = u * pitch_mm``, ``Y = v * pitch_mm``.
    min_coverage : float
        Smallest accepted fraction of valid pixels in *each* box.
    names : sequence of str, optional
        Box names for error messages (default ``base_roi[i]``).
    frame : int, optional
        Frame index for error messages.

    Returns
    -------
    coeffs : ndarray, shape (3,)
        ``(c0, c1, c2)`` of ``z = c0 + c1 X + c2 Y`` (mm, mm/mm, mm/mm).
    residual_rms : float
        Root mean square of the fit residuals (mm, divided by the number of pixels).

    Raises
    ------
    MetrologyError
        NaN-only height map, a box outside the image, a box with too few valid pixels, or
        collinear valid pixels.
    """
    z = _height_map(height, frame)
    pitch = _check_pitch(pitch_mm)
    if len(boxes) == 0:
        raise MetrologyError("at least one base box is needed to fit the base plane", roi="base_roi", frame=frame)
    labels = list(names) if names is not None else [f"base_roi[{i}]" for i in range(len(boxes))]
    xs, ys, zs = [], [], []
    for box, label in zip(boxes, labels, strict=True):
        b = check_box(box, z.shape, label)
        x, y, v = _box_samples(z, b, pitch, name=label, min_coverage=min_coverage, frame=frame, xy=xy)
        xs.append(x)
        ys.append(y)
        zs.append(v)
    coeffs, resid = _lstsq_plane(np.concatenate(xs), np.concatenate(ys), np.concatenate(zs), name="base_roi", frame=frame)
    return coeffs, float(np.sqrt(np.mean(resid**2)))


def plane_height(plane: ArrayLike, x_mm: ArrayLike, y_mm: ArrayLike) -> NDArray[np.float64]:
    """Evaluate ``z = c0 + c1 X + c2 Y`` at ``(X, Y)`` in mm."""
    c = np.asarray(plane, dtype=np.float64).reshape(3)
    return c[0] + c[1] * np.asarray(x_mm, dtype=np.float64) + c[2] * np.asarray(y_mm, dtype=np.float64)


def step_height(
    height: ArrayLike,
    plane: ArrayLike,
    roi: Sequence[int],
    pitch_mm: float,
    edge_exclusion: float = DEFAULT_EDGE_EXCLUSION,
    *,
    name: str = "step",
    min_coverage: float = DEFAULT_MIN_COVERAGE,
    normal: bool = False,
    frame: int | None = None,
    xy: XY | None = None,
) -> float:
    """Height of a step's top above the base plane, with ISO 5436-1 edge exclusion.

    Parameters
    ----------
    height : array_like, shape (H, W)
        Height map in mm, NaN where invalid.
    plane : array_like, shape (3,)
        Base plane ``(c0, c1, c2)`` from :func:`fit_plane` (same ``pitch_mm``).
    roi : sequence of 4 int
        Top box ``[u0, v0, u1, v1)``; only :func:`central_box` ``(roi, edge_exclusion)`` is used.
    pitch_mm : float
        Pixel pitch in mm.
    edge_exclusion : float
        Fraction of each side excluded at each edge (default 1/3: the central third).
    name : str
        ROI name for error messages.
    min_coverage : float
        Smallest accepted fraction of valid pixels in the evaluated (central) box.
    normal : bool
        If True, return the distance normal to the base plane instead of the vertical one.
    frame : int, optional
        Frame index for error messages.

    Returns
    -------
    float
        Mean signed distance (mm) of the evaluated top's valid pixels to the base plane;
        positive above it.

    Raises
    ------
    MetrologyError
        NaN-only map, box outside the image, or too few valid pixels in the evaluated box.
    """
    z = _height_map(height, frame)
    pitch = _check_pitch(pitch_mm)
    box = central_box(check_box(roi, z.shape, name), edge_exclusion)
    x, y, v = _box_samples(z, box, pitch, name=name, min_coverage=min_coverage, frame=frame, xy=xy)
    d = float(np.mean(v - plane_height(plane, x, y)))
    if normal:
        c = np.asarray(plane, dtype=np.float64).reshape(3)
        d /= math.sqrt(1.0 + c[1] ** 2 + c[2] ** 2)
    return d


def flatness(
    height: ArrayLike,
    roi: Sequence[int],
    pitch_mm: float,
    edge_exclusion: float = DEFAULT_EDGE_EXCLUSION,
    *,
    name: str = "step",
    min_coverage: float = DEFAULT_MIN_COVERAGE,
    frame: int | None = None,
    xy: XY | None = None,
) -> dict[str, float]:
    """Areal texture of a levelled top: Sa, Sq, Sp, Sv, Sz (ISO 25178-2), in mm.

    Parameters
    ----------
    height : array_like, shape (H, W)
        Height map in mm, NaN where invalid.
    roi : sequence of 4 int
        Top box; the evaluation area is :func:`central_box` ``(roi, edge_exclusion)``.
    pitch_mm : float
        Pixel pitch in mm.
    edge_exclusion : float
        As in :func:`step_height`.
    name, min_coverage, frame
        As in :func:`step_height`.

    Returns
    -------
    dict
        ``Sa_mm`` (mean absolute residual), ``Sq_mm`` (rms residual), ``Sp_mm`` (highest peak),
        ``Sv_mm`` (deepest pit, positive), ``Sz_mm = Sp_mm + Sv_mm``, and ``pixels`` (number of
        valid pixels used). Residuals are taken from the least-squares plane of the evaluated
        area (levelling); no other filter is applied.
    """
    z = _height_map(height, frame)
    pitch = _check_pitch(pitch_mm)
    box = central_box(check_box(roi, z.shape, name), edge_exclusion)
    x, y, v = _box_samples(z, box, pitch, name=name, min_coverage=min_coverage, frame=frame, xy=xy)
    _, r = _lstsq_plane(x, y, v, name=name, frame=frame)
    sp, sv = float(r.max()), float(-r.min())
    return {
        "Sa_mm": float(np.mean(np.abs(r))),
        "Sq_mm": float(np.sqrt(np.mean(r**2))),
        "Sp_mm": sp,
        "Sv_mm": sv,
        "Sz_mm": sp + sv,
        "pixels": int(r.size),
    }


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
