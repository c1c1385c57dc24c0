"""Form metrology on triangulated points with GUM standard uncertainties.

Points are ``(..., 3)`` arrays of X, Y, Z in mm in the camera frame (camera at the origin), as
``huefringe.rig.triangulate`` returns them, with per-axis standard uncertainties ``sigma`` of the
same shape. Rows with a non-finite point or sigma are dropped.

Noise model (the rig contract): a ray-plane triangulation errs along the camera ray, so the
error of point ``p`` is ``e d`` with ``d = p / ||p||`` and ``std(e) = ||sigma||``; its standard
uncertainty along a unit direction ``n`` is ``|n . d| ||sigma||``. The points' errors are taken
as independent and normal (zero mean). Neighbouring pixels that share a phase filter are in
truth correlated; then every ``u`` here is too small by roughly the square root of the number of
pixels one filter footprint spans, and the calibration's own term (:func:`jackknife_u`) is a
separate, fully correlated term to add with :func:`combine_u`.

The fitted features are the ISO least-squares (Gaussian) associations, unweighted: the feature
is defined by the points, not by their noise. Their uncertainties are propagated from the
per-point noise through the linearised fit (the sandwich ``(J'J)^-1 J' diag(s^2) J (J'J)^-1``),
which stays correct when the noise differs from point to point. Each fit reports
``chi2``, the mean squared normalised residual ``sum (r / s)^2 / (N - p)``: near 1 when the
residuals are the noise alone, above 1 when the surface has form or ``sigma`` is understated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

F64 = NDArray[np.float64]

PV_NOISE_DRAWS: int = 256
"""Monte Carlo draws of the noise-only residuals behind the expected noise peak-to-valley."""


# --------------------------------------------------------------------------------------------
# shared pieces
# --------------------------------------------------------------------------------------------


def _clean(points: ArrayLike, sigma: ArrayLike, need: int, what: str) -> tuple[F64, F64]:
    """Finite rows of ``points`` and ``sigma`` as (N, 3) float64; ValueError when fewer than ``need``."""
    p = np.asarray(points, dtype=np.float64)
    s = np.asarray(sigma, dtype=np.float64)
    if p.shape != s.shape or p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"{what}: points and sigma must both have shape (..., 3); got {p.shape} and {s.shape}")
    p, s = p.reshape(-1, 3), s.reshape(-1, 3)
    keep = np.isfinite(p).all(axis=1) & np.isfinite(s).all(axis=1)
    p, s = p[keep], s[keep]
    if (s < 0).any():
        raise ValueError(f"{what}: sigma must be >= 0 (standard uncertainties)")
    if len(p) < need:
        raise ValueError(f"{what} needs at least {need} points with finite X, Y, Z and sigma; {len(p)} given")
    if (np.linalg.norm(p, axis=1) == 0).any():
        raise ValueError(f"{what}: a point lies at the camera centre (0, 0, 0); its ray is undefined")
    return p, s


def sigma_along(points: ArrayLike, sigma: ArrayLike, direction: ArrayLike) -> F64:
    """Standard uncertainty of each triangulated point along a unit ``direction``.

    A triangulated point's error lies along its camera ray (camera at the origin), so its standard
    uncertainty along ``direction`` is ``|direction . p / |p|| * ||sigma||``.

    Parameters
    ----------
    points, sigma : array_like, shape (..., 3)
        Points (mm) and their per-axis standard uncertainties.
    direction : array_like, shape (3,) or (..., 3)
        Unit direction(s), e.g. a plane's normal or each point's radial direction on a sphere.

    Returns
    -------
    ndarray, shape (...)
        NaN where a point is not finite.
    """
    p = np.asarray(points, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = p / np.linalg.norm(p, axis=-1, keepdims=True)
        return np.abs(np.sum(d * np.asarray(direction, dtype=np.float64), axis=-1)) * np.linalg.norm(np.asarray(sigma, dtype=np.float64), axis=-1)


def _sandwich(J: F64, var: F64) -> tuple[F64, F64]:
    """Covariance ``(J'J)^-1 J' diag(var) J (J'J)^-1`` of a linear least-squares fit, and the hat diagonal."""
    JtJ_inv = np.linalg.inv(J.T @ J)
    cov = JtJ_inv @ (J.T * var) @ J @ JtJ_inv
    hat = np.einsum("ij,jk,ik->i", J, JtJ_inv, J)
    return cov, hat


def combine_u(*terms: float) -> float:
    """Root-sum-square of independent standard uncertainties.

    Parameters
    ----------
    *terms : float
        Standard uncertainties (>= 0), e.g. the noise term of a fit and :func:`jackknife_u`.

    Returns
    -------
    float
        ``sqrt(sum(u_i ** 2))``.
    """
    u = np.asarray(terms, dtype=np.float64)
    if u.size == 0 or not np.isfinite(u).all() or (u < 0).any():
        raise ValueError(f"combine_u needs one or more finite standard uncertainties >= 0; got {terms!r}")
    return float(np.sqrt(np.sum(u**2)))


def jackknife_u(values: ArrayLike, *, t_scaled: bool = False) -> float:
    """Jackknife standard error of a figure recomputed with each leave-one-out calibration.

    Parameters
    ----------
    values : array_like, shape (n,)
        The figure (a step height, a radius, ...) measured with the ``n`` calibrations that each
        leave one calibration pose out.
    t_scaled : bool
        Return the standard deviation of the t-distribution with ``n - 1`` degrees of freedom that
        this standard error scales (JCGM 101:2008, 6.4.9): ``se * sqrt((n - 1) / (n - 3))``, so that
        ``2 u`` is a 95 % interval although the term rests on a few poses (``n >= 4``).

    Returns
    -------
    float
        ``sqrt((n - 1) / n * sum((x_i - mean(x)) ** 2))`` (times the factor above with
        ``t_scaled``): the standard uncertainty the calibration contributes to the figure
        measured with all poses.

    Raises
    ------
    ValueError
        Fewer than 2 values (4 with ``t_scaled``), or a non-finite value.
    """
    x = np.asarray(values, dtype=np.float64).ravel()
    need = 4 if t_scaled else 2
    if x.size < need:
        raise ValueError(f"jackknife_u needs at least {need} leave-one-out values; {x.size} given")
    if not np.isfinite(x).all():
        raise ValueError("jackknife_u: every leave-one-out value must be finite")
    n = x.size
    se = float(np.sqrt((n - 1) / n * np.sum((x - x.mean()) ** 2)))
    return se * float(np.sqrt((n - 1) / (n - 3))) if t_scaled else se


def _form(r: F64, s: F64, J: F64, hat: F64, draws: int, seed: int, noise_rel_u: float = 0.0) -> dict[str, float]:
    """RMS and PV of residuals ``r`` as measured and corrected for the noise ``s`` (see :func:`flatness_u`)."""
    n = len(r)
    rms, pv = float(np.sqrt(np.mean(r**2))), float(r.max() - r.min())
    keep = np.clip(1.0 - hat, 0.0, None)  # the fraction of each point's noise variance the fit leaves
    ms_noise = float(np.sum(s**2 * keep) / n)
    form_sq = max(0.0, float(np.sum(s**2 * (r**2 - s**2 * keep))))
    v = math.sqrt(4.0 * form_sq + 2.0 * float(np.sum(s**4 * keep**2))) / n  # u of the mean square
    v = math.hypot(v, 2.0 * ms_noise * noise_rel_u)  # and of the noise subtracted from it
    x = float(np.mean(r**2)) - ms_noise
    rms_form = math.sqrt(max(0.0, x))
    hi = math.sqrt(max(0.0, x) + 2.0 * v) - rms_form
    lo = rms_form - math.sqrt(max(0.0, x - 2.0 * v))
    # PV of the noise alone: the fit's residuals of independent normal noise, by Monte Carlo
    rng = np.random.default_rng(seed)
    P = np.linalg.solve(J.T @ J, J.T)  # (p, N): residual = e - J (P e)
    ranges = []
    step = max(1, min(draws, 2_000_000 // n))
    for k in range(0, draws, step):
        e = rng.standard_normal((min(step, draws - k), n)) * s
        e -= (e @ P.T) @ J.T
        ranges.append(e.max(axis=1) - e.min(axis=1))
    rr = np.concatenate(ranges)
    pv_noise, sd_noise = float(rr.mean()), float(rr.std(ddof=1))
    return {
        "rms_mm": rms, "pv_mm": pv, "rms_noise_mm": math.sqrt(ms_noise),
        "rms_form_mm": rms_form, "u_rms_form_mm": max(hi, lo) / 2.0,
        "pv_noise_mm": pv_noise, "pv_form_mm": max(0.0, pv - pv_noise),
        "u_pv_form_mm": math.sqrt(sd_noise**2 + pv_noise**2 / 12.0),
    }  # fmt: skip


# --------------------------------------------------------------------------------------------
# plane
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlaneFit:
    """A least-squares plane ``normal . (p - centroid) = 0`` with the covariance of its position.

    Attributes
    ----------
    centroid : ndarray, shape (3,)
        Mean of the fitted points, mm.
    normal : ndarray, shape (3,)
        Unit normal, pointing towards the camera (``normal . centroid < 0``).
    axes : ndarray, shape (2, 3)
        Unit in-plane axes ``e1``, ``e2`` (``e1 x e2 = normal``): the principal directions of the
        points, largest spread first.
    rms_mm : float
        RMS of the orthogonal residuals.
    n : int
        Number of points fitted.
    cov : ndarray, shape (3, 3)
        Covariance of ``(offset, tilt1, tilt2)``: the plane's shift along ``normal`` at the
        centroid (mm) and its slopes along ``e1`` and ``e2`` (rad), from the per-point noise.
    chi2 : float
        ``sum (r / s_n) ** 2 / (n - 3)`` with ``s_n`` each point's noise along the normal.
    """

    centroid: F64
    normal: F64
    axes: F64
    rms_mm: float
    n: int
    cov: F64
    chi2: float

    @property
    def u_offset_mm(self) -> float:
        """Standard uncertainty of the plane's position along its normal at the centroid, mm."""
        return float(np.sqrt(self.cov[0, 0]))

    @property
    def u_tilt_rad(self) -> F64:
        """Standard uncertainties of the two tilts (slopes along ``axes``), rad."""
        return np.sqrt(np.diag(self.cov)[1:])

    def distance(self, points: ArrayLike) -> F64:
        """Signed orthogonal distances of ``points`` (..., 3) from the plane, positive along ``normal``, mm."""
        return (np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.centroid) @ self.normal

    def u_at(self, points: ArrayLike) -> F64:
        """Standard uncertainty of the plane's position along ``normal`` at each of ``points`` (..., 3), mm.

        The offset and tilt uncertainties combined with the lever arm: ``sqrt(g cov g')`` with
        ``g = (1, (p - centroid) . e1, (p - centroid) . e2)``.
        """
        q = np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.centroid
        g = np.column_stack([np.ones(len(q)), q @ self.axes.T])
        return np.sqrt(np.einsum("ij,jk,ik->i", g, self.cov, g))


def _plane(p: F64, s: F64) -> tuple[PlaneFit, F64, F64, F64]:
    """The plane of clean points, with its residuals, noise along the normal and Jacobian."""
    c = p.mean(axis=0)
    _, sv, vt = np.linalg.svd(p - c, full_matrices=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-300):
        raise ValueError("a plane needs points that are not all on one line")
    normal, e1 = vt[2], vt[0]
    if normal @ c > 0:
        normal = -normal
    e2 = np.cross(normal, e1)
    r = (p - c) @ normal
    J = np.column_stack([np.ones(len(p)), (p - c) @ e1, (p - c) @ e2])
    sn = sigma_along(p, s, normal)
    cov, _ = _sandwich(J, sn**2)
    chi2 = float(np.sum((r / sn) ** 2) / (len(p) - 3)) if (sn > 0).all() and len(p) > 3 else math.nan
    fit = PlaneFit(c, normal, np.vstack([e1, e2]), float(np.sqrt(np.mean(r**2))), len(p), cov, chi2)
    return fit, r, sn, J


def fit_plane_u(points: ArrayLike, sigma: ArrayLike) -> PlaneFit:
    """Total least-squares plane of the finite points, with the covariance of its offset and tilt.

    Parameters
    ----------
    points : array_like, shape (..., 3)
        X, Y, Z in mm, camera frame.
    sigma : array_like, shape (..., 3)
        Per-axis standard uncertainties of the points (the error lies along the camera ray).

    Returns
    -------
    PlaneFit
        Centroid, unit normal towards the camera, in-plane axes, RMS residual, ``n``, the
        covariance of (offset mm, tilt1 rad, tilt2 rad) and ``chi2``.

    Raises
    ------
    ValueError
        Fewer than 3 usable points, all points on one line, or mismatched shapes.

    Notes
    -----
    The normal is the smallest principal direction of the centred points (orthogonal
    regression). Linearised, a point's orthogonal residual is ``z_i - (a + b s_i + c t_i)`` with
    ``(s_i, t_i)`` its in-plane coordinates; with ``J = [1, s, t]`` and the noise along the
    normal ``s_n,i = |n . p_i/|p_i|| ||sigma_i||`` (independent), the covariance of
    ``(a, b, c)`` is ``(J'J)^-1 J' diag(s_n^2) J (J'J)^-1``. The offset and the tilts are
    uncorrelated because the in-plane coordinates are centred.
    """
    p, s = _clean(points, sigma, 3, "a plane")
    return _plane(p, s)[0]


def form_deviation(plane: PlaneFit, points: ArrayLike, degree: int = 4) -> float:
    """RMS of the systematic departure of ``points`` from ``plane`` (bowing, tilt of parts), mm.

    The orthogonal residuals are fitted by a polynomial of total ``degree`` in the plane's own
    coordinates (``plane.axes``, scaled to [-1, 1]); the RMS of that fit is the form error
    without the points' random noise.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    r = plane.distance(p)
    s, t = ((p - plane.centroid) @ plane.axes.T).T
    s, t = s / np.abs(s).max(), t / np.abs(t).max()
    A = np.column_stack([s**i * t**j for i in range(degree + 1) for j in range(degree + 1 - i)])
    return float(np.sqrt(np.mean((A @ np.linalg.lstsq(A, r, rcond=None)[0]) ** 2)))


def _mean_distance(plane: PlaneFit, q: F64, sq: F64) -> dict[str, float]:
    """Mean distance of points ``q`` from ``plane`` and its u: the points' noise and the plane's offset and tilt."""
    h = float(np.mean(plane.distance(q)))
    u_points = float(np.sqrt(np.sum(sigma_along(q, sq, plane.normal) ** 2)) / len(q))
    u_plane = float(plane.u_at(q.mean(axis=0))[0])
    lever = float(np.linalg.norm((q.mean(axis=0) - plane.centroid) @ plane.axes.T))
    return {"u_mm": math.hypot(u_points, u_plane), "u_points_mm": u_points, "u_plane_mm": u_plane,
            "lever_arm_mm": lever, "value": h}  # fmt: skip


def step_height_u(base_points: ArrayLike, base_sigma: ArrayLike, top_points: ArrayLike,
                  top_sigma: ArrayLike, *, base: PlaneFit | None = None) -> dict[str, Any]:  # fmt: skip
    """Mean height of a top region above the base plane, with its standard uncertainty.

    Parameters
    ----------
    base_points, base_sigma : array_like, shape (..., 3)
        Points of the datum (base) region and their per-axis standard uncertainties, mm.
    top_points, top_sigma : array_like, shape (..., 3)
        Points of the top region and their uncertainties, mm.
    base : PlaneFit, optional
        :func:`fit_plane_u` of ``base_points`` and ``base_sigma`` when the caller has it already
        (several steps on one base); the base points are then not fitted again.

    Returns
    -------
    dict
        ``height_mm``: mean signed distance of the top's points from the base plane along its
        normal (positive towards the camera); ``u_mm``: its standard uncertainty, the root-sum-
        square of ``u_top_mm`` (the top's mean noise along the normal,
        ``sqrt(sum s_n^2) / n_top``) and ``u_base_mm`` (the base plane's offset and tilt
        uncertainty evaluated at the top's centroid, see :meth:`PlaneFit.u_at`);
        ``lever_arm_mm``: the in-plane distance of the top's centroid from the base's;
        ``n_base``, ``n_top``, ``rms_base_mm`` and ``chi2_base``.

    Raises
    ------
    ValueError
        Fewer than 3 usable base points or no usable top point.
    """
    q, sq = _clean(top_points, top_sigma, 1, "the top region")
    plane = base if base is not None else _plane(*_clean(base_points, base_sigma, 3, "the base plane"))[0]
    m = _mean_distance(plane, q, sq)
    return {"height_mm": m["value"], "u_mm": m["u_mm"], "u_top_mm": m["u_points_mm"],
            "u_base_mm": m["u_plane_mm"], "lever_arm_mm": m["lever_arm_mm"], "n_base": plane.n,
            "n_top": len(q), "rms_base_mm": plane.rms_mm, "chi2_base": plane.chi2}  # fmt: skip


def flatness_u(points: ArrayLike, sigma: ArrayLike, *, draws: int = PV_NOISE_DRAWS, seed: int = 0,
               noise_rel_u: float = 0.0) -> dict[str, Any]:
    """Least-squares flatness (RMS and peak-to-valley of the orthogonal residuals), noise-corrected.

    Parameters
    ----------
    points, sigma : array_like, shape (..., 3)
        Points of the region and their per-axis standard uncertainties, mm.
    draws : int
        Monte Carlo draws of the noise-only residuals for ``pv_noise_mm``.
    seed : int
        Seed of that Monte Carlo's ``numpy.random.Generator`` (the result is deterministic).
    noise_rel_u : float
        Relative standard uncertainty of ``sigma`` itself (e.g. of a noise scale estimated from the
        data): the noise's mean square subtracted from the residuals' carries twice that relative
        uncertainty, which ``u_rms_form_mm`` then includes (it dominates where the form is small
        against the noise).

    Returns
    -------
    dict
        As measured: ``rms_mm`` and ``pv_mm`` of the residuals from the least-squares plane
        (ISO 12781 FLTq and FLTt of the LS reference). Noise-corrected, each with a standard
        uncertainty:

        - ``rms_form_mm = sqrt(max(0, rms^2 - rms_noise^2))`` with ``rms_noise_mm^2 =
          sum s_n,i^2 (1 - h_ii) / n`` the mean square the noise leaves after the fit (``h_ii``
          the fit's leverages). ``u_rms_form_mm`` is half the larger half-width of the k = 2
          interval found by inverting ``mean square +- 2 u(mean square)``, with
          ``u(mean square)^2 = (4 sum s_n^2 f^2 + 2 sum s_n^4) / n^2`` (normal noise; ``f^2``
          estimated by ``r^2 - s_n^2``). Far above the noise this is the delta method
          ``u(ms) / (2 rms_form)``; for a form at or below the noise it does not shrink below
          ``sqrt(u(ms) / 2)``, so a flat surface's ``rms_form_mm`` lies within its ``U = 2u``
          of 0 (about 97 % of the time for normal noise).
        - ``pv_form_mm = max(0, pv - pv_noise)`` with ``pv_noise_mm`` the expected
          peak-to-valley of the noise alone (Monte Carlo of the fit's residuals of independent
          normal noise ``s_n``). The noise raises the peak-to-valley by up to its own range;
          subtracting all of it is exact for a form well below the noise and over-corrects by up
          to ``pv_noise`` when the form's extremes stand well above it. ``u_pv_form_mm =
          sqrt(sd^2 + pv_noise^2 / 12)``: the spread ``sd`` of the noise's range and that
          unknown over-correction as a rectangular distribution of width ``pv_noise``.

        Also ``n``, ``rms_noise_mm``, ``pv_noise_mm``, the plane's ``normal`` and ``chi2``.

    Raises
    ------
    ValueError
        Fewer than 4 usable points (a plane plus one residual degree of freedom).
    """
    p, s = _clean(points, sigma, 4, "flatness")
    plane, r, sn, J = _plane(p, s)
    _, hat = _sandwich(J, sn**2)
    out = _form(r, sn, J, hat, int(draws), int(seed), float(noise_rel_u))
    return {"n": plane.n, **out, "normal": plane.normal.tolist(), "chi2": plane.chi2}


def _tilted(n: F64, axes: F64, t: F64) -> F64:
    m = n - t[0] * axes[0] - t[1] * axes[1]
    return m / np.linalg.norm(m)


def plane_pair_u(a_points: ArrayLike, a_sigma: ArrayLike, b_points: ArrayLike, b_sigma: ArrayLike) -> dict[str, Any]:
    """Distance and parallelism of plane b relative to datum plane a, with standard uncertainties.

    Parameters
    ----------
    a_points, a_sigma : array_like, shape (..., 3)
        Points of the datum plane a and their per-axis standard uncertainties, mm.
    b_points, b_sigma : array_like, shape (..., 3)
        Points of plane b and their uncertainties, mm.

    Returns
    -------
    dict
        ``distance_mm``: mean signed distance of b's points from a along a's normal, with
        ``u_distance_mm`` (b's mean noise and a's offset and tilt at b's centroid, as
        :func:`step_height_u`); ``angle_rad``: the angle between the two normals (in
        ``[0, pi/2]``) with ``u_angle_rad``; ``parallelism_mm``: the width, along a's normal, of
        the zone parallel to a that contains b's fitted plane over b's points (ISO 1101
        parallelism of b's least-squares plane; b's own form is its flatness, not included),
        with ``u_parallelism_mm``; ``tilt``: b's normal less its part along a's normal (a signed
        3-vector of length ``sin(angle)``, for a jackknife over calibrations, whose spread a
        magnitude hides) and ``zone_per_tilt_mm``, ``parallelism_mm`` per unit of it; ``n_a``, ``n_b``.

    Raises
    ------
    ValueError
        Fewer than 3 usable points in either plane, or points of a plane on one line.

    Notes
    -----
    The angle and the zone width are functions of the four tilts (two per plane, independent
    fits of disjoint points); their u are propagated from the tilts' covariances with a
    central-difference Jacobian. Both are magnitudes: when the true angle is comparable to its
    u they are biased upwards (like a Rayleigh variable) and the delta method does not hold;
    for normals closer than 1e-9 rad ``u_angle_rad`` is ``sqrt((tr Ca + tr Cb) / 2)`` of the
    tilt covariances (the Rayleigh scale) and ``u_parallelism_mm`` that times b's extent.
    """
    pa, sa = _clean(a_points, a_sigma, 3, "plane a")
    pb, sb = _clean(b_points, b_sigma, 3, "plane b")
    a, b = _plane(pa, sa)[0], _plane(pb, sb)[0]
    m = _mean_distance(a, pb, sb)
    nb0 = b.normal if b.normal @ a.normal >= 0 else -b.normal
    qb = pb - b.centroid

    def figures(t: F64) -> F64:
        na, nb = _tilted(a.normal, a.axes, t[:2]), _tilted(nb0, b.axes, t[2:])
        angle = math.atan2(float(np.linalg.norm(np.cross(na, nb))), abs(float(na @ nb)))
        d = (qb - np.outer(qb @ nb, nb)) @ na  # b's points projected onto b's plane, distance along na
        return np.array([angle, float(d.max() - d.min())])

    f0 = figures(np.zeros(4))
    cov = np.zeros((4, 4))
    cov[:2, :2], cov[2:, 2:] = a.cov[1:, 1:], b.cov[1:, 1:]
    h = 1e-7
    if f0[0] > 1e-9:
        G = np.column_stack([(figures(h * e) - figures(-h * e)) / (2 * h) for e in np.eye(4)])
        u = np.sqrt(np.diag(G @ cov @ G.T))
    else:
        ua = math.sqrt((np.trace(a.cov[1:, 1:]) + np.trace(b.cov[1:, 1:])) / 2.0)
        ext = float(np.ptp(qb @ b.axes.T, axis=0).max())
        u = np.array([ua, ua * ext])
    tilt = nb0 - (nb0 @ a.normal) * a.normal
    d_unit = (qb - np.outer(qb @ nb0, nb0)) @ (tilt / max(float(np.linalg.norm(tilt)), 1e-300))
    zone_per_tilt = float(np.ptp(d_unit)) if np.linalg.norm(tilt) > 0 else float(np.ptp(qb @ b.axes.T, axis=0).max())
    return {"distance_mm": m["value"], "u_distance_mm": m["u_mm"], "angle_rad": float(f0[0]),
            "u_angle_rad": float(u[0]), "parallelism_mm": float(f0[1]), "u_parallelism_mm": float(u[1]),
            "tilt": tilt.tolist(), "zone_per_tilt_mm": zone_per_tilt, "n_a": a.n, "n_b": b.n}  # fmt: skip


# --------------------------------------------------------------------------------------------
# sphere
# --------------------------------------------------------------------------------------------


def fit_sphere_u(points: ArrayLike, sigma: ArrayLike, *, draws: int = PV_NOISE_DRAWS, seed: int = 0,
                 noise_rel_u: float = 0.0) -> dict[str, Any]:
    """Geometric least-squares sphere with the uncertainty of its centre and radius, and its form.

    Parameters
    ----------
    points, sigma : array_like, shape (..., 3)
        Points on the sphere (mm, camera frame) and their per-axis standard uncertainties.
    draws, seed, noise_rel_u :
        Monte Carlo of the noise's peak-to-valley and the noise's own relative uncertainty, as
        :func:`flatness_u`.

    Returns
    -------
    dict
        ``centre_mm`` (3 floats), ``u_centre_mm`` (3), ``radius_mm``, ``u_radius_mm``, ``cov``
        (4 x 4 nested list: centre X, Y, Z and radius, mm^2), ``n``, ``chi2``, and the form of
        the radial residuals as :func:`flatness_u` gives it for a plane (``rms_mm``, ``pv_mm``,
        ``rms_form_mm``, ``u_rms_form_mm``, ``pv_noise_mm``, ``pv_form_mm``, ``u_pv_form_mm``).

    Raises
    ------
    ValueError
        Fewer than 5 usable points (4 parameters plus one degree of freedom), or points on one
        plane (no unique sphere).

    Notes
    -----
    An algebraic fit starts ``scipy.optimize.least_squares`` (Levenberg-Marquardt) on the radial
    residuals ``|p_i - c| - R``. Their Jacobian is ``J = [-(p_i - c)/|p_i - c|, -1]``; a point's
    noise along its radial direction ``u_i`` is ``s_i = |u_i . p_i/|p_i|| ||sigma_i||``, and the
    covariance of ``(c, R)`` is ``(J'J)^-1 J' diag(s^2) J (J'J)^-1``. A camera sees at most the
    half of the sphere facing it, so the centre's component along the line of sight and the
    radius are strongly correlated; the covariance carries that.
    """
    p, s = _clean(points, sigma, 5, "a sphere")
    A = np.column_stack([2 * p, np.ones(len(p))])
    if np.linalg.svd(A - A.mean(axis=0), compute_uv=False)[2] <= 1e-9 * np.abs(p).max():
        raise ValueError("a sphere needs points that are not all on one plane")
    sol = np.linalg.lstsq(A, (p**2).sum(axis=1), rcond=None)[0]
    x0 = np.r_[sol[:3], math.sqrt(max(sol[3] + sol[:3] @ sol[:3], 1e-12))]

    def res(x: F64) -> F64:
        return np.linalg.norm(p - x[:3], axis=1) - x[3]

    x = least_squares(res, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    r = res(x)
    radial = (p - x[:3]) / np.linalg.norm(p - x[:3], axis=1, keepdims=True)
    J = np.column_stack([-radial, -np.ones(len(p))])
    sr = sigma_along(p, s, radial)
    cov, hat = _sandwich(J, sr**2)
    out = _form(r, sr, J, hat, int(draws), int(seed), float(noise_rel_u))
    chi2 = float(np.sum((r / sr) ** 2) / (len(p) - 4)) if (sr > 0).all() else math.nan
    return {"centre_mm": x[:3].tolist(), "u_centre_mm": np.sqrt(np.diag(cov)[:3]).tolist(),
            "radius_mm": float(x[3]), "u_radius_mm": float(np.sqrt(cov[3, 3])), "cov": cov.tolist(),
            "n": len(p), "chi2": chi2, **out}  # fmt: skip
