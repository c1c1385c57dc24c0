"""Tests of huefringe.metrology on synthetic height maps with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from huefringe.metrology import (
    MetrologyError,
    central_box,
    coverage,
    evaluate_session,
    fit_plane,
    flatness,
    step_height,
)

PITCH = 0.2
H, W = 480, 640
BASE_C = (0.5, 0.002, -0.0015)  # z = c0 + c1 X + c2 Y on the base, mm
SPECIMEN = {
    "kind": "step_heights",
    "base_roi": [[10, 10, 620, 60], [10, 400, 620, 470]],
    "steps": [
        {"name": "green", "nominal_mm": 3.0, "roi": [100, 150, 220, 330]},
        {"name": "blue", "nominal_mm": 1.0, "roi": [260, 150, 380, 330]},
        {"name": "red", "nominal_mm": 4.0, "roi": [420, 150, 540, 330]},
    ],
    "tolerance_mm": 0.05,
}
NOMINAL = {s["name"]: s["nominal_mm"] for s in SPECIMEN["steps"]}


def base_plane(c=BASE_C) -> np.ndarray:
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    return c[0] + c[1] * u * PITCH + c[2] * v * PITCH


def make_map(offset=0.0, heights=None, noise=0.0, rng=None, top_extra=None) -> np.ndarray:
    """Tilted base + blocks (footprint = ROI grown by 10 px) + rigid offset + optional noise."""
    heights = heights or NOMINAL
    z = base_plane()
    for s in SPECIMEN["steps"]:
        u0, v0, u1, v1 = s["roi"]
        z[v0 - 10 : v1 + 10, u0 - 10 : u1 + 10] += heights[s["name"]]
        if top_extra is not None and s["name"] in top_extra:
            z[v0:v1, u0:u1] += top_extra[s["name"]]
    z += offset
    if noise:
        z += rng.normal(0.0, noise, z.shape)
    return z.astype(np.float32)


def make_frames(n=10, noise=0.0, seed=1, deltas=None) -> list[np.ndarray]:
    """n frames with rigid vertical offsets; ``deltas[name][i]`` is added to step i's height."""
    rng = np.random.default_rng(seed)
    offsets = rng.uniform(-0.3, 0.3, n)
    frames = []
    for i in range(n):
        hts = {k: v + (deltas[k][i] if deltas and k in deltas else 0.0) for k, v in NOMINAL.items()}
        frames.append(make_map(offsets[i], hts, noise, rng))
    return frames


# ------------------------------------------------------------------------------------------


def test_central_box_rule():
    assert central_box([100, 150, 220, 330]) == (140, 210, 180, 270)  # 120 x 180 -> 40 x 60
    assert central_box([0, 0, 100, 99]) == (34, 33, 66, 66)  # ceil(33.33) = 34 excluded, ceil(33) = 33
    assert central_box([5, 5, 25, 15], 0.0) == (5, 5, 25, 15)
    assert central_box([0, 0, 10, 20], 0.25) == (3, 5, 7, 15)  # ceil(2.5) = 3, 20/4 = 5
    assert central_box([0, 0, 3, 3], 0.49) == (1, 1, 2, 2)  # at least one pixel is kept
    with pytest.raises(ValueError, match="edge_exclusion"):
        central_box([0, 0, 10, 10], 0.5)


def test_fit_plane_recovers_tilt_noise_free():
    z = make_map(offset=0.25)
    coeffs, rms = fit_plane(z, SPECIMEN["base_roi"], PITCH)
    np.testing.assert_allclose(coeffs, [BASE_C[0] + 0.25, BASE_C[1], BASE_C[2]], atol=2e-7)
    assert rms < 1e-6


def test_fit_plane_noise_rms():
    rng = np.random.default_rng(3)
    z = make_map(noise=0.01, rng=rng)
    coeffs, rms = fit_plane(z, SPECIMEN["base_roi"], PITCH)
    assert rms == pytest.approx(0.01, rel=0.02)
    np.testing.assert_allclose(coeffs[1:], BASE_C[1:], atol=2e-5)


def test_steps_recovered_noise_free_with_tilt_and_offsets():
    frames = make_frames(10)
    res = evaluate_session(frames, SPECIMEN, PITCH, range_mm=4.0)
    assert res["frames"] == 10
    for s in res["steps"]:
        err = np.abs(np.asarray(s["per_frame_mm"]) - NOMINAL[s["name"]])
        assert err.max() < 2e-3  # the brief: < 2 um
        assert err.max() < 1e-5  # float32 storage is the only error source here
    # the per-frame planes follow the rigid offsets and keep the tilt
    planes = np.asarray(res["base"]["plane_per_frame"])
    np.testing.assert_allclose(planes[:, 1], BASE_C[1], atol=2e-7)
    np.testing.assert_allclose(planes[:, 2], BASE_C[2], atol=2e-7)
    assert np.ptp(planes[:, 0]) > 0.1


def test_tilt_removal_matters():
    """Without the tilt the green/red steps would be off by ~60 um: the fit removes it."""
    z = make_map()
    coeffs, _ = fit_plane(z, SPECIMEN["base_roi"], PITCH)
    base_pixels = np.concatenate([z[v0:v1, u0:u1].ravel() for u0, v0, u1, v1 in SPECIMEN["base_roi"]])
    level = np.array([base_pixels.mean(), 0.0, 0.0])
    green = SPECIMEN["steps"][0]["roi"]
    naive = step_height(z, level, green, PITCH)
    good = step_height(z, coeffs, green, PITCH)
    assert abs(naive - 3.0) > 0.03
    assert abs(good - 3.0) < 2e-6


def test_normal_distance():
    z = make_map()
    coeffs, _ = fit_plane(z, SPECIMEN["base_roi"], PITCH)
    roi = SPECIMEN["steps"][2]["roi"]
    vert = step_height(z, coeffs, roi, PITCH)
    norm = step_height(z, coeffs, roi, PITCH, normal=True)
    assert norm == pytest.approx(vert / math.sqrt(1 + BASE_C[1] ** 2 + BASE_C[2] ** 2), rel=1e-12)
    assert vert - norm == pytest.approx(4.0 * (BASE_C[1] ** 2 + BASE_C[2] ** 2) / 2, rel=1e-3)


def test_edge_exclusion_ignores_corrupted_edge_band():
    z = make_map().astype(np.float64)
    u0, v0, u1, v1 = SPECIMEN["steps"][1]["roi"]  # blue, 120 x 180 px -> margins 40 and 60 px
    band = 12
    z[v0:v1, u0 : u0 + band] += 0.3  # edge smear / ringing on all four sides
    z[v0:v1, u1 - band : u1] += 0.3
    z[v0 : v0 + band, u0:u1] -= 0.2
    z[v1 - band : v1, u0:u1] += 0.5
    z[v0:v1, u0 + 5 : u0 + 8] = np.nan  # and a shadow line
    z = z.astype(np.float32)
    coeffs, _ = fit_plane(z, SPECIMEN["base_roi"], PITCH)
    assert abs(step_height(z, coeffs, [u0, v0, u1, v1], PITCH) - 1.0) < 2e-6
    whole = step_height(z, coeffs, [u0, v0, u1, v1], PITCH, edge_exclusion=0.0)
    assert abs(whole - 1.0) > 0.05  # the corruption is real: without exclusion it biases the result


def test_statistics_against_numpy():
    rng = np.random.default_rng(7)
    n = 10
    deltas = {"green": rng.normal(0, 0.01, n), "blue": rng.normal(0.004, 0.006, n), "red": np.zeros(n)}
    frames = make_frames(n, noise=0.008, seed=11, deltas=deltas)
    res = evaluate_session(frames, SPECIMEN, PITCH, range_mm=4.0)
    for s in res["steps"]:
        pf = np.asarray(s["per_frame_mm"])
        truth = NOMINAL[s["name"]] + deltas[s["name"]]
        np.testing.assert_allclose(pf, truth, atol=1e-3)  # noise of a 2400-px mean: 0.16 um
        assert s["mean_mm"] == pytest.approx(np.mean(pf), rel=1e-13, abs=1e-15)
        assert s["std_mm"] == pytest.approx(np.std(pf, ddof=1), rel=1e-12)
        assert s["repeatability_3sigma_mm"] == pytest.approx(3 * np.std(pf, ddof=1), rel=1e-12)
        assert s["error_mm"] == s["mean_mm"] - s["nominal_mm"]
        assert s["error_pct_of_range"] == pytest.approx(100 * s["error_mm"] / 4.0, rel=1e-12)
        if s["name"] != "red":
            # std of the injected deltas, not of anything else (ddof=1, not 0)
            assert s["std_mm"] == pytest.approx(np.std(truth, ddof=1), rel=0.05)
            assert s["std_mm"] != pytest.approx(np.std(truth, ddof=0), rel=0.02)
    blue = res["steps"][1]
    assert blue["mean_mm"] == pytest.approx(1.0 + deltas["blue"].mean(), abs=1e-4)
    # flatness of the noisy tops: Sq ~ per-pixel noise, Sa ~ sqrt(2/pi) sigma
    assert blue["flatness"]["Sq_mm"] == pytest.approx(0.008, rel=0.05)
    assert blue["flatness"]["Sa_mm"] == pytest.approx(0.008 * math.sqrt(2 / math.pi), rel=0.05)


def test_error_pct_is_exactly_the_contract_formula():
    deltas = {"green": np.full(4, 0.021), "blue": np.linspace(-0.01, 0.03, 4), "red": np.full(4, -0.013)}
    res = evaluate_session(make_frames(4, deltas=deltas), SPECIMEN, PITCH, range_mm=4.0)
    for s in res["steps"]:
        assert s["error_pct"] == 100 * (s["mean_mm"] - s["nominal_mm"]) / s["nominal_mm"]
    assert res["steps"][0]["error_pct"] == pytest.approx(100 * 0.021 / 3.0, rel=1e-4)
    assert res["steps"][2]["error_pct"] == pytest.approx(-100 * 0.013 / 4.0, rel=1e-4)


def test_pass_flips_at_the_tolerance():
    deltas = {"red": np.full(5, 0.03)}
    frames = make_frames(5, deltas=deltas)
    res = evaluate_session(frames, SPECIMEN, PITCH, range_mm=4.0)
    err = abs(res["steps"][2]["error_mm"])
    assert err == pytest.approx(0.03, abs=1e-5)
    spec = dict(SPECIMEN)
    outcomes = {}
    for tol in (0.029, np.nextafter(err, 0.0), err, 0.031):
        spec["tolerance_mm"] = float(tol)
        r = evaluate_session(frames, spec, PITCH, range_mm=4.0)
        outcomes[float(tol)] = (r["steps"][2]["pass"], r["verdict"])
        assert r["steps"][0]["pass"] and r["steps"][1]["pass"]
    assert list(outcomes.values()) == [(False, "FAIL"), (False, "FAIL"), (True, "PASS"), (True, "PASS")]


def test_flatness_of_sinusoidal_top_matches_analytic():
    amp = 0.01
    z = make_map().astype(np.float64)
    roi = SPECIMEN["steps"][1]["roi"]
    eu0, ev0, eu1, ev1 = central_box(roi)
    n = eu1 - eu0  # 40 px, 2 periods of 20 px, symmetric about the box centre
    centre = eu0 + (n - 1) / 2
    u = np.arange(W, dtype=np.float64)
    wave = amp * np.cos(2 * np.pi * 2 * (u - centre) / n)
    v0, v1 = roi[1], roi[3]
    z[v0:v1, roi[0] : roi[2]] += wave[roi[0] : roi[2]]
    # a tilt of the top itself must be levelled away
    vv, uu = np.mgrid[0:H, 0:W]
    z[v0:v1, roi[0] : roi[2]] += (0.003 * uu * PITCH - 0.002 * vv * PITCH)[v0:v1, roi[0] : roi[2]]
    fl = flatness(z, roi, PITCH)
    assert fl["pixels"] == 40 * 60
    assert fl["Sq_mm"] == pytest.approx(amp / math.sqrt(2), rel=1e-6)
    assert fl["Sa_mm"] == pytest.approx(2 * amp / math.pi, rel=5e-3)
    assert fl["Sz_mm"] == pytest.approx(2 * amp, rel=2e-2)  # samples miss the crest by half a pixel
    assert fl["Sz_mm"] == pytest.approx(fl["Sp_mm"] + fl["Sv_mm"], rel=1e-12)
    assert fl["Sp_mm"] == pytest.approx(fl["Sv_mm"], rel=1e-6)
    # the same through evaluate_session, and a flat top stays flat
    res = evaluate_session([z.astype(np.float32)], SPECIMEN, PITCH, range_mm=4.0)
    blue = res["steps"][1]
    assert blue["flatness"]["Sq_mm"] == pytest.approx(amp / math.sqrt(2), rel=1e-4)
    assert res["steps"][0]["flatness"]["Sq_mm"] < 1e-5
    assert blue["std_mm"] is None and blue["repeatability_3sigma_mm"] is None  # one frame


def test_nan_only_map_is_refused():
    nan_map = np.full((H, W), np.nan, dtype=np.float32)
    with pytest.raises(MetrologyError, match=r"frame 1: .*no valid pixel \(all NaN\)") as info:
        evaluate_session([make_map(), nan_map], SPECIMEN, PITCH, range_mm=4.0)
    assert info.value.frame == 1
    with pytest.raises(MetrologyError, match="no valid pixel"):
        fit_plane(nan_map, SPECIMEN["base_roi"], PITCH)


def test_roi_without_valid_pixels_is_named():
    z = make_map()
    u0, v0, u1, v1 = SPECIMEN["steps"][1]["roi"]
    z[v0:v1, u0:u1] = np.nan
    with pytest.raises(MetrologyError, match=r"ROI 'blue'.*no valid pixel") as info:
        evaluate_session([make_map(), z], SPECIMEN, PITCH, range_mm=4.0)
    assert info.value.roi == "blue" and info.value.frame == 1
    assert coverage(z, [u0, v0, u1, v1]) == 0.0

    z = make_map()
    u0, v0, u1, v1 = SPECIMEN["base_roi"][1]
    z[v0:v1, u0:u1] = np.nan
    with pytest.raises(MetrologyError, match=r"ROI 'base_roi\[1\]'") as info:
        evaluate_session([z], SPECIMEN, PITCH, range_mm=4.0)
    assert info.value.roi == "base_roi[1]"


def test_low_coverage_threshold():
    z = make_map()
    eu0, ev0, eu1, ev1 = central_box(SPECIMEN["steps"][0]["roi"])
    z[ev0:ev1, eu0 : eu0 + 24] = np.nan  # 60 % of the evaluated green box
    with pytest.raises(MetrologyError, match=r"ROI 'green'.*too few valid pixels.*40\.0 %"):
        evaluate_session([z], SPECIMEN, PITCH, range_mm=4.0)
    res = evaluate_session([z], SPECIMEN, PITCH, range_mm=4.0, min_coverage=0.3)
    green = res["steps"][0]
    assert green["coverage"]["evaluated"] == pytest.approx(0.4)
    assert green["coverage"]["roi"] == pytest.approx(1 - 24 * 60 / (120 * 180))
    assert abs(green["mean_mm"] - 3.0) < 2e-6


def test_bad_boxes_and_inputs():
    z = make_map()
    spec = dict(SPECIMEN, steps=[{"name": "wide", "nominal_mm": 1.0, "roi": [600, 10, 700, 50]}])
    with pytest.raises(MetrologyError, match=r"ROI 'wide'.*not inside"):
        evaluate_session([z], spec, PITCH, range_mm=4.0)
    with pytest.raises(MetrologyError, match="no height map"):
        evaluate_session([], SPECIMEN, PITCH, range_mm=4.0)
    with pytest.raises(MetrologyError, match="differs"):
        evaluate_session([z, z[:-1]], SPECIMEN, PITCH, range_mm=4.0)
    with pytest.raises(ValueError, match="range_mm"):
        evaluate_session([z], SPECIMEN, PITCH, range_mm=0.0)
    with pytest.raises(MetrologyError, match="nominal_mm"):
        evaluate_session([z], dict(SPECIMEN, steps=[dict(SPECIMEN["steps"][0], nominal_mm=0)]), PITCH, range_mm=4.0)
    with pytest.raises(MetrologyError, match="collinear"):
        fit_plane(z, [[10, 10, 620, 11]], PITCH)


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=25, deadline=None)
@given(
    c1=st.floats(-0.01, 0.01),
    c2=st.floats(-0.01, 0.01),
    offset=st.floats(-5.0, 5.0),
    nominal=st.floats(0.05, 8.0),
)
def test_step_height_invariant_to_rigid_tilt_and_offset(c1, c2, offset, nominal):
    """Any tilt/offset of the whole specimen is removed; vertical distance = nominal exactly."""
    h, w = 60, 90
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = offset + c1 * u * PITCH + c2 * v * PITCH
    z[18:42, 30:60] += nominal
    coeffs, rms = fit_plane(z, [[2, 2, 88, 12], [2, 48, 88, 58]], PITCH)
    np.testing.assert_allclose(coeffs, [offset, c1, c2], atol=1e-9)
    assert rms < 1e-9
    assert step_height(z, coeffs, [30, 18, 60, 42], PITCH) == pytest.approx(nominal, abs=1e-9)
    slope2 = c1**2 + c2**2
    assert step_height(z, coeffs, [30, 18, 60, 42], PITCH, normal=True) == pytest.approx(nominal / math.sqrt(1 + slope2), abs=1e-9)


def test_maps_are_taken_one_at_a_time():
    """A generator of maps (the metrology stage reads each TIFF as it goes) gives the list's
    result, key for key, without the maps being held together; a later frame of another
    shape is refused by its index."""
    import weakref

    frames = make_frames(6, noise=0.002, seed=3)
    alive: list[weakref.ref] = []

    def one_by_one():
        for z in frames:
            # every map but the first and the one evaluated last is already released
            assert all(r() is None for r in alive[1:-1])
            c = z.copy()
            alive.append(weakref.ref(c))
            yield c
            del c

    as_list = evaluate_session(frames, SPECIMEN, PITCH, range_mm=4.0)
    streamed = evaluate_session(one_by_one(), SPECIMEN, PITCH, range_mm=4.0)
    assert streamed == as_list
    assert streamed["frames"] == 6 and streamed["steps"][0]["std_mm"] > 0
    with pytest.raises(MetrologyError) as err:
        evaluate_session(iter([frames[0], frames[1], frames[2][:-1]]), SPECIMEN, PITCH, range_mm=4.0)
    assert err.value.frame == 2
