"""Per-pixel hue tables: streamed build, masking, inverse lookup, persistence, Fig. 6 loop, QA.

All scenes come from the toy rig (huefringe.bench.toy.ToyRig) (eqs. 6-8 plus crosstalk):
camera column = projector column, fringes along columns, surfaces in horizontal stripes.
"""

from __future__ import annotations

import functools
import tracemalloc
import weakref
from pathlib import Path

import numpy as np
import pytest

from huefringe import colour, compensation
from huefringe import huetable as cal
from huefringe.bench.toy import BandReader, ToyRig, surface_rows
from huefringe.io import write_png_rgb
from huefringe.patterns import TWO_PI, band_rgb, trapezoid_rgb

N_BANDS, REPEATS = 256, 3
H, W = 14, 112
PERIOD = 37.3  # camera px; not a divisor of W so that many code phases are sampled
CROSSTALK = np.array([[0.85, 0.12, 0.03], [0.10, 0.80, 0.10], [0.03, 0.12, 0.85]])
WHITE, RED, DARK, BLACK = (0.9, 0.9, 0.9), (0.85, 0.2, 0.12), (0.1, 0.1, 0.1), (0.003, 0.003, 0.003)
REGIONS = {"white": slice(0, 4), "red": slice(4, 8), "dark": slice(8, 12)}
BLACK_ROWS = slice(12, 14)

SCENARIOS = {
    # gamma 1 alone does not distort: crosstalk and ambient light do
    "gamma1.0+crosstalk+ambient": dict(gamma=(1.0, 1.0, 1.0), crosstalk=CROSSTALK,
                                       ambient_proj=(0.03, 0.03, 0.03), ambient_cam=(0.02, 0.01, 0.02)),
    "gamma2.2": dict(gamma=(2.2, 2.2, 2.2)),
    "gamma1.8/2.2/2.6+crosstalk+ambient": dict(gamma=(1.8, 2.2, 2.6), crosstalk=CROSSTALK,
                                               ambient_proj=(0.02, 0.02, 0.02), ambient_cam=(0.01, 0.01, 0.01)),
}


def circ(a, b):
    return colour.wrap_pi(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))


def rms(x):
    x = np.asarray(x, dtype=np.float64)
    return float(np.sqrt(np.nanmean(x**2)))


def stripes() -> np.ndarray:
    return surface_rows(H, W, [(4, WHITE), (4, RED), (4, DARK), (2, BLACK)])


def make_rig(name: str, *, bits: int = 12, noise: float = 0.001, seed: int = 1, refl=None) -> ToyRig:
    return ToyRig(stripes() if refl is None else refl, bits=bits, noise=noise, seed=seed, **SCENARIOS[name])


@functools.cache
def built(name: str, model: str = "hexcone", smooth_window: int = 15):
    """(rig, white, table) of a scenario; cached across tests (tables are not modified)."""
    rig = make_rig(name)
    white = rig.white()
    rd = BandReader(rig, N_BANDS)
    tab = cal.build_table(rd.paths(REPEATS), white, read=rd, model=model, smooth_window=smooth_window)
    return rig, white, tab


def decode(tab: cal.HueTable, white, img):
    """Raw hue (white-balanced, table model) and table-corrected phase of a frame."""
    bal = colour.white_balance(img, white, floor=tab.stats["params"]["floor"])
    raw = colour.hue(bal, tab.model)
    return raw, tab.to_phase(raw)


# ============================================================================================
# correction accuracy
# ============================================================================================
@pytest.mark.parametrize(
    ("name", "model"),
    [(n, "hexcone") for n in SCENARIOS] + [("gamma1.8/2.2/2.6+crosstalk+ambient", "hsi")],
)
def test_corrected_phase_matches_true_code_phase(name, model):
    rig, white, tab = built(name, model)
    # the frame is captured without fresh noise (still quantised to 12 bits): this measures the
    # systematic error the table must remove; the frame's own noise is a separate term
    img, true = rig.fringe(PERIOD, noise=0.0)
    raw, ph = decode(tab, white, img)
    for region, rows in REGIONS.items():
        before = rms(circ(raw[rows], true[rows]))
        after = rms(circ(ph[rows], true[rows]))
        print(f"{name:36s} {model:7s} {region:5s} RMS before {before:.4f} after {after:.4f} rad "
              f"(x{before / after:.1f}), valid {tab.valid[rows].mean():.3f}")
        assert tab.valid[rows].mean() >= 0.98, region
        assert np.isfinite(ph[rows][tab.valid[rows]]).all()
        assert before > 0.05, "the scenario must distort the hue"
        assert after <= before / 5, region
    assert not tab.valid[BLACK_ROWS].any()


def test_noisy_frames_are_still_improved():
    rig, white, tab = built("gamma1.8/2.2/2.6+crosstalk+ambient")
    img, true = rig.fringe(PERIOD)  # with camera noise
    raw, ph = decode(tab, white, img)
    np.testing.assert_array_equal(tab.phase_from_rgb(img, white), ph)  # the one-call decoder
    rows = REGIONS["white"]
    before, after = rms(circ(raw[rows], true[rows])), rms(circ(ph[rows], true[rows]))
    print(f"noisy frame, white: before {before:.4f} after {after:.4f}")
    assert after <= before / 5


def test_uncalibrated_hue_error_is_large_on_coloured_surfaces():
    # sanity of the forward model: white balance alone does not fix gamma + crosstalk on red
    rig, white, tab = built("gamma1.8/2.2/2.6+crosstalk+ambient")
    img, true = rig.fringe(PERIOD, noise=0.0)
    raw, _ = decode(tab, white, img)
    assert np.nanmax(np.abs(circ(raw[REGIONS["red"]], true[REGIONS["red"]]))) > 0.3


# ============================================================================================
# inverse lookup
# ============================================================================================
def test_numba_lookup_matches_numpy_reference():
    _, _, tab = built("gamma1.8/2.2/2.6+crosstalk+ambient")
    rng = np.random.default_rng(5)
    hue = rng.uniform(-1.0, TWO_PI + 1.0, tab.shape)  # values outside [0, 2 pi) are taken mod 2 pi
    hue[0, :5] = np.nan
    # hit table entries exactly (ties) and the wrap interval
    v, u = 2, 7
    hue[v, u] = tab.table[tab.start[v, u], v, u] * cal.RAD_PER_COUNT
    hue[v, u + 1] = tab.table[(tab.start[v, u + 1] - 1) % N_BANDS, v, u + 1] * cal.RAD_PER_COUNT
    hue[v, u + 2] = 0.0
    a = tab.to_phase(hue)
    b = tab.to_phase(hue, method="numpy")
    assert a.dtype == b.dtype == np.float32
    assert np.array_equal(np.isnan(a), np.isnan(b))
    assert np.isnan(a[0, :5]).all() and np.isnan(a[BLACK_ROWS]).all()
    fin = np.isfinite(a)
    assert fin.sum() > 0.7 * a.size
    assert np.max(np.abs(circ(a[fin], b[fin]))) < 1e-6
    assert np.all((a[fin] >= 0) & (a[fin] < TWO_PI))


def test_lookup_on_handmade_tables_with_ties_and_every_rotation():
    n, w = 8, 8
    base = np.array([0, 0, 5000, 9000, 20000, 30000, 30000, 50000], dtype=np.int64)  # ties included
    table = np.empty((n, 1, w), dtype=np.uint16)
    start = np.empty((1, w), dtype=np.uint16)
    for k in range(w):  # rotate and offset so that the wrap sits at every band
        col = (np.roll(base, k) + 1000 * k) % cal.COUNTS
        table[:, 0, k] = col
        desc = [i for i in range(n) if col[i] < col[i - 1]]  # start = the band after the descent
        assert len(desc) == 1
        start[0, k] = desc[0]
    tab = cal.HueTable(model="hexcone", n_bands=n, table=table, valid=np.ones((1, w), bool), start=start,
                       reason=np.zeros((1, w), np.uint8), noise_rad=np.zeros((1, w), np.float32))
    rng = np.random.default_rng(0)
    for _ in range(50):
        hue = rng.uniform(0, TWO_PI, (1, w))
        hue[0, ::3] = table[rng.integers(0, n), 0, ::3] * cal.RAD_PER_COUNT  # exact entries
        a, b = tab.to_phase(hue), tab.to_phase(hue, method="numpy")
        assert np.max(np.abs(circ(a, b))) < 1e-6
        # forward(inverse(h)) == h wherever the table is not flat at h
        assert np.max(np.abs(circ(tab.from_phase(a), hue))) < 1e-3


def gamma_table_at_random_codes(seed: int) -> tuple[cal.HueTable, np.ndarray, np.ndarray]:
    """The gamma-2.2 rig's table, random code phases and the hues the table gives them."""
    _, _, tab = built("gamma2.2")
    c = np.random.default_rng(seed).uniform(0, TWO_PI, tab.shape)
    return tab, c, tab.from_phase(c)


def test_forward_and_inverse_tables_are_consistent():
    tab, c, h = gamma_table_at_random_codes(2)
    back = tab.to_phase(h)
    ok = tab.valid
    assert np.isnan(h[~ok]).all()
    # where the table slope is tiny (flat gamma stretches) many codes share a hue: compare hues
    assert np.max(np.abs(circ(tab.from_phase(back)[ok], h[ok]))) < 2e-4
    assert np.median(np.abs(circ(back[ok], c[ok]))) < 1e-3


def test_hue_slope_is_the_central_difference_over_one_band():
    tab, _, hue = gamma_table_at_random_codes(4)
    slope = tab.hue_slope(hue)
    ok = tab.valid & np.isfinite(hue)
    assert np.isnan(slope[~tab.valid]).all()
    # [H(c + pi/N) - H(c - pi/N)] / (2 pi/N) of the forward table at the decoded code phase
    half = np.pi / tab.n_bands
    back = tab.to_phase(hue).astype(np.float64)
    fd = circ(tab.from_phase(np.mod(back + half, TWO_PI)).astype(np.float64),
              tab.from_phase(np.mod(back - half, TWO_PI))) / (2 * half)
    err = np.abs(slope[ok] - fd[ok])
    assert np.median(err) < 1e-4 and np.percentile(err, 99) < 1e-3  # from_phase rounds to float32; one band alone: 0.01, 0.08
    # gamma 2.2 bends the hue: slopes well away from 1 on both sides, mean about 1 (one turn)
    assert np.percentile(slope[ok], 5) < 0.7 and np.percentile(slope[ok], 95) > 1.3
    assert abs(np.mean(slope[ok]) - 1.0) < 0.1


def test_decode_slope_is_the_slope_of_the_decode_segment():
    from huefringe.session import Predistortion

    code = TWO_PI * np.arange(64) / 64
    emitted = code + 0.3 * np.sin(code)  # d emitted / d code = 1 + 0.3 cos(code)
    pd = Predistortion(path=Path("predistortion.csv"), code=code, emitted=emitted)
    e = np.linspace(-1.0, 8.0, 997)
    fd = circ(pd.decode(e + 1e-4).astype(np.float64), pd.decode(e - 1e-4)) / 2e-4
    slope = pd.decode_slope(e)
    inside = np.abs(slope - fd) < 1e-2  # central differences straddle a knot at a few points
    assert inside.mean() > 0.97
    c = pd.decode(e).astype(np.float64)
    assert np.max(np.abs(slope - 1.0 / (1.0 + 0.3 * np.cos(c)))) < 0.02


def test_tables_are_circularly_sorted_from_start():
    _, _, tab = built("gamma1.8/2.2/2.6+crosstalk+ambient")
    t = np.asarray(tab.table).astype(np.int64)
    idx = (tab.start[None].astype(np.int64) + np.arange(N_BANDS)[:, None, None]) % N_BANDS
    rot = np.take_along_axis(t, idx, axis=0)
    assert np.all(np.diff(rot, axis=0)[:, tab.valid] >= 0)


# ============================================================================================
# masking
# ============================================================================================
class TamperedReader(BandReader):
    """Band images with pixels that break the calibration in known ways."""

    def __call__(self, key):
        img = super().__call__(key).copy()
        i = key[0]
        img[0, 0:4] = (0.8, 0.2, 0.1)  # a self-luminous spot: constant colour -> no coverage
        img[0, 4:8] = 1.0  # saturated glint: grey -> no hue
        c = TWO_PI * i / self.n_bands  # hue running backwards over part of the circle
        img[1, 0:4] = trapezoid_rgb(c + 0.6 * np.sin(3 * c)) * 0.8
        img[1, 4:8] = np.clip(img[1, 4:8] + self.rig.rng.normal(0, 0.15, (4, 3)), 0, 1)  # very noisy
        return img


def test_masked_pixels_are_counted_by_reason():
    rig = ToyRig(surface_rows(4, 16, [(2, WHITE), (2, BLACK)]), gamma=(2.2, 2.2, 2.2), bits=12, noise=0.001)
    white = rig.white()
    white[0, 4:8] = 1.0
    rd = TamperedReader(rig, N_BANDS)
    tab = cal.build_table(rd.paths(REPEATS), white, read=rd)
    m = tab.stats["masked_by_reason"]
    assert m == {"low_signal": 32, "low_saturation": 4, "noise": 4, "coverage": 4, "order": 4}
    assert (tab.reason[2:] == cal.REASONS.index("low_signal")).all()
    assert (tab.reason[0, 0:4] == cal.REASONS.index("coverage")).all()
    assert (tab.reason[0, 4:8] == cal.REASONS.index("low_saturation")).all()
    assert (tab.reason[1, 0:4] == cal.REASONS.index("order")).all()
    assert (tab.reason[1, 4:8] == cal.REASONS.index("noise")).all()
    assert tab.valid[:2, 8:].all()
    assert tab.stats["n_valid"] == 16 and tab.stats["valid_fraction"] == pytest.approx(16 / 64)
    assert sum(m.values()) + tab.stats["n_valid"] == 64


def test_build_rejects_bad_input():
    rig = make_rig("gamma2.2")
    white = rig.white()
    rd = BandReader(rig, 8)
    with pytest.raises(ValueError):
        cal.build_table(rd.paths(2)[:5], white, read=rd)
    with pytest.raises(ValueError):
        cal.build_table(rd.paths(2)[:7] + [[(7, 0)]], white, read=rd)
    with pytest.raises(ValueError):
        cal.build_table(rd.paths(2), white[:5], read=rd)
    with pytest.raises(ValueError):
        cal.build_table(rd.paths(2), white, read=rd, model="hsv")  # type: ignore[arg-type]


# ============================================================================================
# smoothing does not bleed across colour edges
# ============================================================================================
def test_smoothing_does_not_bleed_across_a_sharp_colour_edge():
    edge = 50
    refl = np.zeros((4, W, 3))
    refl[:, :edge] = WHITE
    refl[:, edge:] = RED
    kw = SCENARIOS["gamma1.8/2.2/2.6+crosstalk+ambient"]
    # the same noise realisation (same seed, same shape) in both sessions
    edge_rig = ToyRig(refl, bits=12, noise=0.001, seed=9, **kw)
    flat_rig = ToyRig(np.broadcast_to(np.array(WHITE), refl.shape).copy(), bits=12, noise=0.001, seed=9, **kw)
    tabs = []
    for rig in (edge_rig, flat_rig):
        white = rig.white()
        rd = BandReader(rig, N_BANDS)
        tabs.append(cal.build_table(rd.paths(REPEATS), white, read=rd, smooth_window=15))
    te, tf = tabs
    # the white side of the edge gets exactly the table of an all-white scene: no pixel borrows
    # anything from a neighbour, however strong the edge
    assert np.array_equal(np.asarray(te.table)[:, :, :edge], np.asarray(tf.table)[:, :, :edge])
    # and the red side right at the edge is calibrated as well as the red interior
    img, true = edge_rig.fringe(PERIOD, noise=0.0)
    _, ph = decode(te, edge_rig.white(), img)
    err = np.abs(circ(ph, true))
    assert np.nanmax(err[:, edge - 1 : edge + 1]) < 0.1
    assert rms(err[:, edge : edge + 2]) < 3 * rms(err[:, edge + 10 :]) + 0.01
    assert rms(err[:, edge - 2 : edge]) < 3 * rms(err[:, : edge - 10]) + 0.01


def test_band_axis_smoothing_reduces_table_noise():
    name = "gamma1.8/2.2/2.6+crosstalk+ambient"
    _, white, smooth = built(name, "hexcone", 15)
    _, _, raw = built(name, "hexcone", 1)
    # noise-free truth of the same scene, balanced with the same (noisy) white capture: the
    # white's noise is a smooth per-pixel distortion the table must keep, not table noise
    rig0 = make_rig(name, noise=0.0, bits=16)
    rd = BandReader(rig0, N_BANDS)
    truth = cal.build_table(rd.paths(1), white, read=rd, smooth_window=1)
    rows = REGIONS["dark"]
    t0 = np.asarray(truth.table)[:, rows].astype(np.float64) * cal.RAD_PER_COUNT
    e_raw = rms(circ(np.asarray(raw.table)[:, rows] * cal.RAD_PER_COUNT, t0))
    e_smooth = rms(circ(np.asarray(smooth.table)[:, rows] * cal.RAD_PER_COUNT, t0))
    print(f"table error vs noise-free truth: raw {e_raw:.4f}, smoothed {e_smooth:.4f} rad")
    assert e_smooth < 0.8 * e_raw


# ============================================================================================
# streaming, memory, sizes
# ============================================================================================
def test_table_size_formula():
    assert cal.table_nbytes(256, 768, 1024) == 402_653_184  # 403 MB
    assert cal.table_nbytes(256, 494, 768) == 194_248_704
    _, _, tab = built("gamma2.2")
    assert tab.table.dtype == np.uint16
    assert tab.table.nbytes == cal.table_nbytes(N_BANDS, H, W) == 2 * N_BANDS * H * W
    assert tab.stats["table_bytes"] == tab.table.nbytes


def test_build_streams_images_one_band_at_a_time():
    h, w = 32, 48
    rig = ToyRig(surface_rows(h, w, [(h, WHITE)]), gamma=(2.2, 2.2, 2.2), noise=0.002)
    white = rig.white()
    gen = np.random.default_rng(0)
    alive: list[weakref.ref] = []
    max_alive = [0]
    calls = []

    def read(key):
        i, _r = key
        calls.append(key)
        img = np.clip(band_rgb(i, N_BANDS)[None, None] * white + gen.normal(0, 0.002, (h, w, 3)), 0, 1)
        img = img.astype(np.float32)
        alive[:] = [r for r in alive if r() is not None]
        alive.append(weakref.ref(img))
        max_alive[0] = max(max_alive[0], len(alive))
        return img

    paths = [[(i, r) for r in range(REPEATS)] for i in range(N_BANDS)]
    cal.build_table(paths[:8], white, read=read, smooth_window=1)  # warm numba outside tracing
    calls.clear()
    max_alive[0] = 0
    tracemalloc.start()
    try:
        tab = cal.build_table(paths, white, read=read)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert calls == [(i, r) for i in range(N_BANDS) for r in range(REPEATS)]  # sequential, once each
    assert max_alive[0] <= REPEATS  # never more than one band's repeats alive
    table_bytes = cal.table_nbytes(N_BANDS, h, w)
    all_images = N_BANDS * REPEATS * h * w * 3 * 4
    print(f"peak {peak / 1e6:.2f} MB, table {table_bytes / 1e6:.2f} MB, all images {all_images / 1e6:.1f} MB")
    # the sensor-noise fit keeps 56 bytes per sample (every third pixel each way, every band) and
    # about three times that while fitting
    fit_bytes = 3 * 56 * N_BANDS * (-(-h // 3)) * (-(-w // 3))
    assert peak < table_bytes + 60 * h * w * 4 + fit_bytes + 500_000
    assert peak < all_images / 4
    assert tab.stats["valid_fraction"] == 1.0


def test_prefetching_reader_gives_the_same_table():
    rig = make_rig("gamma2.2")
    white = rig.white()
    bands = {(i, r): rig.band(i, 64) for i in range(64) for r in range(2)}
    paths = [[(i, r) for r in range(2)] for i in range(64)]
    a = cal.build_table(paths, white, read=bands.__getitem__)
    b = cal.build_table(paths, white, read=bands.__getitem__, prefetch=2)
    np.testing.assert_array_equal(np.asarray(a.table), np.asarray(b.table))
    np.testing.assert_array_equal(a.reason, b.reason)
    assert a.stats == b.stats


def test_on_image_sees_every_image_as_read_once_in_order_with_prefetch():
    rig = make_rig("gamma2.2")
    white = rig.white()
    bands = {(i, r): rig.band(i, 24) for i in range(24) for r in range(2)}
    paths = [[(i, r) for r in range(2)] for i in range(24)]
    seen = []

    def on_image(i, r, img):
        assert img is bands[(i, r)]                     # the array read, not a copy or a reduction
        seen.append((i, r))

    a = cal.build_table(paths, white, read=bands.__getitem__)
    b = cal.build_table(paths, white, read=bands.__getitem__, prefetch=2, on_image=on_image)
    assert seen == [(i, r) for i in range(24) for r in range(2)]
    np.testing.assert_array_equal(np.asarray(a.table), np.asarray(b.table))
    assert a.stats == b.stats


def test_on_hue_gives_every_image_the_tables_own_white_balanced_hue():
    rig = make_rig("gamma2.2")
    white = rig.white().copy()
    white[0, 0, 2] = 0.006                              # between one 8-bit count and the table's floor 0.01
    bands = {(i, r): rig.band(i, 24) for i in range(24) for r in range(2)}
    paths = [[(i, r) for r in range(2)] for i in range(24)]
    gains = colour.white_gains(white, cal.white_balance_floor(0.02))
    seen = []

    def on_hue(i, r, hue):
        want = colour.balanced_hue(bands[(i, r)], gains, "hexcone", min_saturation=0.05)
        np.testing.assert_array_equal(hue, want)
        seen.append((i, r, float(hue[0, 0])))

    a = cal.build_table(paths, white, read=bands.__getitem__, min_intensity=0.02, min_saturation=0.05)
    b = cal.build_table(paths, white, read=bands.__getitem__, min_intensity=0.02, min_saturation=0.05, on_hue=on_hue)
    assert [s[:2] for s in seen] == [(i, r) for i in range(24) for r in range(2)]
    np.testing.assert_array_equal(np.asarray(a.table), np.asarray(b.table))
    assert cal.white_balance_floor(0.02) == 0.01 and cal.white_balance_floor(0.0) == 1.0 / 255.0
    # the floor is the table's: one 8-bit count would give that pixel another hue
    other = colour.white_gains(white, 1.0 / 255.0)
    moved = [abs(colour.balanced_hue(bands[(i, r)], other, "hexcone", min_saturation=0.05)[0, 0] - h)
             for i, r, h in seen if np.isfinite(h)]
    assert max(moved) > 1e-2


def test_build_from_png_files_and_preallocated_memmap(tmp_path):
    n, reps, h, w = 32, 2, 6, 20
    rig = ToyRig(surface_rows(h, w, [(3, WHITE), (3, RED)]), gamma=(2.2, 2.2, 2.2), bits=16, noise=0.001)
    white = rig.white()
    hue_dir = tmp_path / "hue"
    for i in range(n):
        for r in range(reps):
            write_png_rgb(hue_dir / f"band_{i:03d}_r{r}.png", np.round(rig.band(i, n) * 65535).astype(np.uint16))
    paths = cal.hue_band_paths(hue_dir, n, reps)
    assert paths[3][1].name == "band_003_r1.png"
    out = np.lib.format.open_memmap(tmp_path / "scratch.npy", mode="w+", dtype=np.uint16, shape=(n, h, w))
    tab = cal.build_table(paths, white, out=out, smooth_window=5)
    assert tab.table is out and tab.valid.all()
    img, true = rig.fringe(9.7, noise=0.0)
    _, ph = decode(tab, white, img)
    assert rms(circ(ph, true)) < 0.03


# ============================================================================================
# persistence
# ============================================================================================
def test_save_load_roundtrip(tmp_path):
    _, white, tab = built("gamma1.8/2.2/2.6+crosstalk+ambient")
    path = tab.save(tmp_path / "calib" / "hue_table")
    assert path.name == "hue_table.json"
    names = sorted(p.name for p in (tmp_path / "calib").iterdir())
    assert names == ["hue_table.json", "hue_table.maps.npz", "hue_table.npy"]  # no temporaries left
    back = cal.HueTable.load(tmp_path / "calib" / "hue_table.json", verify=True)
    assert isinstance(back.table, np.memmap)
    assert back.model == tab.model and back.n_bands == tab.n_bands
    for f in ("table", "valid", "start", "reason", "noise_rad"):
        np.testing.assert_array_equal(np.asarray(getattr(back, f)), np.asarray(getattr(tab, f)))
    assert back.stats == tab.stats
    hue = np.random.default_rng(0).uniform(0, TWO_PI, tab.shape)
    np.testing.assert_array_equal(back.to_phase(hue), tab.to_phase(hue))
    loaded = cal.HueTable.load(tmp_path / "calib" / "hue_table", mmap=False)
    assert not isinstance(loaded.table, np.memmap)
    # a table from another save is detected
    other = cal.HueTable(**{**tab.__dict__, "table": np.asarray(tab.table) ^ np.uint16(1)})
    other.save(tmp_path / "other")
    (tmp_path / "other.npy").replace(tmp_path / "calib" / "hue_table.npy")
    with pytest.raises(ValueError):
        cal.HueTable.load(tmp_path / "calib" / "hue_table", verify=True)


# ============================================================================================
# compensation loop (Fig. 6)
# ============================================================================================
def test_compensation_loop_converges_and_linearises_the_captured_hue():
    name = "gamma1.8/2.2/2.6+crosstalk+ambient"
    rig = make_rig(name, refl=surface_rows(H, W, [(H, WHITE)]))  # the flat white plate
    white = rig.white()
    rd = BandReader(rig, N_BANDS)
    tab = cal.build_table(rd.paths(REPEATS), white, read=rd)
    threshold = 0.004
    pattern, hist = compensation.compensate_pattern(tab, period_px_projector=PERIOD, projector_size=(W, 6),
                                           threshold_rad=threshold, max_iter=40, gain=0.8)
    assert pattern.dtype == np.uint8 and pattern.shape == (6, W, 3)
    assert (pattern == pattern[:1]).all()  # constant along rows
    assert [h["iteration"] for h in hist] == list(range(len(hist)))
    print("loop:", [(h["iteration"], round(h["std_rad"], 5)) for h in hist])
    assert hist[-1]["std_rad"] < threshold < hist[0]["std_rad"]
    assert hist[0]["std_rad"] >= 10 * hist[-1]["std_rad"]
    # project the pre-distorted pattern through the rig: the captured hue becomes linear
    _, true = rig.fringe(PERIOD, noise=0.0)
    plain = rig.capture(trapezoid_rgb(true[:1])[0][None], noise=0.0)
    comp = rig.capture(pattern[:1].astype(np.float64) / 255.0, noise=0.0)
    bal = functools.partial(colour.white_balance, white=white, floor=tab.stats["params"]["floor"])
    e_plain = rms(circ(colour.hue(bal(plain)), true))
    e_comp = rms(circ(colour.hue(bal(comp)), true))
    print(f"captured hue vs code phase: plain pattern {e_plain:.4f}, compensated {e_comp:.4f} rad")
    assert e_comp <= e_plain / 5


def test_predistortion_inverts_a_known_transfer():
    code = TWO_PI * np.arange(64) / 64
    dist = 0.25 * np.sin(code) + 0.1 * np.sin(3 * code + 1) + 0.3  # offset included
    c, p, hist = compensation.predistortion(code, dist, threshold_rad=1e-5, max_iter=60, gain=1.0)
    assert hist[-1]["std_rad"] < 1e-5 and hist[-1]["max_rad"] < 1e-4
    f = p + np.interp(np.mod(p, TWO_PI), np.r_[code, TWO_PI], np.r_[dist, dist[0]])
    assert np.max(np.abs(circ(f, c))) < 1e-4
    with pytest.raises(ValueError):
        compensation.predistortion(code, dist, gain=0.0)


# ============================================================================================
# QA
# ============================================================================================
def test_qa_stats_and_figures(tmp_path):
    name = "gamma1.8/2.2/2.6+crosstalk+ambient"
    rig, white, tab = built(name)
    img, true = rig.fringe(PERIOD, noise=0.0)
    raw, ph = decode(tab, white, img)
    bal = colour.white_balance(img, white, floor=tab.stats["params"]["floor"])
    q = compensation.qa_stats(raw, ph, true_phase=true, table=tab, raw_rgb=bal)
    assert q["reference"] == "true_phase"
    assert q["before"]["rms_rad"] > 5 * q["after"]["rms_rad"]
    assert q["improvement"] > 5
    assert q["masked_by_reason"]["low_signal"] == 2 * W
    assert q["valid_fraction"] == pytest.approx(tab.valid.mean())
    assert q["linearity"]["hexcone"]["rms_rad"] < 1e-6 < q["linearity"]["hsi"]["rms_rad"]
    assert set(q["data_linearity"]) == {"hexcone", "hsi"} and q["better_model"] in ("hexcone", "hsi")
    # without the true phase: ripples relative to a per-row straight line
    q2 = compensation.qa_stats(raw, ph, table=tab)
    assert q2["reference"] == "row_linear_fit"
    assert q2["before"]["rms_rad"] > 5 * q2["after"]["rms_rad"]
    f1 = compensation.hue_cross_section_figure(raw[1], ph[1], true[1], tmp_path / "qa" / "cross.png")
    f2 = compensation.residual_map_figure(circ(ph, true), tmp_path / "qa" / "residual.png")
    f3 = compensation.hue_cross_section_figure(raw[1], ph[1], None, tmp_path / "qa" / "cross_fit.png")
    for f in (f1, f2, f3):
        data = f.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    assert sorted(p.name for p in (tmp_path / "qa").iterdir()) == ["cross.png", "cross_fit.png", "residual.png"]


def test_plate_transfer_of_an_ideal_rig_is_the_identity():
    rig = ToyRig(surface_rows(4, 8, [(4, WHITE)]), gamma=(1.0, 1.0, 1.0), bits=16, noise=0.0)
    rd = BandReader(rig, 64)
    tab = cal.build_table(rd.paths(1), rig.white(), read=rd)
    code, dist = compensation.plate_transfer(tab)
    assert np.allclose(code, TWO_PI * np.arange(64) / 64)
    assert np.max(np.abs(dist)) < 0.01  # only 8-bit projector rounding


@pytest.mark.parametrize("n_bands", [7, 10, 14])
def test_fewer_bands_than_the_smoothing_window_take_the_widest_window_they_hold(n_bands: int) -> None:
    """A session of 7-14 bands captured twice (the spec allows 6; captured once, fewer than 19 are
    refused) with the default 15-band window: the table is built with the largest odd window <= N,
    which its stats record, and the uncertainty's table factor uses the same; an even window is
    still refused."""
    from huefringe.huetable import band_smoothing_matrix
    from huefringe.uncertainty import table_variance_factor

    h, w = 6, 8
    white = np.full((h, w, 3), 0.8, np.float32)
    rng = np.random.default_rng(n_bands)
    imgs = {}
    for i in range(n_bands):
        code = 2 * np.pi * i / n_bands
        rgb = np.clip(0.5 + 0.35 * np.cos(code - np.array([0.0, 2.1, 4.2])), 0.05, 0.95)
        for r in range(2):
            imgs[i, r] = (np.broadcast_to(rgb, (h, w, 3)) * 0.8 + rng.normal(0, 0.002, (h, w, 3))).astype(np.float32)
    paths = [[(i, 0), (i, 1)] for i in range(n_bands)]
    tab = cal.build_table(paths, white, read=lambda k: imgs[k])
    used = n_bands - (1 - n_bands % 2)
    assert tab.stats["params"]["smooth_window"] == used
    assert tab.valid.mean() > 0.9
    coef = band_smoothing_matrix(n_bands, used, 2)
    g = float(np.mean(np.sum(coef**2, axis=1)))
    assert table_variance_factor(n_bands, 15, 2, 2) == pytest.approx(g / 2)
    with pytest.raises(ValueError, match="odd"):
        cal.build_table(paths, white, read=lambda k: imgs[k], smooth_window=16)
