"""Validity a metrologist signs: the projector's shadow, signal against noise, saturation, reason
codes; Gray-code-only sequences (OpenCV's GrayCodePattern); frames skipped; Gray code without
inverses or white/black read against the phase frames' mean; relative coordinates never
triangulated."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from codecs_helpers import FULL_WELL_E, READ_DN, render, warp
from huefringe.codecs import (
    DecodeOptions,
    FlatBlock,
    GrayBlock,
    PhaseBlock,
    Reason,
    SequenceError,
    SequenceSpec,
    SkipBlock,
    decode_sequence,
    equal_shifts,
    generate,
    opencv_gray_blocks,
    opencv_graycode_patterns,
    sequence_from_mapping,
    sequence_to_mapping,
)
from huefringe.codecs.graycode import bits_for
from huefringe.rig.decoded import RelativeCoordinateError, relative_axes_problems, triangulation_inputs

SHAPE = (96, 128)
W, H = 1024, 768
OPENCV = Path(__file__).resolve().parents[1].parent / "shared" / "opencv-graycode"


def _opts() -> DecodeOptions:
    return DecodeOptions.from_config()


def _shadow_mask(shape: tuple[int, int]) -> np.ndarray:
    """A cast shadow: a band on the left, a disc (an object's shadow) and a wedge."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    return (xx < 18) | ((xx - 80) ** 2 + (yy - 50) ** 2 < 15**2) | ((yy > 70) & (xx > 100) & (xx - 100 > 80 - yy))


def _in_shadow(frames: np.ndarray, mask: np.ndarray, ambient_frac: np.ndarray, seed: int) -> np.ndarray:
    """Frames where ``mask`` gets no projector light: ambient light (varying across the image) plus
    the camera's shot and read noise, as the captures' render has them."""
    rng = np.random.default_rng(seed)
    full = 255.0 if frames.dtype == np.uint8 else 65535.0
    out = frames.copy()
    amb = full * ambient_frac
    for i in range(len(out)):
        var = (READ_DN * full / 255) ** 2 + amb * full / FULL_WELL_E
        im = np.clip(np.round(amb + rng.standard_normal(amb.shape) * np.sqrt(var)), 0, full)
        out[i][mask] = im[mask].astype(frames.dtype)
    return out


def _sequences() -> dict[str, SequenceSpec]:
    d4, d3 = tuple(equal_shifts(4)), tuple(equal_shifts(3))
    gx, gy = GrayBlock("x", bits_for(W // 8), 8.0), GrayBlock("y", bits_for(H // 8), 8.0)
    wb = (FlatBlock("white"), FlatBlock("black"))
    return {
        "phase + gray + white/black": SequenceSpec((PhaseBlock("x", 16.0, d4), gx, PhaseBlock("y", 16.0, d4), gy, *wb), W, H),
        "three periods, no white/black": SequenceSpec(tuple(PhaseBlock("x", p, d3) for p in (20.0, 23.0, 29.0)), W, H),
        "gray only, inverses": SequenceSpec((GrayBlock("x", bits_for(W), 1.0), GrayBlock("y", bits_for(H), 1.0)), W, H),
        "gray only, white/black": SequenceSpec((GrayBlock("x", bits_for(W // 4), 4.0, False), *wb), W, H),
        "gray without inverses, phase mean": SequenceSpec((PhaseBlock("x", 16.0, d4), GrayBlock("x", bits_for(W // 8), 8.0, False)), W, H),
    }


@pytest.mark.parametrize("name", list(_sequences()))
@pytest.mark.parametrize("bits", [8, 16])
def test_no_pixel_without_projector_light_is_valid(name, bits):
    spec = _sequences()[name]
    ux, uy = warp(SHAPE, spec, 3)
    frames = render(spec, ux, uy, bits=bits, seed=3)
    mask = _shadow_mask(SHAPE)
    # ambient from a dark lab (0) to a bright room (half of full scale) across the image
    ambient = np.broadcast_to(np.linspace(0.0, 0.5, SHAPE[0])[:, None], SHAPE)
    frames = _in_shadow(frames, mask, ambient, seed=4)
    out = decode_sequence(frames, spec, _opts())
    for a, d in out.items():
        assert int(d.valid[mask].sum()) == 0, (name, a, int(d.valid[mask].sum()), int(mask.sum()))
        assert (d.reasons[mask] != 0).all()
        assert (d.valid == (d.reasons == 0)).all()
        assert np.isnan(d.coord[mask]).all()
        lit = ~mask
        assert d.valid[lit].mean() > 0.9, (name, a, d.valid[lit].mean())
        truth = ux if a == "x" else uy
        err = np.abs(d.coord - truth)[d.valid]
        tol = 5 * np.nanmax(d.sigma) + 1e-9
        assert err.max() <= max(tol, 0.5), (name, a, err.max())


def test_shadow_reason_is_the_shadow_and_saturation_is_named():
    spec = _sequences()["phase + gray + white/black"]
    ux, uy = warp(SHAPE, spec, 5)
    frames = render(spec, ux, uy, seed=5)
    mask = _shadow_mask(SHAPE)
    frames = _in_shadow(frames, mask, np.full(SHAPE, 0.3), seed=6)
    frames[:4, 40:50, 40:50] = 255  # a specular glint on the first phase block
    d = decode_sequence(frames, spec, _opts())["x"]
    assert ((d.reasons[mask] & Reason.SHADOW) != 0).all()
    assert ((d.reasons[40:50, 40:50] & Reason.SATURATED) != 0).all()
    assert not d.valid[40:50, 40:50].any()


def test_thresholds_come_from_the_configuration():
    spec = _sequences()["phase + gray + white/black"]
    ux, uy = warp(SHAPE, spec, 5)
    frames = render(spec, ux, uy, seed=5)  # B about 0.4 full scale: 100 DN of modulation
    strict = DecodeOptions.from_config({"codecs": {**_cfg(), "min_modulation_dn": 120.0}})
    d = decode_sequence(frames, spec, strict)["x"]
    assert not d.valid.any() and ((d.reasons & Reason.LOW_SIGNAL) != 0).all()
    strict = DecodeOptions.from_config({"codecs": {**_cfg(), "min_direct_dn": 250.0}})
    d = decode_sequence(frames, spec, strict)["x"]
    assert not d.valid.any() and ((d.reasons & Reason.SHADOW) != 0).all()


def _cfg() -> dict:
    from huefringe.settings import load_config

    return load_config()["codecs"]


def test_opencv_graycode_images_are_the_generator_order():
    if not OPENCV.is_dir():
        pytest.skip(f"no OpenCV Gray code images at {OPENCV} (shared/ beside the clone)")
    files = sorted(OPENCV.glob("*.png"))
    ims = np.stack([cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files])
    assert ims.shape == (42, 600, 800)
    ours = opencv_graycode_patterns(800, 600)
    assert np.array_equal(ims[:40], ours)
    gx, gy = opencv_gray_blocks(800, 600)
    spec = SequenceSpec((gx, gy, FlatBlock("white"), FlatBlock("black")), 800, 600)
    assert np.array_equal(generate(spec), ims)


def test_opencv_graycode_seen_by_a_camera_decodes_to_the_projector_pixel():
    """OpenCV's own images, shot through a known smooth map (bilinear: edges blur), decode to the
    projector pixel each camera pixel sees within 1 px; a Gray-code-only sequence is absolute."""
    if OPENCV.is_dir():
        pats = np.stack([cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in sorted(OPENCV.glob("*.png"))])
    else:
        pats = np.concatenate([opencv_graycode_patterns(800, 600), np.full((1, 600, 800), 255, np.uint8),
                               np.zeros((1, 600, 800), np.uint8)])
    gx, gy = opencv_gray_blocks(800, 600)
    spec = SequenceSpec((gx, gy, FlatBlock("white"), FlatBlock("black")), 800, 600)
    h, w = 240, 320
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    mx = 37.3 + 2.31 * xx + 0.07 * yy + 2e-4 * (xx - 160) ** 2
    my = 21.7 + 2.29 * yy - 0.05 * xx
    rng = np.random.default_rng(0)
    caps = []
    for p in pats:
        seen = cv2.remap(p.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        caps.append(np.clip(np.round(25 + 0.75 * seen + rng.normal(0, 1.0, seen.shape)), 0, 255).astype(np.uint8))
    out = decode_sequence(np.stack(caps), spec, _opts())
    for a, m in (("x", mx), ("y", my)):
        d = out[a]
        assert d.absolute
        assert d.valid.mean() > 0.5, (a, d.valid.mean())
        err = np.abs(d.coord - m)[d.valid]
        assert err.max() <= 1.0, (a, err.max())
        assert np.allclose(d.sigma[d.valid], 1 / np.sqrt(12))


def test_gray_only_sequence_yaml_is_accepted_and_round_trips(tmp_path):
    doc = {"projector": {"width": 800, "height": 600}, "frames": "*.png",
           "blocks": [{"gray": {"axis": "x", "bits": 10, "cell_px": 1}}, {"gray": {"axis": "y", "cells": 600, "cell_px": 1}},
                      {"skip": 2}, "white", "black"]}
    spec = sequence_from_mapping(doc, tmp_path / "s.yaml", tmp_path)
    assert spec.n_frames == 20 + 20 + 2 + 2
    assert isinstance(spec.blocks[2], SkipBlock)
    assert sequence_from_mapping(sequence_to_mapping(spec), tmp_path / "s.yaml", tmp_path) == spec


def test_skipped_frames_are_ignored():
    spec = _sequences()["phase + gray + white/black"]
    ux, uy = warp(SHAPE, spec, 9)
    frames = render(spec, ux, uy, seed=9)
    blocks = list(spec.blocks)
    with_skip = SequenceSpec((SkipBlock(3), *blocks[:2], SkipBlock(1), *blocks[2:]), W, H)
    junk = np.random.default_rng(1).integers(0, 256, size=(4, *SHAPE)).astype(np.uint8)
    extra = np.concatenate([junk[:3], frames[: blocks[0].n_frames + blocks[1].n_frames], junk[3:],
                            frames[blocks[0].n_frames + blocks[1].n_frames:]])
    a, b = decode_sequence(frames, spec, _opts()), decode_sequence(extra, with_skip, _opts())
    for ax in "xy":
        assert np.array_equal(a[ax].coord, b[ax].coord, equal_nan=True)
        assert np.array_equal(a[ax].reasons, b[ax].reasons)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), 0.0])
def test_non_finite_periods_and_cells_are_refused(tmp_path, bad):
    doc = {"projector": {"width": 800, "height": 600},
           "blocks": [{"phase": {"axis": "x", "period_px": bad, "steps": 4}},
                      {"gray": {"axis": "x", "bits": 10, "cell_px": bad}}]}
    with pytest.raises(SequenceError) as exc:
        sequence_from_mapping(doc, tmp_path / "s.yaml", tmp_path)
    msg = str(exc.value)
    assert msg.startswith(str(tmp_path / "s.yaml"))
    assert "blocks[0].phase.period_px must be a finite number > 0" in msg
    assert "blocks[1].gray.cell_px must be a finite number > 0" in msg


def test_periods_that_repeat_within_the_projector_are_relative():
    d3 = tuple(equal_shifts(3))
    spec = SequenceSpec((PhaseBlock("x", 18.0, d3), PhaseBlock("x", 20.0, d3)), W, H)  # repeat every 180 px
    ux, uy = warp(SHAPE, spec, 3)
    d = decode_sequence(render(spec, ux, uy, seed=3), spec, _opts())
    assert not d["x"].absolute
    assert relative_axes_problems(spec) == [
        "axis x: the phase blocks (periods 18, 20 px) repeat within the projector's 1024 px and there is no Gray "
        "code on x: no absolute order; huefringe cannot triangulate a relative projector coordinate"]
    with pytest.raises(RelativeCoordinateError):
        triangulation_inputs(d, spec)


def test_a_relative_axis_is_never_triangulated():
    spec = SequenceSpec((PhaseBlock("x", 32.0, tuple(equal_shifts(12))),), W, H)
    line = ("axis x: the phase block (period 32 px) has no absolute order (no Gray code or second period on x); "
            "huefringe cannot triangulate a relative projector coordinate")
    assert relative_axes_problems(spec) == [line]
    assert relative_axes_problems(spec, "u") == [line]
    ux, uy = warp(SHAPE, spec, 2)
    dec = decode_sequence(render(spec, ux, uy, seed=2), spec, _opts())
    assert not dec["x"].absolute
    for mode in ("auto", "u"):
        with pytest.raises(RelativeCoordinateError, match=r"^axis x: the phase block \(period 32 px\) has no absolute order"):
            triangulation_inputs(dec, spec, mode)
    with pytest.raises(RelativeCoordinateError, match="axis y: not decoded"):
        triangulation_inputs(dec, spec, "v")


def test_triangulation_inputs_keep_only_valid_absolute_pixels():
    spec = _sequences()["phase + gray + white/black"]
    ux, uy = warp(SHAPE, spec, 3)
    mask = _shadow_mask(SHAPE)
    frames = _in_shadow(render(spec, ux, uy, seed=3), mask, np.full(SHAPE, 0.2), seed=4)
    dec = decode_sequence(frames, spec, _opts())
    t = triangulation_inputs(dec, spec)
    assert t.mode == "both" and t.u is not None and t.v is not None
    assert not t.valid[mask].any()
    assert (t.valid == (dec["x"].valid & dec["y"].valid)).all()
    assert np.isnan(t.u[~t.valid]).all() and np.isfinite(t.sigma_v[t.valid]).all()
    # one relative axis beside an absolute one: auto uses the absolute axis, 'both' is refused
    mixed = SequenceSpec((PhaseBlock("x", 16.0, tuple(equal_shifts(4))), spec.blocks[1],
                          PhaseBlock("y", 16.0, tuple(equal_shifts(4)))), W, H)
    dm = decode_sequence(render(mixed, ux, uy, seed=3), mixed, _opts())
    assert triangulation_inputs(dm, mixed).mode == "u"
    with pytest.raises(RelativeCoordinateError, match="axis y: the phase block"):
        triangulation_inputs(dm, mixed, "both")
