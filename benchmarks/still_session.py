"""The still bench session of tests/test_uncertainty.py: noise term by the steps, lateral and texture terms.

Usage: ./run python benchmarks/still_session.py [--frames 40] [--shape along_fringe] [--keep DIR]

The session is the test's ``still`` fixture (``tests/bench_helpers.still_cfg``): the demo bench at 100 x 75 px, 0.8 mm
pitch, 15 px period, 32 hue bands x 3 repeats, no phase shifting, no vibration, ``--frames``
frames that differ only by noise. It is measured by the workflow's stages at config.yaml's
defaults with the filter's weights read through a Gaussian of ``--shape`` (the test's
``still_filtered`` fixture: ``along_fringe``), once with the lateral term off (the fixture) and
once with it on (the defaults; the heights are the same bits). Pixels valid in every frame;
"flat" = 6 px or more from any change of the true height (its 13 x 13 range below 0.05 mm, the
test's selection), "near a step" = within 4 px of one (the 9 x 9 range 0.05 mm or more).

1. **The filter near steps**: per pixel the height's frame-to-frame std over the noise term
   (``uncertainty.split_terms`` of u, rms over the frames; the split gives the noise term the
   edge floor's, the texture term's and the grown windows' part), median over the pixels near a
   step and over the flat ones; on the flat pixels also the rms spread, the rms noise term and
   the error the frames share (per pixel the frames' mean error, its noise part ``std^2 / F``
   taken out; rms).
2. **The lateral term on the flat pixels**: ``sqrt(u_on^2 - u_off^2)`` per pixel and frame, rms
   and median, beside the rms noise term of 1.
3. **The texture term**, first frame, the NumPy reference chain (``measurement.kernel: false``,
   the kernel's numbers; the phase filter's inputs recorded as ``measure_frame`` calls it): the
   moved capture's phase change (the blur moved by its uncertainty ``u_s``, the texture
   correction's own record in the calibration) carried through the frame's own filter over the
   neighbours it accepted (``carry_mean``, what u holds); the same change through two filtered
   passes with the weights held (``dphi + delta`` and ``dphi``, each with its own decisions); and
   its weighted mean over each pixel's whole final window (the filter's ``window_sums``, rejected
   neighbours included). Median and rms of ``|.|`` (rad) on the flat pixels valid in the frame,
   and each one's per-pixel correlation with the two passes' change.

About 20 s on one core (the session written and measured twice; ``--keep`` reuses the session and its results).
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

from huefringe import bench, pipeline, stages, uncertainty
from huefringe.height import PlaneCalibration
from huefringe.huetable import HueTable
from huefringe.perframe import _measure
from huefringe.phase import wrap
from huefringe.session import load_session
from huefringe.settings import load_config

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from bench_helpers import still_cfg  # noqa: E402  (the test's session)

REPO = Path(__file__).resolve().parents[1]


def _config(shape: str, lateral: bool) -> dict:
    cfg = load_config(REPO / "config.yaml")
    cfg["measurement"]["weight_blur_shape"] = shape
    if not lateral:
        cfg["measurement"]["lateral_uncertainty_px"] = 0.0
        cfg["measurement"]["lateral_step_px"] = 0.0
    return cfg


def _measured(session: Path, out: Path, cfg: dict) -> dict:
    s = load_session(session)
    heights = [out / "heights" / f"frame_{n:04d}.tiff" for n in s.frame_ids]
    if not all(h.exists() for h in heights):
        return stages.measure_session(session, out, cfg)
    return {"heights": [str(h) for h in heights],
            "uncertainties": [str(out / "uncertainties" / f"frame_{n:04d}.tiff") for n in s.frame_ids]}


def _stack(paths: list[str]) -> np.ndarray:
    return np.array([tifffile.imread(p) for p in paths], np.float64)


def texture_part(session: Path, out: Path, cfg: dict, flat: np.ndarray) -> None:
    """Section 3: the first frame through the reference chain, the filter's inputs recorded."""
    s = load_session(session)
    cal = PlaneCalibration.load(str(out / "model.npz"))
    table = HueTable.load(out / "table_object.json")
    meas = copy.deepcopy(cfg["measurement"])
    meas["kernel"] = False
    rec: dict = {}
    real = _measure.denoise_phase

    def recorder(dphi, sigma, valid, **kw):  # measure_frame's own call, kept for the variants below
        res = real(dphi, sigma, valid, **kw)
        rec.update(dphi=np.array(dphi, copy=True), sigma=np.array(sigma, copy=True), valid=np.array(valid, copy=True),
                   kw=kw, out=res.copy())
        return res

    _measure.denoise_phase = recorder
    try:
        fp = pipeline.prepare_frames(s, table, cal, cfg["hue_model"], meas,
                                     reader=pipeline.session_corrections(s, str(out / "camera.json"))[1])
        pipeline.measure_one(fp, s.frame_ids[0])
    finally:
        _measure.denoise_phase = real
    print(f"\n3. texture term, frame {s.frame_ids[0]}: blur {fp.blur2:.2f} px^2 (0: the correction off), "
          f"u_s {fp.blur_u:.2f} px^2")
    kw = rec["kw"]
    if kw.get("carry") is None:
        print("   no texture term (u_s = 0)")
        return
    dphi, sigma, valid, delta = rec["dphi"], rec["sigma"], rec["valid"], kw["carry"]
    adaptive = {k: v for k, v in kw.items() if k not in ("weight_sum", "ratio", "ratio_sum", "support", "carry",
                                                          "carry_mean", "bias2")}
    carried = kw["carry_mean"]
    moved = real(np.where(valid, dphi + delta, dphi), sigma, valid, **adaptive)
    again = real(dphi, sigma, valid, **adaptive)
    assert np.array_equal(again, rec["out"], equal_nan=True)  # the recorded call, repeated
    two_pass = wrap(moved.astype(np.float64) - again.astype(np.float64))
    wsum = np.zeros(dphi.shape, np.float32)
    dsum = np.zeros(dphi.shape, np.float32)
    real(dphi, sigma, valid, weight_sum=wsum, ratio=np.ascontiguousarray(delta, np.float32), ratio_sum=dsum, **adaptive)
    with np.errstate(invalid="ignore", divide="ignore"):
        whole = dsum.astype(np.float64) / wsum
    m = flat & np.isfinite(rec["out"]) & np.isfinite(two_pass) & np.isfinite(whole)
    print(f"   {int(m.sum())} flat pixels valid in the frame; |phase change| (rad): median / rms")
    print("| carried how | median rad | rms rad | correlation with two passes |")
    print("| --- | ---: | ---: | ---: |")
    ref = np.asarray(two_pass, np.float64)[m]
    for name, x in (("over the accepted neighbours (carry_mean, in u)", carried),
                    ("two filtered passes, weights held", two_pass), ("the whole final window's mean", whole)):
        a = np.asarray(x, np.float64)[m]
        print(f"| {name} | {np.median(np.abs(a)):.5f} | {np.sqrt(np.mean(a**2)):.5f} | {np.corrcoef(a, ref)[0, 1]:.2f} |")
    print(f"   the unfiltered change itself: median {np.median(np.abs(delta[m])):.5f} rad")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--shape", default="along_fringe", choices=("along_fringe", "isotropic"),
                    help="measurement.weight_blur_shape (the test's filtered fixture: along_fringe)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep the session and results here; reuse them")
    args = ap.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = (args.keep or Path(tmp)) / f"still-{args.frames}f"
        session = root / "session"
        if not (session / "session.yaml").exists():
            bench.write_session(still_cfg(args.frames), session)
        s = load_session(session)
        out_off = root / f"out-{args.shape}-lateral-off"
        out_on = root / f"out-{args.shape}"
        p_off = _measured(session, out_off, _config(args.shape, False))
        p_on = _measured(session, out_on, _config(args.shape, True))
        hs, us = _stack(p_off["heights"]), _stack(p_off["uncertainties"])
        hs_on, us_on = _stack(p_on["heights"]), _stack(p_on["uncertainties"])
        assert np.array_equal(hs, hs_on, equal_nan=True)  # the lateral term moves u only
        cal = PlaneCalibration.load(str(out_off / "model.npz"))
        bud = uncertainty.pixel_budget(HueTable.load(out_off / "table_object.json"), cal)
        noise = np.sqrt(np.mean([uncertainty.split_terms(u, h, cal.a, cal.b, bud)["noise"] ** 2
                                 for h, u in zip(hs, us)], axis=0))
        std = np.std(hs, axis=0, ddof=1)
        ok = np.all(np.isfinite(hs), axis=0)
        gt = tifffile.imread(s.ground_truth[s.frame_ids[0]]).astype(np.float64)
        flat = (ndimage.maximum_filter(gt, 13) - ndimage.minimum_filter(gt, 13)) < 0.05
        near = (ndimage.maximum_filter(gt, 9) - ndimage.minimum_filter(gt, 9)) >= 0.05
        truth = np.array([tifffile.imread(s.ground_truth[n]) for n in s.frame_ids], np.float64)
        mean_e = np.mean(hs - truth, axis=0)
        shared2 = np.maximum(mean_e**2 - std**2 / len(hs), 0.0)
        print(f"still session, {len(hs)} frames, weights {args.shape}; pixels valid in every frame: {int(ok.sum())}")
        print("\n1. frame-to-frame std over the noise term (per pixel; median)")
        print("| pixels | count | median ratio | rms spread mm | rms noise term mm | shared error rms mm |")
        print("| --- | ---: | ---: | ---: | ---: | ---: |")
        for name, m in (("within 4 px of a step", ok & near), ("6 px or more from a step", ok & flat)):
            r = std[m] / noise[m]
            print(f"| {name} | {int(m.sum())} | {np.median(r):.3f} | {np.sqrt(np.mean(std[m] ** 2)):.4f} | "
                  f"{np.sqrt(np.mean(noise[m] ** 2)):.4f} | {np.sqrt(np.mean(shared2[m])):.4f} |")
        lat = np.sqrt(np.maximum(us_on**2 - us**2, 0.0))
        mf = ok & flat
        x = lat[:, mf]
        print(f"\n2. lateral term on the flat pixels (all frames): rms {np.sqrt(np.mean(x**2)):.4f} mm, "
              f"median {np.median(x):.4f} mm; noise term rms {np.sqrt(np.mean(noise[mf] ** 2)):.4f} mm; "
              f"u with it: 2u covers {np.mean(np.abs(hs - truth)[:, mf] <= 2 * us_on[:, mf]):.3f} "
              f"(without: {np.mean(np.abs(hs - truth)[:, mf] <= 2 * us[:, mf]):.3f})")
        texture_part(session, out_off, _config(args.shape, False), ok & flat)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
