"""A structured-light session from real captures (../shared/real, kamino410/phase-shifting's flat
plane): assembly, header and deep checks timed against references measured in the same run (a
plain copy of the folder; OpenCV decoding every capture once), then the plate decoded from the
session at full resolution (compared with decoding the original folder) against a smooth 2-D fit
(degree 6), as docs/real-captures.md does from the original folder.

    ./run python benchmarks/slsession_real.py [--work DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

from huefringe import codecs as C
from huefringe.codecs.checks import smooth_fit, smooth_region
from huefringe.session import assemble_sl_session, load_sl_session

REPO = Path(__file__).resolve().parents[1]
PLANE = REPO.parent / "shared" / "real" / "kamino410-phase-shifting" / "gamma_correction"
REPO_GAMMA = 1.6448412125348637  # the repository's gamma_result.txt ("gamma p")


def _timed(fn) -> tuple[float, object]:
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, help="scratch folder (default a temporary one)")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(dir=args.work))
    try:
        seq = work / "plane.yaml"
        seq.write_text(yaml.safe_dump({"kamino410": {"config": "config.xml", "program": "gamma_correction"},
                                       "projector": {"gamma": REPO_GAMMA}, "id": "kamino410-plane"}))
        t_copy, _ = _timed(lambda: shutil.copytree(PLANE, work / "copy"))
        t_read, _ = _timed(lambda: [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(PLANE.glob("pat*.png"))])
        t_asm, out = _timed(lambda: assemble_sl_session(PLANE, seq, work / "plane"))
        t_chk, s = _timed(lambda: load_sl_session(out))
        t_deep, _ = _timed(lambda: load_sl_session(out, deep=True))
        print(f"assemble {t_asm:.2f} s = {t_asm / t_read:.2f} x decoding every capture once ({t_asm / t_copy:.0f} x a plain copy); "
              f"check {t_chk:.3f} s = {t_chk / t_read:.3f} x decoding; check --deep {t_deep / t_read:.2f} x decoding "
              f"(reference: copy {t_copy:.2f} s, decode {t_read:.2f} s, 54 captures 1936 x 1216)")
        dec = C.decode_sequence(s.read_captures(), s.spec)
        direct = C.decode_sequence(C.read_captures(PLANE, dataclasses.replace(s.spec, frames="pat*.png")), s.spec)
        same = all(np.array_equal(dec[a].coord, direct[a].coord, equal_nan=True) for a in "xy")
        print(f"decoded from the session == decoded from the original folder: {same}")
        region = smooth_region([dec["x"].coord, dec["y"].coord], dec["x"].valid & dec["y"].valid, 10.0, 4)
        for a in "xy":
            f = smooth_fit(dec[a].coord, region, 6)
            print(f"plate {a}: RMS {f.rms:.3f} px, p95 {f.p95:.3f} px over {f.pixels} px ({region.mean():.1%} of the view)")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
