"""One-shot colour frames on a calibrated rig: the sequence's blocks, the order from a reference, and
X, Y, Z of gauge blocks, a flat board and a block beyond the range through the bench rig, against truth."""

from __future__ import annotations

import numpy as np
import pytest

from huefringe.bench.oneshot import (calibrated_rig, face_mask, flatness_scores, gauge_scene, pixel_scores,
                                     render_session, step_scores)
from huefringe.bench.rig import RIGS, CompositeScene, PlaneScene
from huefringe.codecs import (FlatBlock, HueBandsBlock, Reason, SequenceError, SequenceSpec, TrapezoidBlock,
                              decode_sequence, generate, generate_rgb)
from huefringe.codecs.sequence import Decoded, sequence_from_mapping, sequence_to_mapping
from huefringe.colour import hue
from huefringe.metrology import flatness_u
from huefringe.rig.oneshot import (OneShotPhase, OneShotReference, absolute_from_reference, hue_table_from_frames,
                                   measure_oneshot, oneshot_reference)

PROJ = {"width": 800, "height": 600}
ONESHOT = [{"phase": {"axis": "x", "period_px": 16, "steps": 8}}, {"gray": {"axis": "x", "cells": 50, "cell_px": 16}},
           "white", "black", {"hue_bands": {"n": 48, "repeats": 2}}, {"trapezoid": {"axis": "x", "period_px": 36, "frames": 5}}]
GAUGE = {1: 3.0, 2: 1.0, 3: 4.0}


# ------------------------------------------------------------------------------ the sequence's blocks


def test_oneshot_blocks_load_write_and_count_frames() -> None:
    spec = sequence_from_mapping({"projector": PROJ, "blocks": ONESHOT}, "sequence.yaml", ".")
    assert spec.blocks[-2:] == (HueBandsBlock(48, 2), TrapezoidBlock("x", 36.0, 0.0, 5))
    assert spec.n_frames == 8 + 12 + 2 + 96 + 5
    assert sequence_from_mapping(sequence_to_mapping(spec), "again.yaml", ".") == spec
    assert spec.axes() == ["x"]            # the coded axes: the phase and Gray blocks only
    assert sequence_to_mapping(spec)["blocks"][-1] == {"trapezoid": {"axis": "x", "period_px": 36.0, "origin_px": 0.0,
                                                                     "frames": 5}}


def test_oneshot_blocks_refused_with_every_problem_named() -> None:
    with pytest.raises(SequenceError) as e:
        sequence_from_mapping({"projector": PROJ, "blocks": [
            {"trapezoid": {"axis": "z", "period_px": 4, "frames": 0, "speed": 1}}, {"hue_bands": {"n": 6, "repeats": 0}},
            "white"]}, "seq.yaml", ".")
    msg = str(e.value)
    assert msg.startswith("seq.yaml: ")
    for part in ("unknown keys ['speed']", "axis must be x", "period_px must be a finite number >= 6", "frames: the number",
                 "hue_bands.n: the number of hue bands", "repeats: captures of each band"):
        assert part in msg, part
    with pytest.raises(SequenceError, match="white frame; the sequence has none.*hue table of a hue_bands block"):
        sequence_from_mapping({"projector": PROJ, "blocks": [{"trapezoid": {"axis": "x", "period_px": 36}}]}, "s.yaml", ".")


def test_generated_trapezoid_hue_is_the_code_phase() -> None:
    spec = SequenceSpec((FlatBlock("white"), HueBandsBlock(12), TrapezoidBlock("x", 36.0, 5.0)), 216, 4)
    rgb = generate_rgb(spec).astype(np.float64) / 255.0
    assert rgb.shape == (14, 4, 216, 3) and generate(spec).shape == (14, 4, 216)
    u = np.arange(216)
    want = np.mod(2 * np.pi * (u - 5.0) / 36.0, 2 * np.pi)
    got = hue(rgb[-1, 0], "hexcone").astype(np.float64)
    err = np.angle(np.exp(1j * (got - want)))
    assert np.max(np.abs(err)) <= np.pi / 3 * 0.5 / 255 + 1e-6   # half an 8-bit level of a ramp (a sextant is pi/3)
    assert np.allclose(hue(rgb[1 + 4, 0, :1], "hexcone"), 2 * np.pi * 4 / 12, atol=1e-6)


# ------------------------------------------------------------------------------ order from the reference


def _reference(coord: np.ndarray, sigma: float = 0.02, front_sign: float = 1.0, px_per_mm: float = 2.0) -> OneShotReference:
    ok = np.isfinite(coord)
    return OneShotReference(coord, np.full(coord.shape, sigma), ok, np.zeros(coord.shape, np.uint8), 36.0,
                            np.full(coord.shape, 9.0), np.full(coord.shape, 9.0), np.full(coord.shape, front_sign),
                            np.full(coord.shape, px_per_mm))


def _phase(u_true: np.ndarray, sigma: float = 0.05) -> OneShotPhase:
    return OneShotPhase(np.mod(u_true, 36.0), np.full(u_true.shape, sigma), np.ones(u_true.shape, bool),
                        np.zeros(u_true.shape, np.uint8), np.zeros(u_true.shape, np.float32))


def test_order_from_reference_within_half_a_period_and_flags() -> None:
    u_ref = np.linspace(40.0, 700.0, 12)[None, :]
    d = np.array([[0.0, 5.0, 12.0, 17.0, 17.9, 17.5, -0.4, -0.6, -5.0, 30.0, 8.0, 1.0]])
    block = TrapezoidBlock("x", 36.0)
    co = absolute_from_reference(_phase(u_ref + d), _reference(u_ref), block, stands_on_reference=True,
                                 behind_mm=0.25, extent=800)
    # margin 3 sqrt(0.05^2 + 0.02^2) = 0.16 px: 17.9 is within it of 18; -0.6 px is 0.3 mm behind (2 px/mm);
    # 30 px in front wraps to -6: flagged as behind, not measured at -6
    flagged = np.array([False, False, False, False, True, False, False, True, True, True, False, False])
    assert np.array_equal((co.reasons[0] & Reason.ORDER) > 0, flagged)
    assert np.allclose(co.coord[0][~flagged], (u_ref + d)[0][~flagged])
    assert np.allclose(co.sigma[0][~flagged], 0.05)
    both = absolute_from_reference(_phase(u_ref + d), _reference(u_ref), block, stands_on_reference=False)
    assert np.allclose(both.coord[0, 8], u_ref[0, 8] - 5.0)  # either side of the reference without the prior
    assert np.isclose(both.coord[0, 9], u_ref[0, 9] - 6.0)   # the alias a one-sided prior catches


def test_order_outside_the_projector_and_without_reference() -> None:
    u_ref = np.array([[2.0, 400.0, np.nan]])
    co = absolute_from_reference(_phase(np.array([[-3.0, 401.0, 10.0]])), _reference(u_ref), TrapezoidBlock("x", 36.0),
                                 stands_on_reference=False, extent=800)
    assert co.reasons[0, 0] & Reason.OUTSIDE and co.valid[0, 1] and not co.valid[0, 2]


def test_relative_reference_refused() -> None:
    z = np.zeros((2, 2))
    dec = Decoded("x", z, z, z.astype(np.float32), z == 0, z.astype(np.float32), False, z.astype(np.uint8))
    with pytest.raises(ValueError, match="within one period only"):
        oneshot_reference(dec, RIGS["holdout-wide"].calibration, TrapezoidBlock("x", 36.0))


def test_travel_mm_loads_writes_and_is_refused_with_its_problems() -> None:
    blocks = [*ONESHOT[:-1], {"trapezoid": {"axis": "x", "period_px": 36, "frames": 2, "travel_mm": {"front": 30, "back": 0.5}}}]
    spec = sequence_from_mapping({"projector": PROJ, "blocks": blocks}, "sequence.yaml", ".")
    assert spec.blocks[-1] == TrapezoidBlock("x", 36.0, 0.0, 2, (30.0, 0.5))
    assert sequence_to_mapping(spec)["blocks"][-1]["trapezoid"]["travel_mm"] == {"front": 30.0, "back": 0.5}
    assert sequence_from_mapping(sequence_to_mapping(spec), "again.yaml", ".") == spec
    with pytest.raises(SequenceError) as e:
        sequence_from_mapping({"projector": PROJ, "blocks": [
            *ONESHOT[:-1], {"trapezoid": {"axis": "x", "period_px": 36, "travel_mm": {"front": -1, "back": 2}}},
            {"trapezoid": {"axis": "x", "period_px": 36, "travel_mm": [3, 4]}}]}, "seq.yaml", ".")
    msg = str(e.value)
    assert "travel_mm: front and back must be finite, >= 0" in msg and "travel_mm: expected {front: mm, back: mm}" in msg


def _rectified():
    """A rectified rig: projector 100 mm beside the camera, f = 1000 px, no distortion. A surface at
    depth Z shows camera column x the projector column ``x - 1e5 / Z``."""
    from huefringe.rig import RigCalibration

    K = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    return RigCalibration(K, np.zeros(5), K, np.zeros(5), np.eye(3), np.array([-100.0, 0, 0]), (640, 480), (800, 600))


def test_working_volume_orders_one_candidate_and_flags_an_ambiguous_volume() -> None:
    cal = _rectified()
    x = np.arange(300.0, 340.0)[None, :].repeat(2, axis=0)                   # rows 239, 240 of a 40-column strip
    z_ref, z_obj = 500.0, 470.0                                              # the object 30 mm in front
    u_ref = x - 1e5 / z_ref
    u_obj = x - 1e5 / z_obj                                                  # 12.77 px from the reference: P / 2 = 10
    full = np.full((480, 640), np.nan)
    cols = slice(300, 340)
    ref_coord = full.copy()
    ref_coord[239:241, cols] = u_ref
    z = np.zeros((480, 640))
    dec = Decoded("x", ref_coord, np.where(np.isfinite(ref_coord), 0.02, np.nan), z.astype(np.float32),
                  np.isfinite(ref_coord), z.astype(np.float32), True, z.astype(np.uint8))
    obj = full.copy()
    obj[239:241, cols] = u_obj
    phase = OneShotPhase(np.mod(obj, 20.0), np.where(np.isfinite(obj), 0.05, np.nan), np.isfinite(obj),
                         z.astype(np.uint8), z.astype(np.float32))
    plain = TrapezoidBlock("x", 20.0)
    nearest = absolute_from_reference(phase, oneshot_reference(dec, cal, plain), plain, stands_on_reference=False)
    assert np.allclose(nearest.coord[239:241, cols], u_obj + 20.0)           # the alias: 18.8 mm behind, not flagged
    # a working volume 35 mm in front, 1 mm behind: 15.4 px of coordinate, one candidate per pixel
    volume = TrapezoidBlock("x", 20.0, travel_mm=(35.0, 1.0))
    ref = oneshot_reference(dec, cal, volume)
    ends = ref.travel_coord[239:241, cols]
    zf = 500.0 - 35.0 * 500.0 / np.sqrt(500.0**2 + ((x - 320.0) * 0.5) ** 2 + 0.25)   # depth of the front end (approx.)
    assert np.allclose(ends[..., 0], x - 1e5 / zf, atol=0.02) and np.all(ends[..., 1] > u_ref)
    co = absolute_from_reference(phase, ref, volume)
    assert co.valid[239:241, cols].all() and np.allclose(co.coord[239:241, cols], u_obj)
    # the decision's margin: u_obj - 20 and u_obj + 20 lie 2.2-2.5 px outside the 15.4 px interval
    lo, hi = ends.min(axis=-1), ends.max(axis=-1)
    want = np.minimum.reduce([u_obj - lo, hi - u_obj, lo - (u_obj - 20.0), u_obj + 20.0 - hi])
    assert np.allclose(co.margin[239:241, cols], want) and 1.5 < want.min() and want.max() < 3.0
    assert np.allclose(nearest.margin[239:241, cols], 10.0 - np.abs(u_obj + 20.0 - u_ref))
    assert ref.travel_summary()["wider_than_period_fraction"] == 0.0
    # a volume two periods deep (60 mm in front, 30 behind: 440-530 mm): the alias 18.8 mm behind
    # lies in it too, every pixel flagged
    deep = TrapezoidBlock("x", 20.0, travel_mm=(60.0, 30.0))
    dref = oneshot_reference(dec, cal, deep)
    dco = absolute_from_reference(phase, dref, deep)
    assert not dco.valid.any() and ((dco.reasons[239:241, cols] & Reason.ORDER) > 0).all()
    assert dref.travel_summary()["wider_than_period_fraction"] == 1.0
    # the object outside a volume whose candidates all miss it: flagged (10 mm in front, 0.5 behind;
    # 30 mm in front wraps to 18.8 mm behind and 20 mm further in front, both outside)
    near = TrapezoidBlock("x", 20.0, travel_mm=(10.0, 0.5))
    nco = absolute_from_reference(phase, oneshot_reference(dec, cal, near), near)
    assert not nco.valid.any() and ((nco.reasons[239:241, cols] & Reason.ORDER) > 0).all()


# ------------------------------------------------------------------------------ the bench rig, with truth


@pytest.fixture(scope="module")
def rig():
    return calibrated_rig()


@pytest.fixture(scope="module")
def gauge():
    cap = render_session(gauge_scene(), n_bands=64, repeats=3, seed=1)   # the demo session's bands
    return cap, hue_table_from_frames(cap.white, cap.bands, cap.bands_block)


def _measure(cap, table, calib):
    ref = oneshot_reference(cap.reference, calib, cap.block)
    return ref, measure_oneshot(cap.frames[0], cap.white, table, cap.block, calib, ref)


def test_gauge_steps_decoding_alone_within_0p3_percent(gauge) -> None:
    """With the rig's true calibration every error is the one-shot decode's."""
    cap, table = gauge
    _, res = _measure(cap, table, RIGS["holdout-wide"].calibration)
    from huefringe.metrology import step_height_u

    base = face_mask(cap, 0) & res.valid
    for k, h0 in GAUGE.items():
        top = face_mask(cap, k) & res.valid
        s = step_height_u(res.xyz[base], res.sigma[base], res.xyz[top], res.sigma[top])
        assert abs(s["height_mm"] - h0) <= 0.003 * h0, (k, s["height_mm"])
    ok = res.valid & np.isfinite(cap.truth_xyz).all(axis=-1)
    t = cap.truth_xyz[ok]
    e = np.abs(np.einsum("ij,ij->i", res.xyz[ok] - t, t / np.linalg.norm(t, axis=-1, keepdims=True)))
    assert abs(np.mean(e <= 2 * res.sigma_ray[ok]) - 0.95) <= 0.03


def test_sigma_follows_the_frames_own_signal(gauge) -> None:
    """The capture's noise in sigma is the frame's own-signal figure (the table's sensor model
    through the hue): |e| <= 2 sigma along the ray for 0.95 +- 0.03 of the pixels in every
    fifth of the pixels by their own figure over the table's pooled one (measured 0.948-0.958;
    with the pooled figure 0.981 in the lowest fifth and 0.904 in the highest)."""
    from huefringe import colour, perframe

    cap, table = gauge
    _, res = _measure(cap, table, RIGS["holdout-wide"].calibration)
    gains = colour.white_gains(np.asarray(cap.white, np.float32))
    q = perframe.frame_hue_noise(table, np.asarray(cap.frames[0], np.float32), gains, table.model) / \
        perframe.capture_noise(table)
    ok = res.valid & np.isfinite(cap.truth_xyz).all(axis=-1)
    t = cap.truth_xyz[ok]
    e = np.abs(np.einsum("ij,ij->i", res.xyz[ok] - t, t / np.linalg.norm(t, axis=-1, keepdims=True)))
    inside = e <= 2 * res.sigma_ray[ok]
    edges = np.percentile(q[ok], [0, 20, 40, 60, 80, 100])
    for lo, hi in zip(edges[:-1], edges[1:]):
        b = (q[ok] >= lo) & (q[ok] <= hi)
        assert abs(float(np.mean(inside[b])) - 0.95) <= 0.03, (lo, hi, float(np.mean(inside[b])))


def test_gauge_through_calibrated_rig_truth_inside_U(gauge, rig) -> None:
    cap, table = gauge
    cal, jack = rig
    ref, res = _measure(cap, table, cal)
    steps = step_scores(cap, res, jack, GAUGE)
    assert all(s["inside_U"] for s in steps.values()), steps
    assert all(s["n_top"] > 3000 for s in steps.values())
    px = pixel_scores(cap, res, jack)
    assert px["within_2u"] >= 0.92, px
    lit = np.isfinite(cap.truth_xyz).all(axis=-1) & ref.valid
    assert res.valid[lit].mean() > 0.97          # every lit pixel with a reference is measured but edges and shadows
    assert not (res.valid & ~np.isfinite(cap.truth_xyz).all(axis=-1)).any()   # and none the projector does not light


def test_flat_board_flatness(rig) -> None:
    cap = render_session(PlaneScene(point=(0.0, 0.0, 426.0), tilt_deg=(6.0, -5.0)), n_bands=48, repeats=2, seed=2)
    table = hue_table_from_frames(cap.white, cap.bands, cap.bands_block)
    _, res = _measure(cap, table, RIGS["holdout-wide"].calibration)     # the decoding alone
    m = face_mask(cap, 0) & res.valid
    f = flatness_u(res.xyz[m], res.sigma[m])
    assert f["rms_form_mm"] <= 0.02 and f["rms_form_mm"] <= 2 * f["u_rms_form_mm"]
    assert f["rms_mm"] == pytest.approx(f["rms_noise_mm"], rel=0.05)   # what is left is the propagated noise
    _, res = _measure(cap, table, rig[0])                                # through the calibrated rig
    f = flatness_scores(cap, res, rig[1])
    assert f["rms_form_mm"] <= 0.02 and f["rms_form_mm"] <= f["U_mm"], f


def test_beyond_the_range_flagged_not_measured_wrong(rig) -> None:
    cal, _ = rig
    scene = CompositeScene(tilt_deg=(4.0, -3.0), origin=(0.0, 0.0, 430.0), spheres=(),
                           blocks=((-70.0, -25.0, -35.0, 25.0, 6.0), (35.0, -25.0, 70.0, 25.0, 15.0)))
    cap = render_session(scene, n_bands=48, repeats=2, seed=3)
    table = hue_table_from_frames(cap.white, cap.bands, cap.bands_block)
    ref, res = _measure(cap, table, cal)
    for k, height in ((1, 6.0), (2, 15.0)):
        top = face_mask(cap, k) & ref.valid
        front = np.nanmedian(ref.range_front_mm[top])
        measured = top & res.valid
        if height < 0.9 * front:
            assert measured.sum() > 0.99 * top.sum()
        else:
            assert height > front and measured.sum() == 0
            assert np.all(res.coordinate.reasons[top] & Reason.ORDER)


# ------------------------------------------------------------------------------ captures in a folder


def test_oneshot_captures_read_in_colour_and_coded_blocks_decode_alike(tmp_path) -> None:
    import cv2

    from huefringe.codecs import DecodeOptions
    from huefringe.rig.oneshot import oneshot_captures

    spec = sequence_from_mapping({"projector": {"width": 128, "height": 8}, "blocks": [
        {"phase": {"axis": "x", "period_px": 16, "steps": 4}}, {"gray": {"axis": "x", "cells": 8, "cell_px": 16}},
        "white", "black", {"hue_bands": {"n": 12}}, {"trapezoid": {"axis": "x", "period_px": 36, "frames": 2}}]},
        "s.yaml", ".")
    rgb = generate_rgb(spec)
    paths = []
    for k, im in enumerate(rgb):
        paths.append(tmp_path / f"{k:04d}.png")
        cv2.imwrite(str(paths[-1]), cv2.cvtColor(im, cv2.COLOR_RGB2BGR))
    caps = oneshot_captures(paths, spec)
    assert caps.white.shape == (8, 128, 3) and caps.bands.shape == (12, 8, 128, 3) and caps.frames.shape == (2, 8, 128, 3)
    assert caps.block == TrapezoidBlock("x", 36.0, 0.0, 2) and caps.bit_depth == 8
    assert np.allclose(caps.frames[1], rgb[-1] / 255.0) and np.allclose(caps.bands[1, 0, 0], [1.0, 0.5, 0.0], atol=0.01)
    # the coded blocks of a sequence with one-shot blocks decode as without them
    coded = SequenceSpec(spec.blocks[:4], 128, 8)
    grey = generate(spec).astype(np.float64) * 0.8 + 10.0
    d = decode_sequence(list(grey), spec, DecodeOptions.from_config())["x"]
    d0 = decode_sequence(list(grey[: coded.n_frames]), coded, DecodeOptions.from_config())["x"]
    assert d.absolute and np.array_equal(d.valid, d0.valid) and np.array_equal(d.coord, d0.coord, equal_nan=True)
    assert d.valid.mean() > 0.5 and np.max(np.abs(d.coord[d.valid] - np.tile(np.arange(128.0), (8, 1))[d.valid])) < 0.05
    cv2.imwrite(str(paths[-1]), cv2.cvtColor(rgb[-1], cv2.COLOR_RGB2GRAY))
    cv2.imwrite(str(paths[5]), np.zeros((8, 128, 3), np.uint8))          # a frame of the coded blocks: not read
    with pytest.raises(SequenceError, match=r"0025.png: a grey capture"):
        oneshot_captures(paths, spec)
