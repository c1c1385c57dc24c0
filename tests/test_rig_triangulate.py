"""Triangulation against the bench's truth: exactness with the true rig, targets with calibrated rigs."""

from __future__ import annotations

import numpy as np
import pytest
from rig_helpers import COORD_SIGMA_PX, calibrated

from huefringe.bench.rig import RIGS, PlaneScene, SphereScene, StepsScene
from huefringe.rig import triangulate
from huefringe.metrology import fit_plane_u, fit_sphere_u, form_deviation, step_height_u

CASES = [("tune", 8, 1), ("holdout-wide", 6, 7), ("holdout-narrow", 8, 11)]


def _measure(rig, calib, scene, mode, seed=0, sigma=COORD_SIGMA_PX, stride=2):
    """Triangulate a scene at every ``stride``-th camera pixel (vector input)."""
    rng = np.random.default_rng(seed)
    rays = rig.rays[::stride, ::stride]
    xyz, ok, *extra = scene.cast(rays)
    m = rig.coordinates(xyz, ok, rng, sigma)
    yy, xx = np.mgrid[0 : rig.camera_size[1] : stride, 0 : rig.camera_size[0] : stride]
    pix = np.column_stack([xx.ravel(), yy.ravel()])
    t = triangulate(calib, m["u"].ravel(), m["v"].ravel() if mode == "both" else None, sigma_u=m["sigma"].ravel(),
                    sigma_v=m["sigma"].ravel() if mode == "both" else None, valid=m["valid"].ravel(), pixels=pix)
    shape = xyz.shape[:2]
    t = type(t)(t.xyz.reshape(*shape, 3), t.sigma.reshape(*shape, 3), t.valid.reshape(shape), t.sigma_ray.reshape(shape))
    return t, xyz, [e for e in extra]


@pytest.mark.parametrize("mode", ["u", "both"])
def test_true_rig_reconstructs_exactly_without_noise(mode):
    rig = RIGS["holdout-wide"]
    t, xyz, _ = _measure(rig, rig.calibration, SphereScene(), mode, sigma=0.0)
    assert t.valid.mean() > 0.5
    assert np.nanmax(np.abs(t.xyz[t.valid] - xyz[t.valid])) < 1e-6


@pytest.mark.parametrize("mode", ["u", "both"])
def test_propagated_sigma_matches_the_spread(mode):
    rig = RIGS["tune"]
    t, xyz, _ = _measure(rig, rig.calibration, PlaneScene(), mode, seed=3)
    err = (t.xyz - xyz)[t.valid]
    z = err / t.sigma[t.valid]
    assert np.isfinite(z).mean() > 0.999
    z = z[np.isfinite(z).all(axis=1)]
    assert 0.9 < np.std(z[:, 2]) < 1.1
    assert 0.9 < np.std(z[:, 0]) < 1.1


@pytest.mark.parametrize(("rig_name", "n_poses", "seed"), CASES)
def test_flat_board_is_flat(rig_name, n_poses, seed):
    rig, cal, _, _ = calibrated(rig_name, n_poses, seed)
    for scene in (PlaneScene(), PlaneScene(point=(-10.0, 5.0, 480.0), tilt_deg=(-12.0, 15.0))):
        t, _, _ = _measure(rig, cal, scene, "u", seed=seed)
        pts = t.xyz[t.valid]
        plane = fit_plane_u(pts, t.sigma[t.valid])
        assert form_deviation(plane, pts) < 0.02                      # systematic departure from flat
        # the point-to-plane spread is the propagated noise
        assert plane.rms_mm < 1.2 * np.sqrt(np.mean(np.sum(t.sigma[t.valid] ** 2 * plane.normal**2, axis=1)))


@pytest.mark.parametrize(("rig_name", "n_poses", "seed"), CASES)
def test_sphere_radius(rig_name, n_poses, seed):
    rig, cal, _, _ = calibrated(rig_name, n_poses, seed)
    scene = SphereScene()
    t, _, (sphere,) = _measure(rig, cal, scene, "both", seed=seed)
    fit = fit_sphere_u(t.xyz[t.valid & sphere], t.sigma[t.valid & sphere])
    assert abs(fit["radius_mm"] - scene.radius) < 0.05


@pytest.mark.parametrize(("rig_name", "n_poses", "seed"), CASES)
def test_step_heights(rig_name, n_poses, seed):
    rig, cal, _, _ = calibrated(rig_name, n_poses, seed)
    scene = StepsScene()
    t, xyz, (label,) = _measure(rig, cal, scene, "u", seed=seed, stride=1)
    R, o = scene.frame()
    local = (xyz - o) @ R
    for k, (x0, y0, x1, y1, h) in enumerate(scene.blocks, start=1):
        # base: a 10 mm band beside the block's long sides, 3 mm clear of its edges
        band = (label == 0) & (local[..., 1] > y0) & (local[..., 1] < y1) & (
            ((local[..., 0] > x0 - 13) & (local[..., 0] < x0 - 3)) | ((local[..., 0] > x1 + 3) & (local[..., 0] < x1 + 13)))
        top = (label == k) & (local[..., 0] > x0 + 3) & (local[..., 0] < x1 - 3)
        step = step_height_u(t.xyz[t.valid & band], t.sigma[t.valid & band], t.xyz[t.valid & top], t.sigma[t.valid & top])
        assert abs(step["height_mm"] / h - 1) < 0.003, k


def test_calibration_term_on_pixels_away_from_every_sample():
    from dataclasses import replace

    from huefringe.rig.measure import RigFrame, calibration_spread

    rig = RIGS["tune"]
    cal = rig.calibration
    w, h = rig.camera_size
    xyz = rig.rays * (430.0 / rig.rays[..., 2:3])
    uv = rig.to_projector(xyz.reshape(-1, 3)).reshape(h, w, 2)
    valid = np.zeros((h, w), dtype=bool)
    valid[40:120, 40:200] = True                  # a region with samples every 4 pixels
    valid[101:103, 301:303] = True                # an island between the samples (rows and columns 100, 104, 300, 304)
    valid[237, 413] = True                        # a lone pixel
    t = triangulate(cal, uv[..., 0], uv[..., 1], valid=valid)
    frame = RigFrame(t.xyz, t.sigma, t.valid, {"u": uv[..., 0], "v": uv[..., 1]}, "both", t.sigma_ray)
    jack = [(f"j{k}", replace(cal, T=cal.T + np.array([0.05 * k, -0.03 * k, 0.2 * (k % 3)]))) for k in range(6)]
    u_axes, u_ray = calibration_spread(frame, jack)
    assert np.isfinite(u_ray[t.valid]).all() and np.isfinite(u_axes[t.valid]).all()
    assert np.isnan(u_ray[~t.valid]).all()
    # the island's term is its own jackknife spread
    pts = np.stack([triangulate(c, uv[..., 0], uv[..., 1], valid=valid).xyz[101, 301] for _, c in jack])
    dev = pts - pts.mean(axis=0)
    n = len(jack)
    expect = np.sqrt((n - 1) / n * (n - 1) / (n - 3) * np.sum(dev**2, axis=0))
    assert np.allclose(u_axes[101, 301], expect, rtol=1e-9)
    assert u_ray[237, 413] > 0


def _calibrated_scene(mode_sigma=0.05, seed=5):
    """A calibrated bench rig (its fitted lens distortion on both devices) and the steps scene's
    decoded coordinates on every camera pixel."""
    rig, cal, _, _ = calibrated("holdout-wide", 6, 7)
    xyz, ok, _ = StepsScene().cast(rig.rays)
    return rig, cal, rig.coordinates(xyz, ok, np.random.default_rng(seed), mode_sigma)


@pytest.mark.parametrize("mode", ["u", "v"])
def test_plane_solution_projects_onto_its_coordinate_and_its_pixel(mode):
    from huefringe.rig.triangulation import project

    rig, cal, m = _calibrated_scene()
    assert np.abs(cal.projector_distortion[:2]).max() > 0.05 and np.abs(cal.camera_distortion[:2]).max() > 0.1
    t = triangulate(cal, **{mode: m[mode]}, valid=m["valid"], mode=mode)
    assert t.valid.sum() > 0.99 * m["valid"].sum()
    axis = 0 if mode == "u" else 1
    back = project(t.xyz[t.valid], cal.projector_matrix, cal.projector_distortion, cal.R, cal.T)[:, axis]
    assert np.abs(back - m[mode][t.valid]).max() < 1e-8                   # projector px
    yy, xx = np.nonzero(t.valid)
    cam = project(t.xyz[t.valid], cal.camera_matrix, cal.camera_distortion)
    assert np.abs(cam - np.column_stack([xx, yy])).max() < 1e-8            # camera px: on the pixel's ray


@pytest.mark.parametrize("mode", ["u", "both"])
def test_sigma_is_the_solution_derivative_times_the_coordinate_sigma(mode):
    rig, cal, m = _calibrated_scene()
    sl = (slice(100, 380, 7), slice(60, 600, 9))
    u, v, s = (m[k][sl] for k in ("u", "v", "sigma"))
    valid = m["valid"][sl]
    yy, xx = np.mgrid[0:480, 0:640]
    pix = np.column_stack([xx[sl].ravel(), yy[sl].ravel()])
    args = dict(valid=valid.ravel(), pixels=pix, mode=mode)
    vv = v.ravel() if mode == "both" else None
    t = triangulate(cal, u.ravel(), vv, sigma_u=s.ravel(), sigma_v=s.ravel() if mode == "both" else None, **args)
    h = 1e-3
    var = np.zeros_like(t.xyz)
    for k in ("u", "v") if mode == "both" else ("u",):
        step = {"u": u.ravel(), "v": vv}
        hi = triangulate(cal, **{**step, k: step[k] + h}, **args).xyz
        lo = triangulate(cal, **{**step, k: step[k] - h}, **args).xyz
        var += ((hi - lo) / (2 * h) * s.ravel()[:, None]) ** 2
    ok = t.valid & np.isfinite(var).all(axis=1)
    assert ok.sum() > 1500
    ref, got = np.sqrt(var[ok]), t.sigma[ok]
    big = ref > 1e-4 * ref.max()
    assert np.abs(got[big] / ref[big] - 1).max() < 1e-5
    assert 0.005 < np.median(t.sigma_ray[ok]) < 0.2                       # mm per 0.05 px on this rig


@pytest.mark.parametrize("mode", ["u", "both"])
def test_longer_distortion_models_give_the_five_coefficient_solution(mode):
    from dataclasses import replace

    rig, cal, m = _calibrated_scene()
    longer = np.zeros(14)
    longer[:5] = cal.projector_distortion[:5]
    longer[5] = 1e-15                      # a rational coefficient: OpenCV's 14-coefficient model's path
    cam = np.zeros(8)
    cam[:5] = cal.camera_distortion[:5]
    cam[7] = 1e-15
    other = replace(cal, projector_distortion=longer, camera_distortion=cam)
    sl = (slice(0, 480, 5), slice(0, 640, 5))
    kw = dict(u=m["u"][sl], v=m["v"][sl] if mode == "both" else None, sigma_u=m["sigma"][sl],
              sigma_v=m["sigma"][sl] if mode == "both" else None, valid=m["valid"][sl], mode=mode)
    yy, xx = np.mgrid[0:480:5, 0:640:5]
    pix = np.column_stack([xx.ravel(), yy.ravel()])
    a = triangulate(cal, **{k: (None if val is None else val.ravel()) for k, val in kw.items() if k != "mode"},
                    pixels=pix, mode=mode)
    b = triangulate(other, **{k: (None if val is None else val.ravel()) for k, val in kw.items() if k != "mode"},
                    pixels=pix, mode=mode)
    assert np.array_equal(a.valid, b.valid) and a.valid.sum() > 8000
    assert np.abs(a.xyz[a.valid] - b.xyz[a.valid]).max() < 1e-6
    assert np.abs(a.sigma[a.valid] / b.sigma[a.valid] - 1).max() < 1e-6
