"""Wrapped phase: wrapping, the three-step phase, and unwrapping (against a reference or spatially)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from numba import njit

from huefringe.patterns import TWO_PI, phase_shift_steps


UnwrapMode = Literal["reference", "spatial"]


def wrap(x: NDArray[np.floating]) -> NDArray[np.floating]:
    """Wrap angles to (-pi, pi]."""
    return np.pi - np.mod(np.pi - x, TWO_PI)


def three_step_phase(
    i0: NDArray[np.floating], i1: NDArray[np.floating], i2: NDArray[np.floating]
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Phase of three phase-shifted captures ``I_s = A + B cos(phi + delta_s)``.

    The steps are the capture-session format's ``delta_s = 2 pi (s - 1) / 3``. Since
    ``sum_s I_s cos(delta_s) = 1.5 B cos(phi)`` and ``sum_s I_s sin(delta_s) = -1.5 B sin(phi)``,
    ``phi = atan2(-sum I_s sin(delta_s), sum I_s cos(delta_s))``.

    Returns
    -------
    phi : ndarray
        Phase in [0, 2 pi).
    modulation : ndarray
        ``B / A`` (fringe contrast, 0..1); low values mark pixels without a usable fringe.
    """
    d = phase_shift_steps()
    stack = (np.asarray(i0, np.float64), np.asarray(i1, np.float64), np.asarray(i2, np.float64))
    c = sum(im * np.cos(ds) for im, ds in zip(stack, d, strict=True))
    s = sum(im * np.sin(ds) for im, ds in zip(stack, d, strict=True))
    phi = np.mod(np.arctan2(-s, c), TWO_PI)
    mean = (stack[0] + stack[1] + stack[2]) / 3.0
    amp = np.hypot(c, s) / 1.5
    with np.errstate(divide="ignore", invalid="ignore"):
        mod = np.where(mean > 0, amp / mean, 0.0)
    return phi.astype(np.float32), mod.astype(np.float32)


@dataclass
class Unwrapped:
    """Result of unwrapping a phase-difference map."""

    dphi: NDArray[np.float32]
    """Unwrapped phase difference (NaN where invalid)."""
    flags: dict[str, NDArray[np.bool_]] = field(default_factory=dict)
    """Pixel flags: ``isolated`` (region whose 2 pi offset is assumed), ``near_wrap`` (``|dphi|``
    close to pi), ``wrap_edge`` (neighbours differ by more than pi before wrapping: the surface
    crosses the unambiguous range)."""


@njit(cache=True, nogil=True)
def _wrap_flags(d, valid, near_wrap, edge, near):  # pragma: no cover - compiled
    """``edge``: both pixels of every valid 4-neighbour pair whose phases differ by more than pi;
    ``near``: valid pixels with ``|d| > near_wrap``. Differences in float64."""
    h, w = d.shape
    for v in range(h):
        for u in range(w):
            if not valid[v, u]:
                continue
            x = np.float64(d[v, u])
            near[v, u] = abs(x) > near_wrap
            if u + 1 < w and valid[v, u + 1] and abs(np.float64(d[v, u + 1]) - x) > np.pi:
                edge[v, u] = True
                edge[v, u + 1] = True
            if v + 1 < h and valid[v + 1, u] and abs(np.float64(d[v + 1, u]) - x) > np.pi:
                edge[v, u] = True
                edge[v + 1, u] = True


def unwrap(dphi_wrapped: NDArray[np.floating], valid: NDArray[np.bool_], mode: UnwrapMode = "reference",
           *, near_wrap: float = 0.9 * np.pi, min_region_px: int = 1,
           anchor_percentile: float = 1.0) -> Unwrapped:
    """Unwrap a wrapped phase difference to the reference plane.

    Parameters
    ----------
    dphi_wrapped : ndarray
        ``wrap(phi_object - phi_reference)`` in (-pi, pi].
    valid : ndarray of bool
        Pixels with a usable phase.
    mode : {"reference", "spatial"}
        See the module docstring.
    near_wrap : float
        Pixels with ``|dphi| > near_wrap`` (reference mode) are flagged ``near_wrap``.
    anchor_percentile : float
        Spatial mode: each region's 2 pi offset puts this percentile of its values inside
        (-pi, pi] (objects stand on the plate, so their lowest part is near the reference plane).
    """
    d = np.asarray(dphi_wrapped)
    if d.dtype not in (np.float32, np.float64):
        d = d.astype(np.float64)
    valid = np.asarray(valid, bool) & np.isfinite(d)
    flags: dict[str, NDArray[np.bool_]] = {}
    edge = np.zeros(d.shape, bool)
    near = np.zeros(d.shape, bool)
    _wrap_flags(d, valid, float(near_wrap), edge, near)
    flags["wrap_edge"] = edge
    if mode == "reference":
        out = np.where(valid, d, np.nan)
        flags["near_wrap"] = near
        flags["isolated"] = np.zeros(d.shape, bool)
    elif mode == "spatial":
        d = d.astype(np.float64)
        out = np.full(d.shape, np.nan)
        from scipy import ndimage  # here, not at the top: the per-frame jobs never need it
        from skimage.restoration import unwrap_phase

        labels, n = ndimage.label(valid)
        isolated = np.zeros(d.shape, bool)
        if n:
            sizes = ndimage.sum_labels(valid, labels, index=np.arange(1, n + 1))
            largest = int(np.argmax(sizes)) + 1
            masked = np.ma.masked_array(d, mask=~valid)
            uw = np.asarray(unwrap_phase(masked, rng=0).filled(np.nan), np.float64)
            for lab in range(1, n + 1):
                region = labels == lab
                if sizes[lab - 1] < min_region_px:
                    continue
                low = np.percentile(uw[region], anchor_percentile)
                k = np.floor((low + np.pi) / TWO_PI)
                out[region] = uw[region] - k * TWO_PI
                if lab != largest:
                    isolated |= region
        flags["isolated"] = isolated
        flags["near_wrap"] = np.zeros(d.shape, bool)
    else:
        raise ValueError(f"unknown unwrapping mode {mode!r} (reference or spatial)")
    return Unwrapped(out.astype(np.float32), flags)


def unwrap_rows(phi: NDArray[np.floating], valid: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Spatially unwrap a fringe phase map with many periods (e.g. a calibration plane).

    Uses scikit-image's quality-guided unwrapper on the valid pixels and returns NaN elsewhere.
    The absolute 2 pi offset is arbitrary; callers compare planes through differences.
    """
    from skimage.restoration import unwrap_phase

    masked = np.ma.masked_array(np.asarray(phi, np.float64), mask=~np.asarray(valid, bool))
    return np.asarray(unwrap_phase(masked, rng=0).filled(np.nan), np.float64)
