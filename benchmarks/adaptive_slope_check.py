"""What the adaptive phase filter's local plane follows: its slope test on method-matrix cases.

Usage: ./run python benchmarks/adaptive_slope_check.py [--cases NAME ...] [--keep DIR]

The grown rings of the adaptive filter (``huefringe.phase._adaptive_pass``) test and average each
neighbour against the local plane through the pixel's first-pass estimate; the plane's slope along
each axis is the central difference of the first-pass map ``max_radius`` px either side, kept
where the two one-sided differences agree within ``plane_kink_sigma`` (3) sigma and the slope exceeds 2
sigma, sigma
from the first-pass variances ``1 / sum w`` (``phase._plane_slope``). This script measures each
case of ``benchmarks/accuracy_matrix.py`` (``CASES``) with the workflow's stages at config.yaml's
settings, takes the adaptive pass's inputs of every frame, and reports, at the pixels the pass
visits (first-pass sigma above the target, ``max_radius + 2`` px from the border), per axis
(``u`` along the rows, ``v`` down the columns):

- ``consistent``: the share whose one-sided differences agree (the plane is tried);
- ``significant``: the share whose slope the test keeps;
- ``z spread``: the robust spread (1.4826 MAD) of ``z = slope / sigma`` where consistent, 1 when
  ``1 / sum w`` is the slope's whole error on a flat field;
- ``on flat truth``: ``significant`` where the bench's true height is constant over
  ``+-max_radius`` along the axis (no real slope: every kept slope there is an error);
- ``frames' corr``: the correlation of the slope between the first two frames where consistent
  (near 0 when its error is the frame's noise, near 1 when the frames share it).

Errors against the truth only score; the filter never sees the truth.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import tifffile

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe.phase import _denoise  # noqa: E402
from huefringe.session import load_session  # noqa: E402
from huefringe.settings import load_config  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CASES = ("gauge plain p48 96x2 16bit", "flat p40 d1.6 96x2", "gauge plain p64 d2.0 64x3 8bit")


def _wrap(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % (2.0 * np.pi) - np.pi


def slope_test(first: np.ndarray, wfirst: np.ndarray, need: np.ndarray, base: int, axis: int,
               kink2: float = 9.0) -> dict:
    """``phase._plane_slope``'s decision along ``axis`` (float64) at every pixel: the slope ``g``,
    ``z = g / sigma``, whether the sides agree and whether the slope is kept; ``at`` the pixels
    ``need`` with both sides valid, ``base + 2`` px from the border."""
    fa, fc = np.roll(first, base, axis), np.roll(first, -base, axis)
    wa, wc = np.roll(wfirst, base, axis), np.roll(wfirst, -base, axis)
    at = need & (wa > 0) & (wc > 0)
    edge = [slice(None), slice(None)]
    for sl in (slice(0, base + 2), slice(-base - 2, None)):
        edge[axis] = sl
        at[tuple(edge)] = False
    with np.errstate(divide="ignore", invalid="ignore"):
        va, vb, vc = 1.0 / wa, 1.0 / wfirst, 1.0 / wc
        fwd, bwd = _wrap(fc - first) / base, _wrap(first - fa) / base
        consistent = (fwd - bwd) ** 2 * base * base <= kink2 * (va + 4.0 * vb + vc)
        g = 0.5 * (fwd + bwd)
        vg = (va + vc) / (4.0 * base * base)
        z = g / np.sqrt(vg)
    return {"g": g, "z": z, "consistent": consistent, "kept": consistent & (g * g > 4.0 * vg), "at": at}


def flat_truth(truth: np.ndarray, base: int, axis: int) -> np.ndarray:
    """Pixels whose true height is finite and the same over ``+-base`` px along ``axis``."""
    out = np.isfinite(truth)
    for k in range(-base, base + 1):
        out &= np.roll(truth, k, axis) == truth
    return out


def check(name: str, where: Path) -> list[dict]:
    """The slope test's figures of one case (one row per axis)."""
    captured: list[list] = []
    original = _denoise._adaptive_pass

    def spy(d, s2, inv, first, wfirst, radius, max_radius, k2, target_w, *rest):
        # the pass's last two arguments: kink2 (plane_kink_sigma squared) and the bias map
        captured.append([np.array(inv), np.array(first), np.array(wfirst), int(max_radius), float(target_w),
                         float(rest[-2])])
        return original(d, s2, inv, first, wfirst, radius, max_radius, k2, target_w, *rest)

    session, tables = am._case_dirs(where, am.CASES[name]["cfg"])
    _denoise._adaptive_pass = spy
    try:
        am.measure(session, tables, where / "measured", load_config(REPO / "config.yaml"))
    finally:
        _denoise._adaptive_pass = original
    s = load_session(session)
    truths = [tifffile.imread(s.ground_truth[n]).astype(np.float64) for n in s.frame_ids]
    rows = []
    for axis, label in ((1, "u"), (0, "v")):
        per = []
        for (inv, first, wfirst, base, target_w, kink2), truth in zip(captured, truths, strict=True):
            t = slope_test(first, wfirst, (inv > 0) & (wfirst < target_w), base, axis, kink2)
            t["flat"] = t["at"] & flat_truth(truth, base, axis)
            per.append(t)
        cons = [t["at"] & t["consistent"] for t in per]
        z = np.concatenate([t["z"][c] for t, c in zip(per, cons, strict=True)])
        both = cons[0] & cons[1] if len(per) > 1 else None
        rows.append({
            "case": name, "axis": label,
            "consistent": float(sum(c.sum() for c in cons) / sum(t["at"].sum() for t in per)),
            "significant": float(sum((t["at"] & t["kept"]).sum() for t in per) / sum(t["at"].sum() for t in per)),
            "z_spread": float(1.4826 * np.median(np.abs(z - np.median(z)))),
            "flat": float(sum((t["flat"] & t["kept"]).sum() for t in per) / max(sum(t["flat"].sum() for t in per), 1)),
            "flat_px": int(sum(t["flat"].sum() for t in per)),
            "corr": float(np.corrcoef(per[0]["g"][both], per[1]["g"][both])[0, 1]) if both is not None else float("nan"),
        })
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(DEFAULT_CASES))
    ap.add_argument("--keep", type=Path, default=None, help="keep the sessions here; reuse them")
    args = ap.parse_args()
    unknown = [c for c in args.cases if c not in am.CASES]
    if unknown:
        sys.exit(f"adaptive_slope_check: unknown case(s) {unknown}; the cases are accuracy_matrix.CASES")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        print("| case | set | axis | consistent | significant | z spread | significant on flat truth (px) | frames' corr |")
        print("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: |")
        for name in args.cases:
            for r in check(name, root / am._slug(name)):
                kind = "hold-out" if am.CASES[name]["holdout"] else "tuning"
                print(f"| {r['case']} | {kind} | {r['axis']} | {r['consistent']:.3f} | {r['significant']:.3f} | "
                      f"{r['z_spread']:.2f} | {r['flat']:.3f} ({r['flat_px']}) | {r['corr']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
