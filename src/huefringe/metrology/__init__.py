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

Triangulated points
-------------------
``_forms`` fits planes and spheres to X, Y, Z points in the camera frame with per-point
uncertainties and gives each figure a GUM standard uncertainty: :func:`fit_plane_u`,
:func:`step_height_u`, :func:`flatness_u` (noise-corrected RMS and peak-to-valley),
:func:`plane_pair_u` (distance, angle, parallelism), :func:`fit_sphere_u`, and the calibration's
term :func:`jackknife_u` with :func:`combine_u`.
"""

from __future__ import annotations

from ._fit import (  # noqa: F401
    XY,
    DEFAULT_EDGE_EXCLUSION,
    DEFAULT_MIN_COVERAGE,
    MIN_PIXELS,
    Box,
    MetrologyError,
    check_box,
    central_box,
    coverage,
    _height_map,
    _box_samples,
    _check_pitch,
    _lstsq_plane,
    fit_plane,
    plane_height,
    step_height,
    flatness,
)
from ._forms import (  # noqa: F401
    PV_NOISE_DRAWS,
    PlaneFit,
    combine_u,
    fit_plane_u,
    form_deviation,
    fit_sphere_u,
    flatness_u,
    jackknife_u,
    plane_pair_u,
    sigma_along,
    step_height_u,
)
from ._evaluate import (  # noqa: F401
    _specimen_parts,
    evaluate_session,
    _FLAT_KEYS,
    _height_maps,
    _frame_steps,
    _step_summary,
)

__all__ = [
    "DEFAULT_EDGE_EXCLUSION",
    "DEFAULT_MIN_COVERAGE",
    "PV_NOISE_DRAWS",
    "MetrologyError",
    "PlaneFit",
    "central_box",
    "check_box",
    "combine_u",
    "coverage",
    "evaluate_session",
    "fit_plane",
    "fit_plane_u",
    "form_deviation",
    "fit_sphere_u",
    "flatness",
    "flatness_u",
    "jackknife_u",
    "plane_height",
    "plane_pair_u",
    "step_height",
    "step_height_u",
    "sigma_along",
]
