"""The projector's gamma estimated from the captures themselves.

Two independent estimates, each of the exponent ``gamma_p`` in ``display = value**gamma_p``:

``flat``
    With white and black frames, a correctly linearised N-step block has offset 0.5 and amplitude
    0.5 of ``white - black`` (:func:`~huefringe.codecs.nstep.linearise`); the exponent that makes
    the fitted offset equal half the span, over the valid pixels, is the estimate.
``harmonic``
    A wrong exponent leaves a phase error with three cycles per fringe (for three steps) whose
    sign and size depend on the block's encoding exponent; two blocks of the same period but
    different encoding exponents (kamino410's ``gamma_correction``) therefore disagree unless the
    exponent is right: the estimate minimises their RMS wrapped difference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["GammaEstimate", "estimate_projector_gamma"]


@dataclass(frozen=True)
class GammaEstimate:
    """Projector gamma estimates (``nan`` where the sequence lacks what a method needs)."""

    flat: float
    harmonic: float
    pixels: int


def estimate_projector_gamma(images, spec, options=None, *, mask: NDArray[np.bool_] | None = None) -> GammaEstimate:
    """Estimate ``spec``'s projector gamma from its captures (module docstring)."""
    raise NotImplementedError
