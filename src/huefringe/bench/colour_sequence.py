"""A colour-sequential projector seen by a global- or rolling-shutter camera.

A single-chip DLP projector shows its colours one after another (a colour wheel, or R, G and B
LEDs switched in turn), several cycles per refresh period. A camera row integrates the light over
its exposure window; when the window is not a whole number of colour cycles the row receives a
share of each colour that differs from the share in a whole cycle. With a rolling shutter every
row's window starts ``line_time`` later than the one above, so that share changes along the rows.

The captured colour of a row is the pattern's R, G, B times the per-channel weight

    w_k(row) = (time colour k is shown within the row's window) / (exposure * duty_k)

(1 for every channel when the window is a whole number of cycles, whatever its start). Only the
projector's light is weighted; ambient and stray light are steady.

:class:`ColourSequence` holds one cycle's segments; :func:`row_weights` gives ``w_k`` for every
row of an image and for every sub-exposure of a motion-blurred capture.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["ColourSequence", "Shutter", "row_weights", "start_phase"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ColourSequence:
    """One colour cycle of the projector.

    Parameters
    ----------
    segments : tuple of (channel, start, end)
        Each segment's channel (0 R, 1 G, 2 B) and its start and end as fractions of the cycle.
    duty : ndarray, shape (3,)
        Share of one cycle each channel is shown.
    cycle_s : float
        Length of one colour cycle (s).
    """

    segments: tuple[tuple[int, float, float], ...]
    duty: F64
    cycle_s: float

    @classmethod
    def from_config(cls, block: dict[str, Any]) -> ColourSequence:
        """From the bench's ``projector.colour_sequence`` block (defaults filled).

        The segments follow each other from phase 0 in the order of ``segments``; a channel's duty
        is shared equally by its segments; what is left of the cycle (``1 - sum(duty)``) is dark,
        spread equally between the segments (a wheel's spokes).
        """
        order = [("RGB".index(c)) for c in str(block["segments"])]
        duty = np.asarray(block["duty"], dtype=np.float64).reshape(3)
        counts = np.bincount(order, minlength=3)
        if np.any(counts == 0):
            raise ValueError(f"colour_sequence.segments {block['segments']!r} must show R, G and B")
        dark = max(0.0, 1.0 - float(duty.sum())) / len(order)
        segs, t = [], 0.0
        for k in order:
            length = float(duty[k]) / float(counts[k])
            segs.append((int(k), t, t + length))
            t += length + dark
        cycle = 1.0 / (float(block["refresh_hz"]) * float(block["cycles_per_refresh"]))
        return cls(tuple(segs), duty, cycle)

    def shown(self, t_s: F64) -> F64:
        """Time (s) each channel has been shown from 0 to ``t_s``: shape ``t_s.shape + (3,)``."""
        t = np.asarray(t_s, dtype=np.float64) / self.cycle_s
        whole = np.floor(t)
        frac = t - whole
        out = whole[..., None] * self.duty
        for k, a, b in self.segments:
            out[..., k] += np.clip(frac - a, 0.0, b - a)
        return out * self.cycle_s


@dataclass(frozen=True)
class Shutter:
    """The camera's shutter: ``global`` or ``rolling`` with ``line_time_s`` between row starts.

    ``start_phase``: the colour-cycle phase (fraction of a cycle) at which row 0's exposure starts,
    or ``None`` for a phase drawn per image (:func:`start_phase`).
    """

    kind: str = "global"
    line_time_s: float = 0.0
    start_phase: float | None = None

    @classmethod
    def from_config(cls, block: dict[str, Any] | None) -> Shutter:
        """From the bench's ``camera.shutter`` block (absent: global, random start phase)."""
        b = block or {}
        kind = str(b.get("kind", "global"))
        line = float(b["line_time_us"]) * 1e-6 if kind == "rolling" else 0.0
        phase = b.get("start_phase", "random")
        return cls(kind, line, None if phase == "random" else float(phase))


def start_phase(shutter: Shutter, seed: int, name: str) -> float:
    """The start phase of one image: the configured one, or one drawn from ``(seed, name)``.

    The generator is keyed apart from the image's noise stream, so the noise of every image is
    the same with and without a colour sequence.
    """
    if shutter.start_phase is not None:
        return shutter.start_phase
    rng = np.random.default_rng([int(seed), zlib.crc32(name.encode("utf-8")), 0x5EC])
    return float(rng.uniform(0.0, 1.0))


def row_weights(seq: ColourSequence, shutter: Shutter, exposure_s: float, rows: int, phase: float,
                subframes: int = 1) -> F64:
    """The per-row channel weights ``w_k`` of one image.

    Parameters
    ----------
    seq : ColourSequence
        The projector's colour cycle.
    shutter : Shutter
        Global or rolling (``line_time_s``).
    exposure_s : float
        Exposure time of every row (s), > 0.
    rows : int
        Image rows.
    phase : float
        Colour-cycle phase (fraction of a cycle) at which row 0's exposure starts.
    subframes : int
        Split the exposure into this many equal slices (a motion-blurred capture's sub-exposures);
        the mean of the slices' weights is the whole window's.

    Returns
    -------
    ndarray, shape (subframes, rows, 3)
        ``w_k`` of each slice and row: the time colour ``k`` is shown within the slice over
        ``slice length * duty_k``.
    """
    if exposure_s <= 0.0:
        raise ValueError(f"a colour-sequential projector needs an exposure > 0 s, got {exposure_s}")
    n = max(1, int(subframes))
    start = phase * seq.cycle_s + np.arange(rows, dtype=np.float64) * shutter.line_time_s
    edges = start[None, :] + exposure_s * np.arange(n + 1, dtype=np.float64)[:, None] / n
    shown = seq.shown(edges)  # (n + 1, rows, 3)
    return np.diff(shown, axis=0) / ((exposure_s / n) * seq.duty)
