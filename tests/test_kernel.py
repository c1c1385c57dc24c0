"""The fused per-frame kernel against the NumPy reference (perframe.measure_frame) on bench data."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from huefringe import bench, kernel, perframe, stages, uncertainty
from huefringe.huetable import HueTable
from huefringe.height import PlaneCalibration
from huefringe.session import load_session, read_rgb
from huefringe.settings import load_config

REPO = Path(__file__).resolve().parents[1]
CONFIG = load_config(REPO / "config.yaml")
#: the configured keywords :func:`perframe.measure_frame` takes from the top level and ``measurement``
_FRAME_KEYS = {"hue_model": CONFIG["hue_model"], "min_saturation": CONFIG["measurement"]["min_saturation"],
               "unwrap_mode": CONFIG["measurement"]["unwrap"]}
TOL_MM = 1e-4


def _bench_cfg() -> dict:
    """The demo rig (gauge blocks, vibrating membrane) on a small sensor: 160 x 120, 32 bands."""
    cfg = copy.deepcopy(bench.load_bench_config(bench.preset_path("demo")))
    # coarser pixels keep the 80 x 60 mm field of the demo (and its blocks); same 12 mm period
    cfg["session"].update(width=160, height=120, pixel_pitch_mm=0.5, period_px=24, hue_bands=32, repeats=3, frames=2)
    cfg["phase_shift"]["enabled"] = False
    cfg["projector"]["compensation"]["enabled"] = True  # frames carry a pre-distortion to decode
    return cfg


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> dict:
    root = tmp_path_factory.mktemp("kernel")
    session = bench.write_session(_bench_cfg(), root / "session")
    s = load_session(session)
    out: dict = {"session": s, "white": read_rgb(s.object_white)}
    for model in ("hexcone", "hsi"):
        d = root / model
        d.mkdir()
        for which in ("reference", "object"):
            stages.hue_table(str(session), which, model, CONFIG["calibration"], table=str(d / f"table_{which}.json"),
                               stats=str(d / f"table_{which}.stats.json"))
        stages.plane_calibration(str(session), str(d / "table_reference.json"), model, CONFIG["calibration"],
                                   model=str(d / "model.npz"), stats=str(d / "planes.json"))
        out[model] = (HueTable.load(d / "table_object.json"), PlaneCalibration.load(str(d / "model.npz")))
    return out


def _reference(rig: dict, model: str, rgb: np.ndarray, shadow: np.ndarray, denoise: int,
               pd: bool = True, own: bool = False, blur: float = perframe.WEIGHT_BLUR_PX,
               shape: str = perframe.WEIGHT_BLUR_SHAPE) -> perframe.FrameResult:
    table, cal = rig[model]
    m = CONFIG["measurement"]
    return perframe.measure_frame(rgb, rig["white"], table, cal, hue_model=model, min_saturation=m["min_saturation"],
                                  shadow=shadow, unwrap_mode="reference", bit_depth=8, denoise_radius=denoise,
                                  predistortion=rig["session"].predistortion if pd else None, own_noise=own,
                                  weight_blur_px=blur, weight_blur_shape=shape)


def _prepare(rig: dict, model: str, shadow: np.ndarray, pd: bool = True, own: bool = False,
             blur: float = perframe.WEIGHT_BLUR_PX, shape: str = perframe.WEIGHT_BLUR_SHAPE,
             frequency: bool = False) -> kernel.Prepared:
    table, cal = rig[model]
    return kernel.prepare(table, cal, rig["white"], hue_model=model,
                          min_saturation=CONFIG["measurement"]["min_saturation"], shadow=shadow, bit_depth=8,
                          predistortion=rig["session"].predistortion if pd else None, own_noise=own,
                          weight_blur_px=blur, weight_blur_shape=shape, phase_error_frequency=frequency)


def _frame_u8(rig: dict, n: int) -> np.ndarray:
    return np.ascontiguousarray(cv2.imread(str(rig["session"].frames[n]), cv2.IMREAD_UNCHANGED)[..., ::-1])


def _assert_same(h: np.ndarray, valid: np.ndarray, ref: perframe.FrameResult) -> None:
    assert h.dtype == np.float32 and valid.dtype == bool
    np.testing.assert_array_equal(valid, ref.valid)
    np.testing.assert_array_equal(np.isnan(h), ~valid)  # NaN exactly where invalid, in both
    np.testing.assert_array_equal(np.isnan(ref.height), ~ref.valid)
    assert valid.mean() > 0.8
    err = np.abs(h[valid].astype(np.float64) - ref.height[valid])
    assert err.max() <= TOL_MM, f"max |kernel - reference| = {err.max():.2e} mm"


@pytest.mark.parametrize(("model", "pd"), [("hexcone", True), ("hsi", True), ("hexcone", False)])
@pytest.mark.parametrize("denoise", [0, 2])
@pytest.mark.parametrize("own", [False, True])
def test_kernel_matches_reference(rig: dict, model: str, pd: bool, denoise: int, own: bool) -> None:
    """Same heights (to 1e-4 mm; bit for bit with hexcone) and valid mask as measure_frame, with
    and without the session's pre-distortion (the demo bench projects through one)."""
    assert rig["session"].predistortion is not None
    shadow = perframe.shadow_mask(rig["white"], CONFIG["measurement"]["shadow_fraction"])
    prep = _prepare(rig, model, shadow, pd, own)
    for n in rig["session"].frame_ids:
        ref = _reference(rig, model, read_rgb(rig["session"].frames[n]), shadow, denoise, pd, own)
        h, valid = kernel.frame_to_height(prep, _frame_u8(rig, n), denoise_radius=denoise)
        _assert_same(h, valid, ref)
        np.testing.assert_array_equal(h, ref.height)  # in fact bit for bit


@pytest.mark.parametrize(("model", "pd"), [("hexcone", True), ("hsi", True), ("hexcone", False)])
@pytest.mark.parametrize("denoise", [0, 2])
@pytest.mark.parametrize("own", [False, True])
def test_kernel_uncertainty_matches_reference(rig: dict, model: str, pd: bool, denoise: int, own: bool) -> None:
    """The kernel's uncertainty map is measure_frame's bit for bit, NaN exactly where the height
    is NaN, and the heights are those without the map (the weights from the smoothed signal, the
    default, or each pixel's own)."""
    assert perframe.sensor_model(rig[model][0]) is not None  # the weights' own-signal figure is compared
    shadow = perframe.shadow_mask(rig["white"], CONFIG["measurement"]["shadow_fraction"])
    prep = _prepare(rig, model, shadow, pd, own)
    for n in rig["session"].frame_ids:
        ref = _reference(rig, model, read_rgb(rig["session"].frames[n]), shadow, denoise, pd, own)
        m = kernel.frame_maps(prep, _frame_u8(rig, n), denoise_radius=denoise, want_uncertainty=True)
        _assert_same(m.height, m.valid, ref)
        np.testing.assert_array_equal(np.isnan(m.uncertainty), np.isnan(m.height))
        np.testing.assert_array_equal(np.isnan(ref.uncertainty), np.isnan(ref.height))
        if model == "hexcone":
            np.testing.assert_array_equal(m.uncertainty, ref.uncertainty)
            np.testing.assert_array_equal(m.height, ref.height)
        else:
            np.testing.assert_allclose(m.uncertainty[m.valid], ref.uncertainty[m.valid], rtol=1e-3)
        u = m.uncertainty[m.valid]
        assert np.all(u > 0) and 1e-4 < float(np.median(u)) < 0.5


def test_uint8_and_float_input_agree(rig: dict) -> None:
    prep = _prepare(rig, "hexcone", perframe.shadow_mask(rig["white"], 0.12))
    u8 = _frame_u8(rig, 0)
    f32 = read_rgb(rig["session"].frames[0])
    h8, v8 = kernel.frame_to_height(prep, u8)
    # uint8 codes are scaled exactly as session.read_rgb does: bit for bit the same heights
    for other in (f32, f32.astype(np.float64)):
        h, v = kernel.frame_to_height(prep, other)
        np.testing.assert_array_equal(v, v8)
        np.testing.assert_array_equal(h, h8)
    # 16-bit codes of the same levels (x 257) differ only by float32 rounding of the scaling
    h, v = kernel.frame_to_height(prep, u8.astype(np.uint16) * np.uint16(257))
    np.testing.assert_array_equal(v, v8)
    np.testing.assert_allclose(h, h8, rtol=0, atol=TOL_MM, equal_nan=True)


def test_invalid_pixels_are_nan_in_both(rig: dict) -> None:
    """Clipped, grey, shadowed and table-masked pixels: NaN and invalid, as the reference."""
    white = rig["white"]
    shadow = perframe.shadow_mask(white, 0.12)
    shadow[:10, :10] = True
    prep = _prepare(rig, "hexcone", shadow)
    u8 = _frame_u8(rig, 1).copy()
    u8[20:30, 40:60, 1] = 255  # clipped channel
    grey = np.round(white[50:55, 50:90] * 127).astype(np.uint8)  # the white, dimmed: grey once balanced
    u8[50:55, 50:90] = grey
    u8[70:72, :] = 0  # black
    rgb = u8.astype(np.float32) * np.float32(1 / 255)
    for denoise in (0, 2):
        ref = _reference(rig, "hexcone", rgb, shadow, denoise)
        m = kernel.frame_maps(prep, u8, denoise_radius=denoise, want_maps=True)
        _assert_same(m.height, m.valid, ref)
        assert not m.valid[20:30, 40:60].any() and not m.valid[50:55, 50:90].any() and not m.valid[:10, :10].any()
        np.testing.assert_array_equal(m.phase, ref.phase)
        np.testing.assert_array_equal(m.hue, ref.hue)
        assert m.counts["clipped"] == round(ref.stats["clipped_fraction"] * u8[..., 0].size)
        assert m.counts["valid"] == int(ref.valid.sum())
        assert m.counts["hue_undefined"] == round(ref.stats["hue_undefined_fraction"] * u8[..., 0].size)


def test_out_buffers_and_shadow_fraction(rig: dict) -> None:
    table, cal = rig["hexcone"]
    p1 = _prepare(rig, "hexcone", perframe.shadow_mask(rig["white"], 0.12))
    p2 = kernel.prepare(table, cal, rig["white"], min_saturation=0.08, shadow=0.12,  # fraction form
                        predistortion=rig["session"].predistortion)
    np.testing.assert_array_equal(p1.ok, p2.ok)
    u8 = _frame_u8(rig, 0)
    buf = (np.empty(p1.shape, np.float32), np.empty(p1.shape, bool))
    h, v = kernel.frame_to_height(p1, u8, out=buf)
    assert h is buf[0] and v is buf[1]
    np.testing.assert_array_equal(h, kernel.frame_to_height(p2, u8)[0])
    with pytest.raises(ValueError, match="shape"):
        kernel.frame_to_height(p1, u8[:-1])
    with pytest.raises(TypeError, match="dtype"):
        kernel.frame_to_height(p1, u8.astype(np.int16))
    with pytest.raises(ValueError, match="hue model"):
        kernel.prepare(table, cal, rig["white"], hue_model="lab", min_saturation=CONFIG["measurement"]["min_saturation"])


@pytest.mark.parametrize("denoise", [0, 2])
def test_kernel_with_the_phase_error_scaled_to_the_fringe_frequency_matches_reference(rig: dict, denoise: int) -> None:
    """``phase_error_frequency``: the kernel's heights, uncertainty and texture term are
    measure_frame's bit for bit, with the filter and without, and the scaling moves the heights
    (the rig's planes give a phase-error table)."""
    from huefringe import texture

    table, cal = rig["hexcone"]
    assert cal.phase_error is not None
    shadow = perframe.shadow_mask(rig["white"], CONFIG["measurement"]["shadow_fraction"])
    prep = _prepare(rig, "hexcone", shadow, frequency=True)
    adaptive = CONFIG["measurement"]["denoise_adaptive"] if denoise else None
    n = rig["session"].frame_ids[0]
    raw = read_rgb(rig["session"].frames[n])
    rgb, moved = texture.correct_pair(raw, rig["white"], 0.4, 0.5, clipped=perframe.clipped_mask(raw, 8))
    ref = perframe.measure_frame(rgb, rig["white"], table, cal, shadow=shadow, bit_depth=8, denoise_radius=denoise,
                                 **_FRAME_KEYS, predistortion=rig["session"].predistortion, denoise_adaptive=adaptive,
                                 texture_rgb=moved, phase_error_frequency=True)
    m = kernel.frame_maps(prep, rgb, denoise_radius=denoise, denoise_adaptive=adaptive, texture_rgb=moved,
                          want_uncertainty=True)
    _assert_same(m.height, m.valid, ref)
    np.testing.assert_array_equal(m.height, ref.height)
    np.testing.assert_array_equal(m.uncertainty, ref.uncertainty)
    np.testing.assert_array_equal(m.texture_u, ref.texture_u)
    h_only = kernel.frame_maps(prep, rgb, denoise_radius=denoise, denoise_adaptive=adaptive).height
    np.testing.assert_array_equal(h_only, ref.height)  # the path without the uncertainty too
    plain = kernel.frame_maps(_prepare(rig, "hexcone", shadow), rgb, denoise_radius=denoise, denoise_adaptive=adaptive)
    moved_px = np.isfinite(plain.height) & np.isfinite(m.height) & (plain.height != m.height)
    assert moved_px.mean() > 0.1


def test_prepared_layout(rig: dict) -> None:
    """Pixel-major columns: each usable pixel's column rotated to its start, sorted, in lines of
    32 entries, line j holding entries 29 j - 1 .. 29 j + 30 (entry -1 stored as 0, past the end
    65535); line heads; guess tables that mostly hit."""
    table, cal = rig["hexcone"]
    prep = kernel.prepare(table, cal, rig["white"], min_saturation=CONFIG["measurement"]["min_saturation"])
    assert prep.cols.ctypes.data % 64 == 0 and prep.cols.shape[2] == 32 * prep.nlines
    n = table.n_bands
    vv, uu = np.nonzero(prep.ok)
    for v, u in list(zip(vv, uu, strict=True))[:: max(1, len(vv) // 200)]:
        col = np.roll(np.asarray(table.table)[:, v, u], -int(table.start[v, u])).astype(np.int64)
        assert np.all(np.diff(col) >= 0)
        lines = prep.cols[v, u].reshape(prep.nlines, 32).astype(np.int64)
        padded = np.concatenate([[0], col, np.full(29 * prep.nlines + 2 - n, 65535)])  # entries -1 .. 29 nl + 1
        for j in range(prep.nlines):
            np.testing.assert_array_equal(lines[j], padded[29 * j : 29 * j + 32])
        np.testing.assert_array_equal(prep.heads[v, u, : prep.nlines], lines[:, 1])
    m = kernel.frame_maps(prep, _frame_u8(rig, 0))
    assert m.counts["guess_missed"] < 0.05 * m.counts["valid"]
    assert m.counts["guess_far"] < 0.2 * m.counts["guess_missed"]  # misses are mostly one line off


def _rotated_table(cols: np.ndarray, start: np.ndarray,
                   valid: np.ndarray) -> tuple[HueTable, PlaneCalibration, kernel.Prepared]:
    """A hue table whose pixel columns, rotated to ``start``, are the sorted ``cols`` ``(H, W, N)``,
    a flat calibration, and the kernel prepared on them (white image 1)."""
    h, w, n_bands = cols.shape
    idx = (start[..., None] + np.arange(n_bands)) % n_bands
    tab = np.empty((n_bands, h, w), np.uint16)
    np.put_along_axis(tab, np.moveaxis(idx, 2, 0), np.moveaxis(cols, 2, 0).astype(np.uint16), axis=0)
    table = HueTable("hexcone", n_bands, tab, valid, start.astype(np.uint16), np.zeros((h, w), np.uint8),
                     np.full((h, w), 0.01, np.float32), {"repeats": 1})
    cal = PlaneCalibration(np.zeros((h, w), np.float32), np.ones((h, w), np.float32), np.zeros((h, w), np.float32),
                           [0.0, 1.0])
    return table, cal, kernel.prepare(table, cal, np.ones((h, w, 3), np.float32), min_saturation=0.0)


@pytest.mark.parametrize("n_bands", [6, 28, 29, 30, 31, 32, 33, 100, 520])
def test_prepared_layout_of_every_pixel(n_bands: int) -> None:
    """The layout's definition on every pixel of random rotated tables (any N, columns ending
    at or across a line's end): line j holds sorted entries 29 j - 1 .. 29 j + 30 (entry -1 as 0,
    past the end 65535), the heads are the lines' entries 29 j (65535 for padding lines); a pixel
    not usable has columns 0 and heads 65535."""
    rng = np.random.default_rng(100 + n_bands)
    h, w = 7, 45
    cols = np.sort(rng.integers(0, 65536, (h, w, n_bands)), axis=2)
    _, _, prep = _rotated_table(cols, rng.integers(0, n_bands, (h, w)), rng.random((h, w)) > 0.15)
    nl = prep.nlines
    assert nl == -(-n_bands // 29)
    padded = np.concatenate([np.zeros((h, w, 1), np.int64), cols,
                             np.full((h, w, 29 * nl + 2 - n_bands), 65535)], axis=2)  # entries -1 .. 29 nl + 1
    want = np.stack([padded[..., 29 * j : 29 * j + 32] for j in range(nl)], axis=2).reshape(h, w, 32 * nl)
    heads = np.full(prep.heads.shape, 65535, np.int64)
    heads[..., :nl] = want[..., 1::32]
    ok = prep.ok
    assert ok.sum() > 0.7 * h * w and (~ok).sum() > 0
    np.testing.assert_array_equal(prep.cols[ok], want[ok])
    np.testing.assert_array_equal(prep.heads[ok], heads[ok])
    assert np.all(prep.cols[~ok] == 0) and np.all(prep.heads[~ok] == 65535)


@pytest.mark.parametrize("n_bands", [6, 31, 32, 33, 100, 520])
def test_lookup_matches_table_to_phase(n_bands: int) -> None:
    """Random sorted columns (rotated, with ties, any N): the kernel's phase is to_phase(hue)."""
    rng = np.random.default_rng(n_bands)
    h, w = 40, 70
    cols = np.sort(rng.integers(0, 65536, (h, w, n_bands)), axis=2)
    cols[:, :5, 1:3] = cols[:, :5, :1]  # ties
    cols[:3] = np.sort(rng.integers(0, 6000, (3, w, n_bands)), axis=2)  # unlike their tile: far misses
    start = rng.integers(0, n_bands, (h, w))
    valid = rng.random((h, w)) > 0.1
    table, cal, prep = _rotated_table(cols, start, valid)
    for _ in range(3):
        frame = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
        m = kernel.frame_maps(prep, frame, want_maps=True)
        np.testing.assert_array_equal(m.phase[m.valid], table.to_phase(m.hue)[m.valid])
        assert m.valid.sum() > 0.8 * valid.sum()
        # with the phase filter: its slope reads the entries either side of the bracketing pair,
        # here at every place in the lines and across the column's ends (frame scaled as read_rgb does)
        hk, vk = kernel.frame_to_height(prep, frame, denoise_radius=1)
        ref = perframe.measure_frame(frame.astype(np.float32) * np.float32(1 / 255), np.ones((h, w, 3), np.float32),
                                     table, cal, hue_model="hexcone", min_saturation=0.0, unwrap_mode="reference",
                                     denoise_radius=1)
        np.testing.assert_array_equal(vk, ref.valid)
        np.testing.assert_array_equal(hk[vk], ref.height[vk])
    if prep.nlines >= 3:  # random columns: both fallbacks (next line, line heads) are exercised
        assert m.counts["guess_missed"] > m.counts["guess_far"] > 0


def test_quick_benchmark_runs(tmp_path: Path) -> None:
    """``benchmarks/bench_stages.py --quick`` (160 x 120, 16 bands) runs end to end and prints its
    stage tables, the plane path's and the one-shot rig path's, and writes both into the page (a
    smoke test: no speed is asserted, and no time limit either)."""
    page = tmp_path / "page.md"
    page.write_text("# t\n<!-- stages:begin -->\nold\n<!-- stages:end -->\n"
                    "<!-- oneshot-stages:begin -->\nold\n<!-- oneshot-stages:end -->\n", encoding="utf-8")
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "bench_stages.py"), "--quick", "--page", str(page)],
                          capture_output=True, text=True, env=env, cwd=REPO)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "| adaptive |" in proc.stdout and "frames/s, 2 cores" in proc.stdout
    assert "| triangulate |" in proc.stdout and "| calibration u |" in proc.stdout
    text = page.read_text(encoding="utf-8")
    assert "old" not in text and "| texture u |" in text and "| order |" in text
    assert text.endswith("<!-- oneshot-stages:end -->\n")


def test_stage_table_states_the_compute_target() -> None:
    """The stage benchmark's plane table ends with the 640 x 480 compute target and whether it is
    met (docs/throughput.md); sizes without 640 x 480 print none. In a process of its own: the
    benchmark sets its thread count when imported."""
    code = ("import bench_stages as b\n"
            "r = lambda w, h, ms: {'size': [w, h], 'compute_ms': ms, 'threads': 1}\n"
            "print(repr(b.target_line([r(640, 480, 79.6), r(1280, 1024, 348.0)])))\n"
            "print(repr(b.target_line([r(640, 480, 29.9)])))\n"
            "print(repr(b.target_line([r(160, 120, 12.8)])))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO / "benchmarks",
                          env=dict(os.environ, NUMBA_NUM_THREADS="1"))
    assert proc.returncode == 0, proc.stderr[-3000:]
    missed, met, none = proc.stdout.splitlines()
    assert "79.6 ms, missed by 2.7 ×" in missed
    assert met.endswith("29.9 ms, met.\\n'")
    assert none == "''"


@pytest.mark.parametrize("pd", [True, False])
def test_kernel_matches_reference_with_phase_error_and_adaptive_filter(rig: dict, pd: bool) -> None:
    """A strong phase-error table (0.1 rad) and the sigma-adaptive filter with rejection: the
    kernel still gives the reference's heights bit for bit."""
    table, cal = rig["hexcone"]
    assert cal.phase_error is not None  # the default configuration learns one from the planes
    c = (np.arange(256) + 0.5) * 2 * np.pi / 256
    strong = copy.copy(cal)
    strong.phase_error = 0.1 * np.sin(3 * c) + 0.03 * np.cos(c)
    shadow = perframe.shadow_mask(rig["white"], CONFIG["measurement"]["shadow_fraction"])
    adaptive = {"enabled": True, "max_radius": 5, "target_sigma_rad": 0.02, "reject_sigma_rad": 0.05}
    prep = kernel.prepare(table, strong, rig["white"], hue_model="hexcone", min_saturation=CONFIG["measurement"]["min_saturation"],
                          shadow=shadow, bit_depth=8, predistortion=rig["session"].predistortion if pd else None)
    for n in rig["session"].frame_ids:
        ref = perframe.measure_frame(read_rgb(rig["session"].frames[n]), rig["white"], table, strong, shadow=shadow,
                                     bit_depth=8, denoise_radius=2, **_FRAME_KEYS, denoise_adaptive=adaptive,
                                     predistortion=rig["session"].predistortion if pd else None)
        m = kernel.frame_maps(prep, _frame_u8(rig, n), denoise_radius=2, denoise_adaptive=adaptive, want_maps=True)
        np.testing.assert_array_equal(m.valid, ref.valid)
        np.testing.assert_array_equal(m.height, ref.height)
        np.testing.assert_array_equal(m.phase, ref.phase)


@pytest.mark.parametrize("denoise", [0, 2])
def test_texture_term_in_one_pass_matches_reference_and_the_second_pass(rig: dict, denoise: int) -> None:
    """The texture term carried through the frame's own filter (``texture_rgb``): the kernel's is
    measure_frame's bit for bit. Without the filter it is the definition ``|h(s + u) - h(s)|`` (the
    moved capture through the whole chain); with it, the first-order term (the frame's weights and
    windows held fixed) has the definition's median (measured 0.81 / 0.59 um, u = 0.1 px^2) and
    leaves out its tail of the filter's decisions flipping between the two passes (a neighbour
    accepted in one and rejected in the other, a window grown to another radius: p99 15 / 86 um)."""
    from huefringe import texture

    shadow = perframe.shadow_mask(rig["white"], CONFIG["measurement"]["shadow_fraction"])
    prep = _prepare(rig, "hexcone", shadow)
    table, cal = rig["hexcone"]
    adaptive = CONFIG["measurement"]["denoise_adaptive"] if denoise else None
    n = rig["session"].frame_ids[0]
    raw = read_rgb(rig["session"].frames[n])
    rgb, moved = texture.correct_pair(raw, rig["white"], 0.4, 0.5, clipped=perframe.clipped_mask(raw, 8))
    ref = perframe.measure_frame(rgb, rig["white"], table, cal, shadow=shadow, bit_depth=8, denoise_radius=denoise, **_FRAME_KEYS,
                                 predistortion=rig["session"].predistortion, denoise_adaptive=adaptive,
                                 texture_rgb=moved)
    m = kernel.frame_maps(prep, rgb, denoise_radius=denoise, denoise_adaptive=adaptive, texture_rgb=moved)
    np.testing.assert_array_equal(m.height, ref.height)
    np.testing.assert_array_equal(m.texture_u, ref.texture_u)
    np.testing.assert_array_equal(np.isnan(m.texture_u), np.isnan(m.height))
    two = uncertainty.texture_term(m.height, kernel.frame_maps(prep, moved, denoise_radius=denoise,
                                                                 denoise_adaptive=adaptive).height)
    ok = np.isfinite(m.texture_u) & np.isfinite(two)
    one, full = m.texture_u[ok].astype(np.float64), two[ok].astype(np.float64)
    if denoise == 0:
        np.testing.assert_allclose(one, full, rtol=1e-4, atol=1e-6)
    else:
        assert 0.5 < np.median(one) / np.median(full) < 2.0
        assert np.percentile(one, 99) < np.percentile(full, 99)
    assert np.median(full) > 1e-4  # the term has something to say on this frame


def test_kernel_with_pooled_weights_matches_reference(rig: dict) -> None:
    """``weight_blur_px`` 0 (the table's pooled figure weights the filter): the kernel's heights
    and uncertainty are measure_frame's bit for bit, and differ from the default weights'."""
    shadow = perframe.shadow_mask(rig["white"], CONFIG["measurement"]["shadow_fraction"])
    prep = _prepare(rig, "hexcone", shadow, blur=0.0)
    n = rig["session"].frame_ids[0]
    ref = _reference(rig, "hexcone", read_rgb(rig["session"].frames[n]), shadow, 2, blur=0.0)
    m = kernel.frame_maps(prep, _frame_u8(rig, n), denoise_radius=2, want_uncertainty=True)
    np.testing.assert_array_equal(m.height, ref.height)
    np.testing.assert_array_equal(m.uncertainty, ref.uncertainty)
    default = kernel.frame_maps(_prepare(rig, "hexcone", shadow), _frame_u8(rig, n), denoise_radius=2)
    assert np.nanmax(np.abs(default.height - m.height)) > 1e-4


def test_kernel_with_weights_along_the_fringe_matches_reference(rig: dict) -> None:
    """``weight_blur_shape: along_fringe`` (the weights' Gaussian along the reference phase's
    iso-phase lines): the kernel's heights and uncertainty are measure_frame's bit for bit, and
    differ from the default isotropic weights'."""
    shadow = perframe.shadow_mask(rig["white"], CONFIG["measurement"]["shadow_fraction"])
    prep = _prepare(rig, "hexcone", shadow, shape="along_fringe")
    assert prep.weight_angle is not None
    n = rig["session"].frame_ids[0]
    ref = _reference(rig, "hexcone", read_rgb(rig["session"].frames[n]), shadow, 2, shape="along_fringe")
    m = kernel.frame_maps(prep, _frame_u8(rig, n), denoise_radius=2, want_uncertainty=True)
    np.testing.assert_array_equal(m.height, ref.height)
    np.testing.assert_array_equal(m.uncertainty, ref.uncertainty)
    default = kernel.frame_maps(_prepare(rig, "hexcone", shadow), _frame_u8(rig, n), denoise_radius=2)
    assert np.nanmax(np.abs(default.height - m.height)) > 1e-4
