"""Form metrology on triangulated points (huefringe.metrology._forms) against analytic truth.

Scenes sit about 300 mm in front of a camera at the origin; each point's noise is drawn along its
camera ray with a per-point standard deviation (seeded generators), as the rig contract says.
The Monte Carlo checks compare each reported u with the spread of the errors over repeated noise
draws on a fixed geometry, and count how often |error| <= 2u.
"""

from __future__ import annotations

import numpy as np
import pytest

from huefringe.metrology import (
    PlaneFit,
    combine_u,
    fit_plane_u,
    fit_sphere_u,
    flatness_u,
    jackknife_u,
    plane_pair_u,
    step_height_u,
)
from huefringe.report import conformity

TRIALS = 400


def _basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = normal / np.linalg.norm(normal)
    a = np.cross(n, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    return n, a, np.cross(n, a)


def _on_plane(centre, normal, s, t) -> np.ndarray:
    """Points centre + s e1 + t e2 of the plane through ``centre`` with ``normal``."""
    _, e1, e2 = _basis(np.asarray(normal, dtype=float))
    return np.asarray(centre, dtype=float) + np.outer(s, e1) + np.outer(t, e2)


def _sigma(p: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Per-axis sigma whose norm is the along-ray std ``s`` (the triangulation's convention)."""
    return s[:, None] * np.abs(p / np.linalg.norm(p, axis=1, keepdims=True))


def _noisy(rng: np.random.Generator, p: np.ndarray, s: np.ndarray) -> np.ndarray:
    d = p / np.linalg.norm(p, axis=1, keepdims=True)
    return p + (s * rng.standard_normal(len(p)))[:, None] * d


def _check_mc(err: np.ndarray, u: np.ndarray) -> tuple[float, float]:
    """(mean u / spread, coverage of |err| <= 2u), asserted within 1 +- 0.15 and 0.95 +- 0.03."""
    ratio = float(np.mean(u) / np.std(err, ddof=1))
    cover = float(np.mean(np.abs(err) <= 2 * u))
    assert 0.85 <= ratio <= 1.15, ratio
    assert 0.92 <= cover <= 0.98, cover
    return ratio, cover


# a tilted datum plane away from the optical axis, and its normal (towards the camera: N_BASE . C_BASE < 0)
N_BASE = np.array([0.25, -0.35, -1.0])
C_BASE = np.array([30.0, -20.0, 300.0])


# --------------------------------------------------------------------------------------------
# exact data
# --------------------------------------------------------------------------------------------


def test_exact_plane_and_step_to_machine_precision() -> None:
    rng = np.random.default_rng(1)
    base = _on_plane(C_BASE, N_BASE, rng.uniform(-40, -10, 50), rng.uniform(-20, 20, 50))
    n = N_BASE / np.linalg.norm(N_BASE)
    top = _on_plane(C_BASE, N_BASE, rng.uniform(10, 40, 30), rng.uniform(-20, 20, 30)) + 2.5 * n
    zero = np.zeros_like(base)
    fit = fit_plane_u(base, _sigma(base, np.full(50, 0.01)))
    assert isinstance(fit, PlaneFit) and fit.n == 50
    assert n @ C_BASE < 0 and np.abs(fit.normal - n).max() < 1e-13  # towards the camera
    assert fit.normal @ fit.centroid < 0 and fit.rms_mm < 1e-12
    assert abs(np.linalg.det(np.vstack([fit.axes, fit.normal])) - 1) < 1e-12
    st = step_height_u(base, zero, top, np.zeros_like(top))
    assert abs(st["height_mm"] - 2.5) < 1e-12 and st["u_mm"] == 0.0
    fl = flatness_u(base, zero)
    assert fl["rms_mm"] < 1e-12 and fl["pv_mm"] < 1e-12 and fl["rms_form_mm"] < 1e-12 and fl["pv_noise_mm"] == 0.0


def test_exact_sphere_to_machine_precision() -> None:
    centre, radius = np.array([15.0, -10.0, 320.0]), 12.5
    p = _sphere_cap(np.random.default_rng(2), centre, radius, 80)
    out = fit_sphere_u(p, np.zeros_like(p))
    assert np.abs(np.array(out["centre_mm"]) - centre).max() < 1e-9
    assert abs(out["radius_mm"] - radius) < 1e-10 and out["rms_mm"] < 1e-10 and out["n"] == 80


def test_exact_plane_pair() -> None:
    rng = np.random.default_rng(3)
    a = _on_plane(C_BASE, N_BASE, rng.uniform(-40, 0, 60), rng.uniform(-20, 20, 60))
    na, e1, _ = _basis(N_BASE)
    theta = 0.02
    nb = np.cos(theta) * na + np.sin(theta) * e1
    s, t = rng.uniform(-10, 10, 40), rng.uniform(-10, 10, 40)
    b = _on_plane(C_BASE + 30 * e1 + 7 * na, nb, s, t)
    out = plane_pair_u(a, np.zeros_like(a), b, np.zeros_like(b))
    d_true = (b - C_BASE) @ na  # distances along a's camera-facing normal
    assert abs(out["distance_mm"] - d_true.mean()) < 1e-11
    assert abs(out["angle_rad"] - theta) < 1e-12
    assert abs(out["parallelism_mm"] - np.ptp(d_true)) < 1e-11


# --------------------------------------------------------------------------------------------
# Monte Carlo: u against the empirical spread
# --------------------------------------------------------------------------------------------


def test_plane_offset_and_tilt_u_match_spread() -> None:
    rng = np.random.default_rng(10)
    p0 = _on_plane(C_BASE, N_BASE, rng.uniform(-40, 40, 100), rng.uniform(-15, 15, 100))
    s = rng.uniform(0.005, 0.02, 100)
    ref = fit_plane_u(p0, _sigma(p0, s))
    off, tilt, u = [], [], []
    for _ in range(TRIALS):
        f = fit_plane_u(_noisy(rng, p0, s), _sigma(p0, s))
        off.append(f.distance(ref.centroid)[0])
        tilt.append(-(ref.axes @ f.normal))
        u.append(np.r_[f.u_at(ref.centroid), f.u_tilt_rad])
    u_arr, spread = np.array(u), np.std(np.column_stack([off, np.array(tilt)]), axis=0, ddof=1)
    ratio = u_arr.mean(axis=0) / spread
    assert np.all(np.abs(ratio - 1) < 0.15), ratio
    assert u_arr[:, 1].mean() < 0.5 * u_arr[:, 2].mean()  # the long axis is the better-known tilt


def _step_scene(rng: np.random.Generator):
    base = _on_plane(C_BASE, N_BASE, rng.uniform(-45, -15, 120), rng.uniform(-15, 15, 120))
    n = _basis(N_BASE)[0]
    top = _on_plane(C_BASE, N_BASE, rng.uniform(30, 45, 60), rng.uniform(-10, 10, 60)) + 2.0 * n
    return base, top, rng.uniform(0.005, 0.02, 120), rng.uniform(0.005, 0.02, 60)


def test_step_height_u_and_coverage() -> None:
    rng = np.random.default_rng(11)
    base, top, sb, stp = _step_scene(rng)
    err, u, u_top = [], [], []
    for _ in range(TRIALS):
        out = step_height_u(_noisy(rng, base, sb), _sigma(base, sb), _noisy(rng, top, stp), _sigma(top, stp))
        err.append(out["height_mm"] - 2.0)
        u.append(out["u_mm"])
        u_top.append(out["u_top_mm"])
    ratio, cover = _check_mc(np.array(err), np.array(u))
    # the base's tilt at the lever arm dominates here: the top's noise alone understates u
    assert np.mean(u_top) / np.std(err, ddof=1) < 0.5
    assert out["lever_arm_mm"] > 50 and out["n_base"] == 120 and out["n_top"] == 60


def _pair_scene(rng: np.random.Generator, theta: float = 0.02):
    a = _on_plane(C_BASE, N_BASE, rng.uniform(-40, 0, 100), rng.uniform(-20, 20, 100))
    na, e1, e2 = _basis(N_BASE)
    nb = np.cos(theta) * na + np.sin(theta) * (0.6 * e1 + 0.8 * e2)
    b = _on_plane(C_BASE + 30 * e1 + 10 * na, nb, rng.uniform(-12, 12, 80), rng.uniform(-8, 8, 80))
    d = (b - C_BASE) @ na
    return a, b, rng.uniform(0.005, 0.02, 100), rng.uniform(0.005, 0.02, 80), d.mean(), theta, np.ptp(d)


def test_plane_pair_u_and_coverage() -> None:
    rng = np.random.default_rng(12)
    a, b, sa, sb, dist, theta, width = _pair_scene(rng)
    rows = []
    for _ in range(TRIALS):
        o = plane_pair_u(_noisy(rng, a, sa), _sigma(a, sa), _noisy(rng, b, sb), _sigma(b, sb))
        rows.append([o["distance_mm"] - dist, o["u_distance_mm"], o["angle_rad"] - theta, o["u_angle_rad"],
                     o["parallelism_mm"] - width, o["u_parallelism_mm"]])
    r = np.array(rows)
    for k in range(3):
        _check_mc(r[:, 2 * k], r[:, 2 * k + 1])


def _sphere_cap(rng: np.random.Generator, centre: np.ndarray, radius: float, n: int, cone_deg: float = 60.0):
    """Points on the part of the sphere facing the camera, within ``cone_deg`` of the line of sight."""
    view = -centre / np.linalg.norm(centre)
    _, a, b = _basis(view)
    cos_t = rng.uniform(np.cos(np.radians(cone_deg)), 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    sin_t = np.sqrt(1 - cos_t**2)
    d = np.outer(cos_t, view) + np.outer(sin_t * np.cos(phi), a) + np.outer(sin_t * np.sin(phi), b)
    return centre + radius * d


def test_sphere_radius_u_and_coverage() -> None:
    rng = np.random.default_rng(13)
    centre, radius = np.array([15.0, -10.0, 320.0]), 12.5
    p0 = _sphere_cap(rng, centre, radius, 150)
    s = rng.uniform(0.005, 0.02, 150)
    err, u = [], []
    for _ in range(TRIALS // 2):
        o = fit_sphere_u(_noisy(rng, p0, s), _sigma(p0, s), draws=8)
        err.append(o["radius_mm"] - radius)
        u.append(o["u_radius_mm"])
    _check_mc(np.array(err), np.array(u))


# --------------------------------------------------------------------------------------------
# flatness
# --------------------------------------------------------------------------------------------


def test_flat_plane_flatness_within_U_of_zero() -> None:
    rng = np.random.default_rng(20)
    p0 = _on_plane(C_BASE, N_BASE, rng.uniform(-20, 20, 150), rng.uniform(-20, 20, 150))
    s = rng.uniform(0.005, 0.02, 150)
    rows = []
    for _ in range(300):
        o = flatness_u(_noisy(rng, p0, s), _sigma(p0, s), draws=64)
        rows.append([o["rms_form_mm"], o["u_rms_form_mm"], o["pv_form_mm"], o["u_pv_form_mm"], o["rms_mm"], o["pv_mm"]])
    r = np.array(rows)
    assert np.mean(r[:, 0] <= 2 * r[:, 1]) >= 0.93
    assert np.mean(r[:, 2] <= 2 * r[:, 3]) >= 0.93
    # as measured, the noise alone makes the surface look far from flat
    assert np.mean(r[:, 4] <= 2 * r[:, 1]) < 0.05 and np.mean(r[:, 5] <= 2 * r[:, 3]) < 0.2


def test_sinusoidal_form_recovered_within_U() -> None:
    rng = np.random.default_rng(21)
    n_pts, amp, period = 300, 0.03, 25.0
    s_in, t_in = rng.uniform(-30, 30, n_pts), rng.uniform(-15, 15, n_pts)
    na = _basis(N_BASE)[0]
    p0 = _on_plane(C_BASE, N_BASE, s_in, t_in) + np.outer(amp * np.sin(2 * np.pi * s_in / period), na)
    truth = flatness_u(p0, np.zeros_like(p0))
    assert truth["rms_mm"] == pytest.approx(amp / np.sqrt(2), rel=0.1)
    s = rng.uniform(0.005, 0.02, n_pts)
    rows = []
    for _ in range(200):
        o = flatness_u(_noisy(rng, p0, s), _sigma(p0, s), draws=64)
        rows.append([o["rms_form_mm"] - truth["rms_mm"], o["u_rms_form_mm"], o["pv_form_mm"] - truth["pv_mm"],
                     o["u_pv_form_mm"], o["rms_mm"] - truth["rms_mm"]])
    r = np.array(rows)
    ratio = np.mean(r[:, 1]) / np.std(r[:, 0], ddof=1)
    assert 0.85 <= ratio <= 1.15, ratio
    assert np.mean(np.abs(r[:, 0]) <= 2 * r[:, 1]) >= 0.93
    assert np.mean(np.abs(r[:, 2]) <= 2 * r[:, 3]) >= 0.93
    assert np.mean(np.abs(r[:, 4]) <= 2 * r[:, 1]) < 0.5  # the uncorrected RMS is biased out of U


def test_sphere_form_of_a_perfect_ball_within_U_of_zero() -> None:
    rng = np.random.default_rng(22)
    centre = np.array([-20.0, 5.0, 280.0])
    p0 = _sphere_cap(rng, centre, 10.0, 120)
    s = rng.uniform(0.005, 0.02, 120)
    ok = [o["rms_form_mm"] <= 2 * o["u_rms_form_mm"] and o["pv_form_mm"] <= 2 * o["u_pv_form_mm"]
          for o in (fit_sphere_u(_noisy(rng, p0, s), _sigma(p0, s), draws=32) for _ in range(100))]
    assert np.mean(ok) >= 0.93


# --------------------------------------------------------------------------------------------
# calibration term, refusals, input handling
# --------------------------------------------------------------------------------------------


def test_jackknife_of_the_mean_is_its_standard_error() -> None:
    y = np.random.default_rng(30).normal(5.0, 2.0, 12)
    loo = (y.sum() - y) / (len(y) - 1)  # the mean recomputed without each value
    assert jackknife_u(loo) == pytest.approx(np.std(y, ddof=1) / np.sqrt(len(y)), rel=1e-12)
    assert jackknife_u([1.0, 2.0, 3.0, 4.0]) == pytest.approx(np.sqrt(0.75 * 5.0), rel=1e-15)
    assert combine_u(3.0, 4.0) == 5.0 and combine_u(0.5) == 0.5


def test_refusals() -> None:
    p = np.array([[0.0, 0.0, 300.0], [1.0, 0.0, 300.0], [0.0, 1.0, 300.0], [1.0, 1.0, 300.0], [2.0, 1.0, 301.0]])
    s = np.full_like(p, 0.01)
    with pytest.raises(ValueError, match="a plane needs at least 3 points.*2 given"):
        fit_plane_u(p[:2], s[:2])
    with pytest.raises(ValueError, match="not all on one line"):
        fit_plane_u(np.outer(np.arange(5.0), [1.0, 2.0, 3.0]) + [0, 0, 300], s)
    with pytest.raises(ValueError, match="shape"):
        fit_plane_u(p, s[:, :2])
    with pytest.raises(ValueError, match=">= 0"):
        fit_plane_u(p, -s)
    with pytest.raises(ValueError, match="flatness needs at least 4 points"):
        flatness_u(p[:3], s[:3])
    with pytest.raises(ValueError, match="the top region needs at least 1 point"):
        step_height_u(p, s, np.full((2, 3), np.nan), s[:2])
    with pytest.raises(ValueError, match="a sphere needs at least 5 points.*4 given"):
        fit_sphere_u(p[:4], s[:4])
    with pytest.raises(ValueError, match="not all on one plane"):
        fit_sphere_u(p[:4].tolist() + [[3.0, 3.0, 300.0]], np.full((5, 3), 0.01))
    with pytest.raises(ValueError, match="plane b needs at least 3"):
        plane_pair_u(p, s, p[:2], s[:2])
    with pytest.raises(ValueError, match="at least 2"):
        jackknife_u([1.0])
    with pytest.raises(ValueError, match="finite"):
        combine_u(1.0, float("nan"))


def test_image_shaped_input_with_holes() -> None:
    rng = np.random.default_rng(31)
    p = _on_plane(C_BASE, N_BASE, rng.uniform(-20, 20, 48), rng.uniform(-20, 20, 48)).reshape(6, 8, 3)
    sig = np.full_like(p, 0.01)
    p[0, 0] = np.nan
    sig[1, 1] = np.nan
    assert fit_plane_u(p, sig).n == 46
    assert flatness_u(p, sig)["n"] == 46


# --------------------------------------------------------------------------------------------
# conformity with per-figure tolerances
# --------------------------------------------------------------------------------------------


def test_conformity_takes_each_entrys_own_tolerance() -> None:
    common = [{"name": "block-2", "error_mm": 0.01, "U_mm": 0.02, "pass": True}]
    flat = {"name": "top-10", "error_mm": 0.03, "U_mm": 0.01, "tolerance_mm": 0.05, "pass": True}
    assert conformity(common + [flat], 0.05)["decision"] == "conforms"
    # with the common T = 0.035, block-2 conforms and the flatness keeps its own T = 0.05
    c = conformity(common + [flat], 0.035)
    assert c["decision"] == "conforms" and c["conforming"] == ["block-2", "top-10"]
    # without its own T, the same flatness is undecided under T = 0.035, and the reason says so
    c = conformity(common + [{k: v for k, v in flat.items() if k != "tolerance_mm"}], 0.035)
    assert c["decision"] == "undecided"
    assert "top-10: |error| 0.0300 mm lies between T - U = 0.0250 mm and T + U = 0.0450 mm" in c["reason"]
    # a tight own T decides non-conformance and names its own limit
    c = conformity(common + [flat | {"tolerance_mm": 0.01}], 0.05)
    assert c["decision"] == "does not conform" and c["nonconforming"] == ["top-10"]
    assert "top-10: |error| 0.0300 mm > T + U = 0.0200 mm" in c["reason"]
