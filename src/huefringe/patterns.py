"""Projected codes of the capture-session format (paper eq. 3 and the phase-shift sinusoids).

Everything here is a pure function of the *code phase* ``phi`` in radians: the position ``x``
inside one fringe period ``T`` has code phase ``2 pi x / T``. Both the bench (which projects
these codes) and the measuring modules (which know what was projected) use this module; it
holds no rig model.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

TWO_PI = 2.0 * np.pi

#: Header of a patterns folder's ``manifest.csv`` (``huefringe patterns`` writes it, ``huefringe session`` reads it).
MANIFEST_HEADER = ("order", "image", "session_path")

#: Eq. 3 sextant by sextant (``s = 3 phi / pi`` in ``[k, k + 1)``, :func:`trapezoid_rgb`): the one
#: channel on a ramp (0 R, 1 G, 2 B) and its direction (+1 rising, -1 falling); the other two sit
#: at 0 and 1. What the hue bands of a segment show about one primary alone (the camera's channel
#: mixing, the projector's per-channel response) is read through this.
RAMP_SEXTANTS: tuple[tuple[int, int], ...] = ((1, 1), (0, -1), (2, 1), (1, -1), (0, 1), (2, -1))


def trapezoid_rgb(phi: ArrayLike) -> NDArray[np.float64]:
    """Trapezoidal RGB fringe of paper eq. 3 at code phase ``phi``.

    Parameters
    ----------
    phi : array_like
        Code phase in radians; any real value (taken modulo 2 pi).

    Returns
    -------
    ndarray
        Array of shape ``phi.shape + (3,)`` with R, G, B in [0, 1].

    Notes
    -----
    With ``s = 6 x / T = 3 phi / pi`` in [0, 6):
    R = 1, G = s, B = 0 on [0, 1); R = 2 - s, G = 1 on [1, 2); G = 1, B = s - 2 on [2, 3);
    G = 4 - s, B = 1 on [3, 4); R = s - 4, B = 1 on [4, 5); R = 1, B = 6 - s on [5, 6).
    The hexcone hue of this colour is exactly ``phi``.
    """
    s = np.mod(np.asarray(phi, dtype=np.float64), TWO_PI) * (3.0 / np.pi)
    r = np.clip(np.maximum(2.0 - s, s - 4.0), 0.0, 1.0)
    g = np.clip(np.minimum(s, 4.0 - s), 0.0, 1.0)
    b = np.clip(np.minimum(s - 2.0, 6.0 - s), 0.0, 1.0)
    return np.stack([r, g, b], axis=-1)


def band_phase(i: ArrayLike, n_bands: int) -> NDArray[np.float64]:
    """Code phase ``2 pi i / N`` projected by hue band ``i`` of ``N``."""
    return TWO_PI * np.asarray(i, dtype=np.float64) / float(n_bands)


def band_rgb(i: int, n_bands: int) -> NDArray[np.float64]:
    """The uniform RGB colour of hue band ``i`` of ``n_bands`` (shape ``(3,)``)."""
    return trapezoid_rgb(band_phase(i, n_bands))


#: Order of the difference along the bands from which a one-repeat hue table estimates each
#: pixel's noise (:mod:`huefringe.huetable`): the third, over four consecutive bands of one sextant.
BAND_DIFFERENCE_ORDER = 3


def band_sextants(n_bands: int) -> NDArray[np.int64]:
    """Sextant ``k`` (0..5, eq. 3's ramp of one channel) of each band's code phase: ``(6 i) // N``."""
    return (6 * np.arange(int(n_bands), dtype=np.int64)) // int(n_bands)


def band_difference_runs(n_bands: int, order: int = BAND_DIFFERENCE_ORDER) -> int:
    """How many runs of ``order + 1`` consecutive bands (band 0 first, no wrap) lie within one
    sextant: the differences from which a one-repeat hue table estimates its noise. 0 for
    ``N <= 18`` at the third order (at most three bands a sextant)."""
    seg = band_sextants(n_bands)
    return int(np.count_nonzero(seg[: max(0, n_bands - order)] == seg[order:]))


def single_repeat_problem(n_bands: int, repeats: int) -> str | None:
    """Why ``n_bands`` hue bands captured ``repeats`` times cannot give a hue table its noise
    figure, or None where they can.

    With two or more repeats the noise is the repeats' spread. With one it is the third difference
    of four consecutive bands within a sextant of the code (:data:`BAND_DIFFERENCE_ORDER`), which
    needs at least one such run: 19 bands or more. Without it every pixel's u would be unknown, so
    the session is refused before any work rather than at its first frame.
    """
    if int(repeats) >= 2 or band_difference_runs(n_bands) > 0:
        return None
    least = 6 * BAND_DIFFERENCE_ORDER + 1  # sextant 0 holds ceil(N / 6) bands: order + 1 of them from here
    return (f"{n_bands} hue bands captured once give no noise figure: with a single repeat the hue table "
            f"estimates each pixel's noise from four consecutive bands within one sextant of the code, and "
            f"{n_bands} bands give at most {int(np.bincount(band_sextants(n_bands)).max())} a sextant; capture "
            f"each band at least twice (repeats >= 2) or use at least {least} bands (24 give four in every sextant)")


def phase_shift_steps() -> NDArray[np.float64]:
    """Phase steps ``delta_s = 2 pi (s - 1) / 3`` for ``s = 0, 1, 2``, as the spec writes them."""
    return TWO_PI * (np.arange(3) - 1.0) / 3.0


def phase_shift_intensity(phi: ArrayLike, s: int) -> NDArray[np.float64]:
    """Grey sinusoid ``0.5 + 0.5 cos(phi + delta_s)`` of phase-shift capture ``s`` (0, 1, 2)."""
    delta = phase_shift_steps()[s]
    return 0.5 + 0.5 * np.cos(np.asarray(phi, dtype=np.float64) + delta)


def quantise(values: ArrayLike, bit_depth: int = 8) -> NDArray[np.uint8] | NDArray[np.uint16]:
    """Round values in [0, 1] to ``bit_depth``-bit codes (8 -> ``uint8`` 0..255, 16 -> ``uint16``).

    Values outside [0, 1] are clipped. Rounding to the nearest code moves a value by at most
    half a code step, ``0.5 / (2**bit_depth - 1)``.
    """
    if bit_depth not in (8, 16):
        raise ValueError(f"bit_depth must be 8 or 16, got {bit_depth!r}")
    top = float(2**bit_depth - 1)
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    return np.round(np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0) * top).astype(dtype)


def projector_image(
    width: int, height: int, period_px: float, phase_map: ArrayLike | None = None, *, bit_depth: int = 8
) -> NDArray[np.uint8] | NDArray[np.uint16]:
    """A projector frame of the trapezoidal pattern (constant along rows), 8- or 16-bit.

    Parameters
    ----------
    width, height : int
        Projector resolution in pixels (e.g. 1024 x 768, the paper's DMD).
    period_px : float
        Fringe period in projector pixels.
    phase_map : array_like, optional
        A 1-D map of length ``width`` giving the code phase to *emit* at each projector column
        (a pre-distorted pattern); default the linear ``2 pi x / T``.
    bit_depth : {8, 16}
        Code depth: ``uint8`` (default) or ``uint16`` output (see :func:`quantise`).
    """
    if phase_map is None:
        phase = TWO_PI * np.arange(width) / float(period_px)
    else:
        phase = np.asarray(phase_map, dtype=np.float64)
        if phase.shape != (width,):
            raise ValueError(f"phase_map must have shape ({width},), got {phase.shape}")
    row = quantise(trapezoid_rgb(phase), bit_depth)
    return np.broadcast_to(row[None, :, :], (height, width, 3)).copy()
