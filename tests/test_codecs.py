"""huefringe.codecs on analytic sequences: known projector coordinates, bench-like noise."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from codecs_helpers import READ_DN, render, warp
from huefringe.codecs import (
    DecodeOptions,
    FlatBlock,
    GrayBlock,
    PhaseBlock,
    SequenceError,
    SequenceSpec,
    decode_sequence,
    equal_shifts,
    estimate_projector_gamma,
    generate,
    opencv_gray_blocks,
)
from huefringe.codecs.graycode import bits_for

SHAPE = (96, 128)
W, H = 1024, 768


def _opts() -> DecodeOptions:
    return DecodeOptions.from_config()


def _gray(axis: str, cell: float, extent: int) -> GrayBlock:
    return GrayBlock(axis, bits_for(int(np.ceil(extent / cell))), cell, True)


def _spec(n: int, period: float, *, extra: tuple = (), gray: bool = True, axes=("x", "y")) -> SequenceSpec:
    d = tuple(equal_shifts(n))
    blocks = []
    for a in axes:
        blocks.append(PhaseBlock(a, period, d))
        blocks += [PhaseBlock(a, p, d) for p in extra]
        if gray:
            blocks.append(_gray(a, period / 2, W if a == "x" else H))  # complementary: cells of half a period
    return SequenceSpec(tuple(blocks) + (FlatBlock("white"), FlatBlock("black")), W, H)


def _errors(spec, bits=8, seed=1, **kw):
    ux, uy = warp(SHAPE, spec, seed)
    out = decode_sequence(render(spec, ux, uy, bits=bits, seed=seed, **kw), spec, _opts())
    truth = {"x": ux, "y": uy}
    return {a: (d.coord - truth[a], d) for a, d in out.items()}


@pytest.mark.parametrize("n", [3, 4, 5, 8])
@pytest.mark.parametrize("bits", [8, 16])
def test_nstep_with_gray_code_recovers_the_coordinate(n, bits):
    spec = _spec(n, 18.0)
    for axis, (err, d) in _errors(spec, bits=bits, seed=n).items():
        v = d.valid
        assert v.mean() > 0.99, axis
        assert np.max(np.abs(err[v])) < 9.0, f"fringe-order error on axis {axis}"
        rms = float(np.sqrt(np.mean(err[v] ** 2)))
        assert rms <= 0.05, (axis, rms)
        # the uncertainty tells the spread: N steps average the noise down by sqrt(N)
        assert 0.8 < rms / float(np.sqrt(np.mean(d.sigma[v] ** 2))) < 1.2, (axis, n, bits)


def test_uncertainty_covers_the_error():
    spec = _spec(3, 24.0, extra=(36.0,))
    cover, z = [], []
    for seed in range(3):
        for axis, (err, d) in _errors(spec, seed=seed + 10).items():
            v = d.valid
            cover.append(np.mean(np.abs(err[v]) <= 2 * d.sigma[v]))
            z.append(np.std(err[v] / d.sigma[v]))
    assert 0.93 <= np.mean(cover) <= 0.97, cover
    assert 0.9 <= np.mean(z) <= 1.1, z


def test_two_periods_and_coarse_gray_code_as_kamino410():
    """Periods step/3 and step/2, Gray cells step/2 (cell edges on the wrap of both): the beat decides."""
    step = 60
    d = tuple(equal_shifts(3, -2 * np.pi / 3))
    gx, gy = opencv_gray_blocks((W - 1) // (step // 2) + 1, (H - 1) // (step // 2) + 1, step // 2)
    blocks = (PhaseBlock("x", step / 3, d), PhaseBlock("x", step / 2, d), PhaseBlock("y", step / 3, d),
              PhaseBlock("y", step / 2, d), gx, gy, FlatBlock("white"), FlatBlock("black"))
    spec = SequenceSpec(blocks, W, H)
    for axis, (err, d) in _errors(spec, seed=3).items():
        v = d.valid
        assert v.mean() > 0.99
        assert np.max(np.abs(err[v])) < step / 6, "fringe-order error"
        assert np.sqrt(np.mean(err[v] ** 2)) <= 0.05


def test_three_period_heterodyne_without_gray_code():
    ps = (W / 70, W / 64, W / 59)  # beats 1024/6, 1024/5 and their beat 1024: the whole projector
    d = tuple(equal_shifts(4))
    spec = SequenceSpec(tuple(PhaseBlock("x", p, d) for p in ps), W, H)
    (err, dec), = _errors(spec, seed=4).values()
    v = dec.valid
    assert dec.absolute and v.mean() > 0.99
    assert np.max(np.abs(err[v])) < ps[0] / 2
    assert np.sqrt(np.mean(err[v] ** 2)) <= 0.05


def test_number_theoretic_periods():
    ps = (20.0, 23.0, 29.0)  # no useful beat: 153 and 222 px, their beat 493 px < 1024
    d = tuple(equal_shifts(5))
    spec = SequenceSpec(tuple(PhaseBlock("x", p, d) for p in ps), W, H)
    (err, dec), = _errors(spec, seed=5).values()
    v = dec.valid
    assert v.mean() > 0.99
    assert np.max(np.abs(err[v])) < 10.0
    assert np.sqrt(np.mean(err[v] ** 2)) <= 0.05


def test_encoding_gamma_is_undone_and_estimated():
    """Fringes (0.5 + 0.5 cos)**(g gamma_p): ignoring the exponent leaves the third harmonic."""
    d = tuple(equal_shifts(3, -2 * np.pi / 3))
    gx, gy = opencv_gray_blocks(512, 384, 2)
    blocks = (PhaseBlock("x", 128.0, d, 1 / 0.75), PhaseBlock("x", 128.0, d, 1 / 1.25),
              PhaseBlock("y", 128.0, d, 1 / 0.75), PhaseBlock("y", 128.0, d, 1 / 1.25), gx, gy,
              FlatBlock("white"), FlatBlock("black"))
    truth = SequenceSpec(blocks, W, H, projector_gamma=1.8)
    ux, uy = warp(SHAPE, truth, 6)
    frames = render(truth, ux, uy, seed=6)
    naive = decode_sequence(frames, dataclasses.replace(truth, projector_gamma=1.0), _opts())
    est = estimate_projector_gamma(frames, truth, naive["x"].valid & naive["y"].valid)
    assert est.gray == pytest.approx(1.8, abs=0.03)
    good = decode_sequence(frames, dataclasses.replace(truth, projector_gamma=est.gray), _opts())
    for a, u in (("x", ux), ("y", uy)):
        v = good[a].valid
        noise_rms = np.sqrt(np.mean(good[a].sigma[v] ** 2))
        e_naive = np.sqrt(np.nanmean((naive[a].coord - u) ** 2))
        e_good = np.sqrt(np.mean((good[a].coord - u)[v] ** 2))
        assert e_naive > 5 * noise_rms, (e_naive, noise_rms)
        assert e_good < 1.2 * noise_rms, (e_good, noise_rms)


def test_lone_phase_block_is_relative():
    spec = SequenceSpec((PhaseBlock("x", 32.0, tuple(equal_shifts(4))),), W, H)
    ux, uy = warp(SHAPE, spec, 7)
    (d,) = decode_sequence(render(spec, ux, uy, seed=7), spec, _opts()).values()
    assert not d.absolute
    v = d.valid
    err = (d.coord - np.mod(ux, 32.0) + 16) % 32 - 16
    assert np.sqrt(np.mean(err[v] ** 2)) < 0.1


def test_dark_pixels_are_invalid_not_wrong():
    spec = _spec(4, 18.0, axes=("x",))
    ux, uy = warp(SHAPE, spec, 8)
    frames = render(spec, ux, uy, seed=8)
    frames[:, :, :20] = np.random.default_rng(0).integers(0, 4, size=frames[:, :, :20].shape)  # a shadow
    (d,) = decode_sequence(frames, spec, _opts()).values()
    assert not d.valid[:, :20].any()
    assert np.isnan(d.coord[:, :20]).all() and np.isnan(d.sigma[:, :20]).all()
    assert d.valid[:, 24:].mean() > 0.99


def test_generate_matches_the_render():
    spec = _spec(3, 18.0)
    pats = generate(spec)
    assert pats.shape == (spec.n_frames, H, W) and pats.dtype == np.uint8
    u = np.arange(W, dtype=float)
    ux = np.broadcast_to(u, (4, W)).copy()
    uy = np.broadcast_to(np.arange(10.0, 14.0)[:, None], (4, W)).copy()
    r = render(spec, ux, uy, a_frac=0.0, b_frac=0.5, noise=False)
    assert np.abs(r.astype(int) - pats[:, 10:14, :].astype(int)).max() <= 1


def test_refusals_name_the_problem():
    spec = _spec(3, 18.0)
    with pytest.raises(SequenceError, match="captures, the sequence has"):
        decode_sequence(np.zeros((3, 8, 8), np.uint8), spec, _opts())
    bad = SequenceSpec((GrayBlock("x", 4, 8.0, False),), W, H)
    with pytest.raises(SequenceError, match="axis x: a Gray code without inverses .*white and black.*phase frames' mean; the sequence has neither"):
        decode_sequence(np.zeros((4, 8, 8), np.uint8), bad, _opts())
    assert READ_DN > 0
