"""huefringe.codecs on real captures by others (../shared/real, MIT): kamino410/phase-shifting
(three-step sinusoids at two periods plus OpenCV Gray code: mugs, and a flat plane with deliberate
encoding exponents) and nzhagen/fpp_tools (four-step, a lens). Decoded at half resolution (every
second camera pixel) to keep the suite short; docs/real-captures.md has the full-resolution
figures (benchmarks/real_captures.py)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from huefringe import codecs as C
from huefringe.codecs.checks import smooth_fit, smooth_region
from huefringe.codecs.graycode import decode_gray

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real"
KAMINO = REAL / "kamino410-phase-shifting"
LENS = REAL / "nzhagen-fpp-tools-lens"
pytestmark = pytest.mark.skipif(not KAMINO.is_dir(), reason=f"no real captures at {REAL} (shared/ beside the clone)")

REPO_GAMMA = 1.6448412125348637  # kamino410's gamma_result.txt ("gamma p")


def _load(name: str, program: str):
    spec = C.kamino410_sequence(KAMINO / name / "config.xml", program)
    ims = np.stack(C.read_captures(KAMINO / name, spec))[:, ::2, ::2]
    return spec, ims


@pytest.fixture(scope="module")
def plane():
    return _load("gamma_correction", "gamma_correction")


@pytest.fixture(scope="module")
def mugs():
    spec, ims = _load("object2", "phase_shifting")
    first = C.decode_sequence(ims, spec)
    est = C.estimate_projector_gamma(ims, spec, first["x"].valid & first["y"].valid, max_pixels=50_000)
    return spec, ims, est, C.decode_sequence(ims, dataclasses.replace(spec, projector_gamma=est.periods))


def _plane_fit(spec, ims, gamma):
    out = C.decode_sequence(ims, dataclasses.replace(spec, projector_gamma=gamma))
    # the plate; the box above its top edge is another surface (coordinate jumps) and stays out
    region = smooth_region([out["x"].coord, out["y"].coord], out["x"].valid & out["y"].valid, 10.0, 4)
    return region, {a: smooth_fit(out[a].coord, region, 6) for a in "xy"}


@pytest.fixture(scope="module")
def plane_fits(plane):
    spec, ims = plane
    first = C.decode_sequence(ims, spec)
    est = C.estimate_projector_gamma(ims, spec, first["x"].valid & first["y"].valid, max_pixels=50_000)
    return est, {g: _plane_fit(spec, ims, g) for g in (1.0, REPO_GAMMA, est.gray)}


def test_kamino410_plane_with_the_repository_gamma(plane_fits):
    _, fits = plane_fits
    region, f = fits[REPO_GAMMA]
    assert region.mean() > 0.7  # the plate fills most of the view
    for a, fa in f.items():
        assert fa.rms <= 1.5, (a, fa.rms, fa.p95)
        assert fa.p95 <= 2.5, (a, fa.p95)


def test_kamino410_plane_with_our_gamma(plane_fits):
    est, fits = plane_fits
    assert est.gray == pytest.approx(REPO_GAMMA, abs=0.1)
    ours, ignored = fits[est.gray][1], fits[1.0][1]
    for a in "xy":
        assert ours[a].rms <= 1.5, (a, ours[a].rms)
        assert ours[a].p95 <= 2.5, (a, ours[a].p95)
        # a decoder that ignores the exponents leaves the third harmonic: several px
        assert ignored[a].rms > 3.0, (a, ignored[a].rms)


def test_kamino410_mugs_smooth_walls_have_no_order_errors(mugs):
    spec, ims, est, out = mugs
    assert 1.8 < est.periods < 3.2  # this session's projector response, from its two periods
    rois = {"table": (1100, 1180, 400, 1200), "white mug": (600, 950, 520, 740), "wall": (100, 400, 700, 1800)}
    for name, (r0, r1, c0, c1) in rois.items():
        sl = (slice(r0 // 2, r1 // 2), slice(c0 // 2, c1 // 2))
        x, y = out["x"].coord[sl], out["y"].coord[sl]
        assert out["x"].valid[sl].mean() > 0.9, name
        # an order error jumps by a period (>= 66.7 px); the surfaces are smooth
        for c in (x, y):
            for ax in (0, 1):
                assert np.nanmax(np.abs(np.diff(c, axis=ax))) < 100 / 3, name
        # the projector's columns run left to right across the camera's rows, rows downwards
        dx, dy = np.diff(x, axis=1), np.diff(y, axis=0)
        assert np.mean(dx[np.isfinite(dx)] > 0) > 0.98, name
        assert np.mean(dy[np.isfinite(dy)] > 0) > 0.9, name


def test_kamino410_mugs_gray_code_and_two_periods_agree(mugs):
    spec, ims, est, out = mugs
    gray = {b.axis: (b, sl) for b, sl in spec.slices() if isinstance(b, C.GrayBlock)}
    for a in "xy":
        b, sl = gray[a]
        dec = decode_gray(ims[sl][0::2], 0.0, inverse=ims[sl][1::2])  # every bit, OpenCV's decision
        c, v = out[a].coord, out[a].valid
        q = (c + 0.5) / b.cell_px
        away = v & (np.abs(q - np.round(q)) * b.cell_px > 3)  # not within 3 px of a cell edge
        assert np.mean(dec.index[away] == np.floor(q[away])) > 0.998, a
    # the scene: the mugs' walls, the wall behind, the table decode; the dark mugs do not
    assert 0.5 < out["x"].valid.mean() < 0.7


def test_kamino410_counts_and_refusal(tmp_path):
    spec = C.kamino410_sequence(KAMINO / "object2" / "config.xml", "phase_shifting")
    assert spec.n_frames == len(list((KAMINO / "object2").glob("pat*.png"))) == 32
    spec2 = C.kamino410_sequence(KAMINO / "gamma_correction" / "config.xml", "gamma_correction")
    assert spec2.n_frames == 54
    (tmp_path / "pat00.png").write_bytes((KAMINO / "object2" / "pat00.png").read_bytes())
    with pytest.raises(C.SequenceError, match=f"{tmp_path}: 1 files match 'pat\\*.png', the sequence has 32 frames"):
        C.read_captures(tmp_path, spec)


@pytest.mark.skipif(not LENS.is_dir(), reason=f"no {LENS}")
def test_nzhagen_lens_four_step_phase_and_modulation():
    frames = np.stack([cv2.imread(str(LENS / f"lens_orig_{d:03d}.jpg"), cv2.IMREAD_GRAYSCALE) for d in (0, 90, 180, 270)])
    w = C.wrapped_phase(frames, C.equal_shifts(4), C.DecodeOptions.from_config().noise(255.0))
    # the lens: a disc of strong fringes in the lower left (camera rows ~480-860, columns ~60-460)
    h, wd = frames.shape[1:]
    yy, xx = np.mgrid[0:h, 0:wd]
    disc = (yy - 680) ** 2 + (xx - 260) ** 2 < 140**2
    assert np.median(w.modulation[disc]) > 10.0
    # fringes run down the image: the phase advances along rows, so neighbours differ little
    d = np.angle(np.exp(1j * np.diff(w.phase, axis=1)))[disc[:, 1:]]
    assert np.median(np.abs(d)) < 0.6
    # the four-step residual is the noise: sigma small where modulated
    assert np.median(w.sigma[disc]) < 0.05
