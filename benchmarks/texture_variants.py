"""Texture-edge correction variants against the first-order one (prototypes, not in the library).

Usage: ./run python benchmarks/texture_variants.py [--cases NAME ...] [--variants NAME ...] [--noise-free] [--keep DIR]

Each variant replaces :func:`huefringe.texture.correct` and ``correct_pair`` for the run (the frames
are corrected once, before either chain, as the library does; the variants' formula alone, the
light without fringe not taken out), with the bench's true lens blur given
(``calibration.texture_blur_px2: 0.81``; the auto estimate stays first-order and is not run). The
cases are the tuning cases of ``benchmarks/accuracy_matrix.py`` (photographed reliefs astronaut and
chelsea); ``--noise-free`` adds the astronaut relief rendered without sensor noise (full well and
read noise off), which separates the correction's model error from the noise floor.
docs/accuracy-texture.md (top section) gives the table and what it means.

The variants, ``B`` a capture, ``W`` the object's white image, ``s`` the blur variance (px^2):

- ``first_order``: the library's ``B - s grad W . grad(B / W)`` (as the library runs it: with the light
  without fringe taken out, ``calibration.texture_offset``);
- ``fixed_point``: ``W F`` with ``F = B / W - s grad ln W . grad F`` (3 rounds from ``F = B / W``);
- ``smooth_gradient r``: ``B - s grad W . grad(G_r * (B / W))``: for a Gaussian blur the lean's
  coefficient ``s grad ln W`` is exact (the first moment of ``G R``), only the fringe's gradient
  is approximated; the fringe is smooth at the blur's scale, so it is taken after a Gaussian of r px;
- ``wiener e``: ``W G * (D B / D W)``: ``B`` and ``W`` Wiener-deconvolved by the Gaussian
  (regulariser e, gain 1 at zero frequency, 16 px reflected border; ``scipy.fft``), their ratio,
  blurred by the Gaussian again (what the plane calibration's fringe has);
- ``first_order smoothed``: the control for that last blur, ``W G * (B' / W)`` with ``B'`` the
  first-order correction (an extra blur of the fringe);
- ``first_order lowpass 0.03``: the control for ``wiener 0.03``'s noise filtering, the first-order
  correction through the linear filter ``G D`` (what ``wiener`` does to a uniform reflectance).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import fft, ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as am  # noqa: E402

from huefringe import texture  # noqa: E402

_first_order = texture.correct
_first_order_pair = texture.correct_pair


def _grad_dot(w: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``grad W . grad F`` per channel, central differences, 0 on the border rows and columns."""
    out = np.zeros_like(w)
    out[1:-1] += (w[2:] - w[:-2]) * (f[2:] - f[:-2]) / 4.0
    out[:, 1:-1] += (w[:, 2:] - w[:, :-2]) * (f[:, 2:] - f[:, :-2]) / 4.0
    return out


def fixed_point(b: np.ndarray, w: np.ndarray, s: float, rounds: int = 3) -> np.ndarray:
    y = b / w
    f = y
    for _ in range(rounds):
        f = y - s * _grad_dot(w, f) / w
    return w * f


def smooth_gradient(b: np.ndarray, w: np.ndarray, s: float, rho: float) -> np.ndarray:
    y = b / w
    return b - s * _grad_dot(w, ndimage.gaussian_filter(y, (rho, rho, 0), mode="nearest"))


def wiener(b: np.ndarray, w: np.ndarray, s: float, eps: float, pad_px: int = 16) -> np.ndarray:
    p = pad_px
    shape = (b.shape[0] + 2 * p, b.shape[1] + 2 * p)
    otf = np.exp(-2.0 * np.pi**2 * s * (fft.fftfreq(shape[0])[:, None] ** 2 + fft.rfftfreq(shape[1])[None, :] ** 2))
    filt = (otf * (1.0 + eps) / (otf**2 + eps))[..., None]

    def deconvolve(a: np.ndarray) -> np.ndarray:
        spec = fft.rfft2(np.pad(a, ((p, p), (p, p), (0, 0)), mode="reflect"), axes=(0, 1))
        return fft.irfft2(spec * filt, s=shape, axes=(0, 1))

    ratio = deconvolve(b) / np.maximum(deconvolve(w), texture.WHITE_FLOOR)
    sig = float(np.sqrt(s))
    return w * ndimage.gaussian_filter(ratio, (sig, sig, 0), mode="reflect")[p:-p, p:-p]


def first_order_smoothed(b: np.ndarray, w: np.ndarray, s: float) -> np.ndarray:
    """The control for ``wiener``'s low-pass: ``W G * (B' / W)``, ``B'`` the first-order correction."""
    sig = float(np.sqrt(s))
    f = np.asarray(_first_order(b, w, s), np.float64) / w
    return w * ndimage.gaussian_filter(f, (sig, sig, 0), mode="reflect")


def first_order_lowpass(b: np.ndarray, w: np.ndarray, s: float, eps: float, pad_px: int = 16) -> np.ndarray:
    """The control for ``wiener``'s noise filtering: the first-order correction ``B'`` through the
    linear filter ``wiener`` applies to a uniform reflectance, ``G D`` (transfer
    ``otf^2 (1 + e) / (otf^2 + e)``: 1 at the fringe's frequencies, ~0.5 at 0.33 cycle/px for
    s = 0.81 and e = 0.03), with no deconvolution of the ratio."""
    p = pad_px
    shape = (b.shape[0] + 2 * p, b.shape[1] + 2 * p)
    otf = np.exp(-2.0 * np.pi**2 * s * (fft.fftfreq(shape[0])[:, None] ** 2 + fft.rfftfreq(shape[1])[None, :] ** 2))
    filt = (otf**2 * (1.0 + eps) / (otf**2 + eps))[..., None]
    c = np.asarray(_first_order(b, w, s), np.float64)
    spec = fft.rfft2(np.pad(c, ((p, p), (p, p), (0, 0)), mode="reflect"), axes=(0, 1))
    return fft.irfft2(spec * filt, s=shape, axes=(0, 1))[p:-p, p:-p]


def _patched(fn):
    """``texture.correct``'s signature around a variant ``fn(b, w, s)`` (clip, clipped pixels kept)."""
    def correct(rgb, white, sigma2_px2, clipped=None):
        b = np.asarray(rgb, np.float64)
        if sigma2_px2 == 0:
            return b.astype(np.float32)
        out = np.clip(fn(b, texture.white_floor(white), sigma2_px2), 0.0, 1.0)
        if clipped is not None:
            out[clipped] = b[clipped]
        return out.astype(np.float32)
    return correct


def _pair(correct):
    """``texture.correct_pair``'s signature around a patched ``correct`` (the light without fringe is
    not taken out: the variants are of the correction's formula alone)."""
    def correct_pair(rgb, white, sigma2_px2, moved_px2, clipped=None, offset=None):
        return (correct(rgb, white, sigma2_px2, clipped),
                None if moved_px2 is None else correct(rgb, white, moved_px2, clipped))
    return correct_pair


VARIANTS = {
    "off": (None, 0.0),
    "first_order": (None, 0.81),
    "fixed_point": (_patched(fixed_point), 0.81),
    "smooth_gradient 1": (_patched(lambda b, w, s: smooth_gradient(b, w, s, 1.0)), 0.81),
    "smooth_gradient 2": (_patched(lambda b, w, s: smooth_gradient(b, w, s, 2.0)), 0.81),
    "first_order smoothed": (_patched(first_order_smoothed), 0.81),
    "first_order lowpass 0.03": (_patched(lambda b, w, s: first_order_lowpass(b, w, s, 0.03)), 0.81),
    **{f"wiener {e:g}": (_patched(lambda b, w, s, e=e: wiener(b, w, s, e)), 0.81) for e in (1e-4, 1e-3, 1e-2, 3e-2, 1e-1)},
}

NOISE_FREE = {"nf astronaut p56 72x1 (no sensor noise)":
              am._case("photo_relief", session=am._TEX, camera={"full_well_e": None, "read_noise_dn": 0.0})}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=["tex astronaut p56 72x1", "tex chelsea p56 72x1"])
    ap.add_argument("--variants", nargs="*", default=list(VARIANTS))
    ap.add_argument("--noise-free", action="store_true", help="add the astronaut relief without sensor noise")
    ap.add_argument("--keep", type=Path, default=None, help="write sessions and results here, reuse sessions found there")
    args = ap.parse_args()
    cases = {**{c: am.CASES[c] for c in args.cases}, **(NOISE_FREE if args.noise_free else {})}
    t0 = time.perf_counter()
    print("| case | variant | median mm | p95 mm | coverage | 2u all | 2u edge | 2u texture | 2u rest |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        for name, case in cases.items():
            session, tables = am._case_dirs(root / am._slug(name), case["cfg"])
            for vname in args.variants:
                fn, blur = VARIANTS[vname]
                if fn is not None:  # the measurement corrects through correct_pair: both take the variant
                    texture.correct, texture.correct_pair = fn, _pair(fn)
                try:
                    cfg = am._config({"calibration": {"texture_blur_px2": blur}})
                    r = am.score(am.measure(session, tables, root / am._slug(name) / ("var-" + am._slug(vname)), cfg))
                finally:
                    texture.correct, texture.correct_pair = _first_order, _first_order_pair
                cov = " | ".join(f"{r[f'cov2u_{z}']:.3f}" for z in ("all", "edge", "texture", "rest"))
                print(f"| {name} | {vname} | {r['median_abs_mm']:.4f} | {r['p95_abs_mm']:.4f} | {r['coverage']:.3f} | {cov} |",
                      flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
