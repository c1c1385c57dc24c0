"""The ray test after triangulation: where both projector axes are decoded, the camera ray and the
projector ray of (u, v) meet; a wrong fringe order or Gray cell across the epipolar line is
dropped (reason RAY), clean pixels are kept, one-axis triangulation is untouched."""

from __future__ import annotations

from functools import cache

import numpy as np
from rig_helpers import calibrated

from huefringe.bench.rig_session import load_sl_bench_config, scene_truth
from huefringe.codecs import Decoded, Reason
from huefringe.rig import triangulate
from huefringe.rig.measure import triangulate_frame
from huefringe.rig.triangulation import epipolar_residual
from huefringe.settings import load_config

SIGMA_PX = 0.05          # the rig sequence's decoded noise (four-step phase, 8 bit, 1 DN)


@cache
def _gauge():
    """The rig-gauge scene's truth (blocks, a ball, projector shadows) and a rig calibrated from 8 board poses."""
    t = scene_truth(load_sl_bench_config("rig-gauge"))
    _, cal, _, _ = calibrated("holdout-wide", 8, 4)
    return t, cal


def _decoded(t: dict, seed: int, errors: dict[str, float] | None = None, every: int = 97):
    """Decoded maps of the truth with the decoder's noise; ``errors``: every ``every``-th lit pixel
    gets a wrong order of that many projector px on that axis (u or v, alternately)."""
    rng = np.random.default_rng(seed)
    lit = t["lit"]
    coords = {"x": t["u"] + rng.normal(0, SIGMA_PX, lit.shape), "y": t["v"] + rng.normal(0, SIGMA_PX, lit.shape)}
    hit = {}
    if errors:
        idx = np.flatnonzero(lit.ravel())[::every]
        for i, (axis, step) in enumerate(errors.items()):
            p = idx[i :: len(errors)]
            coords[axis].ravel()[p] += step * rng.choice([-1.0, 1.0], len(p))
            hit[axis] = p
    dec = {a: Decoded(a, np.where(lit, c, np.nan), np.where(lit, SIGMA_PX, np.nan), np.ones(lit.shape, np.float32), lit.copy(),
                      np.zeros(lit.shape, np.float32), True, np.where(lit, 0, Reason.SHADOW).astype(np.uint8))
           for a, c in coords.items()}
    d = {"mean": np.zeros(lit.shape), "decoded": dec}
    for a, k in (("x", "u"), ("y", "v")):
        d[k], d["sigma_" + k], d["valid_" + k] = dec[a].coord, dec[a].sigma, dec[a].valid
    return d, hit


def _z_from_truth(frame, t, cal):
    """|error along the ray| / sigma_ray of every point against the true projector coordinates
    triangulated with the same calibration (the decoding's own error)."""
    truth = triangulate(cal, t["u"], t["v"], valid=t["lit"]).xyz
    ray = frame.xyz / np.linalg.norm(frame.xyz, axis=-1, keepdims=True)
    return np.abs(np.einsum("...k,...k", frame.xyz - truth, ray)) / frame.sigma_ray


def test_epipolar_residual_is_zero_on_the_truth_and_the_move_across_the_line():
    t, _ = _gauge()
    from huefringe.bench.rig import RIGS

    calib = RIGS["holdout-wide"].calibration
    r, s = epipolar_residual(calib, t["u"], t["v"], sigma_u=0.1, sigma_v=0.1)
    lit = t["lit"]
    assert np.nanmax(np.abs(r[lit])) < 1e-6 and np.isnan(r[~lit]).all()
    assert np.allclose(s[lit], 0.1)
    # 3 px along v: the rig's baseline is along x, the epipolar lines nearly rows
    r3, _ = epipolar_residual(calib, t["u"], t["v"] + 3.0)
    assert 2.9 < np.nanmin(np.abs(r3[lit])) and np.nanmax(np.abs(r3[lit])) < 3.05


def test_clean_pixels_pass_and_wrong_orders_across_the_epipolar_line_are_dropped():
    t, cal = _gauge()
    cfg = load_config()
    clean, _ = _decoded(t, 1)
    f = triangulate_frame(clean, cal, cfg, where="clean")
    lit = t["lit"]
    assert f.mode == "both" and int(f.valid.sum()) == int(lit.sum())     # no clean pixel dropped
    assert np.nanmax(np.abs(f.ray_residual)) < cfg["codecs"]["ray_floor_px"]
    assert int(np.sum(_z_from_truth(f, t, cal)[f.valid] > 5)) == 0

    bad, hit = _decoded(t, 2, {"x": 16.0, "y": 16.0})
    f = triangulate_frame(bad, cal, cfg, where="bad")
    ray = {a: (f.decoded["decoded"][a].reasons & Reason.RAY) != 0 for a in ("x", "y")}
    assert np.array_equal(ray["x"], ray["y"]) and not (ray["x"] & f.valid).any()
    assert ray["x"].ravel()[hit["y"]].all()                 # every wrong row order: across the line
    caught_u = ray["x"].ravel()[hit["x"]].mean()            # a wrong column moves mostly along the line
    assert 0.5 < caught_u < 0.9, caught_u
    # nothing else dropped: the clean pixels all kept
    others = np.ones(lit.size, bool)
    others[np.concatenate(list(hit.values()))] = False
    assert not ray["x"].ravel()[others & lit.ravel()].any()
    # what is kept beyond 5 sigma of the truth is a wrong column along the epipolar line only
    z = _z_from_truth(f, t, cal)
    far = np.flatnonzero((z > 5).ravel() & f.valid.ravel())
    assert np.isin(far, hit["x"]).all()
    r, s = epipolar_residual(cal, f.decoded["u"], f.decoded["v"])
    assert np.nanmax(np.abs(r.ravel()[far])) <= cfg["codecs"]["ray_floor_px"]


def test_ray_thresholds_come_from_the_configuration_and_one_axis_is_unchanged():
    t, cal = _gauge()
    bad, hit = _decoded(t, 3, {"y": 16.0})
    off = load_config({"codecs": {"max_ray_sigma": 1e6, "ray_floor_px": 1e6}})
    f = triangulate_frame(bad, cal, off, where="off")
    assert int(f.valid.sum()) == int(t["lit"].sum())
    tight = triangulate_frame(_decoded(t, 3)[0], cal, load_config({"codecs": {"ray_floor_px": 0.0}}), where="tight")
    dropped = int(t["lit"].sum() - tight.valid.sum())
    assert dropped > 0            # the calibration's epipolar error exceeds 5 sigma of the noise somewhere
    one = triangulate_frame(bad, cal, load_config({"rig": {"triangulation": "u"}}), where="u")
    assert one.mode == "u" and one.ray_residual is None and int(one.valid.sum()) == int(t["lit"].sum())
    assert not any(((d.reasons & Reason.RAY) != 0).any() for d in one.decoded["decoded"].values())

