"""From decoded projector coordinates to triangulation inputs: only absolute, valid coordinates.

A phase block alone gives the projector coordinate within one period: triangulating it puts the
surface at a wrong, plausible-looking depth. :func:`relative_axes_problems` names such an axis
from the sequence alone (before any work); :func:`triangulation_inputs`, called between
:func:`~huefringe.codecs.decode_sequence` and :func:`~huefringe.rig.triangulate`, refuses it
again on the decoded result, and passes on only pixels whose every validity test passed (no
shadow, signal above the noise, no saturation, a readable Gray code, every fringe order decided:
:class:`~huefringe.codecs.Reason`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from huefringe.codecs.sequence import Decoded, PhaseBlock, SequenceSpec, axis_is_absolute

__all__ = ["RelativeCoordinateError", "TriangulationInputs", "relative_axes_problems", "triangulation_inputs"]

Mode = Literal["auto", "u", "v", "both"]
_AXIS = {"u": "x", "v": "y"}


class RelativeCoordinateError(ValueError):
    """A projector axis needed for triangulation that carries no absolute coordinate."""


@dataclass(frozen=True, eq=False)
class TriangulationInputs:
    """What :func:`huefringe.rig.triangulate` takes: ``u``/``v`` None for an axis not used.

    Attributes
    ----------
    u, v : ndarray of float64 or None
        Projector column / row per camera pixel (NaN where not valid).
    sigma_u, sigma_v : ndarray of float64 or None
        Their standard uncertainties (projector px).
    valid : ndarray of bool
        Every used axis decoded and valid (``reasons == 0``) at the pixel.
    mode : {'u', 'v', 'both'}
        The triangulation mode these inputs are for.
    """

    u: NDArray[np.float64] | None
    v: NDArray[np.float64] | None
    sigma_u: NDArray[np.float64] | None
    sigma_v: NDArray[np.float64] | None
    valid: NDArray[np.bool_]
    mode: Literal["u", "v", "both"]


def _missing(spec: SequenceSpec | None, axis: str) -> str:
    if spec is None:
        return f"axis {axis}: the decoded coordinate is relative (within one fringe period)"
    periods = sorted({b.period_px for b in spec.blocks if isinstance(b, PhaseBlock) and b.axis == axis})
    if len(periods) >= 2:
        return (f"axis {axis}: the phase blocks (periods {', '.join(f'{p:g}' for p in periods)} px) repeat within the "
                f"projector's {spec.extent(axis)} px and there is no Gray code on {axis}: no absolute order")
    what = f"the phase block (period {periods[0]:g} px)" if periods else "the sequence"
    return f"axis {axis}: {what} has no absolute order (no Gray code or second period on {axis})"


def relative_axes_problems(spec: SequenceSpec, mode: Mode = "auto") -> list[str]:
    """Every axis that ``mode`` triangulates and ``spec`` decodes only relatively, one line each.

    ``auto`` needs at least one absolute axis (and uses the absolute ones only).

    Examples
    --------
    >>> from huefringe.codecs import PhaseBlock, SequenceSpec, equal_shifts
    >>> spec = SequenceSpec((PhaseBlock("x", 32.0, tuple(equal_shifts(12))),), 800, 600)
    >>> relative_axes_problems(spec)[0].split(";")[0]
    'axis x: the phase block (period 32 px) has no absolute order (no Gray code or second period on x)'
    """
    axes = spec.axes()
    need = [a for a in axes if not axis_is_absolute(spec, a)]
    if mode == "auto":
        if any(axis_is_absolute(spec, a) for a in axes):
            return []
    else:
        want = ["x", "y"] if mode == "both" else [_AXIS[mode]]
        missing_axes = [a for a in want if a not in axes]
        out = [f"axis {a}: the sequence does not encode it (mode {mode!r} triangulates with it)" for a in missing_axes]
        need = [a for a in want if a in need]
        return out + [f"{_missing(spec, a)}; huefringe cannot triangulate a relative projector coordinate" for a in need]
    return [f"{_missing(spec, a)}; huefringe cannot triangulate a relative projector coordinate" for a in need]


def triangulation_inputs(decoded: Mapping[str, Decoded], spec: SequenceSpec | None = None, mode: Mode = "auto") -> TriangulationInputs:
    """The coordinates :func:`huefringe.rig.triangulate` may use, or a refusal naming the axis.

    Parameters
    ----------
    decoded : mapping
        :func:`~huefringe.codecs.decode_sequence`'s ``{"x": Decoded, "y": Decoded}``.
    spec : SequenceSpec, optional
        The sequence, to name the missing block in a refusal.
    mode : {'auto', 'u', 'v', 'both'}
        ``u`` the projector column (axis x), ``v`` the row (axis y), ``both``; ``auto``: both
        absolute axes when there are two, else the one.

    Returns
    -------
    TriangulationInputs

    Raises
    ------
    RelativeCoordinateError
        An axis the mode needs that is missing or not absolute (every one in one message).
    """
    absolute = [a for a in ("x", "y") if a in decoded and decoded[a].absolute]
    if mode == "auto":
        if not absolute:
            raise RelativeCoordinateError("; ".join(
                f"{_missing(spec, a)}; huefringe cannot triangulate a relative projector coordinate" for a in decoded)
                or "no decoded projector axis")
        resolved: Literal["u", "v", "both"] = "both" if len(absolute) == 2 else ("u" if absolute == ["x"] else "v")
    else:
        resolved = mode
    want = ["x", "y"] if resolved == "both" else [_AXIS[resolved]]
    problems = [f"axis {a}: not decoded (mode {resolved!r} triangulates with it)" for a in want if a not in decoded]
    problems += [f"{_missing(spec, a)}; huefringe cannot triangulate a relative projector coordinate"
                 for a in want if a in decoded and not decoded[a].absolute]
    if problems:
        raise RelativeCoordinateError("; ".join(problems))
    valid = np.logical_and.reduce([decoded[a].valid & (decoded[a].reasons == 0) if decoded[a].reasons.size
                                   else decoded[a].valid for a in want])
    for a in want:
        valid &= np.isfinite(decoded[a].coord) & np.isfinite(decoded[a].sigma)

    def pick(axis: str, what: str) -> NDArray[np.float64] | None:
        if axis not in want:
            return None
        return np.where(valid, getattr(decoded[axis], what), np.nan)

    return TriangulationInputs(pick("x", "coord"), pick("y", "coord"), pick("x", "sigma"), pick("y", "sigma"), valid, resolved)
