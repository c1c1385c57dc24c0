"""The texture term on an analytic capture: a fringe on a reflectance edge, four-step phase shifting.

Usage: ./run python benchmarks/texture_term_edge.py [--blur 0.81] [--step 0.2]

The capture of tests/test_uncertainty.py's ``test_texture_term_is_the_phase_error_of_a_wrong_blur``
(``tests/bench_helpers.texture_edge_case``):
a fringe (period 24 px, 0.5 + 0.4 cos) on a reflectance edge (0.2 : 0.8 at column 80 of
16 x 160 px), blurred by a Gaussian of variance ``--blur`` px^2, its phase decoded by four-step
phase shifting after ``texture.correct`` with a given blur. "At the edge" = rows 4-11, columns
76-83; "far" = rows 4-11, columns 20-59. It prints:

- the term for the blur left uncorrected (``s = 0``, ``u = --blur``: ``uncertainty.texture_term``
  of the phase corrected with no blur and with the true one) against the uncorrected phase's
  error from the uniform-reflectance phase, their largest values at the edge;
- with the true blur corrected, the term for ``+u`` and ``-u`` (``u = --step``) at the edge
  (the correction is linear in the blur) and far from it.

A second or so.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from huefringe import uncertainty

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from bench_helpers import texture_edge_case  # noqa: E402  (the test's capture)

EDGE = (slice(4, 12), slice(76, 84))
FAR = (slice(4, 12), slice(20, 60))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blur", type=float, default=0.81, help="the lens blur's variance (px^2)")
    ap.add_argument("--step", type=float, default=0.2, help="u of the +u / -u check (px^2)")
    args = ap.parse_args()
    sigma2 = args.blur
    refl, phase = texture_edge_case(sigma2)

    truth = phase(0.0, np.full_like(refl, 0.5))  # no texture: the fringe's own phase
    plain = phase(0.0, refl)
    err = np.abs(np.angle(np.exp(1j * (plain - truth))))
    pred = uncertainty.texture_term(plain, phase(sigma2, refl))
    p, e = float(pred[EDGE].max()), float(err[EDGE].max())
    print(f"blur {sigma2} px^2 left uncorrected (s = 0, u = {sigma2}): term {p:.3f} rad against the error "
          f"{e:.3f} rad at the edge ({p / e - 1:+.1%})")
    up = uncertainty.texture_term(phase(sigma2, refl), phase(sigma2 + args.step, refl))
    down = uncertainty.texture_term(phase(sigma2, refl), phase(sigma2 - args.step, refl))
    a, b = float(up[EDGE].max()), float(down[EDGE].max())
    print(f"blur corrected, u = {args.step} px^2: +u {a:.4f} rad, -u {b:.4f} rad at the edge ({a / b - 1:+.1%}); "
          f"far from it {float(up[FAR].max()):.1e} rad")


if __name__ == "__main__":
    main()
