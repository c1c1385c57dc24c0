"""Texture-edge correction (huefringe.texture) against an analytic blurred capture."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from huefringe import texture


def _scene(sig: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:120, 0:160]
    # blocky two-level reflectance (sharp texture edges) per channel, smoothed a little
    blocks = rng.uniform(0.08, 0.9, (12, 16, 3)).astype(np.float32)
    r = cv2.resize(blocks, (160, 120), interpolation=cv2.INTER_NEAREST)
    r = cv2.GaussianBlur(r, (0, 0), 0.7)
    ph = 2 * np.pi * xx / 40.0
    f = np.stack([0.5 + 0.4 * np.cos(ph - k * 2 * np.pi / 3) for k in range(3)], -1).astype(np.float32)
    b = cv2.GaussianBlur(r * f, (0, 0), sig)
    w = cv2.GaussianBlur(r, (0, 0), sig)
    target = w * cv2.GaussianBlur(f, (0, 0), sig)  # what a uniform reflectance would give
    return b, w, target


@pytest.mark.parametrize("sig", [0.6, 0.9, 1.2])
def test_correction_removes_most_of_the_lean(sig: float) -> None:
    b, w, target = _scene(sig)
    inner = (slice(4, -4), slice(4, -4))
    before = np.sqrt(np.mean((b - target)[inner] ** 2))
    after = np.sqrt(np.mean((texture.correct(b, w, sig**2) - target)[inner] ** 2))
    assert after < 0.3 * before  # measured 0.16-0.20, (before, after)


def test_zero_blur_and_clipped_pixels_unchanged() -> None:
    b, w, _ = _scene(0.9)
    assert np.array_equal(texture.correct(b, w, 0.0), b.astype(np.float32))
    clipped = np.zeros(b.shape[:2], bool)
    clipped[10:20, 10:20] = True
    c = texture.correct(b, w, 0.81, clipped=clipped)
    assert np.array_equal(c[clipped], b[clipped].astype(np.float32))
    assert not np.array_equal(c[~clipped], b[~clipped].astype(np.float32))


@pytest.fixture(scope="module")
def photo_runs(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A photographed relief (skimage astronaut, lens blur 0.9 px: sigma^2 = 0.81 px^2; ambient and
    stray light), 2 frames, measured with the texture correction off, with its own estimate (auto)
    and with it formed from capture and white as they are (``texture_offset`` false); and with the
    estimate and the phase-error table's correction scaled to the fringe frequency
    (``measurement.phase_error_frequency``)."""
    import copy

    import bench_helpers as bh

    root = tmp_path_factory.mktemp("photo")
    session = bh.write(bh.bench_config("photo_relief", frames=2), root)
    runs = {}
    for name, blur, offset, freq in (("off", 0, True, False), ("auto", "auto", True, False),
                                     ("auto, no offset", "auto", False, False), ("auto, frequency", "auto", True, True)):
        cfg = copy.deepcopy(bh.CONFIG)
        cfg["calibration"]["texture_blur_px2"] = blur
        cfg["calibration"]["texture_offset"] = offset
        cfg["measurement"]["phase_error_frequency"] = freq
        runs[name] = bh.process(session, root / name, config=cfg)
    runs["bench"] = bh.bench_config("photo_relief", frames=2)
    return runs


def _errors(paths: dict) -> np.ndarray:
    import tifffile

    s = paths["session"]
    e = [tifffile.imread(h).astype(np.float64) - tifffile.imread(s.ground_truth[n]) for h, n in
         zip(paths["heights"], s.frame_ids, strict=True)]
    e = np.abs(np.concatenate([x.ravel() for x in e]))
    return e[np.isfinite(e)]


def test_blur_estimate_recovers_the_bench_lens(photo_runs: dict) -> None:
    import json
    from pathlib import Path

    rec = json.loads((Path(photo_runs["auto"]["heights"][0]).parents[1] / "planes.json").read_text())["texture_blur"]
    assert rec["pairs"] == 1 and rec["samples"] > 10000
    assert 0.81 * 0.8 <= rec["sigma2_px2"] <= 0.81 * 1.2, rec  # measured 0.809
    off = json.loads((Path(photo_runs["off"]["heights"][0]).parents[1] / "planes.json").read_text())["texture_blur"]
    assert off["sigma2_px2"] == 0.0


def test_correction_lowers_the_error_on_a_photographed_relief(photo_runs: dict) -> None:
    off, auto = _errors(photo_runs["off"]), _errors(photo_runs["auto"])
    # measured: median 0.0190 -> 0.0165 mm, p95 0.110 -> 0.087 mm, coverage 0.817 -> 0.809
    assert np.median(auto) < 0.92 * np.median(off)
    assert np.percentile(auto, 95) < 0.85 * np.percentile(off, 95)
    assert auto.size > 0.97 * off.size


def _phases(s2: float, texture_rad: float, noise_rad: float, seed: int = 1):
    """Two frames' raw phases ``phi_0 = -s2 g + noise`` and their unit-corrected ``phi_0 + g``:
    ``g`` is the texture's predicted lean (shared by the frames), the noise is each frame's own."""
    rng = np.random.default_rng(seed)
    g = cv2.GaussianBlur(rng.normal(0.0, 1.0, (240, 320)), (0, 0), 1.0) * texture_rad
    plain = [-s2 * g + rng.normal(0.0, noise_rad, g.shape) for _ in range(2)]
    return plain, [p + g for p in plain]


def test_blur_from_phases_recovers_a_textured_slope() -> None:
    plain, unit = _phases(0.8, texture_rad=0.02, noise_rad=0.01)
    est = texture.blur_from_phases(plain, unit)
    assert "rejected" not in est and abs(est["sigma2_px2"] - 0.8) < 0.08, est
    assert est["stderr_px2"] < 0.8 / 3


def test_blur_from_phases_refuses_noise_without_texture() -> None:
    # no shared lean: the ratio of two near-zero sums is noise (once read as 42.8 px^2 on a real
    # untextured session): the estimate must be refused, not used
    for seed in range(6):
        plain, unit = _phases(0.8, texture_rad=0.0, noise_rad=0.01, seed=seed)
        unit = [p + np.random.default_rng(seed + 50 + k).normal(0.0, 1e-4, p.shape) for k, p in enumerate(plain)]
        est = texture.blur_from_phases(plain, unit)
        assert est["sigma2_px2"] == 0.0 and "rejected" in est, est


def test_blur_from_phases_refuses_an_implausible_blur() -> None:
    plain, unit = _phases(20.0, texture_rad=0.02, noise_rad=0.01)
    est = texture.blur_from_phases(plain, unit)
    assert est["sigma2_px2"] == 0.0 and "exceeds" in est["rejected"] and est["raw_px2"] > 15, est


def _gauge_white(sig: float, supersample: int = 1, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """A 320 x 240 white image of four coloured blocks on a grey base (the bench gauge's coatings),
    blurred by a Gaussian lens of ``sig`` px; ``supersample`` > 1 puts the edges inside pixels (box
    integration over that many sub-pixels per axis)."""
    from scipy import ndimage

    n = supersample
    r = np.full((240 * n, 320 * n, 3), 0.55)
    coats = ([0.12, 0.65, 0.18], [0.08, 0.12, 0.32], [0.72, 0.13, 0.11], [0.17, 0.15, 0.14])
    for x0, c in zip((33, 105, 177, 249), coats, strict=True):
        r[int(57.3 * n):int(185.1 * n), int((x0 + 0.4) * n):int((x0 + 48.3) * n)] = c
    r = r.reshape(240, n, 320, n, 3).mean(axis=(1, 3))
    w = np.stack([ndimage.gaussian_filter(r[..., c], sig) for c in range(3)], -1)
    return w + np.random.default_rng(seed).normal(0.0, noise, w.shape)


@pytest.mark.parametrize(("sig", "supersample", "lo", "hi"), [
    (0.6, 1, 0.33, 0.42),   # measured 0.393 (noise 0.004)
    (0.9, 1, 0.76, 0.86),   # measured 0.817
    (1.1, 1, 1.09, 1.27),   # measured 1.153
    (0.9, 4, 0.85, 1.05),   # edges inside pixels: + about 1/12 px^2 of pixel integration; measured 0.950
])
def test_blur_from_white_reads_the_lens_at_sharp_coating_edges(sig: float, supersample: int, lo: float, hi: float) -> None:
    est = texture.blur_from_white(_gauge_white(sig, supersample, noise=0.004))
    assert "rejected" not in est and est["edges"] > 1000, est
    assert lo <= est["sigma2_px2"] <= hi, (sig**2, est)


def test_blur_from_white_refuses_a_plate_without_edges() -> None:
    flat = np.full((240, 320, 3), 0.5) + np.random.default_rng(1).normal(0.0, 0.004, (240, 320, 3))
    est = texture.blur_from_white(flat)
    assert est["sigma2_px2"] == 0.0 and est["edges"] < 50 and "sharp edges" in est["rejected"], est


def test_blur_from_white_overreads_soft_texture() -> None:
    # reflectance edges that are soft themselves widen the edges it sees: an upper bound there,
    # which is why it is only the fallback of the phase estimate (documented in blur_from_white)
    _, w, _ = _scene(0.9)
    est = texture.blur_from_white(w)
    assert est["sigma2_px2"] > 0.81 + 0.3, est  # the scene's own 0.7 px smoothing adds 0.49 px^2: measured 1.276


def test_blur_from_white_refuses_edges_that_disagree() -> None:
    # one lens blurs every sharp edge alike: half the edges at 0.6 px and half at 1.2 px is no lens
    w = _gauge_white(0.6, noise=0.004)
    w[:, 160:] = _gauge_white(1.2, noise=0.004)[:, 160:]
    est = texture.blur_from_white(w)
    assert est["sigma2_px2"] == 0.0 and "disagree" in est["rejected"], est
    q25, _, q75 = est["quartiles_px2"]
    assert q75 > 1.6 * q25 and q25 < 0.5, est
    # an estimate wider than the window measures is refused (a blur of sigma 1.5 px reads about 1.9 px^2)
    wide = texture.blur_from_white(_gauge_white(1.5, noise=0.004))
    assert wide["sigma2_px2"] == 0.0 and "exceeds" in wide["rejected"], wide


def _lit_scene(sig: float, seed: int = 0):
    """:func:`_scene` with light that carries no fringe: ambient light the surface reflects (blurred
    with it) and the camera's stray light, on capture and white alike."""
    rng = np.random.default_rng(seed)
    blocks = rng.uniform(0.05, 0.9, (12, 16, 3)).astype(np.float32)
    r = cv2.GaussianBlur(cv2.resize(blocks, (160, 120), interpolation=cv2.INTER_NEAREST), (0, 0), 0.7)
    xx = np.mgrid[0:120, 0:160][1]
    f = np.stack([0.5 + 0.4 * np.cos(2 * np.pi * xx / 40.0 - k * 2 * np.pi / 3) for k in range(3)], -1)
    f = f.astype(np.float32)
    q = cv2.GaussianBlur(r * np.float32(0.08), (0, 0), sig) + np.float32(0.02)
    b = cv2.GaussianBlur(r * f, (0, 0), sig) + q
    w = cv2.GaussianBlur(r, (0, 0), sig) + q
    target = (w - q) * cv2.GaussianBlur(f, (0, 0), sig) + q  # the fringe without the texture's lean
    return b, w, q, target


@pytest.mark.parametrize("sig", [0.6, 0.9, 1.2])
def test_light_without_fringe_is_taken_out_before_the_lean(sig: float) -> None:
    """``offset``: with ambient and stray light on capture and white, the lean formed from them as
    they are is off on the dark blocks; formed from the fringe-carrying light (both less ``Q``) it
    removes the lean as :func:`test_correction_removes_most_of_the_lean` does, and it is the
    plain correction of ``b - Q``, ``w - Q`` with ``Q`` added back; ``correct_pair`` gives the
    same arrays."""
    b, w, q, target = _lit_scene(sig)
    inner = (slice(4, -4), slice(4, -4))
    dark = np.zeros(b.shape, bool)
    dark[inner] = (w - q)[inner] < 0.25
    before = np.sqrt(np.mean((b - target)[dark] ** 2))
    plain = np.sqrt(np.mean((texture.correct(b, w, sig**2) - target)[dark] ** 2))
    with_q = texture.correct(b, w, sig**2, offset=q)
    after = np.sqrt(np.mean((with_q - target)[dark] ** 2))
    assert after < 0.3 * before and after < 0.6 * plain, (before, plain, after)
    np.testing.assert_allclose(with_q, texture.correct(b - q, w - q, sig**2) + q, atol=2e-7)
    one, two = texture.correct_pair(b, w, sig**2, 1.3 * sig**2, offset=q)
    assert np.array_equal(one, with_q)
    assert np.array_equal(two, texture.correct(b, w, 1.3 * sig**2, offset=q))


@pytest.mark.parametrize("shape", [(1, 4), (2, 2), (3, 1), (7, 5), (33, 17), (70, 41)])
def test_correct_pair_is_two_corrections_bit_for_bit(shape: tuple[int, int]) -> None:
    """``correct_pair`` (one compiled pass in blocks of rows: each pixel's ratio formed once for
    its four neighbours, the stencil along the row's channels; float32 captures read as they are)
    returns the arrays of two :func:`texture.correct` calls, the NumPy definition, bit for bit:
    float32 and float64 captures, with and without the light without fringe and clipped pixels,
    without the moved capture, at zero blur, on sizes whose rows and columns have no interior or
    cross a block of rows."""
    rng = np.random.default_rng(sum(shape))
    b32 = rng.random((*shape, 3)).astype(np.float32)
    w32 = (0.01 + rng.random((*shape, 3))).astype(np.float32)  # some below the white floor
    q = 0.05 * rng.random((*shape, 3))
    clipped = rng.random(shape) < 0.1
    for b, w in ((b32, w32), (b32.astype(np.float64) * 0.7, w32.astype(np.float64) + 1e-9)):
        for offset in (None, q):
            for clip in (None, clipped):
                for s1, s2 in ((0.81, 1.3 * 0.81), (0.81, None), (0.0, 0.4)):
                    one, two = texture.correct_pair(b, w, s1, s2, clipped=clip, offset=offset)
                    assert np.array_equal(one, texture.correct(b, w, s1, clipped=clip, offset=offset))
                    if s2 is None:
                        assert two is None
                    else:
                        assert np.array_equal(two, texture.correct(b, w, s2, clipped=clip, offset=offset))


def test_projector_off_light_is_the_mean_of_the_captures_at_code_zero() -> None:
    """``projector_off_light``: per channel, the mean over the uniform captures whose code is 0 in
    that channel (a third of the trapezoid's bands, ``patterns.band_rgb``); noise averages out; a set
    without a channel at 0 is refused."""
    from huefringe import patterns

    rng = np.random.default_rng(3)
    q = rng.uniform(0.01, 0.05, (20, 30, 3))
    gain = rng.uniform(0.2, 0.9, (20, 30, 3))
    n = 72
    caps = [(q + gain * patterns.band_rgb(i, n) + rng.normal(0, 0.002, q.shape), patterns.band_rgb(i, n))
            for i in range(n)]
    got = texture.projector_off_light(caps)
    assert got.dtype == np.float32 and got.shape == q.shape
    assert np.abs(got - q).max() < 5 * 0.002 / np.sqrt(24)  # 24 of 72 bands at 0 per channel
    with pytest.raises(ValueError, match="no capture at code 0"):
        texture.projector_off_light([(c, np.maximum(k, 0.1)) for c, k in caps])


def test_offset_lowers_the_error_of_the_relief_s_dark_pixels(photo_runs: dict) -> None:
    """On the photographed relief (ambient and stray light) the correction formed from the
    fringe-carrying light lowers the dark pixels' error (white level below 0.35 of its 99th
    percentile), the blur estimate being the same; the light it takes out is the bench's capture
    with the projector's code at 0, demixed as the frames are."""
    import json
    from pathlib import Path

    import tifffile

    from huefringe import bench
    from huefringe.bench.radiometry import Pattern
    from huefringe.height import PlaneCalibration
    from huefringe.session import read_rgb

    auto, plain = photo_runs["auto"], photo_runs["auto, no offset"]
    calib = Path(auto["heights"][0]).parents[1]
    rec = json.loads((calib / "planes.json").read_text())["texture_blur"]
    rec0 = json.loads((Path(plain["heights"][0]).parents[1] / "planes.json").read_text())["texture_blur"]
    assert rec["sigma2_px2"] == rec0["sigma2_px2"] > 0  # estimated without the offset either way
    s = auto["session"]
    white = np.asarray(read_rgb(s.object_white), np.float64).mean(axis=-1)
    dark = white / np.percentile(white, 99) < 0.35
    truth = [tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids]

    def rms(paths: dict) -> float:
        e = np.stack([tifffile.imread(h) - t for h, t in zip(paths["heights"], truth, strict=True)])
        ok = np.all(np.isfinite(e), axis=0) & dark
        return float(np.sqrt(np.mean(e[:, ok] ** 2)))

    assert rms(auto) < 0.92 * rms(plain), (rms(plain), rms(auto))  # measured 0.242 -> 0.216 mm
    cal = PlaneCalibration.load(str(calib / "model.npz"))
    assert cal.projector_off is not None and PlaneCalibration.load(
        str(Path(plain["heights"][0]).parents[1] / "model.npz")).projector_off is None
    rig = bench.Bench(photo_runs["bench"])
    camera = json.loads((calib / "camera.json").read_text())["colour_demixing"]
    q = (rig.capture(Pattern("uniform", (0.0, 0.0, 0.0))).astype(np.float64) / rig.rig.max_dn) @ np.asarray(
        camera["demix"] if camera["applied"] else np.eye(3)).T
    lit = white / np.percentile(white, 99) > 0.1
    ratio = np.median(cal.projector_off[lit], axis=0) / np.median(q[lit], axis=0)
    assert np.all(np.abs(ratio - 1.0) < 0.05), ratio  # measured within 0.001


def test_phase_error_scaled_to_the_fringe_frequency_lowers_the_relief_s_error(photo_runs: dict) -> None:
    """The relief's slopes change the fringe frequency the phase-error table holds its error at;
    scaled to it (``measurement.phase_error_frequency``) the relief's p95 error falls and its
    median does not rise, nearly the same pixels valid (measured: p95 0.0699 -> 0.0648 mm, median
    0.0109 -> 0.0105 mm)."""
    learned, scaled = _errors(photo_runs["auto"]), _errors(photo_runs["auto, frequency"])
    assert abs(scaled.size - learned.size) < 0.002 * learned.size  # the step-edge mask reads the heights
    assert np.percentile(scaled, 95) < 0.97 * np.percentile(learned, 95)
    assert np.median(scaled) < 1.01 * np.median(learned)
