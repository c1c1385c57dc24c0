"""Per-pixel noise that is estimated, never assumed (docs/noise.md): the single repeat's
second-difference estimator, the refusal of a table without a figure, the noise-aware step-edge
tests and the bench's electron read noise."""

from __future__ import annotations

import numpy as np
import pytest

from huefringe import patterns
from huefringe.huetable import HueTable, HueTableError, build_table
from huefringe.perframe import capture_noise, height_noise, plane_edge_mask, remove_step_edges, step_edge_mask

GAMMA = np.array([1.9, 2.4, 2.1])


def _bands(n_bands: int, repeats: int, seed: int) -> tuple[list[list[tuple[int, int]]], object, np.ndarray]:
    """Synthetic hue bands: per-channel gamma, a reflectance that darkens along u (0.08-0.9 of the
    white), Gaussian read noise of 0.004 full scale; ``read((band, repeat))`` makes each image."""
    h, w = 12, 60
    refl = np.linspace(0.08, 0.9, w)[None, :, None] * np.ones((h, 1, 1))
    rng = np.random.default_rng(seed)

    def read(key: tuple[int, int]) -> np.ndarray:
        i, r = key
        rgb = patterns.band_rgb(i, n_bands) ** GAMMA
        img = refl * (0.05 + 0.9 * rgb)[None, None, :]
        return np.clip(img + rng.normal(0.0, 0.004, img.shape), 0.0, 1.0).astype(np.float32)

    white = np.repeat(refl * 0.95, 3, axis=2).astype(np.float32)
    return [[(i, r) for r in range(repeats)] for i in range(n_bands)], read, white


def test_one_repeat_noise_from_the_second_difference_matches_the_repeats_figure() -> None:
    """With one repeat the table's per-pixel noise is the third difference along the bands of
    each sextant, sqrt(mean(d3^2) / 20): within 8 % of the spread of 12 repeats (dof 792) in each
    brightness third, dark (0.4 rad) to bright (0.01 rad); its source is recorded."""
    n = 72
    paths, read, white = _bands(n, 12, seed=1)
    many = build_table(paths, white, read=read, min_intensity=0.01)
    truth = many.noise_rad.astype(np.float64) * np.sqrt(12)
    paths1, read1, _ = _bands(n, 1, seed=2)
    one = build_table(paths1, white, read=read1, min_intensity=0.01)
    assert one.stats["noise_rad"]["source"] == "band_difference"
    assert many.stats["noise_rad"]["source"] == "repeats"
    est = one.noise_rad.astype(np.float64)
    ok = one.valid & many.valid
    assert ok.mean() > 0.9
    thirds = np.array_split(np.arange(white.shape[1]), 3)
    ratios = [np.sqrt(np.mean(est[:, c][ok[:, c]] ** 2) / np.mean(truth[:, c][ok[:, c]] ** 2)) for c in thirds]
    assert all(abs(r - 1.0) < 0.08 for r in ratios), ratios
    dark, bright = (np.median(truth[:, c][ok[:, c]]) for c in (thirds[0], thirds[-1]))
    assert dark > 3 * bright  # the case spans a real range of noise


def test_capture_noise_refuses_a_table_without_a_noise_figure() -> None:
    """No constant is assumed: a table whose noise is NaN everywhere is refused with the cause."""
    shape = (3, 4)
    t = HueTable(model="hexcone", n_bands=6, table=np.zeros((6, *shape), np.uint16), valid=np.ones(shape, bool),
                 start=np.zeros(shape, np.uint16), reason=np.zeros(shape, np.uint8),
                 noise_rad=np.full(shape, np.nan, np.float32), stats={"repeats": 1})
    with pytest.raises(HueTableError, match="no per-pixel noise"):
        capture_noise(t)
    t.noise_rad[0, 0] = 0.02
    t.noise_rad[1, 1] = 0.04
    got = capture_noise(t)
    assert got[0, 0] == pytest.approx(0.02) and got[1, 1] == pytest.approx(0.04)
    assert got[2, 3] == pytest.approx(0.03)  # the others: the median of the known ones


@pytest.mark.parametrize("test, k", [("pair", 3.0), ("plane", 3.0), ("plane", 1.5), ("pair", 0.0)])
def test_noise_aware_edge_tests_equal_their_numpy_definitions(test: str, k: float) -> None:
    """The compiled passes with a noise map (NaN and inf among heights, NaN among the noise) mark
    exactly the NumPy definitions' pixels; noise_k 0 is the fixed test."""
    rng = np.random.default_rng(7)
    for shape in ((48, 64), (47, 63), (3, 2)):
        h = rng.normal(0.0, 0.08, shape).astype(np.float32) + np.linspace(0, 3, shape[1], dtype=np.float32)
        h[10:30, 20:40] += 1.0
        h[rng.random(shape) < 0.1] = np.nan
        h[1, 1] = np.inf
        s = rng.uniform(0.0, 0.12, shape).astype(np.float32)
        s[rng.random(shape) < 0.05] = np.nan
        got_h, (), (), st = remove_step_edges(h, 0.25, test=test, tol_mm=0.1, noise=s, noise_k=k)
        want = (plane_edge_mask(h, 0.25, 0.1, s, k) if test == "plane" else step_edge_mask(h, 0.25, s, k))
        assert np.array_equal(got_h, np.where(want, np.float32(np.nan), h), equal_nan=True)
        assert st["edge_fraction"] == float(want.mean())
        if k == 0:
            fixed = plane_edge_mask(h, 0.25, 0.1) if test == "plane" else step_edge_mask(h, 0.25)
            assert np.array_equal(want, fixed)


def test_a_jump_the_noise_explains_is_no_edge_a_step_still_is() -> None:
    """Noisy heights (sigma 0.1 mm) on a plane with a 2 mm step: the fixed tests cut a large part
    of the noisy pixels as edges; with noise_k = 3 almost none, and both sides of the step go (all
    rows with the pair test, more than 95 % with the plane test)."""
    rng = np.random.default_rng(11)
    shape = (60, 80)
    sigma = np.full(shape, 0.1, np.float32)
    h = rng.normal(0.0, 0.1, shape).astype(np.float32)
    h[:, 40:] += 2.0
    for test in ("pair", "plane"):
        def mask(k: float) -> np.ndarray:
            return remove_step_edges(h, 0.25, test=test, tol_mm=0.1, noise=sigma, noise_k=k)[0]

        fixed, aware = ~np.isfinite(mask(0.0)), ~np.isfinite(mask(3.0))
        flat = np.ones(shape, bool)
        flat[:, 37:43] = False
        assert fixed[flat].mean() > 0.15, (test, fixed[flat].mean())
        assert aware[flat].mean() < 0.03, (test, aware[flat].mean())
        # the plane test's outlier line (3 z0 - 2 z1) carries 3.7 sigma of noise: k = 3 explains up to
        # 1.1 mm of it, so a few rows of a 20-sigma step stay (2 of 60 here)
        assert aware[:, 39].mean() > 0.95 and aware[:, 40].mean() > 0.95, (test, aware[:, 39:41].mean(axis=0))


def test_height_noise_is_the_phase_noise_through_the_height_model() -> None:
    """sigma_h = |dh/dphi| / sqrt(sumw), dh/dphi = a / (a + b dphi)^2 (checked by a difference
    quotient of the height model); NaN without weight or where invalid."""
    a = np.full((2, 3), 0.8, np.float32)
    b = np.full((2, 3), 0.05, np.float32)
    dphi = np.array([[0.1, -0.4, 1.2], [0.0, 0.5, 0.3]], np.float32)
    sumw = np.array([[1e4, 400.0, 2500.0], [0.0, 1e4, 1e4]], np.float32)
    valid = np.array([[True, True, True], [True, True, False]])
    got = height_noise(dphi, sumw, valid, a, b)
    d = 1e-4
    slope = ((dphi + d) / (a + b * (dphi + d)) - (dphi - d) / (a + b * (dphi - d))) / (2 * d)
    with np.errstate(divide="ignore"):
        want = np.abs(slope) / np.sqrt(sumw)
    assert np.allclose(got[0], want[0], rtol=1e-3)
    assert np.isnan(got[1, 0]) and np.isnan(got[1, 2]) and got[1, 1] == pytest.approx(want[1, 1], rel=1e-3)


def test_bench_read_noise_in_electrons() -> None:
    """camera.read_noise_e at full_well_e electrons per full scale gives read_noise_dn =
    e * (2^bits - 1) / full_well_e; without full_well_e it is refused."""
    from huefringe import bench
    from huefringe.bench.radiometry import Rig

    cfg = bench.load_bench_config(bench.preset_path("photo_sensor"))
    rig = Rig.from_config(cfg)
    assert rig.read_noise_dn == pytest.approx(25.0 * 65535 / 10000)
    cfg["camera"]["full_well_e"] = None
    with pytest.raises(ValueError, match="full_well_e"):
        Rig.from_config(cfg)


def test_refused_blur_estimate_uncertainty_is_bounded_by_the_largest_blur() -> None:
    """A noise-dominated blur estimate (standard error 409 px^2, photo_sensor with two repeats)
    does not make the texture term move the blur beyond MAX_BLUR_PX2 (rectangular: / sqrt 3)."""
    from huefringe import texture

    rec = {"sigma2_px2": 0.0, "raw_px2": 15.1, "stderr_px2": 409.0, "rejected": "not significant"}
    assert texture.blur_uncertainty(rec) == pytest.approx(texture.MAX_BLUR_PX2 / np.sqrt(3.0))
    small = {"sigma2_px2": 0.0, "raw_px2": 0.07, "stderr_px2": 0.26, "rejected": "not significant"}
    assert texture.blur_uncertainty(small) == pytest.approx((0.07 + 0.78) / np.sqrt(3.0))


def test_noise_ratio_trusts_the_own_figure_below_the_pooled_one_where_its_propagation_holds() -> None:
    """``noise_ratio2`` by its definition: the own figure squared over the pooled one where it is
    above it or below ``OWN_TRUSTED_RAD``; the pooled figure (ratio 1) below it from twice that on,
    linearly between; NaN -> 1."""
    from huefringe.perframe import OWN_TRUSTED_RAD, noise_ratio2

    t = OWN_TRUSTED_RAD
    own = np.array([0.5 * t, 0.9 * t, 1.5 * t, 2.0 * t, 3.0 * t, 0.2, np.nan])
    pooled = np.array([t, 2.0 * t, 4.0 * t, 4.0 * t, 4.0 * t, 0.1, 0.1])
    lam = np.clip(own / t - 1.0, 0.0, 1.0)
    want = (own**2 + lam * np.maximum(pooled**2 - own**2, 0.0)) / pooled**2
    want[-1] = 1.0
    got = noise_ratio2(own, pooled)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert got[0] == pytest.approx(0.25) and got[3] == pytest.approx(0.25 + 0.75) and got[5] == pytest.approx(4.0)


def _chroma_bands(n_bands: int, repeats: int, seed: int, h: int = 24, w: int = 60
                  ) -> tuple[list[list[tuple[int, int]]], object, np.ndarray, np.ndarray]:
    """Like :func:`_bands`, with a chroma that varies along the bands (the band colour mixed with
    grey, 0.35-1 of it, once round the hue circle): the hue noise varies with the hue. Also returns
    each band's noise-free image, ``clean[i]``."""
    refl = np.linspace(0.08, 0.9, w)[None, :, None] * np.ones((h, 1, 1))
    rng = np.random.default_rng(seed)
    mix = 0.675 + 0.325 * np.cos(2.0 * np.pi * np.arange(n_bands) / n_bands)
    clean = np.array([refl * (0.05 + 0.9 * (mix[i] * patterns.band_rgb(i, n_bands) ** GAMMA + (1.0 - mix[i]) * 0.5))
                      for i in range(n_bands)], np.float32)

    def read(key: tuple[int, int]) -> np.ndarray:
        img = clean[key[0]]
        return np.clip(img + rng.normal(0.0, 0.004, img.shape), 0.0, 1.0).astype(np.float32)

    white = np.repeat(refl * 0.95, 3, axis=2).astype(np.float32)
    return [[(i, r) for r in range(repeats)] for i in range(n_bands)], read, white, clean


def test_noise_ratio_follows_each_hues_own_spread_on_bright_pixels() -> None:
    """The table's pooled noise is one figure per pixel over all its bands, while a hue's noise
    depends on its chroma. Synthetic bands whose chroma varies along the hue circle (24 bands x 3
    repeats, read noise 0.004 full scale), bright third of the pixels, 200 fresh draws of each
    band: the noise the ratio assigns, ``pooled sqrt(noise_ratio2(own, pooled))``, against each
    pixel's hue spread over the draws, median per band within 10 % on every band (measured
    0.975-1.043), including the 13 high-chroma bands whose spread is below 0.8 of the pooled
    figure, where the pooled figure alone (the ratio held at 1 or more) over-states it by
    1.26-1.76 x."""
    from huefringe import colour
    from huefringe.perframe import frame_hue_noise, noise_ratio2

    n = 24
    paths, read, white, clean = _chroma_bands(n, 3, seed=5)
    table = build_table(paths, white, read=read, min_intensity=0.01)
    assert table.stats.get("sensor_noise")
    pooled = capture_noise(table)
    gains = colour.white_gains(white)
    ok = table.valid.copy()
    ok[:, : 2 * white.shape[1] // 3] = False
    rng = np.random.default_rng(11)
    low, ratios, over = 0, [], []
    for i in range(n):
        draws = np.clip(clean[i][None] + rng.normal(0.0, 0.004, (200, *clean[i].shape)), 0.0, 1.0).astype(np.float32)
        hues = np.array([colour.hue(colour.white_balance(d, white), "hexcone") for d in draws], np.float64)
        spread = np.std(colour.wrap_pi(hues - hues[0]), axis=0, ddof=1)
        own = frame_hue_noise(table, clean[i], gains, "hexcone")
        assigned = pooled * np.sqrt(noise_ratio2(own, pooled))
        m = ok & np.isfinite(spread) & (spread > 0)
        ratios.append(float(np.median(assigned[m] / spread[m])))
        if np.median(spread[m] / pooled[m]) < 0.8:
            low += 1
            over.append(float(np.median(pooled[m] / spread[m])))
    assert low >= 3 and max(over) > 1.5, (low, over)  # high-chroma hues well below the pooled figure
    assert all(abs(r - 1.0) < 0.10 for r in ratios), np.round(ratios, 3)


def _shot_read_bands(n_bands: int, repeats: int, seed: int, flicker: float, gain: float, read_var: float,
                     h: int = 60, w: int = 120) -> tuple[list[list[tuple[int, int]]], object, np.ndarray]:
    """Hue bands (per-channel gamma, reflectance 0.08-0.9 across the columns) with the shot + read
    noise ``variance = gain * signal + read_var`` of each capture, every capture's brightness
    scaled by ``1 + flicker * N(0, 1)`` (the same factor on the three channels, as a projector
    whose output changes from capture to capture)."""
    refl = np.linspace(0.08, 0.9, w)[None, :, None] * np.ones((h, 1, 1))
    clean = np.array([refl * (0.05 + 0.9 * patterns.band_rgb(i, n_bands) ** GAMMA) for i in range(n_bands)],
                     np.float32)
    rng = np.random.default_rng(seed)

    def read(key: tuple[int, int]) -> np.ndarray:
        img = clean[key[0]] * (1.0 + flicker * rng.standard_normal())
        return np.clip(img + np.sqrt(gain * img + read_var) * rng.standard_normal(img.shape), 0.0, 1.0
                       ).astype(np.float32)

    white = np.repeat(refl * 0.95, 3, axis=2).astype(np.float32)
    return [[(i, r) for r in range(repeats)] for i in range(n_bands)], read, white


@pytest.mark.parametrize(("repeats", "seed"), [(1, 5), (1, 6), (1, 7), (2, 5), (3, 6)])
def test_sensor_noise_fitted_on_the_hue_recovers_the_shot_and_read_terms(repeats: int, seed: int) -> None:
    """The shot + read model fitted on the bands' hue (``huetable.fit_hue_noise``: with repeats
    their hue spread, ``source: repeats``; with one repeat the hue's third differences along the
    bands, ``source: band_difference``) recovers the gain and the read term of every channel within
    15 % (72 bands, 60 x 120 px; measured 0.86-1.13 with one repeat over three seeds, 0.94-1.06 with
    two and three repeats), and a projector brightness that changes by 1 % from capture to capture
    does not move it beyond 2 % (the hue is the same at any brightness, while the channels' spread
    between repeats would take that flicker for noise)."""
    g, r = 6.7e-5, 6.8e-6
    fits = []
    for flicker in (0.0, 0.01):
        paths, read, white = _shot_read_bands(72, repeats, seed, flicker, g, r)
        m = build_table(paths, white, read=read, min_intensity=0.01).stats["sensor_noise"]
        assert m["source"] == ("repeats" if repeats >= 2 else "band_difference") and m["repeats"] == repeats
        for c in range(3):
            assert m["gain"][c] == pytest.approx(g, rel=0.15), (flicker, m["gain"])
            assert m["read"][c] == pytest.approx(r, rel=0.15), (flicker, m["read"])
            assert m["rel_rms"][c] < 0.1
        fits.append(np.array(m["gain"] + m["read"]))
    np.testing.assert_allclose(fits[1], fits[0], rtol=0.02)  # flicker: the same fit


def test_one_repeat_needs_runs_of_four_bands_inside_a_sextant() -> None:
    """Twelve bands hold two bands per sextant of the code, no run of four: captured once they give
    neither a per-pixel noise figure nor a sensor model, and the build refuses them naming the
    count and the remedies (not a table whose every u would be unknown); captured twice they have
    both. Nineteen bands hold one run of four (sextant 0): a per-pixel figure, a model from too few
    samples (None)."""
    assert [patterns.band_difference_runs(n) for n in (6, 12, 18, 19, 24, 64)] == [0, 0, 0, 1, 6, 46]
    paths, read, white = _shot_read_bands(12, 1, 3, 0.0, 6.7e-5, 6.8e-6)
    with pytest.raises(ValueError, match=r"12 hue bands captured once give no noise figure: .* at most 2 a sextant; "
                                         r"capture each band at least twice \(repeats >= 2\) or use at least 19 bands"):
        build_table(paths, white, read=read, min_intensity=0.01)
    assert patterns.single_repeat_problem(12, 2) is None and patterns.single_repeat_problem(19, 1) is None
    paths, read, white = _shot_read_bands(12, 2, 3, 0.0, 6.7e-5, 6.8e-6)
    assert build_table(paths, white, read=read, min_intensity=0.01).stats["sensor_noise"]["repeats"] == 2
    paths, read, white = _shot_read_bands(19, 1, 3, 0.0, 6.7e-5, 6.8e-6)
    t = build_table(paths, white, read=read, min_intensity=0.01)
    assert np.isfinite(t.noise_rad[t.valid]).all() and t.stats["noise_rad"]["source"] == "band_difference"
    assert t.stats["sensor_noise"] is None  # one run of 40 x 20 sampled pixels: under the fit's 1,000 samples


def test_one_repeat_sensor_fit_predicts_a_frames_hue_noise_as_the_repeats_fit_does(tmp_path) -> None:
    """On a bench session (the demo rig, small: 100 x 75 px, 32 bands x 3 repeats), the table built
    from the first repeat of each band alone predicts a frame's per-pixel hue noise
    (:func:`huefringe.perframe.frame_hue_noise`) as the table of all three repeats does: median
    ratio within 6 % and 80 % of the pixels within 12 % (measured 1.029-1.038, p10-p90 1.00-1.10
    over three seeds)."""
    import copy

    from huefringe import bench, colour, perframe
    from huefringe.session import load_session, read_rgb

    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("demo")))
    cfg["session"].update(width=100, height=75, pixel_pitch_mm=0.8, period_px=15, hue_bands=32, repeats=3, frames=1,
                          seed=2)
    cfg["phase_shift"]["enabled"] = False
    cfg["vibration"]["amplitude_mm"] = 0.0
    s = load_session(bench.write_session(cfg, tmp_path / "session"))
    white = read_rgb(s.object_white)
    three = build_table(s.object_bands, white, min_intensity=0.01)
    one = build_table([b[:1] for b in s.object_bands], white, min_intensity=0.01)
    assert one.stats["sensor_noise"]["source"] == "band_difference"
    rgb = read_rgb(s.frames[s.frame_ids[0]])
    gains = colour.white_gains(white)
    n3, n1 = (perframe.frame_hue_noise(t, rgb, gains, "hexcone") for t in (three, one))
    ok = three.valid & one.valid & np.isfinite(n1) & np.isfinite(n3)
    q = n1[ok] / n3[ok]
    assert ok.sum() > 5000
    assert abs(float(np.median(q)) - 1.0) < 0.06, float(np.median(q))
    lo, hi = np.quantile(q, [0.1, 0.9])
    assert lo > 0.88 and hi < 1.12, (lo, hi)


def test_hue_noise_fit_records_no_misfit_for_a_channel_that_never_dominates() -> None:
    """``fit_hue_noise``'s ``rel_rms`` is None (JSON has no NaN) for a channel whose terms carry
    half of no sample's prediction, and the record saves as strict JSON; the dominant channel's
    terms are recovered from noise-free expectations exactly."""
    import json

    from huefringe.huetable import fit_hue_noise

    rng = np.random.default_rng(2)
    x = np.zeros((4000, 6))
    x[:, 0] = rng.uniform(10.0, 200.0, 4000)  # gain R: signal times J^2
    x[:, 3] = rng.uniform(50.0, 300.0, 4000)  # read R: J^2
    x[:, 1] = rng.uniform(0.1, 2.0, 4000)  # G present, never dominant
    beta = np.array([6.7e-5, 6.7e-5, 0.0, 6.8e-6, 0.0, 0.0])
    m = fit_hue_noise(x, x @ beta, 2)
    assert m["rel_rms"][1] is None and m["rel_rms"][2] is None and m["rel_rms"][0] == pytest.approx(0.0, abs=1e-9)
    assert m["gain"][0] == pytest.approx(6.7e-5, rel=1e-6) and m["read"][0] == pytest.approx(6.8e-6, rel=1e-6)
    json.dumps(m, allow_nan=False)


def _uniform_table(h: int, w: int, gain: float, read: float) -> HueTable:
    """A table with a pooled figure of 0.03 rad and the shot + read model ``gain``, ``read`` on
    every channel (what :func:`perframe.weight_noise` reads of it)."""
    n = 16
    return HueTable(model="hexcone", n_bands=n, table=np.zeros((n, h, w), np.uint16), valid=np.ones((h, w), bool),
                    start=np.zeros((h, w), np.uint16), reason=np.zeros((h, w), np.uint8),
                    noise_rad=np.full((h, w), 0.03, np.float32),
                    stats={"repeats": 1, "sensor_noise": {"gain": [gain] * 3, "read": [read] * 3}})


def test_weight_noise_is_the_own_figure_of_the_smoothed_signal() -> None:
    """The filter's weights' noise: the pooled figure times ``sqrt(noise_ratio2)`` of the own
    figure of the capture through a Gaussian of ``blur_px`` (OpenCV), the same from codes with
    their scale as from float; None without a sensor model or without the blur."""
    import cv2

    from huefringe.perframe import frame_hue_noise, noise_ratio2, weight_noise

    rng = np.random.default_rng(2)
    h, w = 40, 50
    tab = _uniform_table(h, w, 2e-3, 1e-5)
    codes = rng.integers(20, 235, (h, w, 3)).astype(np.uint8)
    rgb = codes.astype(np.float32) * np.float32(1 / 255)
    gains = np.ones((h, w, 3), np.float32)
    noise, r_w = weight_noise(tab, rgb, gains, "hexcone", 2.0)
    smooth = cv2.GaussianBlur(rgb, (0, 0), 2.0, borderType=cv2.BORDER_REFLECT_101)
    want = noise_ratio2(frame_hue_noise(tab, smooth, gains, "hexcone"), capture_noise(tab))
    np.testing.assert_array_equal(r_w, want)
    np.testing.assert_array_equal(noise, capture_noise(tab) * np.sqrt(want.astype(np.float64)))
    from_codes = weight_noise(tab, codes, gains, "hexcone", 2.0, scale=np.float32(1 / 255))
    np.testing.assert_array_equal(from_codes[1], r_w)
    assert weight_noise(tab, rgb, gains, "hexcone", 0.0) is None
    no_model = _uniform_table(h, w, 2e-3, 1e-5)
    no_model.stats = {"repeats": 1}
    assert weight_noise(no_model, rgb, gains, "hexcone", 2.0) is None


@pytest.mark.parametrize("colour_rgb", [(0.6, 0.35, 0.2), (0.5, 0.2, 0.45)])
def test_weights_of_the_smoothed_signal_do_not_bias_the_mean_they_weight(colour_rgb) -> None:
    """A uniform patch under shot + read noise: weighting each pixel's hue by its own figure
    read from its own noisy signal ties the weight to the noise it weights (a brighter draw of a
    channel moves the hue and that figure together) and biases the weighted mean; read from the
    signal through the 2 px Gaussian the weight hardly follows it; through the 2 px Gaussian along
    the fringe (a column here), which averages fewer pixels, a little more. Measured (20 draws of
    240 x 320 px), the weighted mean's bias beyond the unweighted one's (the hue's own
    nonlinearity): -7.7e-3 / +2.7e-2 rad with the unsmoothed figure, -0.3e-3 / +1.5e-3 rad with the
    smoothed, -1.6e-3 / +7.5e-3 rad along the fringe."""
    from huefringe import colour
    from huefringe.perframe import frame_hue_noise, weight_noise

    rng = np.random.default_rng(5)
    h, w, gain, read = 240, 320, 2e-3, 1e-5
    tab = _uniform_table(h, w, gain, read)
    gains = np.ones((h, w, 3), np.float32)
    t = np.array(colour_rgb, np.float32)
    truth = float(colour.hue(t[None, None, :], "hexcone")[0, 0])
    bias = {"unsmoothed": [], "smoothed": [], "along": [], "unweighted": []}
    for _ in range(20):
        rgb = (t + rng.normal(0.0, 1.0, (h, w, 3)) * np.sqrt(gain * t + read)).astype(np.float32)
        d = np.angle(np.exp(1j * (colour.hue(rgb, "hexcone").astype(np.float64) - truth)))
        for name, wt in (("unsmoothed", frame_hue_noise(tab, rgb, gains, "hexcone") ** -2.0),
                         ("smoothed", weight_noise(tab, rgb, gains, "hexcone", 2.0)[0] ** -2.0),
                         ("along", weight_noise(tab, rgb, gains, "hexcone", 2.0, angle=0.0)[0] ** -2.0),
                         ("unweighted", np.ones((h, w)))):
            bias[name].append(np.sum(wt * d) / np.sum(wt))
    base = np.mean(bias["unweighted"])
    raw, smooth = abs(np.mean(bias["unsmoothed"]) - base), abs(np.mean(bias["smoothed"]) - base)
    along = abs(np.mean(bias["along"]) - base)
    assert raw > 5e-3 and smooth < 0.1 * raw and smooth < along < 0.35 * raw, (raw, smooth, along)


def test_fringe_angle_and_kernel() -> None:
    """The reference phase's gradient direction from its wrapped differences (holes and wraps
    ignored), and the weights' Gaussian along the fringe: a column's normalised Gaussian out to 3
    sigma when the fringes run along the columns; at any angle centred, of unit sum, with the
    truncated Gaussian's variance along the fringe and at most 0.2 px^2 across it (the linear
    interpolation's: 0.185 at 45 degrees); an unknown shape of the Gaussian refused."""
    from huefringe.perframe import fringe_angle, fringe_kernel, weight_blur_angle

    y, x = np.mgrid[0:60, 0:80].astype(np.float64)
    phi = np.mod(0.31 * x - 0.07 * y, 2 * np.pi) - np.pi
    phi[10:20, 30:50] = np.nan
    assert fringe_angle(phi) == pytest.approx(np.arctan2(-0.07, 0.31), abs=1e-6)
    assert fringe_angle(np.full((5, 5), np.nan)) is None and fringe_angle(np.zeros((5, 5))) is None
    assert weight_blur_angle(phi, "along_fringe") == fringe_angle(phi) and weight_blur_angle(phi, "isotropic") is None
    with pytest.raises(ValueError, match="along-fringe"):
        weight_blur_angle(phi, "along-fringe")
    k = fringe_kernel(2.0, 0.0)
    g = np.exp(-0.5 * (np.arange(-6, 7) / 2.0) ** 2)
    np.testing.assert_allclose(k[:, 0], g / g.sum(), rtol=1e-6)
    assert k.shape == (13, 1)
    trunc = 1.0 - 6.0 * np.exp(-4.5) / np.sqrt(2 * np.pi) / 0.9973  # a Gaussian's variance truncated at 3 sigma
    for a in (0.05, 0.5, np.pi / 4, 1.2, -0.3):
        k = fringe_kernel(2.0, a).astype(np.float64)
        assert k.shape[0] % 2 == 1 and k.shape[1] % 2 == 1
        np.testing.assert_allclose(k, k[::-1, ::-1], atol=1e-7)
        assert k.sum() == pytest.approx(1.0, abs=1e-6)
        yy, xx = np.mgrid[-(k.shape[0] // 2):k.shape[0] // 2 + 1, -(k.shape[1] // 2):k.shape[1] // 2 + 1]
        along = -xx * np.sin(a) + yy * np.cos(a)
        across = xx * np.cos(a) + yy * np.sin(a)
        assert np.sum(k * along**2) == pytest.approx(4.0 * trunc, rel=0.03)
        assert np.sum(k * across**2) <= 0.2


@pytest.mark.parametrize("angle_deg", [0.0, 30.0])
def test_weights_along_the_fringe_keep_the_pixels_hue(angle_deg: float) -> None:
    """A noise-free trapezoid fringe of 15 px: the weights' own-noise figure read along the
    fringe is the pixel's own (the hue does not change along the fringe); the isotropic 2 px
    Gaussian mixes the neighbouring phases' hues, whose mean has less chroma, and reads it high
    (measured: mean ratio 1.000 / 1.021 along the fringe at 0 / 30 degrees, where the line's
    interpolation across it mixes a little, against 1.52 / 1.49 isotropic)."""
    from huefringe.colour import white_gains
    from huefringe.patterns import trapezoid_rgb
    from huefringe.perframe import frame_hue_noise, fringe_angle, noise_ratio2, weight_noise

    h, w = 80, 100
    tab = _uniform_table(h, w, 2e-3, 1e-5)
    a = np.radians(angle_deg)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    phi = 2 * np.pi * (x * np.cos(a) + y * np.sin(a)) / 15.0
    rgb = (0.15 + 0.6 * trapezoid_rgb(phi)).astype(np.float32)
    gains = white_gains(np.full((h, w, 3), 0.8, np.float32))
    ang = fringe_angle(np.mod(phi, 2 * np.pi) - np.pi)
    assert ang == pytest.approx(a, abs=1e-6)
    own = frame_hue_noise(tab, rgb, gains, "hexcone")
    inner = (slice(8, -8), slice(8, -8))
    along = weight_noise(tab, rgb, gains, "hexcone", 2.0, angle=ang)[0]
    iso = weight_noise(tab, rgb, gains, "hexcone", 2.0)[0]
    own_w = capture_noise(tab) * np.sqrt(noise_ratio2(own, capture_noise(tab)).astype(np.float64))
    r_along = float(np.mean((along / own_w)[inner]))
    r_iso = float(np.mean((iso / own_w)[inner]))
    assert abs(r_along - 1.0) < 0.04, r_along
    assert r_iso > 1.2, r_iso
