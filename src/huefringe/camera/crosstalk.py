"""Channel mixing (colour crosstalk) from the reference plate's hue bands: in each sixth of the
trapezoid's period one primary alone varies, so each camera channel's answer to it is a column
of the mixing matrix (:func:`estimate_channel_mixing`, :func:`segment_check`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe.patterns import RAMP_SEXTANTS
from huefringe.camera.lateral import CA_MIN_PIXELS


#: the six segments of the trapezoid's period (capture-session/1, "Projected codes") in which one
#: primary alone varies, the other two held at 0 or 1: (start, end) as fractions of the period,
#: the varying primary (0 R, 1 G, 2 B) and its direction (+1 rising, -1 falling)
_MIXING_SEGMENTS = tuple((k / 6, (k + 1) / 6, ch, sign) for k, (ch, sign) in enumerate(RAMP_SEXTANTS))

CA_MIXING_MAX_OFF_DIAGONAL = 0.5
"""A channel-mixing estimate with an off-diagonal entry beyond this (a camera channel answering
another primary half as strongly as its own) or a condition number above 10 is not used: the
registration then works on the camera channels themselves (``mixing`` ``estimable: false``)."""


def mixing_band_pairs(n_bands: int) -> list[tuple[int, int, int, int]]:
    """The hue bands :func:`estimate_channel_mixing` reads: ``(primary, first, last, direction)``
    per segment of the period in which one primary alone varies (first and last band inside it),
    for segments holding two bands at least (``n_bands >= 12`` gives all six)."""
    out = []
    for a, b, k, sign in _MIXING_SEGMENTS:
        first, last = int(np.ceil(a * n_bands - 1e-9)), int(np.ceil(b * n_bands - 1e-9)) - 1
        if last > first:
            out.append((k, first, last, sign))
    return out


def estimate_channel_mixing(bands: Mapping[int, NDArray[np.floating]], n_bands: int, *,
                            shadow: NDArray[np.bool_] | None = None) -> dict[str, Any]:
    """The camera's response to each projector primary, from the uniform hue bands of a plate.

    Lateral chromatic aberration magnifies the image of each projector primary (a narrow band of
    wavelengths), not each camera channel: a camera channel that also sees the neighbouring
    primaries (the colour filters' overlap, crosstalk) records a mix of images magnified
    differently. Between two hue bands of a segment of the period in which one primary alone
    varies (R falls from 1 to 0 while G is 1 and B is 0, ...: capture-session/1's trapezoid), the
    change of the camera's RGB at any pixel is that primary's column of the mixing matrix times
    a positive factor (the plate's reflectance, the irradiance, the projector's gamma: none of
    them known or needed). The column is the sum of those changes over the plate's lit pixels,
    both segments of the primary pooled, scaled to 1 in the primary's own channel.

    Parameters
    ----------
    bands : mapping of band index to (H, W, 3) float image
        The reference hue bands (repeats averaged) named by :func:`mixing_band_pairs`.
    n_bands : int
        ``pattern.hue_bands``.
    shadow : (H, W) bool, optional
        Pixels to leave out.

    Returns
    -------
    dict
        ``matrix`` (3 x 3, column k = the camera's R, G, B response to primary k, ``matrix[k][k]
        = 1``; the identity when not estimable), ``estimable``, ``bands`` (the pairs read),
        ``pixels``, and ``why`` when not estimable; when estimable also the leave-out check's
        ``segment_spread`` and ``max_segment_spread`` (:func:`segment_check`).
    """
    pairs = mixing_band_pairs(n_bands)
    cols = np.zeros((3, 3))
    per_segment: list[tuple[int, NDArray[np.float64]]] = []  # (primary, that segment's change) for the leave-out check
    npix = 0
    for k, first, last, sign in pairs:
        if first not in bands or last not in bands:
            continue
        lo, hi = np.asarray(bands[first], np.float64), np.asarray(bands[last], np.float64)
        ok = np.all((lo > 0.0) & (lo < 1.0) & (hi > 0.0) & (hi < 1.0), axis=-1)  # no clipped channel
        if shadow is not None:
            ok &= ~shadow
        npix = max(npix, int(ok.sum()))
        change = sign * (hi - lo)[ok].sum(axis=0)
        cols[:, k] += change
        per_segment.append((k, change))
    out: dict[str, Any] = {"matrix": np.eye(3).tolist(), "estimable": False,
                           "bands": [list(p) for p in pairs], "pixels": npix}
    diag = np.diag(cols)
    if npix < CA_MIN_PIXELS or np.any(diag <= 0):
        out["why"] = "no segment of the period with two hue bands for every primary" if len(
            {p[0] for p in pairs}) < 3 else "too few unclipped lit pixels in the hue bands"
        return out
    m = cols / diag[None, :]
    off = np.abs(m - np.diag(np.diag(m)))
    if off.max() > CA_MIXING_MAX_OFF_DIAGONAL or np.linalg.cond(m) > 10.0:
        out["why"] = f"implausible mixing (largest off-diagonal {off.max():.2f}, condition {np.linalg.cond(m):.1f})"
        return out
    out.update(matrix=m.tolist(), estimable=True)
    out.update(segment_check(per_segment))
    return out


def segment_check(per_segment: Sequence[tuple[int, NDArray[np.float64]]]) -> dict[str, Any]:
    """The leave-out check of a channel-mixing estimate: each primary's column from each of its two
    ramp segments alone (the rising and the falling one, disjoint bands), each scaled to a unit
    diagonal, and how far they disagree.

    Both segments see the same column of the camera's response whatever the gamma, the plate and the
    illumination; they disagree by the bands' noise, and by whatever is not a fixed linear mixing
    (a camera that stores gamma-encoded values, a drifting exposure between the bands: 0.19 and
    0.014-0.10 in tests/test_camera_demixing.py).

    Returns
    -------
    dict
        ``segment_spread``: (3, 3) ``|column(segment 1) - column(segment 2)|`` per entry (None for
        a primary with one segment), ``max_segment_spread`` (its largest entry, None when a primary
        has no second segment).
    """
    by_primary: dict[int, list[NDArray[np.float64]]] = {}
    for k, change in per_segment:
        if change[k] > 0:
            by_primary.setdefault(k, []).append(change / change[k])
    spread = np.full((3, 3), np.nan)
    for k, c in by_primary.items():
        if len(c) >= 2:
            spread[:, k] = np.abs(c[0] - c[1])
    worst = None if np.isnan(spread).any() else float(spread.max())
    return {"segment_spread": [[None if np.isnan(x) else float(x) for x in row] for row in spread],
            "max_segment_spread": worst}
