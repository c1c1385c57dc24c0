"""One-shot colour frames through the bench's projector-camera rig, with truth.

A :class:`~huefringe.bench.rig.BenchRig` is calibrated from simulated checkerboard poses
(detected corners with noise, projector corners from decoded coordinates with noise, OpenCV's
stereo calibration: :func:`calibrated_rig`, with its leave-one-pose-out calibrations). On the
rig, :func:`render_session` renders what a one-shot structured-light session holds:

* the reference (the gauge's base plane alone) under an absolute coded sequence (phase shifting
  + Gray code along the trapezoid's axis, grey captures), decoded with
  :func:`huefringe.codecs.decode_sequence`;
* the object (colour-coated gauge blocks of the paper's Fig. 9, 3.0 / 1.0 / 4.0 mm, on that
  base; or a flat board; or a block beyond the unambiguous range) under the white frame, the
  ``N x R`` hue bands and the trapezoid frames, in colour (:meth:`BenchRig.capture_rgb`: per
  channel projector response, surface colour, camera crosstalk, 8-bit read noise);
* the truth: every camera pixel's true point and face label.

Used by the tests and ``benchmarks/oneshot_rig.py``; the measuring code never imports it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from huefringe.bench.rig import RIGS, BenchRig, CompositeScene, PlaneScene, pose_set
from huefringe.bench.scenes import BLOCK_COLOURS
from huefringe.codecs import DecodeOptions, decode_sequence, generate, generate_rgb, sequence_from_mapping
from huefringe.codecs.sequence import FlatBlock, HueBandsBlock, SequenceSpec, TrapezoidBlock
from huefringe.rig import Board, CalibrationReport, PoseObservation, RigCalibration, calibrate_rig, projector_corners

__all__ = ["CROSSTALK", "GAUGE_BLOCKS", "OneShotCapture", "calibrated_rig", "calibrated_rig_report", "face_mask", "flatness_scores", "gauge_scene", "pixel_scores",
           "reference_scene", "step_scores",
           "reference_spec", "render_session"]

F64 = NDArray[np.float64]

BOARD = Board(9, 7, 12.0)
#: the demo camera's channel mixing (rows: camera R, G, B; columns: projector primaries), times its sensitivities
CROSSTALK = np.array([[0.90, 0.08, 0.02], [0.07, 0.86, 0.07], [0.02, 0.10, 0.88]]) * np.array([[0.95], [1.0], [0.9]])
#: the paper's Fig. 9 gauge blocks: (x0, y0, x1, y1, height mm) in the base plane's frame and their coating
GAUGE_BLOCKS: tuple[tuple[tuple[float, float, float, float, float], str], ...] = (
    ((-70.0, -25.0, -35.0, 25.0, 3.0), "green"), ((-17.5, -25.0, 17.5, 25.0, 1.0), "blue"),
    ((35.0, -25.0, 70.0, 25.0, 4.0), "red"))
BASE_ALBEDO = (0.78, 0.76, 0.74)
BASE_TILT = (4.0, -3.0)
BASE_ORIGIN = (0.0, 0.0, 430.0)


def gauge_scene(blocks: tuple[tuple[tuple[float, float, float, float, float], str], ...] = GAUGE_BLOCKS) -> CompositeScene:
    """Gauge blocks on the tilted base plane (the reference)."""
    return CompositeScene(tilt_deg=BASE_TILT, origin=BASE_ORIGIN, blocks=tuple(b for b, _ in blocks), spheres=())


def reference_scene() -> CompositeScene:
    """The base plane alone: the reference the order comes from."""
    return CompositeScene(tilt_deg=BASE_TILT, origin=BASE_ORIGIN, blocks=(), spheres=())


def reference_spec(width: int, height: int, axis: str = "x", period_px: float = 16.0, steps: int = 8) -> SequenceSpec:
    """The reference's absolute sequence: ``steps``-step phase shifting of ``period_px`` and a Gray
    code of ``period_px`` cells along ``axis``, white, black."""
    n = width if axis == "x" else height
    cells = int(np.ceil(n / period_px))
    return sequence_from_mapping({"projector": {"width": width, "height": height}, "blocks": [
        {"phase": {"axis": axis, "period_px": period_px, "steps": steps}},
        {"gray": {"axis": axis, "cells": cells, "cell_px": period_px}}, "white", "black"]}, "<bench>", ".")


def calibrated_rig(rig_name: str = "holdout-wide", n_poses: int = 6, seed: int = 7, *, corner_sigma_px: float = 0.03,
                   coord_sigma_px: float = 0.05, aim: tuple[float, float] = (0.06, 0.05)
                   ) -> tuple[RigCalibration, tuple[tuple[str, RigCalibration], ...]]:
    """The bench rig calibrated from ``n_poses`` board poses, and its leave-one-pose-out calibrations.

    Corners detected with ``corner_sigma_px`` noise, decoded projector coordinates with
    ``coord_sigma_px``; projector corners by local homographies
    (:func:`~huefringe.rig.projector_corners`), :func:`~huefringe.rig.calibrate_rig`. ``aim``:
    how far off the camera's axis the boards are placed (:func:`~huefringe.bench.rig.pose_set`;
    the default keeps them near the middle of the image, ``(0.14, 0.11)`` spreads them over it).
    :func:`calibrated_rig_report` gives the calibration's report beside them.
    """
    cal, jack, _ = calibrated_rig_report(rig_name, n_poses, seed, corner_sigma_px=corner_sigma_px,
                                         coord_sigma_px=coord_sigma_px, aim=aim)
    return cal, jack


@lru_cache(maxsize=4)
def calibrated_rig_report(rig_name: str = "holdout-wide", n_poses: int = 6, seed: int = 7, *,
                          corner_sigma_px: float = 0.03, coord_sigma_px: float = 0.05,
                          aim: tuple[float, float] = (0.06, 0.05)
                          ) -> tuple[RigCalibration, tuple[tuple[str, RigCalibration], ...], CalibrationReport]:
    """:func:`calibrated_rig` with the calibration's :class:`~huefringe.rig.CalibrationReport`
    (per-pose RMS, the calibrated field)."""
    rig = RIGS[rig_name]
    rng = np.random.default_rng(seed + 100)
    obs = []
    for i, (R, t) in enumerate(pose_set(rig, BOARD, n_poses, seed=seed, aim=aim)):
        p = rig.board_pose(BOARD, R, t, rng, corner_sigma_px=corner_sigma_px, coord_sigma_px=coord_sigma_px)
        pc, _ = projector_corners(p["camera"], p["u"], p["v"], p["valid"], 10, 50, sigma_u=p["sigma"], sigma_v=p["sigma"])
        obs.append(PoseObservation(f"pose{i:02d}", p["camera"], pc))
    kw = dict(outlier_factor=3.0, fix_k3=True, min_poses=4)
    cal, report = calibrate_rig(obs, BOARD, rig.camera_size, rig.projector_size, **kw)
    jack = tuple((o.name, calibrate_rig([q for q in obs if q is not o], BOARD, rig.camera_size, rig.projector_size,
                                        **kw)[0]) for o in obs)
    return cal, jack, report


@dataclass
class OneShotCapture:
    """A rendered one-shot session on the bench rig (colour frames float in [0, 1], R, G, B)."""

    rig: BenchRig
    block: TrapezoidBlock
    bands_block: HueBandsBlock
    reference: Any
    """:func:`~huefringe.codecs.decode_sequence`'s ``Decoded`` of the reference along the trapezoid's axis."""
    white: F64
    bands: F64
    frames: F64
    truth_xyz: F64
    """True camera-frame point of every pixel the projector lights directly (NaN elsewhere)."""
    labels: NDArray[np.int64]
    names: dict[int, str] = field(default_factory=dict)
    spec: SequenceSpec | None = None


def _albedo(labels: NDArray[np.int64], colours: dict[int, tuple[float, float, float]]) -> F64:
    out = np.empty((*labels.shape, 3))
    out[:] = BASE_ALBEDO
    for k, c in colours.items():
        out[labels == k] = c
        out[labels == -k] = c
    return out


def render_session(scene: CompositeScene | PlaneScene, *, rig_name: str = "holdout-wide", period_px: float = 36.0,
                   n_bands: int = 64, repeats: int = 3, frames: int = 1, seed: int = 0, noise_dn: float = 1.0,
                   ambient: float = 0.05, gamma: tuple[float, float, float] = (1.0, 1.0, 1.0),
                   colours: dict[int, tuple[float, float, float]] | None = None,
                   reference: CompositeScene | None = None, rig: BenchRig | None = None) -> OneShotCapture:
    """Render the reference decode and the object's white, hue bands and ``frames`` trapezoid frames.

    ``colours``: face label -> RGB albedo (default: the gauge blocks' coatings for the gauge scene,
    the base's grey elsewhere). ``reference``: the reference scene (default :func:`reference_scene`).
    ``rig``: a rig of its own instead of ``RIGS[rig_name]`` (e.g. another camera size).
    """
    rig = rig if rig is not None else RIGS[rig_name]
    pw, ph = rig.projector_size
    rng = np.random.default_rng(seed)
    # the reference, absolute sequence, grey captures
    ref = reference or reference_scene()
    rspec = reference_spec(pw, ph, "x")
    xyz_r, seen_r, _ = ref.cast(rig.rays)
    m = rig.coordinates(xyz_r, ref.lit(rig, xyz_r, seen_r), rng, 0.0)
    imgs = rig.capture(generate(rspec), m["u_true"], m["v_true"], m["valid"], rng, noise_dn=noise_dn, ambient=ambient,
                       albedo=0.8)
    decoded = decode_sequence(list(imgs), rspec, DecodeOptions.from_config())["x"]
    # the object: white, hue bands, trapezoid frames in colour
    block = TrapezoidBlock("x", float(period_px), 0.0, int(frames))
    bands = HueBandsBlock(int(n_bands), int(repeats))
    spec = SequenceSpec((FlatBlock("white"), bands, block), pw, ph)
    if isinstance(scene, PlaneScene):
        xyz, seen = scene.cast(rig.rays)
        labels = np.zeros(seen.shape, np.int64)
        names = {0: "board"}
    else:
        xyz, seen, labels = scene.cast(rig.rays)
        names = scene.names()
    lit = scene.lit(rig, xyz, seen)
    mo = rig.coordinates(xyz, lit, rng, 0.0)
    if colours is None:
        colours = {k + 1: BLOCK_COLOURS[c] for k, (_, c) in enumerate(GAUGE_BLOCKS)} \
            if isinstance(scene, CompositeScene) and scene.blocks == gauge_scene().blocks else {}
    alb = _albedo(labels, colours)
    distinct = generate_rgb(SequenceSpec((FlatBlock("white"), HueBandsBlock(bands.n), TrapezoidBlock("x", block.period_px)),
                                         pw, ph))           # each image once; repeats and frames refer to it
    pats = [distinct[0]] + [distinct[1 + i] for i in range(bands.n) for _ in range(bands.repeats)] \
        + [distinct[-1]] * block.frames
    cap = rig.capture_rgb(pats, mo["u_true"], mo["v_true"], mo["valid"], rng, albedo=alb,
                          ambient=ambient, noise_dn=noise_dn, gamma=gamma, crosstalk=CROSSTALK).astype(np.float32) / 255.0
    truth = np.where(mo["valid"][..., None], xyz, np.nan)
    return OneShotCapture(rig, block, bands, decoded, cap[0], cap[1 : 1 + bands.n_frames], cap[1 + bands.n_frames :],
                          truth, labels, names, spec)


def face_mask(cap: OneShotCapture, label: int, margin_px: int = 6) -> NDArray[np.bool_]:
    """Pixels of face ``label`` lit directly, eroded by ``margin_px`` (clear of edges and shadows)."""
    m = ((cap.labels == label) & np.isfinite(cap.truth_xyz).all(axis=-1)).astype(np.uint8)
    k = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
    return cv2.erode(m, k).astype(bool)


def _with_calibration_term(res: Any, jackknife: tuple[tuple[str, RigCalibration], ...]) -> tuple[F64, F64]:
    """The result's per-axis and along-ray standard uncertainties with the calibration's jackknife
    term (:func:`huefringe.rig.measure.calibration_spread`) added in quadrature."""
    from huefringe.rig.measure import RigFrame, calibration_spread

    frame = RigFrame(res.xyz, res.sigma, res.valid, {"u": res.coordinate.coord, "v": None}, "u", res.sigma_ray)
    u_axes, u_ray = calibration_spread(frame, list(jackknife))
    return np.sqrt(res.sigma**2 + u_axes**2), np.sqrt(res.sigma_ray**2 + u_ray**2)


def pixel_scores(cap: OneShotCapture, res: Any, jackknife: tuple[tuple[str, RigCalibration], ...]) -> dict[str, Any]:
    """Per-pixel errors along the camera ray against the truth: the median ``|e|``, the median ``u``,
    the share of valid pixels with ``|e| <= 2 u`` (``u``: the one-shot noise and the calibration's term)."""
    _, u_ray = _with_calibration_term(res, jackknife)
    ok = res.valid & np.isfinite(cap.truth_xyz).all(axis=-1)
    t = cap.truth_xyz[ok]
    e = np.abs(np.einsum("ij,ij->i", res.xyz[ok] - t, t / np.linalg.norm(t, axis=-1, keepdims=True)))
    return {"pixels": int(ok.sum()), "median_abs_error_mm": float(np.median(e)), "median_u_mm": float(np.median(u_ray[ok])),
            "median_sigma_noise_mm": float(np.median(res.sigma_ray[ok])),
            "within_2u": float(np.mean(e <= 2 * u_ray[ok]))}


def _retriangulated(res: Any, calib: RigCalibration, mask: NDArray[np.bool_]) -> F64:
    from huefringe.rig.triangulation import triangulate

    return triangulate(calib, res.coordinate.coord, valid=mask, mode="u").xyz[mask]


def step_scores(cap: OneShotCapture, res: Any, jackknife: tuple[tuple[str, RigCalibration], ...],
                nominal: dict[int, float], margin_px: int = 6) -> dict[str, Any]:
    """Each block's height over the base (:func:`huefringe.metrology.step_height_u`) with its
    expanded uncertainty ``U = 2 sqrt(u_points^2 + u_calibration^2)``, the calibration's term the
    jackknife of the step over the leave-one-pose-out calibrations
    (:func:`huefringe.metrology.jackknife_u`, t-scaled)."""
    from huefringe.metrology import jackknife_u, step_height_u

    base = face_mask(cap, 0, margin_px) & res.valid
    out: dict[str, Any] = {}
    for k, h0 in nominal.items():
        top = face_mask(cap, k, margin_px) & res.valid
        s = step_height_u(res.xyz[base], res.sigma[base], res.xyz[top], res.sigma[top])
        vals = []
        for _, c in jackknife:
            pb, pt = _retriangulated(res, c, base), _retriangulated(res, c, top)
            vals.append(step_height_u(pb, res.sigma[base], pt, res.sigma[top])["height_mm"])
        u_cal = jackknife_u(vals, t_scaled=True)
        U = 2.0 * float(np.hypot(s["u_mm"], u_cal))
        err = s["height_mm"] - h0
        out[cap.names.get(k, str(k))] = {"nominal_mm": h0, "height_mm": s["height_mm"], "error_mm": err,
                                         "relative_error": err / h0, "u_points_mm": s["u_mm"], "u_calibration_mm": u_cal,
                                         "U_mm": U, "inside_U": bool(abs(err) <= U), "n_top": s["n_top"]}
    return out


def flatness_scores(cap: OneShotCapture, res: Any, jackknife: tuple[tuple[str, RigCalibration], ...],
                    label: int = 0, margin_px: int = 6, within: NDArray[np.bool_] | None = None) -> dict[str, Any]:
    """A face's flatness as the report gives it (:func:`huefringe.rig.metrology.flatness_as_reported`:
    FLTq noise-corrected with the noise scaled to the data, raw RMS) with ``U = 2 sqrt(u_form^2 +
    u_calibration^2)``, the calibration's term the jackknife of FLTq over the leave-one-pose-out
    calibrations (t-scaled; zero without them). ``within``: only these pixels (e.g. the calibrated
    field, :func:`huefringe.rig.field_mask`)."""
    from huefringe.metrology import flatness_u, jackknife_u
    from huefringe.rig.metrology import flatness_as_reported

    m = face_mask(cap, label, margin_px) & res.valid
    if within is not None:
        m &= within
    f = flatness_as_reported(res.xyz, res.sigma, m)
    u_cal = 0.0
    if jackknife:
        sg = f["noise_scale"] * res.sigma[m]
        u_cal = jackknife_u([flatness_u(_retriangulated(res, c, m), sg, draws=2)["rms_form_mm"]
                             for _, c in jackknife], t_scaled=True)
    return {"n": f["n"], "rms_form_mm": f["rms_form_mm"], "rms_mm": f["rms_mm"], "rms_noise_mm": f["rms_noise_mm"],
            "u_form_mm": f["u_rms_form_mm"], "u_calibration_mm": u_cal,
            "U_mm": 2.0 * float(np.hypot(f["u_rms_form_mm"], u_cal))}
