"""Hue models (paper eqs. 1-2 and hexcone), saturation, intensity, white balance."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from huefringe import colour
from huefringe.patterns import RAMP_SEXTANTS, TWO_PI, trapezoid_rgb


def circ(a, b):
    """Circular difference in [-pi, pi)."""
    return colour.wrap_pi(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))


# ------------------------------------------------------------------ linearity on eq. 3
def test_hexcone_hue_of_trapezoid_is_the_code_phase():
    phi = np.concatenate([np.linspace(0, TWO_PI, 60001, endpoint=False), np.arange(6) * np.pi / 3])
    h = colour.hue_hexcone(trapezoid_rgb(phi))
    assert h.dtype == np.float32
    assert np.max(np.abs(circ(h, phi))) < 1e-6


def test_ramp_sextants_name_the_one_channel_eq3_ramps():
    """In sextant k of eq. 3 exactly the channel RAMP_SEXTANTS names changes, by +-1 in its direction,
    while the other two stay at 0 and 1."""
    for k, (ch, sign) in enumerate(RAMP_SEXTANTS):
        a, b = trapezoid_rgb(np.array([k, k + 1 - 1e-9]) * np.pi / 3)
        change = b - a
        assert change[ch] == pytest.approx(sign, abs=1e-6)
        others = [c for c in range(3) if c != ch]
        assert np.allclose(change[others], 0.0) and np.allclose(sorted(a[others]), [0.0, 1.0])


def test_hsi_hue_of_trapezoid_is_only_nearly_linear_and_monotonic():
    phi = np.linspace(0, TWO_PI, 60000, endpoint=False)
    h = colour.hue_hsi(trapezoid_rgb(phi)).astype(np.float64)
    err = np.abs(circ(h, phi))
    assert 0.01 < err.max() < 0.2  # about 0.0195 rad, eqs. 4-5 are an approximation
    steps = circ(np.roll(h, -1), h)
    assert np.all(steps > 0)  # strictly increasing round the circle
    assert abs(steps.sum() - TWO_PI) < 1e-6  # winds exactly once
    # the deviation is zero at the sextant boundaries and mid-sextant (symmetry)
    nodes = np.arange(12) * np.pi / 6
    assert np.max(np.abs(circ(colour.hue_hsi(trapezoid_rgb(nodes)), nodes))) < 1e-6


def test_hue_linearity_report():
    hx, hs = colour.hue_linearity("hexcone"), colour.hue_linearity("hsi")
    assert hx["max_rad"] < 1e-6 and hx["rms_rad"] < 1e-6
    assert 0.01 < hs["max_rad"] < 0.2
    assert 0.005 < hs["rms_rad"] < hs["max_rad"]


# ------------------------------------------------------------------ eqs. 1-2 details
def test_hsi_atan2_form_equals_literal_eqs_1_2():
    rng = np.random.default_rng(3)
    rgb = rng.random((50000, 3))
    # include the G == B ray (eq. 2 branch) and near-clamp cases
    rgb[:500, 2] = rgb[:500, 1]
    rgb[500:1000] = rng.random((500, 1)) * np.array([1.0, 1e-9, 0.0]) + np.array([0.5, 0.2, 0.2])
    a = colour.hue_hsi(rgb)
    b = colour.hue_hsi_arccos(rgb)
    assert np.max(np.abs(circ(a, b))) < 1e-6


@pytest.mark.parametrize(
    ("rgb", "expected"),
    [
        ((1.0, 0.0, 0.0), 0.0),  # B >= G branch gives 2 pi - 0, wrapped to 0
        ((1.0, 0.5, 0.5), 0.0),
        ((0.0, 1.0, 1.0), np.pi),  # cyan, on the B == G ray
        ((1.0, 1.0, 0.0), np.pi / 3),
        ((0.0, 1.0, 0.0), 2 * np.pi / 3),
        ((0.0, 0.0, 1.0), 4 * np.pi / 3),
        ((1.0, 0.0, 1.0), 5 * np.pi / 3),
    ],
)
def test_primary_and_secondary_hues_both_models(rgb, expected):
    for f in (colour.hue_hsi, colour.hue_hsi_arccos, colour.hue_hexcone):
        h = float(f(np.array(rgb)))
        assert 0.0 <= h < TWO_PI
        assert abs(circ(h, expected)) < 1e-6, f.__name__


def test_hue_just_below_two_pi_stays_in_range():
    rgb = np.array([[1.0, 0.0, 1e-7], [1.0, 0.0, 1e-30]], dtype=np.float32)
    for model in colour.HUE_MODELS:
        h = colour.hue(rgb, model)
        assert np.all((h >= 0) & (h < TWO_PI))
        assert np.all(np.abs(circ(h, 0.0)) < 1e-5)


# ------------------------------------------------------------------ undefined hue
def test_grey_pixels_have_nan_hue():
    rgb = np.array([[0.5, 0.5, 0.5], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.2, 0.1]])
    for model in colour.HUE_MODELS:
        h = colour.hue(rgb, model)
        assert np.isnan(h[:3]).all() and np.isfinite(h[3])
        assert not colour.chromatic_mask(rgb, model)[:3].any()
    assert np.isnan(colour.hue_hsi_arccos(rgb[:3])).all()


def test_low_saturation_and_low_intensity_thresholds_flag_pixels():
    rgb = np.array([[0.50, 0.49, 0.48],  # nearly grey: S = 0.04 (hexcone)
                    [0.02, 0.01, 0.00],  # dark but saturated: I = 0.01
                    [0.90, 0.30, 0.10]])
    h = colour.hue(rgb, "hexcone", min_saturation=0.05, min_intensity=0.05)
    assert np.isnan(h[0]) and np.isnan(h[1]) and np.isfinite(h[2])
    h = colour.hue(rgb, "hexcone")  # defaults: only exact greys are NaN
    assert np.isfinite(h).all()
    m = colour.chromatic_mask(rgb, "hsi", min_saturation=0.05, min_intensity=0.05)
    assert m.tolist() == [False, False, True]


def test_saturation_and_intensity_values():
    rgb = np.array([[1.0, 0.5, 0.0], [0.6, 0.3, 0.3], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(colour.saturation(rgb, "hexcone"), [1.0, 0.5, 0.0], atol=1e-7)
    np.testing.assert_allclose(colour.saturation(rgb, "hsi"), [1.0, 1 - 3 * 0.3 / 1.2, 0.0], atol=1e-7)
    np.testing.assert_allclose(colour.intensity(rgb), [0.5, 0.4, 0.0], atol=1e-7)
    with pytest.raises(ValueError):
        colour.hue(rgb, "hsv")  # type: ignore[arg-type]


# ------------------------------------------------------------------ white balance
def test_white_balance_removes_per_pixel_per_channel_gains():
    rng = np.random.default_rng(0)
    h, w = 12, 17
    gain = rng.uniform(0.05, 0.95, (h, w, 3)).astype(np.float32)  # alpha_k r_k per pixel
    phi = rng.uniform(0, TWO_PI, (h, w))
    scene = trapezoid_rgb(phi).astype(np.float32)
    bal = colour.white_balance(scene * gain, gain)
    assert bal.dtype == np.float32
    np.testing.assert_allclose(bal, scene, atol=1e-6)
    assert np.max(np.abs(circ(colour.hue(bal), phi))) < 1e-5
    # without white balance the hue of a coloured surface is wrong
    assert np.max(np.abs(circ(colour.hue(scene * gain), phi))) > 0.3


def test_white_balance_floor_bounds_gain_on_black_pixels():
    white = np.zeros((2, 2, 3), np.float32)
    white[0, 0] = (0.8, 0.0, 0.8)
    img = np.full((2, 2, 3), 0.01, np.float32)
    bal = colour.white_balance(img, white, floor=0.02)
    assert np.isfinite(bal).all()
    assert bal.max() <= 0.01 / 0.02 + 1e-6
    assert colour.white_gains(white, 0.02).max() == pytest.approx(50.0)
    with pytest.raises(ValueError):
        colour.white_gains(white, 0.0)


# ------------------------------------------------------------------ fused fast path
@pytest.mark.parametrize("model", colour.HUE_MODELS)
def test_balanced_hue_kernel_matches_numpy(model):
    rng = np.random.default_rng(7)
    img = rng.random((40, 50, 3)).astype(np.float32)
    img[:3] = img[:3, :, :1]  # some exact greys
    white = rng.uniform(0.0, 1.0, (40, 50, 3)).astype(np.float32)
    white[:3] = white[:3, :, :1]  # grey white there too, so the balanced colour stays grey
    gains = colour.white_gains(white, 0.05)
    ref = colour.hue(img * gains, model, min_saturation=0.1)
    fast = colour.balanced_hue(img, gains, model, min_saturation=0.1)
    s = colour.saturation(img * gains, model)
    borderline = np.abs(s - 0.1) < 1e-6
    same_nan = np.isnan(ref) == np.isnan(fast)
    assert np.all(same_nan | borderline)
    both = np.isfinite(ref) & np.isfinite(fast)
    assert np.isnan(fast[:3]).all()
    assert np.max(np.abs(circ(ref[both], fast[both]))) < 1e-6


def test_float32_and_float64_inputs_agree():
    rng = np.random.default_rng(1)
    x = rng.random((1000, 3))
    for model in colour.HUE_MODELS:
        a = colour.hue(x, model)
        b = colour.hue(x.astype(np.float32), model)
        assert np.max(np.abs(circ(a, b))) < 2e-6


# ------------------------------------------------------------------ properties
rgb_arrays = arrays(np.float64, st.tuples(st.integers(1, 20), st.just(3)),
                    elements=st.floats(0.0, 1.0, allow_nan=False, allow_infinity=False))


@settings(max_examples=200, deadline=None)
@given(rgb_arrays, st.sampled_from(colour.HUE_MODELS), st.booleans())
def test_hue_is_in_range_or_nan_for_any_rgb(rgb, model, as_f32):
    x = rgb.astype(np.float32) if as_f32 else rgb
    h = colour.hue(x, model)
    assert h.dtype == np.float32 and h.shape == rgb.shape[:1]
    fin = h[~np.isnan(h)]
    assert np.all((fin >= 0) & (fin < TWO_PI))
    # NaN exactly where the colour is grey (max == min)
    grey = x.max(axis=1) == x.min(axis=1)
    assert np.array_equal(np.isnan(h), grey)
    s = colour.saturation(x, model)
    assert np.all((s >= 0) & (s <= 1 + 1e-6))
    g = colour.balanced_hue(x.reshape(1, -1, 3), np.ones((1, x.shape[0], 3), np.float32), model)[0]
    assert np.array_equal(np.isnan(g), grey)
    assert np.all((g[~grey] >= 0) & (g[~grey] < TWO_PI))


@settings(max_examples=150, deadline=None)
@given(arrays(np.float64, (3,), elements=st.floats(0.05, 1.0)), st.floats(0.1, 10.0),
       st.sampled_from(colour.HUE_MODELS))
def test_hue_is_scale_invariant(rgb, k, model):
    if np.ptp(rgb) < 1e-3:
        return  # near grey: hue ill-conditioned
    a, b = colour.hue(rgb, model), colour.hue(rgb * k, model)
    assert abs(circ(a, b)) < 1e-4


def test_any_channel_at_least_is_the_any_of_its_channels() -> None:
    """The clipped-code mask channel by channel equals ``np.any(rgb >= top, axis=-1)``, codes at
    the top included, for 8- and 16-bit codes and float images."""
    from huefringe.colour import any_channel_at_least

    rng = np.random.default_rng(3)
    for dtype, top in ((np.uint8, 255), (np.uint16, 65535), (np.float32, 1.0 - 0.5 / 255)):
        if dtype == np.float32:
            a = rng.random((40, 50, 3)).astype(np.float32)
        else:
            a = rng.integers(top - 3, top + 1, (40, 50, 3), endpoint=False).astype(dtype)
            a[::2] //= 2
        want = np.any(a >= top, axis=-1)
        assert 0 < want.sum() < want.size
        assert np.array_equal(any_channel_at_least(a, top), want)
