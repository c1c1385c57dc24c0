"""Phase, unwrapping and plane calibration against analytic triangulation."""

from __future__ import annotations

import numpy as np
import pytest

from huefringe.height import PlaneCalibrationError, accuracy, calibrate_planes, coverage
from huefringe.patterns import TWO_PI, phase_shift_intensity
from huefringe.phase import three_step_phase, unwrap, wrap

W, H_IMG, PITCH, PERIOD_PX = 160, 120, 0.2, 40.0
XP, HP = -150.0, 300.0  # projector pupil x and height (mm)


def code_phase(h: np.ndarray) -> np.ndarray:
    """Ideal rig: code phase seen at each pixel for a surface of height h (mm)."""
    X = np.arange(W)[None, :] * PITCH * np.ones((H_IMG, 1))
    x0 = XP + (X - XP) * HP / (HP - h)
    return np.mod(TWO_PI * x0 / (PERIOD_PX * PITCH), TWO_PI)


def ideal_calibration(planes=(0.0, 3.0, 6.0), noise=0.0, degree=3, seed=0):
    rng = np.random.default_rng(seed)
    phases = {z: np.mod(code_phase(np.full((H_IMG, W), z)) + rng.normal(0, noise, (H_IMG, W)), TWO_PI) for z in planes}
    valid = {z: np.ones((H_IMG, W), bool) for z in planes}
    return calibrate_planes(phases, valid, smooth_degree=degree)


def test_wrap_range() -> None:
    x = np.linspace(-20, 20, 1001)
    w = wrap(x)
    assert np.all(w > -np.pi - 1e-12) and np.all(w <= np.pi + 1e-12)
    np.testing.assert_allclose(np.cos(w), np.cos(x), atol=1e-12)


def test_three_step_recovers_phase_and_contrast() -> None:
    phi = np.linspace(0, TWO_PI, 500, endpoint=False)
    A, B = 0.3, 0.2
    imgs = [A + B * (2 * phase_shift_intensity(phi, s) - 1) for s in range(3)]
    out, mod = three_step_phase(*imgs)
    np.testing.assert_allclose(wrap(out - phi), 0, atol=1e-6)
    np.testing.assert_allclose(mod, B / A, rtol=1e-5)


@pytest.mark.parametrize("degree", [3, None])
def test_plane_calibration_matches_triangulation(degree) -> None:
    cal = ideal_calibration(degree=degree)
    # the model is exact: a = k (X - Xp) / H, b = 1 / H
    X = np.arange(W) * PITCH
    k = TWO_PI / (PERIOD_PX * PITCH)
    np.testing.assert_allclose(cal.a[0], k * (X - XP) / HP, rtol=1e-4)
    np.testing.assert_allclose(np.median(cal.b), 1 / HP, rtol=1e-3)
    assert cal.stats["fit_residual_rms_mm"] < 1e-4
    # a freeform surface within the unambiguous range reconstructs exactly
    vv, uu = np.mgrid[0:H_IMG, 0:W]
    h = 2.5 + 2.0 * np.sin(uu / 17.0) * np.cos(vv / 23.0)
    dphi = wrap(code_phase(h) - cal.phi_ref)
    np.testing.assert_allclose(cal.height(dphi), h, atol=2e-4)
    lo, hi = cal.unambiguous_range_mm()
    assert lo < 0 < 6.0 < hi


def test_smoothing_beats_raw_pixels_with_noise() -> None:
    vv, uu = np.mgrid[0:H_IMG, 0:W]
    h = np.where((uu > 50) & (uu < 110), 3.0, 0.5)
    errs = {}
    for degree in (3, None):
        cal = ideal_calibration(noise=0.02, degree=degree, seed=1)
        dphi = wrap(code_phase(h) - cal.phi_ref)
        errs[degree] = accuracy(cal.height(dphi), h)["rms_mm"]
    assert errs[3] < 0.6 * errs[None]


def test_single_extra_plane_gives_linear_model() -> None:
    cal = ideal_calibration(planes=(0.0, 2.0))
    assert np.all(cal.b == 0) and "linear" in cal.stats["model"]
    dphi = wrap(code_phase(np.full((H_IMG, W), 1.0)) - cal.phi_ref)
    np.testing.assert_allclose(cal.height(dphi), 1.0, atol=0.01)


def test_planes_too_close_refused() -> None:
    with pytest.raises(PlaneCalibrationError, match="too close"):
        ideal_calibration(planes=(0.0, 1e-7, 2e-7))


def test_far_planes_unwrap_sequentially() -> None:
    # plane 12 mm lies beyond the unambiguous range but is reached through 3, 6, 9 mm
    cal = ideal_calibration(planes=(0.0, 3.0, 6.0, 9.0, 12.0))
    assert cal.stats["fit_residual_rms_mm"] < 1e-3


def test_reference_unwrap_flags_and_spatial_unwrap() -> None:
    vv, uu = np.mgrid[0:H_IMG, 0:W]
    true = 0.06 * (uu - 20.0)  # a ramp from -1.2 to 8.3 rad: crosses pi
    wrapped = wrap(true)
    valid = np.ones(true.shape, bool)
    ref = unwrap(wrapped, valid, "reference")
    assert ref.flags["wrap_edge"].any() and ref.flags["near_wrap"].any()
    sp = unwrap(wrapped, valid, "spatial")
    np.testing.assert_allclose(sp.dphi, true, atol=1e-5)
    assert not sp.flags["isolated"].any()
    # an island separated by invalid pixels is flagged isolated
    valid2 = valid.copy()
    valid2[:, 100:104] = False
    sp2 = unwrap(wrapped, valid2, "spatial")
    assert sp2.flags["isolated"][:, 110].all() and not sp2.flags["isolated"][:, 10].any()


def test_accuracy_figures() -> None:
    truth = np.zeros((10, 10))
    h = truth + 0.1
    h[0, 0] = np.nan
    acc = accuracy(h, truth)
    assert acc["coverage"] == pytest.approx(0.99)
    assert acc["rms_mm"] == pytest.approx(0.1) and acc["median_abs_mm"] == pytest.approx(0.1)
    assert coverage(h, truth) == acc["coverage"]
    region = np.zeros((10, 10), bool)
    region[:2] = True  # 20 pixels, one of them NaN
    assert coverage(h, truth, region) == pytest.approx(0.95) == accuracy(h, truth, region)["coverage"]


def test_nearest_plane_crossing_pi_is_unwrapped() -> None:
    # fine fringes: the 3 mm plane's phase difference crosses pi inside the field
    global PERIOD_PX
    saved = PERIOD_PX
    PERIOD_PX = 17.0
    try:
        h = np.full((H_IMG, W), 3.0)
        d = code_phase(h) - code_phase(np.zeros((H_IMG, W)))
        d = np.mod(d, TWO_PI)
        assert (d > np.pi).any() and (d < np.pi).any()  # the wrapped difference jumps in the field
        cal = ideal_calibration(planes=(0.0, 3.0, 6.0))
        assert cal.stats["fit_residual_rms_mm"] < 1e-3
        for z in (1.5, 4.5):  # heights through the spatial unwrap of dphi, not the wrapped one
            dphi = code_phase(np.full((H_IMG, W), z)) - cal.phi_ref
            dphi = wrap(dphi) + TWO_PI * np.round((cal.a * z / (1 - cal.b * z) - wrap(dphi)) / TWO_PI)
            np.testing.assert_allclose(cal.height(dphi), z, atol=1e-3)
    finally:
        PERIOD_PX = saved


def test_wrap_edge_flags_exactly_the_pixels_on_both_sides_of_a_jump() -> None:
    d = np.zeros((6, 7))
    d[:, 4:] = 3.0  # a jump of 3 rad between columns 3 and 4 (not > pi): no edge
    d[2:, 5:] = -3.0  # 6 rad between columns 4 and 5 and between rows 1 and 2: edges
    valid = np.ones(d.shape, bool)
    valid[5, 4] = False  # an invalid pixel is never flagged, and breaks its edges
    f = unwrap(d, valid, "reference").flags["wrap_edge"]
    want = np.zeros(d.shape, bool)
    want[2:5, 4:6] = True  # the u-jump, rows 2..4 (row 5's left side is invalid)
    want[5, 5] = False
    want[1:3, 5:] = True  # the v-jump between rows 1 and 2, columns 5, 6
    want[5, 5] = False
    assert np.array_equal(f, want), np.argwhere(f != want)
    assert unwrap(d[:, :4], valid[:, :4], "reference").flags["wrap_edge"].sum() == 0


def _design_reference(shape: tuple[int, int], degree: int, uu: np.ndarray, vv: np.ndarray) -> np.ndarray:
    """The polynomial's design matrix at pixel coordinates ``uu``, ``vv``: ``x^i y^j``, ``x``, ``y``
    the coordinates scaled to [-1, 1] over the image."""
    h, w = shape
    x = (uu / max(w - 1, 1)) * 2.0 - 1.0
    y = (vv / max(h - 1, 1)) * 2.0 - 1.0
    return np.stack([x**i * y**j for i in range(degree + 1) for j in range(degree + 1 - i)], axis=-1)


@pytest.mark.parametrize("shape", [(480, 640), (300, 400), (241, 319), (7, 5), (1, 9)])
@pytest.mark.parametrize("step", [1, 2, 3])
def test_polynomial_design_on_the_grid_is_the_pointwise_one(shape: tuple[int, int], step: int) -> None:
    """The grid's design (powers per row and column, broadcast) holds the pointwise definition's
    values bit for bit, at every step-th pixel and every degree, and so does the fit it
    evaluates."""
    from huefringe.height import _design_grid, fit_poly2d

    vv, uu = np.mgrid[0 : shape[0] : step, 0 : shape[1] : step]
    for degree in (1, 2, 3, 4):
        ref = _design_reference(shape, degree, uu.astype(np.float64), vv.astype(np.float64))
        np.testing.assert_array_equal(_design_grid(shape, degree, step), ref)
    if min(shape) > 20:
        rng = np.random.default_rng(step)
        v, u = np.mgrid[0 : shape[0], 0 : shape[1]]
        values = 0.3 + 1e-3 * u - 2e-3 * v + 1e-6 * u * v + rng.normal(0, 0.01, shape)
        valid = rng.random(shape) > 0.2
        fit = fit_poly2d(values, valid, 3, step=step)
        sub = valid[::step, ::step]
        A = _design_reference(shape, 3, uu[sub].astype(np.float64), vv[sub].astype(np.float64))
        coef, *_ = np.linalg.lstsq(A, values[::step, ::step][sub], rcond=None)
        full = _design_reference(shape, 3, u.astype(np.float64), v.astype(np.float64))
        assert np.abs(fit - full @ coef).max() < 1e-3  # the robust fit: a few samples clipped at most
        assert np.abs(fit - (0.3 + 1e-3 * u - 2e-3 * v + 1e-6 * u * v)).max() < 0.01
