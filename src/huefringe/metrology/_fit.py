"""The metrology primitives on a height map: measurement boxes, coverage, the least-squares plane, step height and flatness."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray


XY = tuple[NDArray[np.float64], NDArray[np.float64]]
"""X and Y maps in mm of a height map (:meth:`huefringe.camera.CameraModel.xy`)."""

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
