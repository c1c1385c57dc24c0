"""Content checks of a folder of camera captures that ``huefringe session`` makes before writing.

Three questions a file count and a header cannot answer, each answered from numbers
:func:`huefringe.assemble.assemble_session` gathers in its one reading pass:

- **Duplicates** (:func:`duplicate_groups`): captures with the same pixel values (a file copied
  under another name, or re-saved in another format), or near-identical ones (at most
  :data:`NEAR_IDENTICAL_FRACTION` of the pixels differ, by at most one code). Two real captures
  never agree that well: camera noise alone changes most pixels from one exposure to the next.
- **Hue-band order** (:func:`band_order_problems`): each uniform hue band's captured hue against
  its code phase ``2 pi i / N``. The captured hue follows the code through a bent but rising
  transfer (projector gamma, camera crosstalk), once round the circle; a capture outside the
  longest rising run was captured in another band's place.
- **Bayer pattern** (:func:`bayer_fit`): the four patterns compared on the mosaic's own
  statistics: for each, the reference bands' hue computed from its assignment of the 2 x 2
  photosites to R, G, G, B (each photosite normalised by its white), against the bands' code
  phases. The true pattern gives a hue that winds with the code; the three others do not.

Layer: below :mod:`huefringe.assemble`; uses :mod:`huefringe.colour` only.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from huefringe.colour import hue_hexcone

__all__ = [
    "BAYER_SITES",
    "NEAR_IDENTICAL_FRACTION",
    "BandMisplaced",
    "BayerFit",
    "band_order_problems",
    "bayer_fit",
    "duplicate_groups",
    "site_means",
]

NEAR_IDENTICAL_FRACTION = 1e-3
"""Largest fraction of pixels (differing by one code at most) for two captures to count as near-identical."""

BAYER_SITES: dict[str, str] = {"RGGB": "RGGB", "BGGR": "BGGR", "GRBG": "GRBG", "GBRG": "GBRG"}
"""Colour of the photosites (row 0 col 0, row 0 col 1, row 1 col 0, row 1 col 1) per pattern."""

def site_means(raw: NDArray) -> NDArray[np.float64]:
    """Mean of each of the four photosites of the 2 x 2 Bayer cell, in the order of :data:`BAYER_SITES`."""
    return np.array([raw[0::2, 0::2].mean(dtype=np.float64), raw[0::2, 1::2].mean(dtype=np.float64),
                     raw[1::2, 0::2].mean(dtype=np.float64), raw[1::2, 1::2].mean(dtype=np.float64)])


# ------------------------------------------------------------------------------------------ duplicates


def duplicate_groups(digests: Sequence[bytes | None], signatures: NDArray[np.float64], code_step: float,
                     differ_fraction: Callable[[int, int], float]) -> list[tuple[list[int], bool]]:
    """Groups of captures with the same or nearly the same pixel values.

    Parameters
    ----------
    digests : sequence of bytes or None
        A digest of each capture's decoded pixel values (None: unreadable, skipped).
    signatures : ndarray, shape (n, m)
        A short profile of each capture (column means binned), same units as ``code_step``.
    code_step : float
        One code of the captures (1 for 8-bit, 16 for 12-bit data in 16-bit files, ...).
    differ_fraction : callable
        ``differ_fraction(i, j)``: the fraction of pixels of captures ``i`` and ``j`` that differ by
        more than one code, or 1.0 when more than one code apart anywhere; called only for
        candidate pairs whose signatures agree to a hundredth of a code.

    Returns
    -------
    list of (indices, identical)
        Each group in ascending index order; ``identical`` False for near-identical groups.
    """
    groups: dict[bytes, list[int]] = {}
    for i, d in enumerate(digests):
        if d is not None:
            groups.setdefault(d, []).append(i)
    out = [(g, True) for g in groups.values() if len(g) > 1]
    firsts = [g[0] for g in groups.values()]  # one representative per distinct content
    if len(firsts) > 1:
        sig = signatures[firsts]
        # pairs whose binned profiles agree to 1/100 code: sort on the first component, compare neighbours
        order = np.argsort(sig[:, 0], kind="stable")
        seen: set[int] = set()
        for a_pos, a in enumerate(order):
            for b in order[a_pos + 1:]:
                if sig[b, 0] - sig[a, 0] > 0.01 * code_step:
                    break
                if np.max(np.abs(sig[a] - sig[b])) <= 0.01 * code_step:
                    i, j = sorted((firsts[a], firsts[b]))
                    if j in seen:
                        continue
                    if differ_fraction(i, j) <= NEAR_IDENTICAL_FRACTION:
                        out.append(([i, j], False))
                        seen.add(j)
    return sorted(out, key=lambda g: g[0][0])


# ------------------------------------------------------------------------------------------ band order


@dataclass(frozen=True)
class BandMisplaced:
    """A hue-band capture whose hue fits another band."""

    index: int
    """Position of the capture in the list given to :func:`band_order_problems`."""
    band: int
    """The band its place in the manifest says it is."""
    fits: int
    """The band whose hue it has: a band left without captures between the two bands whose hue
    brackets it, or the nearer of those two."""
    hue_rad: float
    """Its captured hue."""


def _circ_mean(a: NDArray[np.float64]) -> float:
    return float(np.angle(np.mean(np.exp(1j * a))))


def _wrap(a: NDArray[np.float64] | float) -> NDArray[np.float64]:
    return (np.asarray(a, dtype=np.float64) + np.pi) % (2 * np.pi) - np.pi


def _longest_rising(values: Sequence[float]) -> list[int]:
    """Positions of a longest non-decreasing subsequence of ``values`` (patience sorting)."""
    import bisect

    tails: list[float] = []
    tail_pos: list[int] = []
    prev = [-1] * len(values)
    for k, v in enumerate(values):
        j = bisect.bisect_right(tails, v)
        if j == len(tails):
            tails.append(v)
            tail_pos.append(k)
        else:
            tails[j], tail_pos[j] = v, k
        prev[k] = tail_pos[j - 1] if j else -1
    out, k = [], tail_pos[-1] if tail_pos else -1
    while k >= 0:
        out.append(k)
        k = prev[k]
    return out[::-1]


def band_order_problems(rgb: NDArray[np.float64], bands: Sequence[int], hue_bands: int) -> list[BandMisplaced]:
    """Hue-band captures whose hue does not fit their place in the band order.

    Parameters
    ----------
    rgb : ndarray, shape (n, 3)
        Mean R, G, B of each band capture divided by the white capture's (channel by channel).
    bands : sequence of int
        The band ``i`` (code phase ``2 pi i / N``) each capture goes to.
    hue_bands : int
        N.

    Returns
    -------
    list of BandMisplaced
        Empty when the captured hue rises once round the circle with the band index, as the code
        phase does (the transfer from code to captured hue bends, never turns back: on the bench
        one band's step ranges from 0.13 to 2.2 times ``2 pi / N``). Otherwise the captures
        outside the longest run that does rise (tried from every band as the start of the
        circle; the repeats of a band are interchangeable), each with the band whose hue it has.
    """
    n_b = int(hue_bands)
    band_of = np.asarray(bands, dtype=np.intp)
    h = hue_hexcone(np.asarray(rgb, dtype=np.float64)).astype(np.float64)
    ok = np.flatnonzero(np.isfinite(h))
    if ok.size < 6:
        return []
    best: list[int] = []
    for start in np.unique(band_of[ok]):
        rot = (band_of[ok] - start) % n_b
        anchor = _circ_mean(h[ok][rot == 0]) - 1e-3  # the first band's captures sit just above 0
        u = (h[ok] - anchor) % (2 * np.pi)
        order = np.lexsort((u, rot))  # band by band; a band's repeats in order of hue
        keep = [int(ok[order[k]]) for k in _longest_rising(u[order].tolist())]
        if len(keep) > len(best):
            best = keep
        if len(best) == ok.size:
            return []
    kept = np.zeros(len(h), bool)
    kept[best] = True
    kept_bands, kept_h = band_of[kept], h[kept]
    out = []
    for k in ok[~kept[ok]]:
        d = (kept_h - h[k]) % (2 * np.pi)  # hue distance up from capture k to each kept capture
        hi, lo = int(kept_bands[np.argmin(d)]), int(kept_bands[np.argmax(d)])
        gap = [(lo + j) % n_b for j in range(1, (hi - lo) % n_b)]  # bands between, none of them kept
        if gap:  # interpolate in hue between the two kept neighbours
            d_lo, d_hi = 2 * np.pi - float(d.max()), float(d.min())
            fits = gap[min(len(gap) - 1, int(len(gap) * d_lo / max(d_lo + d_hi, 1e-12)))]
        else:
            fits = lo if 2 * np.pi - float(d.max()) < float(d.min()) else hi
        out.append(BandMisplaced(int(k), int(band_of[k]), int(fits), float(h[k])))
    return out


# ------------------------------------------------------------------------------------------ Bayer


@dataclass(frozen=True)
class BayerFit:
    """How well each Bayer pattern explains the mosaic: the RMS hue error of the bands (rad)."""

    rms_rad: dict[str, float]

    @property
    def best(self) -> str:
        """The pattern whose hue follows the bands' code phases best."""
        return min(self.rms_rad, key=lambda p: self.rms_rad[p])

    def fits(self, pattern: str) -> bool:
        """Whether ``pattern`` explains the mosaic: it is the best, or within 1.5 times the best and 0.3 rad."""
        best = self.rms_rad[self.best]
        return pattern == self.best or (self.rms_rad[pattern] <= max(1.5 * best, best + 0.05)
                                        and self.rms_rad[pattern] < 0.3)

    def describe(self) -> str:
        """``RGGB 0.08 rad, BGGR 2.1 rad, ...`` best first."""
        return ", ".join(f"{p} {v:.2f} rad" for p, v in sorted(self.rms_rad.items(), key=lambda kv: kv[1]))


def bayer_fit(white_sites: NDArray[np.float64], band_sites: NDArray[np.float64], bands: Sequence[int],
              hue_bands: int) -> BayerFit:
    """Compare the four Bayer patterns on the reference white and hue bands of a raw mosaic.

    Parameters
    ----------
    white_sites : ndarray, shape (4,)
        :func:`site_means` of the reference white capture.
    band_sites : ndarray, shape (n, 4)
        :func:`site_means` of each reference hue-band capture.
    bands : sequence of int
        The band of each capture (code phase ``2 pi i / N``).
    hue_bands : int
        N.

    Returns
    -------
    BayerFit
        For each pattern, the RMS of the bands' hue about the code phase (after the mean offset),
        with the photosites read as that pattern's R, G, G, B. The true pattern gives the
        calibration's own ripple (about 0.1-0.3 rad); a wrong one a hue that runs backwards or
        barely moves (above 1 rad).
    """
    norm = np.asarray(band_sites, dtype=np.float64) / np.maximum(np.asarray(white_sites, dtype=np.float64), 1e-9)
    code = 2 * np.pi * np.asarray(bands, dtype=np.float64) / int(hue_bands)
    out = {}
    for pattern, sites in BAYER_SITES.items():
        chan = {c: [k for k, s in enumerate(sites) if s == c] for c in "RGB"}
        rgb = np.stack([norm[:, chan[c]].mean(axis=1) for c in "RGB"], axis=1)
        h = hue_hexcone(rgb).astype(np.float64)
        ok = np.isfinite(h)
        if ok.sum() < 3:
            out[pattern] = float(np.pi)
            continue
        d = _wrap(h[ok] - code[ok])
        d = _wrap(d - _circ_mean(d))
        out[pattern] = float(np.sqrt(np.mean(d ** 2)))
    return BayerFit(out)


def band_rgb_means(profiles: Mapping[str, NDArray[np.float64]], white: NDArray[np.float64]) -> dict[str, NDArray]:
    """Mean R, G, B of each column profile over the white's (channel by channel)."""
    w = np.maximum(white, 1e-9)
    return {k: (p / w).mean(axis=0) for k, p in profiles.items()}
