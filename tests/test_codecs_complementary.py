"""The complementary Gray code (Zhang, Su et al. 2012; SLMaster's SinusCompleGrayCode): N Gray bits
of one fringe period per cell plus one bit of half-period stripes, the order taken from whichever
code is far from its own stripe edges."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
import yaml

from codecs_helpers import render, warp
from huefringe.codecs import (
    DecodeOptions,
    GrayBlock,
    PhaseBlock,
    Reason,
    SequenceError,
    SequenceSpec,
    decode_sequence,
    equal_shifts,
    generate,
    load_sequence,
    sequence_from_mapping,
    sequence_to_mapping,
)

P = 16.0
W, H = 1024, 64
N = 6  # 64 cells of 16 px
D4 = tuple(float(v) for v in equal_shifts(4))


def _spec(kind: str, inverse: bool = False) -> SequenceSpec:
    """One phase block of period P (origin at half a period, as SLMaster's fringes) and a Gray code:
    ``plain`` N bits of P cells, ``half`` N + 1 bits of P / 2 cells, ``complementary`` N bits + 1."""
    gray = {"plain": GrayBlock("x", N, P, inverse), "half": GrayBlock("x", N + 1, P / 2, inverse),
            "complementary": GrayBlock("x", N, P, inverse, True)}[kind]
    return SequenceSpec((PhaseBlock("x", P, D4, origin_px=P / 2), gray), W, H, projector_gamma=2.2)


def _defocused(spec: SequenceSpec, ux: np.ndarray, blur_px: float, seed: int) -> np.ndarray:
    """A camera's frames of ``spec`` through a defocused projector: the projector's images (gamma
    2.2 display) blurred by a Gaussian of ``blur_px`` projector pixels, sampled at ``ux``, ambient
    light, albedo 0.8, Gaussian noise of 1 DN, 8 bits."""
    rng = np.random.default_rng(seed)
    mapx = ux.astype(np.float32)
    mapy = np.full(ux.shape, H / 2, np.float32)
    out = []
    for p in generate(spec).astype(np.float32) / 255.0:
        p = cv2.GaussianBlur(p**spec.projector_gamma, (0, 0), blur_px)
        s = cv2.remap(p, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        out.append(np.clip(np.rint(255.0 * (0.05 + 0.8 * s) + rng.normal(0.0, 1.0, ux.shape)), 0, 255).astype(np.uint8))
    return np.stack(out)


@pytest.fixture(scope="module")
def blurred() -> dict[str, object]:
    yy, xx = np.mgrid[0:120, 0:640].astype(np.float64)
    ux = 30.0 + xx * (W - 60.0) / 640.0 + 0.013 * yy
    out: dict[str, object] = {"ux": ux}
    for kind in ("plain", "half", "complementary"):
        spec = _spec(kind)
        out[kind] = decode_sequence(_defocused(spec, ux, 5.0, seed=3), spec, DecodeOptions.from_config())["x"]
    return out


def test_defocused_edges_misread_by_plain_gray_are_decoded_by_the_complementary_bit(blurred):
    ux = blurred["ux"]
    edge = np.abs((ux + 0.5) / P - np.round((ux + 0.5) / P)) * P < P / 4  # within a quarter period of a cell edge
    plain, half, comp = blurred["plain"], blurred["half"], blurred["complementary"]
    # N bits of one period per cell: the order is a coin toss at every cell edge
    order_plain = (plain.reasons & Reason.ORDER) > 0
    assert order_plain.sum() > 0.25 * ux.size and order_plain[edge].mean() > 0.55
    # N + 1 bits of half periods, as many frames as the complementary code: the shifted threshold
    # (the phase frames' mean of a gamma-2.2 display) and the blur misread stripes > 0.1 P from their edges
    order_half = (half.reasons & Reason.ORDER) > 0
    assert 0.01 * ux.size < order_half.sum() < 0.1 * ux.size
    # the complementary code decodes every pixel, those the plain codes dropped or misread among them
    assert comp.valid.all()
    err = comp.coord - ux
    z = np.abs(err) / comp.sigma
    assert z.max() < 5.0 and z[order_plain].max() < 5.0 and z[order_half].max() < 5.0
    assert np.sqrt(np.mean(err**2)) < 1.2 * np.sqrt(np.mean(comp.sigma**2))
    assert np.abs(err).max() < 0.2 * P  # never a period away
    assert comp.order_margin.max() < 0.3 and np.median(comp.order_margin[edge]) < 0.15
    # where the plain codes kept a pixel, they agree with the complementary code
    for dec in (plain, half):
        np.testing.assert_allclose(dec.coord[dec.valid], comp.coord[dec.valid], atol=1e-9)


@pytest.mark.parametrize("inverse", [False, True])
def test_complementary_sequence_decodes_to_the_truth_on_both_axes(inverse):
    """Both axes, with or without inverses; without, no white and black frame: each bit against the
    mean of its axis' phase frames, as SLMaster captures it."""
    spec = SequenceSpec((PhaseBlock("x", 32.0, D4, origin_px=16.0), GrayBlock("x", 5, 32.0, inverse, True),
                         PhaseBlock("y", 32.0, D4), GrayBlock("y", 4, 32.0, inverse, True)), 1024, 512)
    assert spec.n_frames == 4 + 6 * (1 + inverse) + 4 + 5 * (1 + inverse)
    ux, uy = warp((96, 128), spec)
    dec = decode_sequence(render(spec, ux, uy), spec, DecodeOptions.from_config())
    for axis, truth in (("x", ux), ("y", uy)):
        d = dec[axis]
        assert d.absolute and d.valid.mean() > 0.999
        err = (d.coord - truth)[d.valid]
        z = np.abs(err) / d.sigma[d.valid]
        assert z.max() < 5.0 and np.sqrt(np.mean(err**2)) < 1.2 * np.sqrt(np.mean(d.sigma[d.valid] ** 2))


def test_slmaster_patterns_are_the_generated_sequence():
    """SLMaster's SinusCompleGrayCode for a 1920 px projector, 32 periods, 12 steps, as its
    documentation of the generator describes it (written here independently): fringes
    ``127.5 + 127.5 cos(2 pi (u mod P) / P - pi + 2 pi n / 12)``, then log2(32) + 1 Gray images,
    image i with 2**(i+1) blocks, each image's block values the previous ones then their mirror."""
    p, steps, width = 60, 12, 1920
    u = np.arange(width)
    fringes = [127.5 + 127.5 * np.cos(2 * np.pi * (u % p) / p - np.pi + 2 * np.pi * n / steps) for n in range(steps)]
    seq, grays = [0, 255], []
    for _ in range(6):
        grays.append(np.repeat(seq, width // len(seq)))
        seq = seq + seq[::-1]
    spec = load_sequence_text(f"""
projector: {{width: {width}, height: 8}}
frames: "*.bmp"
blocks:
  - phase: {{axis: x, period_px: {p}, steps: {steps}, origin_px: {p / 2}}}
  - gray: {{axis: x, bits: 5, cell_px: {p}, inverse: false, complementary: true}}
""")
    ours = generate(spec)[:, 0, :].astype(np.float64)
    assert ours.shape == (18, width)
    np.testing.assert_allclose(ours[:steps], fringes, atol=0.5 + 1e-9)
    np.testing.assert_array_equal(ours[steps:], grays)


def load_sequence_text(text: str) -> SequenceSpec:
    return sequence_from_mapping(yaml.safe_load(text), "sequence.yaml", ".")


def test_complementary_block_round_trips_and_adds_one_pattern_after_the_plain_code(tmp_path):
    spec = load_sequence_text("""
projector: {width: 1024, height: 768}
blocks:
  - phase: {axis: x, period_px: 16, steps: 4}
  - gray: {axis: x, bits: 6, cell_px: 16, complementary: true}
  - phase: {axis: y, period_px: 16, steps: 4}
  - gray: {axis: y, cells: 48, cell_px: 16}
""")
    gx, gy = spec.blocks[1], spec.blocks[3]
    assert gx == GrayBlock("x", 6, 16.0, True, True) and gx.n_frames == 14 and gy.n_frames == 12
    m = sequence_to_mapping(spec)
    assert m["blocks"][1]["gray"] == {"axis": "x", "bits": 6, "cell_px": 16.0, "inverse": True, "complementary": True}
    assert m["blocks"][3]["gray"] == {"axis": "y", "bits": 6, "cell_px": 16.0, "inverse": True}
    (tmp_path / "sequence.yaml").write_text(yaml.safe_dump(m))
    assert load_sequence(tmp_path / "sequence.yaml") == spec
    # the first N patterns are those of the plain N-bit code: the extra one follows them
    plain = replace(spec, blocks=(spec.blocks[0], replace(gx, complementary=False)))
    ims = generate(replace(spec, blocks=spec.blocks[:2]))
    np.testing.assert_array_equal(ims[:16], generate(plain))
    extra = ims[16, 0] > 0  # stripes of 8 px, edges mid-cell: 0, 1, 1, 0 per pair of cells
    assert extra[:8].sum() == 0 and extra[8:24].all() and extra[24:40].sum() == 0


@pytest.mark.parametrize(("blocks", "why"), [
    ("  - gray: {axis: x, bits: 6, cell_px: 16, inverse: false, complementary: true}\n  - white\n  - black\n",
     "phase periods on axis x: none"),
    ("  - phase: {axis: x, period_px: 32, steps: 4}\n  - gray: {axis: x, bits: 6, cell_px: 16, complementary: true}\n",
     "phase periods on axis x: 32"),
    ("  - phase: {axis: y, period_px: 16, steps: 4}\n  - gray: {axis: x, bits: 6, cell_px: 16, complementary: true}\n",
     "phase periods on axis x: none"),
])
def test_complementary_block_without_its_phase_block_is_refused(tmp_path, blocks, why):
    path = tmp_path / "sequence.yaml"
    path.write_text("projector: {width: 1024, height: 768}\nblocks:\n" + blocks)
    with pytest.raises(SequenceError) as err:
        load_sequence(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: axis x: a complementary Gray code needs a phase block of period_px equal to its "
                          "cell_px 16 on the same axis")
    assert msg.endswith(why)


def test_complementary_must_be_a_boolean(tmp_path):
    path = tmp_path / "sequence.yaml"
    path.write_text("projector: {width: 1024, height: 768}\nblocks:\n"
                    "  - phase: {axis: x, period_px: 16, steps: 4}\n  - gray: {axis: x, bits: 6, cell_px: 16, complementary: 1}\n")
    with pytest.raises(SequenceError, match=r"sequence\.yaml: blocks\[1\]\.gray\.complementary must be true or false, got 1"):
        load_sequence(path)


def test_bench_rig_captures_of_slmaster_sequence_decode_every_lit_pixel(tmp_path):
    """The bench rig shooting the steps scene with one-period cells, as SLMaster projects them (no
    inverses, no white or black), written as PNGs and read back: with the complementary bit every
    lit pixel decodes within 5 sigma of the truth; without it the pixels at each phase wrap are
    flagged ORDER, none kept wrong."""
    from huefringe.bench.rig import RIGS, StepsScene, write_captures
    from huefringe.codecs import read_captures

    rig = RIGS["holdout-wide"]
    xyz, ok = StepsScene().cast(rig.rays)[:2]
    m = rig.coordinates(xyz, ok, np.random.default_rng(2), 0.0)
    kept = {}
    for comp in (False, True):
        spec = load_sequence_text(f"""
projector: {{width: 800, height: 600}}
frames: "cap_*.png"
blocks:
  - phase: {{axis: x, period_px: 16, steps: 4, origin_px: 8}}
  - gray: {{axis: x, bits: 6, cell_px: 16, inverse: false, complementary: {str(comp).lower()}}}
  - phase: {{axis: y, period_px: 16, steps: 4, origin_px: 8}}
  - gray: {{axis: y, bits: 6, cell_px: 16, inverse: false, complementary: {str(comp).lower()}}}
""")
        folder = tmp_path / f"steps-{comp}"
        write_captures(rig, spec, folder, m["u_true"], m["v_true"], m["valid"], np.random.default_rng(12))
        dec = decode_sequence(read_captures(folder, spec), spec, DecodeOptions.from_config())
        for axis, truth in (("x", m["u_true"]), ("y", m["v_true"])):
            d = dec[axis]
            assert not (d.valid & ~m["valid"]).any()  # no pixel without projector light
            z = np.abs(d.coord - truth)[d.valid] / d.sigma[d.valid]
            assert z.max() < 5.0
            kept[comp, axis] = d.valid[m["valid"]].mean()
            if not comp:
                assert ((d.reasons & Reason.ORDER) > 0)[m["valid"]].mean() > 0.2
    for axis in ("x", "y"):
        assert kept[True, axis] > 0.995 and kept[False, axis] < 0.8


def test_an_unclear_bit_the_order_depends_on_is_flagged_not_misread():
    """A coarse Gray bit washed out to its threshold (a specular streak, a pixel the bit's stripe
    never lit clearly): mid-period pixels, whose order is k1, and edge pixels whose cell edge is
    not that bit's are flagged GRAY; edge pixels at that bit's own edges keep their k2 order."""
    spec = SequenceSpec((PhaseBlock("x", 32.0, D4, origin_px=16.0), GrayBlock("x", 5, 32.0, False, True),
                         PhaseBlock("y", 32.0, D4), GrayBlock("y", 4, 32.0, False, True)), 1024, 512)
    ux, uy = warp((96, 128), spec)
    frames = render(spec, ux, uy, noise=False).astype(np.float32)
    thr = frames[:4].mean(axis=0)
    bit = 2  # the third x pattern, Gray bit 2 (of 4 .. 0): it changes between cells 8 m + 3 and 8 m + 4
    frames[4 + bit] = thr + 0.5  # read as 1 everywhere, with no contrast
    dec = decode_sequence(np.clip(np.round(frames), 0, 255).astype(np.uint8), spec, DecodeOptions.from_config())["x"]
    assert not dec.valid.all()
    err = np.abs(dec.coord - ux)[dec.valid]
    assert err.max() < 0.2  # nothing kept a cell or a period away
    w = np.mod(ux, 32.0)
    middle = (w > 9) & (w < 23)
    gray = (dec.reasons & Reason.GRAY) > 0
    assert gray[middle].all()
    k2 = np.round((ux + 0.5) / 32.0)  # the nearest Gray cell edge (cells start half a pixel before the fringes)
    own_edge = (np.abs(ux + 0.5 - 32.0 * k2) < 7) & (k2 % 8 == 4)  # that bit's own edges: the other code decides
    assert own_edge.sum() > 100 and dec.valid[own_edge].mean() > 0.99
