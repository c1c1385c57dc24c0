"""Benchmark: the parts of a frame's stages that the manual prices one by one, on the stage benchmark's frame.

Usage: ./run python benchmarks/stage_parts.py [PART ...] [--calls 7]

PART: ``unc`` (the uncertainty's per-frame passes: the own-signal noise pass, the weights' figure
and its Gaussian, the noise ratio, the filter's sums ``window_sums``, the budget
``height_uncertainty``, the edge floor), ``filter`` (the first pass, the adaptive pass, the filter
with and without the texture term's carried sums), ``lateral`` (``add_lateral`` as the stage
benchmark's *flags* row calls it and with the filter's centroid part as the workflow calls it,
``filter_centroid`` alone; the step-edge test compiled against ``np.where(step_edge_mask(...))``
and ``np.nanmedian``), ``texture`` (``texture.correct`` and ``correct_pair`` at 640 x 480 and
1280 x 1024), ``cloud`` (``cloud.write_height_cloud`` against ``cloud.write_points`` of gathered
arrays, with and without a ``sigma_mm`` property), ``reg`` (``camera.lateral.ChannelRegistration.apply``
on an 8-bit capture without and with a mixing, a 16-bit one); default all. On the frame of
``benchmarks/bench_stages.py`` (``_kernel_case.make_case(640, 480, 64)``, a texture blur of 0.4 px^2),
each call's inputs captured from one ``kernel.frame_maps`` call as the workflow makes it (the
functions wrapped for that call only). One thread (``NUMBA_NUM_THREADS``, OpenCV), CPU time of the
process, the minimum of ``--calls`` calls after a warm-up call (pairs compared in the same run are
interleaved); the load average is printed with each figure. The stage table
(``bench_stages.py``) holds the same work summed per stage. About 1 min.
"""

from __future__ import annotations

import os

for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _kernel_case import make_case, tile_case  # noqa: E402

import huefringe.perframe._noise as pn  # noqa: E402
import huefringe.phase._denoise as dn  # noqa: E402
from huefringe import kernel, perframe, texture  # noqa: E402
from huefringe.settings import defaults  # noqa: E402
from huefringe.uncertainty import add_lateral, filter_centroid  # noqa: E402

PARTS = ("unc", "filter", "lateral", "texture", "cloud", "reg")


def main() -> None:  # noqa: C901, PLR0915 - one frame, the parts in turn
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("parts", nargs="*", default=[], help=f"any of {', '.join(PARTS)} (default: all)")
    ap.add_argument("--calls", type=int, default=7)
    args = ap.parse_args()
    bad = [p for p in args.parts if p not in PARTS]
    if bad:
        ap.error(f"unknown part(s) {', '.join(bad)}: choose from {', '.join(PARTS)}")
    N = args.calls
    cv2.setNumThreads(1)

    def cpu(fn, n=N):  # noqa: ANN001, ANN202
        fn()
        ts = []
        for _ in range(n):
            c = time.process_time()
            fn()
            ts.append(time.process_time() - c)
        return 1e3 * min(ts)

    def report(name, ms):  # noqa: ANN001, ANN202
        print(f"{name:60s} {ms:7.2f} ms   (load {os.getloadavg()[0]:.2f})", flush=True)

    which = args.parts or ["all"]
    print("load at start", os.getloadavg())
    m = defaults()["measurement"]
    adaptive = m["denoise_adaptive"]
    radius = int(m["denoise_radius"])
    rig = make_case(640, 480, n_bands=64)
    shadow = perframe.shadow_mask(rig.white, m["shadow_fraction"])
    prep = kernel.prepare(rig.table, rig.cal, rig.white, hue_model="hexcone", min_saturation=m["min_saturation"],
                          shadow=shadow, bit_depth=8)
    raw = rig.frame.astype(np.float32) * np.float32(1 / 255)
    clip = perframe.clipped_mask(raw, 8)
    rgb = texture.correct(raw, rig.white, 0.4, clipped=clip, offset=rig.offset)
    _, moved = texture.correct_pair(raw, rig.white, 0.4, 0.5, clipped=clip, offset=rig.offset)

    # the inputs of the named calls inside frame_maps, captured from one call of each kind
    cap = {}

    def spy(mod, name, key=None):  # noqa: ANN001, ANN202
        f = getattr(mod, name)
        def w(*a, **k):
            cap.setdefault(key or name, (a, k))
            return f(*a, **k)
        setattr(mod, name, w)
        return f
    orig = {}
    for n in ("weight_noise_of", "_hue_noise_kernel", "noise_ratio2", "ratio_over", "denoise_weighted",
              "height_uncertainty", "edge_floor", "height_noise"):
        orig[n] = spy(kernel, n)
    for n in ("first_pass", "_adaptive_pass", "window_sums"):
        orig[n] = spy(dn, n)
    orig["smoothed_signal"] = spy(pn, "smoothed_signal")
    kernel.frame_maps(prep, rgb, want_dphi=True, denoise_radius=radius, denoise_adaptive=adaptive,
                               want_uncertainty=True, texture_rgb=moved)
    captex = dict(cap)
    cap.clear()
    full = kernel.frame_maps(prep, rgb, want_dphi=True, denoise_radius=radius, denoise_adaptive=adaptive,
                             want_uncertainty=True)
    capu = dict(cap)
    # restore
    for n in ("weight_noise_of", "_hue_noise_kernel", "noise_ratio2", "ratio_over", "denoise_weighted",
              "height_uncertainty", "edge_floor", "height_noise"):
        setattr(kernel, n, orig[n])
    for n in ("first_pass", "_adaptive_pass", "window_sums"):
        setattr(dn, n, orig[n])
    pn.smoothed_signal = orig["smoothed_signal"]

    def call(d, n):  # noqa: ANN001, ANN202
        a, k = d[n]
        return lambda: orig[n](*a, **k)

    if "all" in which or "unc" in which:
        # first call of _hue_noise_kernel is the weights' sensor noise (if prep.sensor) else own
        report("own-signal noise pass (_hue_noise_kernel, u)", cpu(call(capu, "_hue_noise_kernel")))
        if "weight_noise_of" in capu:
            report("weights' figure (weight_noise_of)", cpu(call(capu, "weight_noise_of")))
            report("  its Gaussian (smoothed_signal)", cpu(call(capu, "smoothed_signal")))
        report("noise ratio (noise_ratio2)", cpu(call(capu, "noise_ratio2")))
        if "ratio_over" in capu:
            report("noise ratio (ratio_over)", cpu(call(capu, "ratio_over")))
        report("filter's sums (window_sums)", cpu(call(capu, "window_sums")))
        report("budget (height_uncertainty)", cpu(call(capu, "height_uncertainty")))
        report("edge floor (edge_floor)", cpu(call(capu, "edge_floor")))
        report("height_noise", cpu(call(capu, "height_noise")))

    if "all" in which or "filter" in which:
        a, k = capu["first_pass"]
        report("first pass (first_pass, r=2)", cpu(lambda: orig["first_pass"](*a, **k)))
        a, k = capu["_adaptive_pass"]
        report("adaptive pass (_adaptive_pass)", cpu(lambda: orig["_adaptive_pass"](*a, **k)))
        # filter with and without the carried sums, same inputs (u call with texture)
        a, k = captex["denoise_weighted"]
        k_no = dict(k, carry=None, carry_mean=None)
        with_c, without_c = [], []
        f = orig["denoise_weighted"]
        f(*a, **k); f(*a, **k_no)
        for _ in range(N):
            c = time.process_time(); f(*a, **k); with_c.append(time.process_time() - c)
            c = time.process_time(); f(*a, **k_no); without_c.append(time.process_time() - c)
        report("filter (denoise_weighted, u sums) with carried sums", 1e3 * min(with_c))
        report("filter (denoise_weighted, u sums) without", 1e3 * min(without_c))

    if "all" in which or "lateral" in which:
        hh, (uu,), (ss,), _ = perframe.remove_step_edges(full.height, float(m["edge_jump_mm"]), nan_maps=(full.uncertainty,),
                                                         zero_maps=(full.support,), test=str(m["edge_test"]),
                                                         tol_mm=float(m["edge_plane_tol_mm"]))
        lat, step = float(m["lateral_uncertainty_px"]), float(m["lateral_step_px"])
        print("lateral_px", lat, "step_px", step)
        t_plain, t_cent, t_fc = [], [], []
        fa = lambda: add_lateral(hh, uu, lateral_px=lat, step_px=step)
        fb = lambda: add_lateral(hh, uu, lateral_px=lat, step_px=step, weight=full.weight, filter_radius=radius,
                                 grown=full.bias2)
        fc = lambda: filter_centroid(full.weight, radius)
        fa(); fb(); fc()
        for _ in range(N):
            for lst, fn in ((t_plain, fa), (t_cent, fb), (t_fc, fc)):
                c = time.process_time(); fn(); lst.append(time.process_time() - c)
        report("lateral term (add_lateral as bench flags, no centroid)", 1e3 * min(t_plain))
        report("lateral term with the centroid part (workflow call)", 1e3 * min(t_cent))
        report("filter_centroid alone", 1e3 * min(t_fc))
        # edges: compiled vs np.where(step_edge_mask)+nanmedian (pair test)
        jump = float(m["edge_jump_mm"])
        h0 = full.height
        def ref_pair():
            msk = perframe.step_edge_mask(h0, jump)
            hn = np.where(msk, np.float32(np.nan), h0)
            un = np.where(msk, np.float32(np.nan), full.uncertainty)
            return np.nanmedian(hn)
        def comp_pair():
            return perframe.remove_step_edges(h0, jump, nan_maps=(full.uncertainty,), test="pair")
        tr, tc = [], []
        ref_pair(); comp_pair()
        for _ in range(N):
            c = time.process_time(); comp_pair(); tc.append(time.process_time() - c)
            c = time.process_time(); ref_pair(); tr.append(time.process_time() - c)
        report("remove_step_edges pair (compiled)", 1e3 * min(tc))
        report("np.where(step_edge_mask) + nanmedian", 1e3 * min(tr))
        report("remove_step_edges as flags (default test)", cpu(lambda: perframe.remove_step_edges(
            h0, jump, nan_maps=(full.uncertainty,), zero_maps=(full.support,), test=str(m["edge_test"]),
            tol_mm=float(m["edge_plane_tol_mm"]))))

    if "all" in which or "texture" in which:
        report("texture.correct 640x480", cpu(lambda: texture.correct(raw, rig.white, 0.4, clipped=clip, offset=rig.offset)))
        report("texture.correct_pair 640x480", cpu(lambda: texture.correct_pair(raw, rig.white, 0.4, 0.5, clipped=clip,
                                                                                offset=rig.offset)))
        big = tile_case(rig, 1280, 1024)
        rawb = big.frame.astype(np.float32) * np.float32(1 / 255)
        clipb = perframe.clipped_mask(rawb, 8)
        report("texture.correct 1280x1024", cpu(lambda: texture.correct(rawb, big.white, 0.4, clipped=clipb, offset=big.offset), n=5))

    if "all" in which or "cloud" in which:
        from huefringe import cloud
        with tempfile.TemporaryDirectory() as tmp:
            p = Path(tmp) / "c.ply"
            h = full.height
            u = full.uncertainty
            rgbb = cloud.colour_bytes(cloud.check_colours(rig.white, rig.white.shape[:2]).reshape(-1, 3))
            def packed():
                return cloud.write_height_cloud(p, h, 0.1, colours=rgbb, scalars={"sigma_mm": u})
            def gathered():
                pts, pix = cloud.height_to_points(h, 0.1)
                return cloud.write_points(p, pts, rgbb[pix], scalars={"sigma_mm": u.reshape(-1)[pix]})
            def packed_nc():
                return cloud.write_height_cloud(p, h, 0.1, colours=rgbb)
            def gathered_nc():
                pts, pix = cloud.height_to_points(h, 0.1)
                return cloud.write_points(p, pts, rgbb[pix])
            ta, tb, tc, td = [], [], [], []
            for f in (packed, gathered, packed_nc, gathered_nc):
                f()
            for _ in range(N):
                for lst, f in ((ta, packed), (tb, gathered), (tc, packed_nc), (td, gathered_nc)):
                    c = time.process_time(); f(); lst.append(time.process_time() - c)
            report("write_height_cloud (colour bytes, sigma scalar)", 1e3 * min(ta))
            report("write_points of gathered arrays (same)", 1e3 * min(tb))
            report("write_height_cloud (colour bytes)", 1e3 * min(tc))
            report("write_points of gathered arrays (colour bytes)", 1e3 * min(td))

    if "all" in which or "reg" in which:
        from huefringe.camera.lateral import ChannelRegistration
        img = rig.frame  # uint8 640x480x3
        r1 = ChannelRegistration(centre=(320.0, 240.0), scale_r=0.001, scale_b=-0.001)
        r2 = ChannelRegistration(centre=(320.0, 240.0), scale_r=0.001, scale_b=-0.001, mixing=tuple(map(tuple, np.array(
            [[0.90, 0.08, 0.02], [0.07, 0.86, 0.07], [0.02, 0.10, 0.88]]))))
        report("ChannelRegistration.apply uint8 640x480 (no mixing)", cpu(lambda: r1.apply(img)))
        report("ChannelRegistration.apply uint8 640x480 (mixing)", cpu(lambda: r2.apply(img)))
        img16 = (img.astype(np.uint16) * 257)
        report("ChannelRegistration.apply uint16 640x480 (mixing)", cpu(lambda: r2.apply(img16)))
    print("load at end", os.getloadavg())


if __name__ == "__main__":
    main()
