"""The edge-preserving, uncertainty-weighted phase filter (``phase.denoise_phase``)."""

from __future__ import annotations

import numpy as np
import pytest

from huefringe.phase import denoise_phase, wrap


def _window(d: np.ndarray, valid: np.ndarray, v: int, u: int, radius: int):
    """The valid pixels of pixel ``(v, u)``'s window, itself included: their position and
    ``wrap(d_j - d_i)`` (float64)."""
    h, w = d.shape
    for vv in range(max(0, v - radius), min(h, v + radius + 1)):
        for uu in range(max(0, u - radius), min(w, u + radius + 1)):
            if valid[vv, uu]:
                yield vv, uu, float(wrap(np.float64(d[vv, uu]) - d[v, u]))


def _own_side_by_pixel(d: np.ndarray, sigma: np.ndarray, valid: np.ndarray, v: int, u: int, radius: int,
                       k: float) -> tuple[float, float]:
    """A pixel's own-side estimate by its definition (float64): the offset from the pixel of the
    weighted mean of the window's valid neighbours with ``wrap(d_j - d_i)^2 <= 2 k^2 min(s_i^2,
    s_j^2)`` (itself included), and its variance ``1 / sum w``."""
    acc = wsum = 0.0
    for vv, uu, diff in _window(d, valid, v, u, radius):
        if diff**2 <= 2 * k**2 * min(sigma[v, u] ** 2, sigma[vv, uu] ** 2):
            acc += diff / sigma[vv, uu] ** 2
            wsum += 1.0 / sigma[vv, uu] ** 2
    return acc / wsum, 1.0 / wsum


def _brute(d: np.ndarray, sigma: np.ndarray, valid: np.ndarray, radius: int, k: float) -> np.ndarray:
    """The filter's definition, pixel by pixel in float64 (slow, small maps only): the pixel and
    the neighbours that agree with its own-side estimate within ``k`` combined sigma."""
    out = np.full(d.shape, np.nan)
    for v, u in zip(*np.nonzero(valid), strict=True):
        off, var = _own_side_by_pixel(d, sigma, valid, v, u, radius, k)
        acc = wsum = 0.0
        for vv, uu, diff in _window(d, valid, v, u, radius):
            if (vv, uu) == (v, u) or (diff - off) ** 2 <= k**2 * (var + sigma[vv, uu] ** 2):
                acc += diff / sigma[vv, uu] ** 2
                wsum += 1.0 / sigma[vv, uu] ** 2
        out[v, u] = d[v, u] + acc / wsum
    return out


def test_matches_definition_on_random_maps() -> None:
    rng = np.random.default_rng(3)
    d = rng.uniform(-np.pi, np.pi, (23, 31)).astype(np.float32)
    d[5:15, 5:20] = np.float32(0.3) + rng.normal(0, 0.05, (10, 15)).astype(np.float32)
    sigma = rng.uniform(0.02, 0.4, d.shape)
    valid = rng.random(d.shape) > 0.15
    for radius, k in ((1, 3.0), (2, 3.0), (3, 1.5)):
        got = denoise_phase(np.where(valid, d, np.nan), sigma, valid, radius=radius, k=k)
        want = _brute(d, sigma, valid, radius, k)
        assert np.array_equal(np.isnan(got), ~valid)
        assert np.nanmax(np.abs(wrap(got.astype(np.float64) - want))) < 2e-5


def test_flat_noise_drops_by_the_window_size_and_wraps() -> None:
    """Constant sigma on a flat phase at the wrap point: std falls by ~(2 r + 1), mean kept."""
    rng = np.random.default_rng(0)
    true, s = np.pi - 0.01, 0.05  # half the samples wrap to about -pi
    d = wrap(true + rng.normal(0, s, (120, 160))).astype(np.float32)
    out = denoise_phase(d, np.full(d.shape, s), np.ones(d.shape, bool), radius=2)
    err_in = wrap(d[4:-4, 4:-4].astype(np.float64) - true)
    err_out = wrap(out[4:-4, 4:-4].astype(np.float64) - true)
    gain = err_in.std() / err_out.std()
    assert 4.0 < gain < 5.5  # 25 samples, k = 3 keeps almost all of them: ~5
    assert abs(err_out.mean()) < 0.002


def test_steps_are_not_blurred() -> None:
    rng = np.random.default_rng(1)
    s = 0.01
    true = np.where(np.arange(100)[None, :] >= 50, 1.0, 0.0) * np.ones((60, 1))  # 1 rad step = 100 sigma
    d = (true + rng.normal(0, s, true.shape)).astype(np.float32)
    out = denoise_phase(d, np.full(d.shape, s), np.ones(d.shape, bool), radius=2)
    edge = out[:, 47:53] - true[:, 47:53]
    assert np.abs(edge).max() < 5 * s
    assert np.abs(out - true).std() < 0.5 * s


def test_uncertain_pixels_follow_their_neighbours_and_invalid_ones_are_ignored() -> None:
    d = np.zeros((9, 9), np.float32)
    sigma = np.full(d.shape, 0.01)
    d[4, 4], sigma[4, 4] = 0.5, 1.0  # a poorly determined pixel, off by 0.5 rad
    valid = np.ones(d.shape, bool)
    d[2, 3], valid[2, 3] = 3.0, False  # garbage in an invalid pixel must not count
    out = denoise_phase(np.where(valid, d, np.nan), sigma, valid, radius=2)
    assert abs(out[4, 4]) < 0.5 * 1e-3  # weight 1 against 23 neighbours of weight 1e4
    assert np.isnan(out[2, 3])
    assert np.abs(out[valid]).max() < 1e-3
    # a pixel without a valid neighbour keeps its own value
    lone = np.zeros((5, 5), bool)
    lone[2, 2] = True
    assert denoise_phase(np.full((5, 5), 0.7, np.float32), np.full((5, 5), 0.1), lone)[2, 2] == np.float32(0.7)


def test_a_noisy_strip_beside_a_step_keeps_its_own_side() -> None:
    """A strip of noisy pixels (sigma 0.3 rad: a dark print) along a 1 rad step whose far side is
    precise (0.02 rad): each strip pixel averages its own side (the strip's neighbours its noise
    cannot tell from it), not the far side that a test against its single value lets in when the
    noise draws it toward the step (the far side's weights, 225 x the strip's, then carry its
    level in: about 0.44 rad on the strip's two columns by the step). Its weight sum stays its
    spread's: ``1 / sqrt(sum w)`` within 15 % of the strip's error over rows, except on its first
    column, whose precise neighbours on the same level join it or not with its noise (1.4 x;
    2.4 x with a test against the pixel's value)."""
    rng = np.random.default_rng(0)
    h, w = 400, 100
    true = np.where(np.arange(w)[None, :] >= 50, 1.0, 0.0) * np.ones((h, 1))
    sigma = np.full((h, w), 0.02)
    sigma[:, 45:50] = 0.3
    d = true + rng.normal(0, 1, (h, w)) * sigma
    ws = np.empty((h, w), np.float32)
    out = denoise_phase(d, sigma, np.ones((h, w), bool), radius=2, weight_sum=ws)
    err = out[:, 45:50] - true[:, 45:50]
    assert np.abs(err.mean(axis=0)).max() < 0.03  # the two columns by the step: 0.007, 0.012
    assert np.abs(out[:, 50:55] - 1.0).mean(axis=0).max() < 0.01  # the far side untouched
    ratio = err.std(axis=0) / np.sqrt(np.mean(1.0 / ws[:, 45:50], axis=0))
    assert np.all(np.abs(ratio[1:] - 1.0) < 0.15) and ratio[0] < 1.6, ratio


def _plane_by_pixel(first, wfirst, v, u, base, kink_sigma=3.0):
    """The local plane the grown rings test against at pixel ``(v, u)``: its slopes along ``u``
    and ``v`` (rad/px) and their variances, each the central difference of the first-pass
    estimates ``base`` px either side (float32), where the two one-sided differences agree within
    ``kink_sigma`` sigma of their difference and the slope exceeds 2 of its sigma; else 0 (a step, an edge, a
    slope lost in the noise, a side outside the image or not valid)."""
    f32 = np.float32
    two_pi, inv_two_pi, pi = f32(2 * np.pi), f32(1 / (2 * np.pi)), f32(np.pi)

    def wrapped(x):
        return f32(x - two_pi * np.floor(f32((x + pi) * inv_two_pi)))

    def slope(a, c, e):
        if a is None or e is None or wfirst[a] <= 0 or wfirst[e] <= 0:
            return f32(0), f32(0)
        va, vb, vc = f32(1) / wfirst[a], f32(1) / wfirst[c], f32(1) / wfirst[e]
        b = f32(base)
        fwd = f32(wrapped(f32(first[e] - first[c])) / b)
        bwd = f32(wrapped(f32(first[c] - first[a])) / b)
        dd = f32(fwd - bwd)
        if f32(f32(dd * dd) * b * b) > f32(f32(kink_sigma**2) * f32(f32(va + f32(4) * vb) + vc)):
            return f32(0), f32(0)
        g = f32(f32(0.5) * f32(fwd + bwd))
        vg = f32(f32(va + vc) / f32(f32(4) * b * b))
        if f32(g * g) <= f32(f32(4) * vg):
            return f32(0), f32(0)
        return g, vg

    h, w = first.shape
    gu, vu = slope((v, u - base) if u >= base else None, (v, u), (v, u + base) if u + base < w else None)
    gv, vv = slope((v - base, u) if v >= base else None, (v, u), (v + base, u) if v + base < h else None)
    return gu, vu, gv, vv


def _adaptive_by_pixel(d, s2, inv, first, wfirst, radius, max_radius, k2, target_w, reject_w, kink_sigma=3.0):
    """The adaptive pass pixel by pixel, its definition (float32, rings in order, each pixel's
    neighbours added row by row, column by column, stopping once the weights reach the target),
    and each pixel's final window half side."""
    f32 = np.float32
    two_pi, inv_two_pi, pi = f32(2 * np.pi), f32(1 / (2 * np.pi)), f32(np.pi)

    def wrapped(x):
        return f32(x - two_pi * np.floor(f32((x + pi) * inv_two_pi)))

    h, w = d.shape
    out = first.copy()
    wout = wfirst.copy()
    rad = np.where(inv > 0, radius, radius).astype(np.float32)
    for v in range(h):
        for u in range(w):
            if inv[v, u] <= 0:
                continue
            ws = wfirst[v, u]
            if ws >= target_w or max_radius <= radius:
                out[v, u] = first[v, u] if ws >= reject_w else np.nan
                continue
            m, sf2 = first[v, u], f32(1) / ws
            gu, vu, gv, vv_ = _plane_by_pixel(first, wfirst, v, u, max_radius, kink_sigma)
            acc = wsum = f32(0)
            rr = radius
            for r in range(max_radius + 1):
                for dv in range(-r, r + 1):
                    if not 0 <= v + dv < h:
                        continue
                    dus = range(-r, r + 1) if abs(dv) == r else (-r, r)
                    for du in dus:
                        vv, uu = v + dv, u + du
                        if 0 <= uu < w and inv[vv, uu] > 0:
                            fu, fv = f32(du), f32(dv)
                            plane = f32(f32(gu * fu) + f32(gv * fv))
                            dm = wrapped(f32(f32(d[vv, uu] - m) - plane))
                            lim = f32(k2 * f32(s2[vv, uu] + sf2))
                            extra = f32(k2 * f32(f32(vu * f32(fu * fu)) + f32(vv_ * f32(fv * fv))))
                            if f32(plane * plane) <= lim and f32(dm * dm) <= f32(lim + extra):
                                diff = wrapped(f32(d[vv, uu] - d[v, u]))
                                acc = f32(acc + f32(inv[vv, uu] * f32(diff - plane)))
                                wsum = f32(wsum + inv[vv, uu])
                rr = r
                if r >= radius and wsum >= target_w:
                    break
            if wsum < ws:
                wsum, val = ws, m
            else:
                val = f32(d[v, u] + f32(acc / wsum))
                rad[v, u] = rr
            out[v, u] = val if wsum >= reject_w else np.nan
            wout[v, u] = wsum
    return out, wout, rad


#: ``_adaptive_pass``'s carry arguments when nothing is carried (and ``boxed`` not asked for)
_NO_CARRY = (False, np.empty((1, 1), np.float32), np.empty((1, 1), np.float32), np.empty((1, 1), np.float32),
             np.empty((1, 1), np.float32))
#: ``_adaptive_pass``'s ``kink2`` at the default ``plane_kink_sigma`` (3), no bias map asked for (and the
#: default ``lacking_probe_bias``)
_KINK3 = (np.float32(9.0), np.empty((1, 1), np.float32), False)


def _first_pass(d: np.ndarray, sigma: np.ndarray, valid: np.ndarray, radius: int) -> tuple[np.ndarray, ...]:
    """The adaptive pass's inputs: the filter's prepared weights ``dz, s2, inv`` and the first pass
    (``k = 3``, ``radius``) ``first, wfirst``."""
    from huefringe.phase import _denoise_weights, first_pass

    h, w = d.shape
    dz, s2, inv = (np.empty((h, w), np.float32) for _ in range(3))
    _denoise_weights(d, sigma, valid, dz, s2, inv)
    first, wfirst = np.empty_like(dz), np.empty_like(dz)
    first_pass(dz, s2, inv, radius, np.float32(9.0), first, wfirst)
    return dz, s2, inv, first, wfirst


def test_adaptive_pass_is_its_pixel_by_pixel_definition_bit_for_bit() -> None:
    """The compiled pass (all of a row's pixels through each window offset together) gives the
    pixel-by-pixel loop's bits: noisy pixels near the borders, invalid neighbours, a step."""
    from huefringe.phase import _adaptive_pass

    rng = np.random.default_rng(7)
    h, w = 23, 31
    sigma = np.where(rng.random((h, w)) < 0.3, 0.02, 0.003) * rng.uniform(0.5, 2, (h, w))
    d = rng.normal(0, 1, (h, w)) * sigma + 0.4
    d[:, 20:] += 1.0  # a step
    d = wrap(d)
    valid = rng.random((h, w)) > 0.1
    dz, s2, inv, first, wfirst = _first_pass(d, sigma, valid, 1)
    k2 = np.float32(9.0)
    none = np.empty((1, 1), np.float32)
    ok = inv > 0
    for max_radius, target, reject in ((4, 0.0008, 0.002), (6, 0.0005, 0.001), (2, 0.0009, 0.0)):
        tw, rw = np.float32(1 / target**2), np.float32(1 / reject**2 if reject else 0.0)
        got, got_w, got_rad = (np.empty_like(dz) for _ in range(3))
        _adaptive_pass(dz, s2, inv, first, wfirst, 1, max_radius, k2, tw, rw, got, got_w, got_rad, True, 0.0, none,
                       *_NO_CARRY, *_KINK3)  # rings everywhere (box_chi_z = 0)
        want, want_w, want_rad = _adaptive_by_pixel(dz, s2, inv, first, wfirst, 1, max_radius, k2, tw, rw)
        assert np.array_equal(got_w.view(np.uint32), want_w.view(np.uint32))  # the final weight sums too
        assert np.array_equal(got_rad[ok], want_rad[ok])  # and each pixel's final window
        assert got_rad[ok].max() > 1  # windows grew
        bare, bare_w = np.empty_like(dz), np.empty_like(dz)
        _adaptive_pass(dz, s2, inv, first, wfirst, 1, max_radius, k2, tw, rw, bare, bare_w, none, False, 0.0, none,
                       *_NO_CARRY, *_KINK3)
        assert np.array_equal(bare.view(np.uint32), got.view(np.uint32))
        assert np.array_equal(bare_w.view(np.uint32), got_w.view(np.uint32))
        grown = (inv > 0) & (wfirst < tw)
        assert grown.sum() > 50  # the pass has work to do
        assert np.array_equal(got.view(np.uint32), want.view(np.uint32))
        assert not np.array_equal(got[grown], first[grown])  # and it changed those pixels


def test_plane_kink_sigma_is_the_definitions_threshold() -> None:
    """``plane_kink_sigma`` is the threshold of the plane's kink test, bit for bit against the
    pixel-by-pixel definition, on a curved ramp with a step (noisy pixels grow): a larger one keeps
    the plane on more pixels and changes them, through ``denoise_phase``'s keyword too."""
    from huefringe.phase import _adaptive_pass

    rng = np.random.default_rng(11)
    h, w = 25, 33
    sigma = np.where(rng.random((h, w)) < 0.4, 0.03, 0.004) * rng.uniform(0.5, 2, (h, w))
    yy, xx = np.mgrid[0:h, 0:w]
    d = wrap(0.06 * xx + 0.004 * (xx - 16.0) ** 2 + 0.003 * (yy - 12.0) ** 2 + 1.5 * (xx >= 24)
             + rng.normal(0, 1, (h, w)) * sigma)
    valid = rng.random((h, w)) > 0.05
    dz, s2, inv, first, wfirst = _first_pass(d, sigma, valid, 1)
    k2 = np.float32(9.0)
    none = np.empty((1, 1), np.float32)
    tw, rw = np.float32(1 / 0.003**2), np.float32(0.0)
    outs = {}
    for kink in (1.0, 3.0, 10.0):
        got, got_w = np.empty_like(dz), np.empty_like(dz)
        _adaptive_pass(dz, s2, inv, first, wfirst, 1, 5, k2, tw, rw, got, got_w, none, False, 0.0, none,
                       *_NO_CARRY, np.float32(kink**2), *_KINK3[1:])
        want, want_w, _ = _adaptive_by_pixel(dz, s2, inv, first, wfirst, 1, 5, k2, tw, rw, kink)
        assert np.array_equal(got.view(np.uint32), want.view(np.uint32))
        assert np.array_equal(got_w.view(np.uint32), want_w.view(np.uint32))
        outs[kink] = got
    grown = (inv > 0) & (wfirst < tw)
    assert grown.sum() > 100
    changed = [int((outs[a] != outs[b])[grown].sum()) for a, b in ((1.0, 3.0), (3.0, 10.0))]
    assert min(changed) > 5, changed
    kw = {"radius": 1, "max_radius": 5, "target_sigma": 0.003}
    assert np.array_equal(denoise_phase(d, sigma, valid, plane_kink_sigma=10.0, **kw), outs[10.0], equal_nan=True)
    assert np.array_equal(denoise_phase(d, sigma, valid, **kw), outs[3.0], equal_nan=True)


def _box_case(d: np.ndarray, sigma: np.ndarray, valid: np.ndarray, radius: int, max_radius: int, target: float,
              chi_z: float) -> dict[str, np.ndarray]:
    """The adaptive pass on a map with plane boxes (``chi_z``) and rings only (``chi_z = 0``): each
    one's phase, weight sums, final half side and the box codes (``boxed``), the inputs, the grown pixels."""
    from huefringe.phase import _adaptive_pass, band_floor

    dz, s2, inv, first, wfirst = _first_pass(d, sigma, valid, radius)
    k2 = np.float32(9.0)
    tw, rw = np.float32(1 / target**2), np.float32(0.0)
    res: dict[str, np.ndarray] = {"dz": dz, "inv": inv, "grown": (inv > 0) & (wfirst < tw)}
    for tag, z in (("box", chi_z), ("ring", 0.0)):
        out, wout, rad, boxed = (np.zeros_like(dz) for _ in range(4))
        _adaptive_pass(dz, s2, inv, first, wfirst, radius, max_radius, k2, tw, rw, out, wout, rad, True, z,
                       band_floor(s2, max_radius), *_NO_CARRY[:-1], boxed, *_KINK3)
        res.update({tag: out, tag + "_w": wout, tag + "_rad": rad, tag + "_boxed": boxed})
    return res


@pytest.mark.parametrize("texture", [False, True])
def test_plane_boxes_equal_the_rings_where_the_rings_take_every_pixel(texture: bool) -> None:
    """On a ramp (0.004 and 0.003 rad/px) whose pixels the rings all accept (noise-free with one
    sigma; with textured sigma and noise of half of it), a grown pixel that takes a plane box gets
    the ring pass's phase, weight sum and half side to float rounding (float64 tables against
    float32 sums in ring order), and most grown pixels take one."""
    rng = np.random.default_rng(3)
    h, w = 48, 64
    vv, uu = np.mgrid[0:h, 0:w]
    truth = 0.004 * uu + 0.003 * vv - 0.2
    sigma = np.full((h, w), 0.03)
    d = truth.copy()
    if texture:
        sigma = 0.03 * np.exp(rng.normal(0, 0.3, (h, w)))
        d = truth + 0.5 * sigma * rng.normal(0, 1, (h, w))
    r = _box_case(d, sigma, np.ones((h, w), bool), 1, 6, 0.0035, 3.0)
    grown, took = r["grown"], r["box_boxed"] == 1
    assert grown.sum() > 0.9 * h * w and np.all(r["ring_boxed"] == 0)
    assert took[grown].mean() > 0.6  # most grown pixels take a box (the others: the band near the borders ...)
    assert np.all(r["box_boxed"][~grown] == 0)
    same = took & (np.abs(r["ring_w"] / r["box_w"] - 1) < 1e-5)  # ... where the rings took every pixel too
    assert same.sum() > 0.95 * took.sum()
    np.testing.assert_allclose(r["box"][same], r["ring"][same], rtol=0, atol=2e-6)
    np.testing.assert_allclose(r["box_w"][same], r["ring_w"][same], rtol=2e-6)
    assert np.array_equal(r["box_rad"][same], r["ring_rad"][same])
    assert np.array_equal(r["box"][~took].view(np.uint32), r["ring"][~took].view(np.uint32))  # the rest: ring bits
    inner = took & (vv >= 6) & (vv < h - 6) & (uu >= 6) & (uu < w - 6)  # the slope known both sides
    if not texture:
        assert np.max(np.abs(r["box"][inner] - truth[inner])) < 2e-6  # a plane's mean at the pixel is its value


@pytest.mark.parametrize("chi_z", [3.0, 30.0])
def test_plane_boxes_never_cross_a_step_or_the_wrap(chi_z: float) -> None:
    """On a ramp with a step (0.3 rad, 10 sigma of the noisy pixels) and a wrap at +-pi, no plane
    box holds pixels of both sides of either (the scatter about the plane rejects it), the pixels
    beside them get the ring pass's bits, and boxes and rings estimate the truth alike."""
    rng = np.random.default_rng(11)
    h, w = 40, 90
    vv, uu = np.mgrid[0:h, 0:w]
    truth = 0.0025 * uu + 0.0005 * vv + 2.7 + np.where(uu >= 30, 0.3, 0.0)  # crosses pi at u = 49 .. 57
    sigma = np.where(rng.random((h, w)) < 0.3, 0.03, 0.01) * rng.uniform(0.8, 1.25, (h, w))
    d = wrap(truth + rng.normal(0, 1, (h, w)) * sigma)
    valid = rng.random((h, w)) > 0.05
    r = _box_case(d, sigma, valid, 1, 5, 0.002, chi_z)
    took = r["box_boxed"] == 1
    wrap_u = np.argmax(truth > np.pi, axis=1)  # the first column past pi, per row
    assert np.all((wrap_u > 40) & (wrap_u < 60))
    assert took[r["grown"]].mean() > 0.3
    for v, u in zip(*np.nonzero(took), strict=True):
        rr = int(r["box_rad"][v, u])
        u0, u1 = u - rr, u + rr
        assert u1 < 30 or u0 >= 30  # the step
        rows = wrap_u[max(v - rr, 0):v + rr + 1]
        assert np.all((u1 < rows) | (u0 >= rows))  # the wrap
    near = (np.abs(uu - 29.5) < 2) | (np.abs(uu - wrap_u[:, None] + 0.5) < 2)
    assert np.array_equal(r["box"][near].view(np.uint32), r["ring"][near].view(np.uint32))
    ok = r["grown"] & np.isfinite(r["box"])
    e_box = np.abs(wrap(r["box"][ok] - truth[ok]))
    e_ring = np.abs(wrap(r["ring"][ok] - truth[ok]))
    assert np.median(e_box) < 1.2 * np.median(e_ring) and np.percentile(e_box, 99) < 1.2 * np.percentile(e_ring, 99)


def test_plane_tables_keep_their_precision_far_from_the_origin() -> None:
    """The boxes' plane statistics from summed-area tables of a 1024 x 1280 map in its global
    coordinates (the worst case: the pass's tables count rows from each block, a few tens) with
    weights of 1e6 (sigma 1 mm rad) and phases near +-3: mean and scatter about the plane against
    the direct float64 sums over the box, at boxes across the map and in its far corner."""
    from huefringe.phase import _plane_box, _plane_tables

    rng = np.random.default_rng(2)
    h, w = 1024, 1280
    vv, uu = np.mgrid[0:h, 0:w]
    gu, gv = 0.0021, -0.0017
    d = (np.where(uu < w // 2, 2.9, -2.9) + gu * (uu % 200) + gv * (vv % 150)
         + 1e-3 * rng.normal(0, 1, (h, w))).astype(np.float32)
    inv = (1e6 * rng.uniform(0.5, 2, (h, w))).astype(np.float32)
    inv[rng.random((h, w)) < 0.05] = 0
    d[inv == 0] = 0
    xc = float(w // 2)
    tab = _plane_tables(d, inv, np.empty((1, 1), np.float32), False, xc)
    worst_mean = worst_chi = 0.0
    for v, u in [(h - 7, w - 7), (h - 7, 6), (500, 700), (6, w - 7)] + [tuple(x) for x in rng.integers(6, 1000, (40, 2))]:
        rr = 6
        sl = (slice(v - rr, v + rr + 1), slice(u - rr, u + rr + 1))
        ww = inv[sl].astype(np.float64)
        oy, ox = np.mgrid[-rr:rr + 1, -rr:rr + 1]
        e = d[sl].astype(np.float64) - gu * ox - gv * oy
        mean = (ww * e).sum() / ww.sum()
        chi = (ww * (e - mean) ** 2).sum()
        bw, bn, m, c, _ = _plane_box(tab, v - rr, v + rr + 1, u - rr, u + rr + 1, u - xc, float(v), gu, gv, 0.0, 0.0)
        assert bn == (ww > 0).sum() and abs(bw / ww.sum() - 1) < 1e-12
        worst_mean = max(worst_mean, abs(m - mean))
        worst_chi = max(worst_chi, abs(c - chi))
    assert worst_mean < 1e-9  # rad, against a target sigma of 2e-3
    assert worst_chi < 0.05  # against a chi-square of ~168 +- 18 on a 13 x 13 box


def test_plane_boxes_keep_the_carried_map_and_window_sums_consistent() -> None:
    """With plane boxes the carried map is the box's weighted mean of it, the support and ``sum w
    ratio`` the box's, where a box was taken; the phase and weights are the same with or without them."""
    from huefringe.phase import _denoise_weights

    rng = np.random.default_rng(8)
    h, w = 40, 50
    vv, uu = np.mgrid[0:h, 0:w]
    sigma = 0.03 * np.exp(rng.normal(0, 0.3, (h, w)))
    d = 0.004 * uu + 0.003 * vv + 0.5 * sigma * rng.normal(0, 1, (h, w))
    valid = rng.random((h, w)) > 0.05
    c = rng.normal(0, 1, (h, w)).astype(np.float32)
    ratio = rng.uniform(0.5, 2, (h, w)).astype(np.float32)
    kw = {"radius": 1, "max_radius": 6, "target_sigma": 0.0035, "box_chi_z": 3.0}
    cm, ws, rs, sup = (np.zeros((h, w), np.float32) for _ in range(4))
    got = denoise_phase(d, sigma, valid, carry=c, carry_mean=cm, weight_sum=ws, ratio=ratio, ratio_sum=rs,
                        support=sup, **kw)
    ws0 = np.zeros((h, w), np.float32)
    bare = denoise_phase(d, sigma, valid, weight_sum=ws0, **kw)
    assert np.array_equal(got.view(np.uint32), bare.view(np.uint32)) and np.array_equal(ws, ws0)
    r = _box_case(d, sigma, valid, 1, 6, 0.0035, 3.0)
    assert np.array_equal(r["box"].view(np.uint32), got.view(np.uint32))
    dz, s2, inv = (np.empty((h, w), np.float32) for _ in range(3))
    _denoise_weights(d, sigma, valid, dz, s2, inv)
    took = np.nonzero(r["box_boxed"] == 1)
    assert took[0].size > 200
    for v, u in zip(*took, strict=True):
        rr = int(r["box_rad"][v, u])
        sl = (slice(max(v - rr, 0), v + rr + 1), slice(max(u - rr, 0), u + rr + 1))
        wb = inv[sl].astype(np.float64)
        assert abs(ws[v, u] / wb.sum() - 1) < 1e-6
        assert abs(cm[v, u] - (wb * c[sl]).sum() / wb.sum()) < 1e-5
        assert abs(rs[v, u] / (wb * ratio[sl]).sum() - 1) < 1e-5
        assert abs(sup[v, u] - (wb > 0).sum()) < 1e-3


def _exact_sums(dz, s2, inv, r2, radius, k2):
    """``sum w r2`` and the count over each pixel's accepted neighbours, by their definition:
    the pixel and the valid neighbours with ``(wrap(d_j - d_i) - off_i)^2 <= k2 (var_i + s2_j)``
    (float64), ``off, var`` the compiled own-side estimate (``phase._own_side``)."""
    from huefringe.phase import _own_side

    h, w = dz.shape
    off, var = np.empty((h, w), np.float32), np.empty((h, w), np.float32)
    _own_side(dz, s2, inv, radius, np.float32(k2), off, var)
    rs, cn = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    for v in range(h):
        for u in range(w):
            if inv[v, u] <= 0:
                continue
            sl = (slice(max(v - radius, 0), v + radius + 1), slice(max(u - radius, 0), u + radius + 1))
            diff = wrap(dz[sl].astype(np.float64) - dz[v, u]) - float(off[v, u])
            keep = (inv[sl] > 0) & (diff**2 <= k2 * (float(var[v, u]) + s2[sl].astype(np.float64)))
            keep[v - sl[0].start, u - sl[1].start] = True
            rs[v, u] = np.sum((inv[sl] * r2[sl])[keep], dtype=np.float64)
            cn[v, u] = keep.sum()
    return rs, cn


def _box_sums_by_tables(inv, r2, rad, radius, wsum):
    """The grown windows' ``sum w r2`` and support from whole summed-area tables (NumPy: each row's
    running sums, then running sums of the rows, float64), the boxes' four corners in order."""
    h, w = inv.shape
    tables = []
    for x in (inv.astype(np.float64), inv.astype(np.float64) * r2, (inv > 0).astype(np.float64)):
        t = np.zeros((h + 1, w + 1))
        t[1:, 1:] = np.cumsum(np.cumsum(x, axis=1), axis=0)
        tables.append(t)
    rsum, cnt = np.full((h, w), -1, np.float32), np.full((h, w), -1, np.float32)
    for v, u in zip(*np.nonzero((rad > radius) & (inv > 0)), strict=True):
        r = int(rad[v, u])
        v0, v1, u0, u1 = max(v - r, 0), min(v + r + 1, h), max(u - r, 0), min(u + r + 1, w)
        bw, br, bn = (t[v1, u1] - t[v0, u1] - t[v1, u0] + t[v0, u0] for t in tables)
        sc = float(wsum[v, u]) / bw if bw > 0 else 0.0
        rsum[v, u], cnt[v, u] = np.float32(sc * br), np.float32(sc * bn)
    return rsum, cnt


@pytest.mark.parametrize("shape", [(40, 57), (1, 30), (25, 1), (3, 3)])
def test_grown_window_sums_are_the_summed_area_tables_bit_for_bit(shape: tuple[int, int]) -> None:
    """``_box_sums`` (the tables' rows built in a ring of the rows the boxes reach) gives the
    whole tables' bits: windows of half sides up to past the image, invalid pixels, any ratio;
    the pixels at the common half side keep the values their outputs held."""
    from huefringe.phase import _box_sums

    rng = np.random.default_rng(sum(shape))
    inv = rng.uniform(1e2, 1e6, shape).astype(np.float32) * rng.choice([1e-3, 1.0, 1e3], shape).astype(np.float32)
    inv[rng.random(shape) < 0.2] = 0
    r2 = rng.uniform(0.5, 2.0, shape).astype(np.float32)
    wsum = rng.uniform(0, 5, shape).astype(np.float32) * inv
    for top in (3, 7, 60):
        rad = rng.integers(1, top, shape).astype(np.float32)
        rsum, cnt = np.full(shape, -1, np.float32), np.full(shape, -1, np.float32)
        _box_sums(inv, r2, rad, 2, wsum, rsum, cnt)
        want_r, want_n = _box_sums_by_tables(inv, r2, rad, 2, wsum)
        assert np.array_equal(rsum.view(np.uint32), want_r.view(np.uint32))
        assert np.array_equal(cnt.view(np.uint32), want_n.view(np.uint32))
    assert ((rad > 2) & (inv > 0)).sum() > 0


def test_first_pass_sums_are_the_exact_sums_where_nothing_was_rejected() -> None:
    """The fixed window's ``sum w r2`` and support from box sums (``window_sums``) against
    their exact accumulation over the accepted neighbours (``_exact_sums``): equal to float
    rounding wherever the window took every valid neighbour, and near a step (where it rejected
    some) the support is the number of equal-weight pixels that give its weight sum: the
    accepted count when the weights are equal."""
    from huefringe.phase import _denoise_weights, first_pass, window_sums

    rng = np.random.default_rng(3)
    h, w = 40, 57
    for equal in (False, True):
        sigma = np.full((h, w), 0.01) if equal else rng.uniform(0.005, 0.02, (h, w))
        d = rng.normal(0, 1, (h, w)) * sigma + 0.3
        d[:, 30:] += 1.0  # a step: rejected neighbours beside it
        valid = rng.random((h, w)) > 0.1
        dz, s2, inv = (np.empty((h, w), np.float32) for _ in range(3))
        _denoise_weights(d, sigma, valid, dz, s2, inv)
        r2 = rng.uniform(0.5, 2.0, (h, w)).astype(np.float32)
        out, ws = np.empty_like(dz), np.empty_like(dz)
        first_pass(dz, s2, inv, 2, np.float32(9.0), out, ws)
        rs, cn = _exact_sums(dz, s2, inv, r2, 2, np.float32(9.0))
        got_r, got_c = window_sums(inv, r2, 2, ws)
        box_n = np.array([[np.count_nonzero(inv[max(v - 2, 0):v + 3, max(u - 2, 0):u + 3]) for u in range(w)]
                          for v in range(h)])
        took_all = (inv > 0) & (cn == box_n)
        assert took_all.mean() > 0.7 and (~took_all & (inv > 0)).sum() > 50
        np.testing.assert_allclose(got_r[took_all], rs[took_all], rtol=2e-6)
        np.testing.assert_allclose(got_c[took_all], cn[took_all], rtol=2e-6)
        assert np.all(got_r[inv == 0] == 0) and np.all(got_c[inv == 0] == 0)
        if equal:
            rej = ~took_all & (inv > 0)
            assert np.max(np.abs(got_c[rej] - cn[rej])) < 1e-3


def _carried_by_pixel(d, s2, inv, c, first, wfirst, out, radius, max_radius, k2, target_w):
    """Each pixel's ``sum w c / sum w`` over the neighbours its final window accepted, by the
    filter's definition (float32 decisions, float64 sums): the fixed window's test against the
    pixel's own side (the compiled estimate, ``phase._own_side``), the grown window's (rings in
    order, stopping at the target) against the local plane through its first-pass estimate; the
    first pass's where the grown window found less support."""
    from huefringe.phase import _own_side

    f32 = np.float32
    off, var = np.empty(d.shape, f32), np.empty(d.shape, f32)
    _own_side(d, s2, inv, radius, f32(k2), off, var)
    two_pi, inv_two_pi, pi = f32(2 * np.pi), f32(1 / (2 * np.pi)), f32(np.pi)

    def wrapped(x):
        return f32(x - two_pi * np.floor(f32((x + pi) * inv_two_pi)))

    h, w = d.shape
    cm = np.zeros((h, w))
    for v in range(h):
        for u in range(w):
            if inv[v, u] <= 0:
                continue
            sums = []
            plane = _plane_by_pixel(first, wfirst, v, u, max_radius)
            for fixed, r_max, ref, s_ref, (gu, vu, gv, vg) in (
                    (True, radius, d[v, u], s2[v, u], (f32(0),) * 4),
                    (False, max_radius, first[v, u], f32(1) / wfirst[v, u], plane)):
                sw = sc = 0.0
                wf = f32(0)
                for r in range(r_max + 1):
                    for dv in range(-r, r + 1):
                        dus = range(-r, r + 1) if abs(dv) == r else (-r, r)
                        for du in dus:
                            vv, uu = v + dv, u + du
                            if 0 <= vv < h and 0 <= uu < w and inv[vv, uu] > 0:
                                fu, fv = f32(du), f32(dv)
                                pl = f32(f32(gu * fu) + f32(gv * fv))
                                if fixed:
                                    e = f32(wrapped(f32(d[vv, uu] - ref)) - off[v, u])
                                    take = (dv, du) == (0, 0) or f32(e * e) <= f32(k2 * f32(var[v, u] + s2[vv, uu]))
                                else:
                                    dm = wrapped(f32(f32(d[vv, uu] - ref) - pl))
                                    lim = f32(k2 * f32(s2[vv, uu] + s_ref))
                                    extra = f32(k2 * f32(f32(vu * f32(fu * fu)) + f32(vg * f32(fv * fv))))
                                    take = f32(pl * pl) <= lim and f32(dm * dm) <= f32(lim + extra)
                                if take:
                                    sw += float(inv[vv, uu])
                                    sc += float(inv[vv, uu]) * float(c[vv, uu])
                                    wf = f32(wf + inv[vv, uu])
                    if r_max == max_radius and r >= radius and wf >= target_w:
                        break
                sums.append((sc / sw, wf))
            grown = max_radius > radius and wfirst[v, u] < target_w and sums[1][1] >= wfirst[v, u]
            cm[v, u] = sums[1][0] if grown else sums[0][0]
    return cm


def test_carried_map_is_the_mean_over_the_accepted_neighbours() -> None:
    """``carry_mean``: each pixel's weighted mean of the carried map over the neighbours its window
    accepted (fixed and grown windows), against that definition pixel by pixel, beside a step whose
    far side carries a large value the filter rejects (the whole window's mean takes it in there,
    which is the test's contrast); the phase and the weight sums are the same bits with or without
    it, and a small phase change is carried as the filter passes it (the two filtered maps'
    difference, where no decision moves)."""
    from huefringe.phase import _denoise_weights, window_sums

    rng = np.random.default_rng(5)
    h, w = 30, 41
    sigma = np.where(rng.random((h, w)) < 0.3, 0.02, 0.004) * rng.uniform(0.5, 2, (h, w))
    d = wrap(np.where(np.arange(w)[None, :] >= 20, 1.4, 0.4) + rng.normal(0, 1, (h, w)) * sigma)
    valid = rng.random((h, w)) > 0.05
    c = np.where(np.arange(w)[None, :] >= 20, 0.5, 0.0) + rng.normal(0, 1e-3, (h, w))
    c = c.astype(np.float32)
    dz, s2, inv = (np.empty((h, w), np.float32) for _ in range(3))
    _denoise_weights(d, sigma, valid, dz, s2, inv)
    k2 = np.float32(9.0)
    for kw in ({}, {"max_radius": 5, "target_sigma": 0.0007}):
        cm = np.empty((h, w), np.float32)
        ws, ws0 = np.empty((h, w), np.float32), np.empty((h, w), np.float32)
        got = denoise_phase(d, sigma, valid, radius=2, carry=c, carry_mean=cm, weight_sum=ws, **kw)
        bare = denoise_phase(d, sigma, valid, radius=2, weight_sum=ws0, **kw)
        assert np.array_equal(got.view(np.uint32), bare.view(np.uint32))
        assert np.array_equal(ws.view(np.uint32), ws0.view(np.uint32))
        first, wfirst = (denoise_phase(d, sigma, valid, radius=2), np.empty((h, w), np.float32))
        denoise_phase(d, sigma, valid, radius=2, weight_sum=wfirst)
        want = _carried_by_pixel(dz, s2, inv, c, first, wfirst, got, 2, kw.get("max_radius", 2), k2,
                                 np.float32(1 / kw["target_sigma"] ** 2) if kw else np.float32(0))
        ok = inv > 0
        np.testing.assert_allclose(cm[ok], want[ok], rtol=1e-5, atol=1e-7)
        assert np.all(cm[~ok] == 0)
        left = ok & (np.arange(w)[None, :] < 20)
        assert np.max(np.abs(cm[left])) < 0.01  # the far side's 0.5 is not carried across the step
        whole = window_sums(inv, c, 2, np.ones((h, w), np.float32))[0]
        assert np.max(np.abs(whole[left])) > 0.1  # the whole window's mean would have taken it
    # a phase change too small to move a decision is carried as the filter passes it
    kw = {"max_radius": 5, "target_sigma": 0.0007}
    small = (1e-4 * rng.standard_normal((h, w))).astype(np.float32)
    cm = np.empty((h, w), np.float32)
    f0 = denoise_phase(d, sigma, valid, radius=2, carry=small, carry_mean=cm, **kw).astype(np.float64)
    f1 = denoise_phase(d + small, sigma, valid, radius=2, **kw).astype(np.float64)
    ok = np.isfinite(f0) & np.isfinite(f1)
    assert np.median(np.abs((f1 - f0)[ok] - cm[ok])) < 0.02 * np.median(np.abs(cm[ok]))


def test_grown_windows_on_a_textured_ramp_have_the_predicted_spread() -> None:
    """On a phase ramp (0.007 rad/px) whose pixels carry different sigma (lognormal about
    0.05 rad, a textured surface), the default adaptive filter (radius 2, target 0.002 rad, up
    to radius 6, k = 3) grows its windows to 13 x 13 and its spread over noise draws is the
    predicted ``1 / sqrt(weight_sum)``: the rings test each neighbour against the local plane,
    so the accepted set does not follow the noise (against the pixel's level alone it does, and
    the ratio exceeds 1.3). Flat, the same holds."""
    rng = np.random.default_rng(5)
    h, w, draws = 60, 70, 30
    valid = np.ones((h, w), bool)
    sig = np.exp(rng.normal(np.log(0.05), 0.5, (h, w))).astype(np.float32)
    for slope in (0.007, 0.0):
        base = (np.add.outer(np.arange(h), np.arange(w)) * slope).astype(np.float32)
        outs, sums = [], []
        for _ in range(draws):
            ws = np.zeros((h, w), np.float32)
            d = base + rng.normal(0.0, 1.0, (h, w)).astype(np.float32) * sig
            outs.append(denoise_phase(d, sig, valid, radius=2, k=3.0, max_radius=6, target_sigma=0.002,
                                      reject_sigma=0.03, weight_sum=ws) - base)
            sums.append(ws)
        o, ws = np.array(outs)[:, 8:-8, 8:-8], np.array(sums)[:, 8:-8, 8:-8]
        assert np.median(ws) > 2.5 * np.median(1 / sig[8:-8, 8:-8].astype(np.float64) ** 2) * 25  # grown
        ratio = float(np.median(np.std(o, axis=0) / np.sqrt(np.mean(1.0 / ws, axis=0))))
        assert abs(ratio - 1.0) < 0.08, (slope, ratio)
        assert abs(float(np.mean(o))) < 2e-3  # and unbiased on the ramp


def _slope_unknown(first: np.ndarray, wfirst: np.ndarray, bu: int, axis: int) -> np.ndarray:
    """NumPy definition of the adaptive pass's test of whether nothing says the surface is flat along
    ``axis`` where the local plane lacks a probe (``bu`` px either side): both probes missing
    (outside or not valid), or the one there differs from the pixel's first-pass estimate by a
    significant slope (``g^2 > 4 var(g)``); False where both probes are there."""
    f = np.moveaxis(first.astype(np.float64), axis, 0)
    wm = np.moveaxis(wfirst.astype(np.float64), axis, 0)
    lo, lw = np.full(f.shape, np.nan), np.zeros(f.shape)
    hi, hw = np.full(f.shape, np.nan), np.zeros(f.shape)
    lo[bu:], lw[bu:], hi[:-bu], hw[:-bu] = f[:-bu], wm[:-bu], f[bu:], wm[bu:]
    oka, okc = lw > 0, hw > 0
    d = np.where(okc, hi, lo) - f
    g = (d - 2 * np.pi * np.floor((d + np.pi) / (2 * np.pi))) / bu
    with np.errstate(divide="ignore", invalid="ignore"):
        significant = g * g > 4.0 * (1.0 / np.where(okc, hw, lw) + 1.0 / wm) / bu**2
    return np.moveaxis(np.where(oka & okc, False, np.where(~oka & ~okc, True, significant)), 0, axis)


def _shadowed_surfaces() -> tuple:
    """The grown windows' bias tests' scene (70 x 90 px): pixel grid ``uu``, ``vv``; textured sigma
    (lognormal about 0.05 rad, a 4 x noisier band at columns 40-43); two shadow bands (columns
    60-65, rows 45-50) invalid; the adaptive filter's keywords (radius 2 grown to 5 up to 0.004
    rad); a ramp and a 1.5 rad step at column 30."""
    rng = np.random.default_rng(29)
    vv, uu = np.mgrid[:70, :90].astype(np.float64)
    sigma = np.exp(rng.normal(np.log(0.05), 0.5, uu.shape)).astype(np.float32)
    sigma[:, 40:44] *= 4.0
    valid = np.ones(uu.shape, bool)
    valid[:, 60:66] = False
    valid[45:51, :] = False
    kw = {"radius": 2, "k": 3.0, "max_radius": 5, "target_sigma": 0.004}
    ramp = (0.007 * uu - 0.004 * vv).astype(np.float32)
    step = np.where(uu >= 30, 1.5, 0.0).astype(np.float32)
    return uu, vv, sigma, valid, kw, ramp, step


def _assert_flat_tops_beside_the_step(b2: np.ndarray, err: np.ndarray, grown: np.ndarray, uu: np.ndarray) -> None:
    """The grown windows' bias on the flat tops either side of :func:`_shadowed_surfaces`' step (at
    u = 30): no error, a bias of 0; where the plane's probes straddle the step (a kink) the window's
    bias is left to the lateral term (NaN), farther away it is computed."""
    assert grown.sum() > 300 and err[grown].max() < 1e-5  # no slope on either side of the step
    assert np.nanmax(np.sqrt(b2[grown])) < 1e-4
    kinked = grown & np.isnan(b2)
    assert kinked.any() and np.abs(uu[kinked] - 30).max() <= 6
    assert np.isfinite(b2[grown & (np.abs(uu - 30) > 6)]).all()


def test_grown_windows_report_their_own_bias() -> None:
    """``bias2``: on a noise-free ramp with shadows (windows with weight on one side) the grown
    windows' error at the pixel is their accepted neighbours' own slope times their centroid, with
    or without the local plane (a plane's slope error is the same kind): ``sqrt(bias2)`` is that
    error less its noise share (the ramp has no curvature); on flat tops beside a step (the far
    side rejected, the window as lopsided) it is 0, and NaN where the plane's probes straddle the step (a kink: the lateral
    term's); NaN where the first pass's fixed window stands."""
    uu, vv, sigma, valid, kw, ramp, step = _shadowed_surfaces()
    for surface, sloped in ((ramp, True), (step, False)):
        b2, ws = np.zeros(uu.shape, np.float32), np.zeros(uu.shape, np.float32)
        out = denoise_phase(np.where(valid, surface, np.nan), sigma, valid, weight_sum=ws, bias2=b2, **kw)
        err = np.abs(out.astype(np.float64) - surface)
        wf = np.zeros(uu.shape, np.float32)  # the first pass's weights: which windows grew
        denoise_phase(np.where(valid, surface, np.nan), sigma, valid, radius=2, k=3.0, weight_sum=wf)
        inner = valid & (uu >= 6) & (uu < 84) & (vv >= 6) & (vv < 64)
        grown = inner & (wf < 1 / 0.004**2) & (ws > wf)
        if sloped:  # the fit is exact on a ramp; the term less its slope's noise variance (about 0.002 rad here)
            big = grown & (err > 0.005)
            assert big.sum() > 100  # lopsided windows do err
            ratio = np.sqrt(b2[big]) / err[big]
            assert 0.85 < np.median(ratio) <= 1.0 and np.percentile(ratio, 5) > 0.4, np.percentile(ratio, [5, 50, 95])
            # never more than the error itself but where the first pass's own centroid error (its
            # weights follow the texture) reads as a curvature in its second differences
            excess = np.sqrt(b2[grown]) - err[grown]
            assert np.mean(excess <= 1e-4) > 0.995 and excess.max() < 0.002, (np.mean(excess <= 1e-4), excess.max())
            assert np.isfinite(b2[grown]).all()  # shadows drop the plane, no kink: computed everywhere
        else:
            _assert_flat_tops_beside_the_step(b2, err, grown, uu)
        assert np.isnan(b2[inner & (wf >= 1 / 0.004**2)]).all()  # NaN: the fixed window
    none = denoise_phase(np.where(valid, ramp, np.nan), sigma, valid, **kw)
    assert np.array_equal(none, denoise_phase(np.where(valid, ramp, np.nan), sigma, valid, bias2=b2, **kw),
                          equal_nan=True)  # asking for it changes no phase


def test_posterior_bias_covers_the_error_where_the_plane_lacked_a_probe() -> None:
    """``bias2`` with ``lacking_probe_bias="posterior"``, on the surfaces of
    :func:`test_grown_windows_report_their_own_bias`: where the plane lacked a probe and nothing says
    the surface is flat there (beside the shadows on the ramp) it is the error plus its noise
    share, so it covers the error; elsewhere it is the default's (the error less its noise share);
    on the flat tops beside a step still 0 (the probe left reads no slope)."""
    uu, vv, sigma, valid, kw, ramp, step = _shadowed_surfaces()
    for surface, sloped in ((ramp, True), (step, False)):
        b2, ws = np.zeros(uu.shape, np.float32), np.zeros(uu.shape, np.float32)
        out = denoise_phase(np.where(valid, surface, np.nan), sigma, valid, weight_sum=ws, bias2=b2,
                            lacking_probe_bias="posterior", **kw)
        err = np.abs(out.astype(np.float64) - surface)
        wf = np.zeros(uu.shape, np.float32)  # the first pass's estimates and weights: which windows grew
        first = denoise_phase(np.where(valid, surface, np.nan), sigma, valid, radius=2, k=3.0, weight_sum=wf)
        inner = valid & (uu >= 6) & (uu < 84) & (vv >= 6) & (vv < 64)
        grown = inner & (wf < 1 / 0.004**2) & (ws > wf)
        unknown = _slope_unknown(first, wf, 5, 1) | _slope_unknown(first, wf, 5, 0)
        if sloped:  # the fit is exact on a ramp; the term less its slope's noise variance (about 0.002 rad here)
            known = grown & ~unknown
            big = known & (err > 0.005)
            assert big.sum() > 100  # lopsided windows do err
            ratio = np.sqrt(b2[big]) / err[big]
            assert 0.75 < np.median(ratio) <= 1.0, np.percentile(ratio, [5, 50, 95])
            # never more than the error itself but where the first pass's own centroid error (its
            # weights follow the texture) reads as a curvature in its second differences
            excess = np.sqrt(b2[known]) - err[known]
            assert np.mean(excess <= 1e-4) > 0.995 and excess.max() < 0.002, (np.mean(excess <= 1e-4), excess.max())
            # beside the shadows, where a probe falls on them and the one left reads the ramp's slope:
            # the error plus its noise share, so at least the error
            beside = grown & unknown
            pad = np.pad(valid, 5, constant_values=False)  # a probe 5 px along an axis outside or not valid
            lacks = ~(pad[5:-5, :-10] & pad[5:-5, 10:] & pad[:-10, 5:-5] & pad[10:, 5:-5])
            assert beside.sum() > 300 and not (beside & ~lacks).any()
            ratio = np.sqrt(b2[beside & (err > 0.005)]) / err[beside & (err > 0.005)]
            assert np.all(np.sqrt(b2[beside]) >= err[beside] - 1e-4) and 1.0 < np.median(ratio) < 1.2, \
                np.percentile(ratio, [5, 50, 95])
            assert np.isfinite(b2[grown]).all()  # shadows drop the plane, no kink: computed everywhere
        else:  # the flat tops: the probe left reads no slope, the default's 0
            _assert_flat_tops_beside_the_step(b2, err, grown, uu)
        assert np.isnan(b2[inner & (wf >= 1 / 0.004**2)]).all()  # NaN: the fixed window


def test_lacking_probe_bias_changes_only_the_bias_where_the_plane_lacked_a_probe() -> None:
    """``lacking_probe_bias``: ``"unbiased"`` (the default) reports ``b^2 - var(b)`` beside the shadows too, where
    ``"posterior"`` reports ``b^2 + var(b)``: the two differ only on the pixels whose
    plane lacked a probe where nothing says the surface is flat (the NumPy definition above), and
    there the posterior is the larger on nearly all; the phase and the weights are the same bits;
    anything else is refused."""
    uu, vv, sigma, valid, kw, ramp, _ = _shadowed_surfaces()
    rng = np.random.default_rng(31)
    d = np.where(valid, ramp + rng.normal(0, 1, uu.shape) * sigma, np.nan).astype(np.float32)
    got = {}
    for mode in ("posterior", "unbiased"):
        b2, ws = np.zeros(uu.shape, np.float32), np.zeros(uu.shape, np.float32)
        out = denoise_phase(d, sigma, valid, weight_sum=ws, bias2=b2, lacking_probe_bias=mode, **kw)
        got[mode] = out, ws, b2.astype(np.float64)
    assert np.array_equal(got["posterior"][0], got["unbiased"][0], equal_nan=True)
    assert np.array_equal(got["posterior"][1], got["unbiased"][1])
    wf = np.zeros(uu.shape, np.float32)
    first = denoise_phase(d, sigma, valid, radius=2, k=3.0, weight_sum=wf)
    unknown = _slope_unknown(first, wf, 5, 1) | _slope_unknown(first, wf, 5, 0)
    bp, bu_ = got["posterior"][2], got["unbiased"][2]
    fin = np.isfinite(bp) & np.isfinite(bu_)
    assert np.array_equal(np.isnan(bp), np.isnan(bu_))
    same = fin & ~unknown
    assert same.sum() > 500 and np.array_equal(bp[same], bu_[same])
    moved = fin & unknown
    assert moved.sum() > 100 and np.all(bp[moved] >= bu_[moved]) and np.mean(bp[moved] > bu_[moved]) > 0.9
    with pytest.raises(ValueError, match="lacking_probe_bias"):
        denoise_phase(d, sigma, valid, lacking_probe_bias="flat", **kw)


def test_grown_windows_bias_holds_the_surfaces_curvature() -> None:
    """``bias2`` on a noise-free curved surface (a paraboloid with a cross term, gentle enough that
    the local plane stays): a grown window's mean errs by the curvature over its offsets,
    ``mean(o^T H o) / 2``, even where the window is symmetric and its centroid at the pixel. The
    term takes ``H`` from the first-pass map's second differences and the fitted slope's share of
    the curvature out, so ``sqrt(bias2)`` follows the error on every kind of window: symmetric
    ones, and lopsided ones beside a shadow band, where the error is smaller than the
    curvature's mean (the slope fit takes part of it). A linear fit alone reports nothing where the
    window is symmetric."""
    rng = np.random.default_rng(31)
    vv, uu = np.mgrid[:80, :100].astype(np.float64)
    sigma = np.exp(rng.normal(np.log(0.05), 0.5, uu.shape)).astype(np.float32)
    valid = np.ones(uu.shape, bool)
    valid[:, 62:68] = False
    x, y = uu - 40.0, vv - 38.0
    surface = (0.5 * 8e-4 * x * x + 2e-4 * x * y + 0.5 * 4e-4 * y * y).astype(np.float32)
    kw = {"radius": 2, "k": 3.0, "max_radius": 5, "target_sigma": 0.004}
    b2, ws = np.zeros(uu.shape, np.float32), np.zeros(uu.shape, np.float32)
    sp = np.zeros(uu.shape, np.float32)
    out = denoise_phase(np.where(valid, surface, np.nan), sigma, valid, weight_sum=ws, bias2=b2, support=sp, **kw)
    err = out.astype(np.float64) - surface
    wf = np.zeros(uu.shape, np.float32)
    denoise_phase(np.where(valid, surface, np.nan), sigma, valid, radius=2, k=3.0, weight_sum=wf)
    inner = valid & (uu >= 12) & (uu < 88) & (vv >= 12) & (vv < 68)
    grown = inner & (wf < 1 / 0.004**2) & (ws > wf)
    # computed on the grown windows but where the curvature against the pixel's noise reads as a
    # kink of 5 sigma or more between the plane's probes (a step: the lateral term's)
    assert grown.sum() > 1500 and np.mean(np.isfinite(b2[grown])) > 0.99
    # the whole window (11 x 11) away from the band: its centroid near the pixel, its mean off by
    # the curvature, (8e-4 + 4e-4) / 2 * 10 px^2 = 0.006 rad
    whole = grown & (np.abs(uu - 65) > 9) & (np.abs(sp - 121) < 0.01) & np.isfinite(b2)
    beside = grown & (np.abs(uu - 65) <= 6) & np.isfinite(b2)
    assert whole.sum() > 150 and beside.sum() > 300
    assert 0.005 < np.median(err[whole]) < 0.007
    # the term: the curvature shrunk by its own noise (from the first pass's weights), so a little
    # short of the error where the window is whole; beside the band, where the slope fit takes part
    # of the curvature, at the error
    ratio = np.sqrt(b2[whole]) / np.abs(err[whole])
    assert 0.75 < np.median(ratio) <= 1.0 and np.percentile(ratio, 25) > 0.6, np.percentile(ratio, [5, 25, 50, 95])
    ratio = np.sqrt(b2[beside]) / np.abs(err[beside])
    assert 0.9 < np.median(ratio) < 1.1 and np.percentile(ratio, 5) > 0.6, np.percentile(ratio, [5, 50, 95])


@pytest.mark.parametrize("kink_sigma", [3.0, 10.0])
def test_row_planes_are_the_per_pixel_probes_bit_for_bit(kink_sigma: float) -> None:
    """The adaptive pass's row-wise local planes and curvature terms (``_row_planes``: one
    branch-free pass over a row's inner pixels, SIMD, on flat offsets of its own) are the per-pixel
    functions' values bit for bit (``_plane_slope`` along u and v, ``_curvature_probe``,
    ``_cross_probe``, ``_shrunk``; both share the value-level definitions, so this checks the row
    pass's probe offsets and choices) on a first-pass map with wrapped phase, steps, invalid pixels
    (weight 0) and every decision of the kink and agreement tests taken both ways."""
    from huefringe.phase import _passes as P

    rng = np.random.default_rng(41)
    h, w, mr = 40, 64, 5
    vv, uu = np.mgrid[:h, :w].astype(np.float64)
    surface = 0.3 * uu - 0.2 * vv + 2e-3 * (uu - 30) ** 2 + np.where(uu > 40, 1.5, 0.0) + np.where(vv > 25, -2.0, 0.0)
    first = wrap(surface + rng.normal(0.0, 0.05, (h, w))).astype(np.float32)
    wfirst = np.exp(rng.normal(np.log(400.0), 1.0, (h, w))).astype(np.float32)
    wfirst[rng.random((h, w)) < 0.08] = 0.0
    fl, wl = first.ravel(), wfirst.ravel()
    kink2 = np.float32(kink_sigma**2)
    out = [np.empty(w, np.float32), np.empty(w, np.float32), np.empty(w, np.bool_),
           np.empty(w, np.float32), np.empty(w, np.float32), np.empty(w, np.bool_), np.empty((3, w), np.float32)]
    kinks = decided = 0
    for v in range(2 * mr, h - 2 * mr):
        P._row_planes(fl, wl, v, w, mr, kink2, True, *out)
        for u in range(2 * mr, w - 2 * mr):
            i = v * w + u
            bu = np.float32(mr)
            want = (P._plane_slope(fl, wl, i - mr, i, i + mr, bu, kink2)
                    + P._plane_slope(fl, wl, i - mr * w, i, i + mr * w, bu, kink2))
            got = tuple(x[u] for x in out[:6])
            assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True)), (v, u, got, want)
            huu, vuu = P._curvature_probe(fl, wl, i, u, w, mr, 1)
            hvv, vvv = P._curvature_probe(fl, wl, i, v, h, mr, w)
            huv, vuv = P._cross_probe(fl, wl, i, u, v, w, h, mr)
            ph = (np.float32(0.5 * P._shrunk(huu, vuu)), np.float32(P._shrunk(huv, vuv)),
                  np.float32(0.5 * P._shrunk(hvv, vvv)))
            assert all(np.array_equal(out[6][k, u], ph[k]) for k in range(3)), (v, u, out[6][:, u], ph)
            kinks += bool(want[2] or want[5])
            decided += (want[0] != 0) + (want[3] != 0)
    assert kinks > 20 and decided > 200  # both branches of the tests taken
