"""The phase-error table (huefringe.phase_error): an injected phase-dependent error is learned from
planes alone and removed; the correction is the same in the reference chain and the kernel."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import tifffile
import yaml

from huefringe import bench, phase_error, stages
from huefringe.settings import load_config
from huefringe.height import accuracy

REPO = Path(__file__).resolve().parents[1]
CONFIG = load_config(REPO / "config.yaml")


def _sawtooth(phi: np.ndarray, amp: float = 0.05) -> np.ndarray:
    """A smooth 2 pi / 3-periodic, sawtooth-like error (monotonic decoding: |de/dphi| < 1)."""
    return amp * (np.sin(3 * phi) - 0.4 * np.sin(6 * phi)) + 0.015 * np.sin(phi + 0.3)


def _planes(shape=(120, 200), period_px=23.0, zs=(0.0, 3.0, 6.0), rng=None):
    """Analytic plane phases (tilted fringes, a lens-like quadratic term) with an injected e(phi)."""
    rng = rng or np.random.default_rng(0)
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    phases, valid, truth = {}, {}, {}
    for z in zs:
        true = 2 * np.pi * u / period_px + 0.35 * z + 1e-5 * (u - 100) ** 2 + 0.002 * v
        t = np.mod(true, 2 * np.pi)
        decoded = np.mod(t + _sawtooth(t) + rng.normal(0, 0.005, t.shape), 2 * np.pi)
        phases[z], valid[z], truth[z] = decoded.astype(np.float32), np.ones(shape, bool), t
    return phases, valid, truth


def test_injected_error_is_learned_and_removed() -> None:
    phases, valid, truth = _planes()
    lut = phase_error.estimate(phases, valid, bins=256)
    # the table matches the injected error at the decoded phases, away from the jumps
    c = lut.centres
    t = np.linspace(0, 2 * np.pi, 20001)
    inj = np.interp(c, np.mod(t + _sawtooth(t), 2 * np.pi)[np.argsort(np.mod(t + _sawtooth(t), 2 * np.pi))],
                    _sawtooth(t)[np.argsort(np.mod(t + _sawtooth(t), 2 * np.pi))])  # e at the decoded phase
    assert np.sqrt(np.mean((lut.error - inj) ** 2)) < 0.004
    # applied to a fresh capture, the rms error against the truth drops at least fivefold
    phases2, _, truth2 = _planes(rng=np.random.default_rng(1), zs=(1.7,))
    before = np.angle(np.exp(1j * (phases2[1.7].astype(np.float64) - truth2[1.7])))
    fixed = phase_error.correct(phases2[1.7], lut.error)
    after = np.angle(np.exp(1j * (fixed.astype(np.float64) - truth2[1.7])))
    rms_b, rms_a = np.sqrt(np.mean(before**2)), np.sqrt(np.mean(after**2))
    assert rms_b > 0.035
    assert rms_a < rms_b / 4, (rms_b, rms_a)
    assert lut.stats["binned_rms_after_rad"] < 0.2 * lut.stats["binned_rms_before_rad"]


def test_correct_keeps_nan_range_and_zero_table() -> None:
    phi = np.array([0.0, 1.0, np.nan, 2 * np.pi - 1e-6, 3.0], np.float32)
    out = phase_error.correct(phi, np.zeros(64))
    np.testing.assert_array_equal(np.isnan(out), np.isnan(phi))
    np.testing.assert_array_equal(out[~np.isnan(out)], phi[~np.isnan(phi)])
    big = phase_error.correct(phi, np.full(64, -0.5))  # phi + 0.5, wrapped into [0, 2 pi)
    ok = np.isfinite(big)
    assert np.all((big[ok] >= 0) & (big[ok] < 2 * np.pi))
    np.testing.assert_allclose(big[ok], np.mod(phi[ok].astype(np.float64) + 0.5, 2 * np.pi), atol=1e-6)
    with pytest.raises(ValueError):
        phase_error.correct(phi, np.zeros((2, 2)))


@pytest.fixture(scope="module")
def plain_flat(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bench's hard case: the plain trapezoid at 40 px, 1.6 px defocus, 96 bands x 2."""
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("flat")))
    cfg["session"].update(period_px=40, hue_bands=96, repeats=2, frames=1, width=320, height=240)
    cfg["projector"]["defocus_sigma_px"] = 1.6
    cfg["phase_shift"]["enabled"] = False
    return bench.write_session(cfg, tmp_path_factory.mktemp("plainflat") / "s")


def _score(session: Path, out: Path, enabled: bool) -> dict:
    cfg = copy.deepcopy(CONFIG)
    cfg["calibration"]["phase_error"] = {**cfg["calibration"].get("phase_error", {}), "enabled": enabled}
    p = stages.measure_session(session, out, cfg)
    s = p["session"]
    return accuracy(tifffile.imread(p["heights"][0]), tifffile.imread(s.ground_truth[s.frame_ids[0]]))


def test_plain_flat_reaches_the_target_only_with_the_table(plain_flat: Path, tmp_path: Path) -> None:
    """Flat board, plain pattern: the table takes median/p95 from about 0.044/0.095 mm to the
    issue's targets (<= 0.012 / 0.06 mm); the calibration outputs record it."""
    off = _score(plain_flat, tmp_path / "off", False)
    on = _score(plain_flat, tmp_path / "on", True)
    assert off["median_abs_mm"] > 0.03  # the error is there without the table
    assert on["median_abs_mm"] <= 0.012 and on["p95_abs_mm"] <= 0.06, on
    assert on["coverage"] > 0.99
    import json

    st = json.loads((tmp_path / "on" / "phase_error.json").read_text())
    assert st["enabled"] and st["binned_rms_after_rad"] < 0.3 * st["binned_rms_before_rad"]
    with np.load(tmp_path / "on" / "model.npz") as z:
        assert "phase_error" in z.files
    with np.load(tmp_path / "off" / "model.npz") as z:
        assert "phase_error" not in z.files


def test_table_never_reads_ground_truth(plain_flat: Path, tmp_path: Path) -> None:
    """The same table with the ground-truth folder removed from a copy of the session."""
    import shutil

    copy_dir = tmp_path / "nogt"
    shutil.copytree(plain_flat, copy_dir)
    shutil.rmtree(copy_dir / "ground_truth")
    doc = yaml.safe_load((copy_dir / "session.yaml").read_text())
    doc.pop("ground_truth", None)
    (copy_dir / "session.yaml").write_text(yaml.safe_dump(doc))
    outs = []
    for sess, name in ((plain_flat, "a"), (copy_dir, "b")):
        for which in ("reference",):
            stages.hue_table(str(sess), which, "hexcone", CONFIG["calibration"], table=str(tmp_path / f"{name}.json"),
                               stats=str(tmp_path / f"{name}.stats.json"))
        stages.plane_calibration(str(sess), str(tmp_path / f"{name}.json"), "hexcone", CONFIG["calibration"],
                                   model=str(tmp_path / f"{name}.npz"), stats=str(tmp_path / f"{name}.planes.json"),
                                   phase_error_table=str(tmp_path / f"{name}.pe.npz"))
        with np.load(tmp_path / f"{name}.pe.npz") as z:
            outs.append(z["error"])
    np.testing.assert_array_equal(outs[0], outs[1])


def test_holdout_check_applies_a_real_error_and_refuses_noise() -> None:
    """``enabled: auto``: a table learned from two planes must lower the third plane's residual.
    With an injected e(phi) it does (applied); with noise alone it does not (not applied)."""
    phases, valid, _ = _planes()
    check = phase_error.holdout_check(phases, valid, bins=256, smooth_bins=1.5)
    assert check["helps"] and check["holdout_residual_rms_after_rad"] < 0.5 * check["holdout_residual_rms_before_rad"]
    rng = np.random.default_rng(3)
    v, u = np.mgrid[0:120, 0:200].astype(np.float64)
    noisy = {z: np.mod(2 * np.pi * u / 23.0 + 0.35 * z + rng.normal(0, 0.02, u.shape), 2 * np.pi).astype(np.float32)
             for z in (0.0, 3.0, 6.0)}
    ones = {z: np.ones(u.shape, bool) for z in noisy}
    check = phase_error.holdout_check(noisy, ones, bins=512, smooth_bins=1.5)
    assert not check["helps"], check
    cal = load_config({"calibration": {"phase_error": {"enabled": "auto", "smooth_bins": 1.5}}})["calibration"]
    assert phase_error.from_calibration(noisy, ones, cal) is None
    assert phase_error.from_calibration(phases, valid, cal) is not None
    with pytest.raises(ValueError, match="true, false or auto"):
        phase_error.from_calibration(phases, valid, load_config({"calibration": {"phase_error": {"enabled": "yes"}}})["calibration"])


def _frequency_cal(phi_ref: np.ndarray, a: np.ndarray | None = None, planes: tuple[float, ...] = (0.0,)):
    """A plane calibration's fields that :func:`phase_error.frequency_inputs` reads."""
    from types import SimpleNamespace

    a = np.zeros(phi_ref.shape) if a is None else a
    return SimpleNamespace(phi_ref=phi_ref, a=a, b=np.zeros(phi_ref.shape), planes_mm=list(planes))


def test_frequency_inputs_are_the_reference_planes_frequency() -> None:
    """The table's frequency is the reference phase's (tilted fringes: both components, and the
    square of their length), whatever the other planes see."""
    h, w = 20, 30
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    phi_ref = np.mod(0.12 * uu + 0.03 * vv, 2 * np.pi).astype(np.float32)
    inputs = phase_error.frequency_inputs(_frequency_cal(phi_ref, a=0.004 * uu, planes=(0.0, 3.0, 6.0)))
    np.testing.assert_allclose(inputs[0], 0.12, atol=2e-6)
    np.testing.assert_allclose(inputs[1], 0.03, atol=2e-6)
    np.testing.assert_allclose(inputs[2], 0.12**2 + 0.03**2, rtol=1e-4)


def test_correction_scaled_to_the_local_fringe_frequency() -> None:
    """``correct_frequency`` takes out ``((g / g_0)^2 - 1) e(phi)`` (one plane, the reference: ``g_0``
    its frequency): nothing where the phase
    difference is flat (the reference's frequency), the analytic amount on a ramp that raises the
    frequency by a quarter, nothing at a step between two flat sides (the step-robust slope) nor
    at one blurred over three pixels or on a ramp four times the reference's frequency (outside
    the range taken as a slope), and the phase difference unchanged without a table or where
    invalid."""
    h, w = 40, 60
    g0 = 2 * np.pi / 48  # the reference plane's fringe: 48 px a period along the columns
    uu = np.arange(w)[None, :] * np.ones((h, 1))
    phi_ref = np.mod(0.2 + g0 * uu, 2 * np.pi).astype(np.float32)
    bins = 512
    centres = (np.arange(bins) + 0.5) * 2 * np.pi / bins
    error = 0.02 * np.sin(3 * centres) + 0.01 * np.cos(7 * centres)
    valid = np.ones((h, w), bool)
    valid[5, 7] = False
    inputs = phase_error.frequency_inputs(_frequency_cal(phi_ref))

    flat = np.full((h, w), 0.3, np.float32)
    np.testing.assert_array_equal(phase_error.correct_frequency(flat, valid, phi_ref, error, inputs), flat)

    ramp = (0.25 * g0 * uu).astype(np.float32)  # g = 1.25 g0
    got = phase_error.correct_frequency(ramp, valid, phi_ref, error, inputs)
    inner = (slice(8, -8), slice(8, -8))
    code = np.mod(phi_ref.astype(np.float64) + ramp, 2 * np.pi)
    want = ramp - (1.25**2 - 1.0) * phase_error.table_at(code, error)
    np.testing.assert_allclose(got[inner], want[inner], atol=2e-6)
    assert np.abs(got - ramp)[inner].max() > 0.01  # the correction is there

    step = np.where(uu < 30, 0.0, 1.0).astype(np.float32)
    got = phase_error.correct_frequency(step, valid, phi_ref, error, inputs)
    np.testing.assert_allclose(got[10:30], step[10:30], atol=1e-7)  # both sides flat: g = g0 at the step too

    steep = (3.0 * g0 * uu).astype(np.float32)  # (4 g0)^2: not a slope the table's error scales with
    got = phase_error.correct_frequency(steep, valid, phi_ref, error, inputs)
    np.testing.assert_array_equal(got, steep)
    blurred = step.copy()
    blurred[:, 29:31] = [0.25, 0.75]  # a step over three pixels: their differences cross the range
    got = phase_error.correct_frequency(blurred, valid, phi_ref, error, inputs)
    np.testing.assert_allclose(got[10:30], blurred[10:30], atol=1e-7)

    assert phase_error.correct_frequency(ramp, valid, phi_ref, error, inputs)[5, 7] == ramp[5, 7]  # invalid: kept
    np.testing.assert_array_equal(phase_error.correct_frequency(ramp, valid, phi_ref, None, inputs), ramp)


def test_frequency_ratio_is_its_numpy_definition() -> None:
    """The compiled ratio against its NumPy definition (the slope: of the forward and backward
    differences between valid pixels the smaller; a pixel on a slope when its own ``|g_ref +
    slope|^2 / g_t^2`` lies in the range; there ``|g_ref + mean slope|^2 / g_t^2``, the
    mean over the box's pixels on a slope (9 x 9); 1 elsewhere) on a noisy, tilted, partly invalid
    map with a step: to 1e-12."""
    from scipy.ndimage import uniform_filter

    rng = np.random.default_rng(5)
    h, w = 50, 70
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    phi_ref = np.mod(0.4 + 0.13 * uu + 0.02 * vv, 2 * np.pi).astype(np.float32)
    d = (0.03 * np.sin(uu / 9.0) + 0.02 * vv / h + rng.normal(0, 0.01, (h, w)) + np.where(uu > 40, 0.8, 0.0))
    d = d.astype(np.float32)
    valid = rng.random((h, w)) > 0.1
    g = phase_error.frequency_inputs(_frequency_cal(phi_ref))

    def smaller(x: np.ndarray, axis: int) -> np.ndarray:
        xm = np.moveaxis(np.where(valid, x, np.nan), axis, 0)
        f = np.full(xm.shape, np.nan)
        f[:-1] = xm[1:] - xm[:-1]
        b = np.full(xm.shape, np.nan)
        b[1:] = f[:-1]
        f2, b2 = np.where(np.isfinite(f), f, b), np.where(np.isfinite(b), b, f)
        return np.moveaxis(np.nan_to_num(np.where(np.abs(f2) < np.abs(b2), f2, b2)), 0, axis)

    x = d.astype(np.float64)
    su, sv = smaller(x, 1), smaller(x, 0)
    g02 = g[2]
    q = ((g[0] + su) ** 2 + (g[1] + sv) ** 2) / g02
    lo, hi = phase_error.FREQUENCY_RATIO_RANGE
    taken = valid & (q >= lo) & (q <= hi)
    box = phase_error.FREQUENCY_BOX_PX
    count = uniform_filter(taken.astype(float), box, mode="constant")
    mu = uniform_filter(np.where(taken, su, 0.0), box, mode="constant") / count
    mv = uniform_filter(np.where(taken, sv, 0.0), box, mode="constant") / count
    want = np.where(taken, ((g[0] + mu) ** 2 + (g[1] + mv) ** 2) / g02, 1.0)
    got = phase_error.frequency_ratio(d, valid, g)
    assert 0.2 < taken.mean() < 0.99  # both outcomes of the slope test occur
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
