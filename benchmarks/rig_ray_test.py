"""The ray test (reason RAY) on a measured bench session: clean pixels dropped, injected wrong orders
caught, points beyond 5 sigma of the truth with the test off and on, and its cost.

Usage (after the demo workflow wrote the rig-gauge session and its calibration):
    ./run python benchmarks/rig_ray_test.py resources/demo/rig-gauge results/rig-gauge/calib/rig.yml

3000 valid pixels get a wrong order (a quarter each of +-16 px and +-8 px on u and on v,
the rig sequence's period and Gray cell); a point is "beyond 5 sigma" when its error along the
camera ray against the true projector coordinates triangulated with the same calibration exceeds
5 times its sigma_ray (the decoding's own error).
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np
import tifffile

from huefringe.rig import read_calibration
from huefringe.rig.measure import decode_frame, triangulate_frame
from huefringe.rig.triangulation import epipolar_residual, triangulate
from huefringe.session import load_sl_session
from huefringe.settings import load_config


def main(session: str, calibration: str) -> None:
    base = load_config({"codecs": {"noise": {"read_dn": 1.0, "full_well_e": None}}})
    off = load_config(base, {"codecs": {"max_ray_sigma": 1e9, "ray_floor_px": 1e9}})
    s = load_sl_session(session)
    calib = read_calibration(calibration)
    imgs = s.read_captures()
    d = decode_frame(imgs, s.spec, base)
    ut, vt = (tifffile.imread(s.root / "ground_truth" / f"{a}.tiff").astype(float) for a in "xy")
    truth = triangulate(calib, ut, vt, valid=np.isfinite(ut)).xyz

    def z_of(f):
        ray = f.xyz / np.linalg.norm(f.xyz, axis=-1, keepdims=True)
        return np.abs(np.einsum("...k,...k", f.xyz - truth, ray)) / f.sigma_ray

    def inject(seed, n=3000):
        rng = np.random.default_rng(seed)
        dec, out, which = dict(d["decoded"]), dict(d), {}
        pick = rng.choice(np.flatnonzero((d["valid_u"] & d["valid_v"]).ravel()), n, replace=False)
        for i, (axis, key, step) in enumerate((("x", "u", 16.0), ("y", "v", 16.0), ("x", "u", 8.0), ("y", "v", 8.0))):
            p = pick[i::4]
            c = dec[axis].coord.copy()
            c.ravel()[p] += step * rng.choice([-1, 1], len(p))
            dec[axis] = replace(dec[axis], coord=c)
            out[key] = np.where(dec[axis].valid, c, np.nan)
            which[f"{key} {step:g} px"] = p
        out["decoded"] = dec
        return out, which

    r, _ = epipolar_residual(calib, d["u"], d["v"])
    r = np.abs(r[np.isfinite(r)])
    print(f"clean miss (projector px): median {np.median(r):.4f}, p99 {np.percentile(r, 99):.4f}, max {r.max():.4f}")
    for name, cfg in (("ray test off", off), ("ray test on", base)):
        f = triangulate_frame(d, calib, cfg, where=name, spec=s.spec)
        z = z_of(f)
        dropped = int(((f.decoded["decoded"]["x"].reasons & 64) != 0).sum())
        print(f"{name}: clean: {int(f.valid.sum())} points, {dropped} dropped by RAY, {int(np.sum(z[f.valid] > 5))} beyond 5 sigma")
        di, which = inject(7)
        f = triangulate_frame(di, calib, cfg, where=name, spec=s.spec)
        z = z_of(f)
        print(f"  with wrong orders: {int(np.sum(z[f.valid] > 5))} of {int(f.valid.sum())} points beyond 5 sigma")
        for k, p in which.items():
            print(f"    {k}: {len(p)} injected, {len(p) - int(f.valid.ravel()[p].sum())} dropped")
    for name, cfg in (("off", off), ("on", base)):
        ts = []
        for _ in range(5):
            t0 = time.perf_counter()
            triangulate_frame(d, calib, cfg, where=name, spec=s.spec)
            ts.append(time.perf_counter() - t0)
        print(f"triangulate_frame, ray test {name}: {1000 * min(ts):.0f} ms (min of 5)")
    ts = []
    for _ in range(5):
        t0 = time.perf_counter()
        epipolar_residual(calib, d["u"], d["v"], sigma_u=d["sigma_u"], sigma_v=d["sigma_v"])
        ts.append(time.perf_counter() - t0)
    print(f"epipolar_residual alone: {1000 * min(ts):.0f} ms (min of 5)")


if __name__ == "__main__":
    main(*sys.argv[1:3])
