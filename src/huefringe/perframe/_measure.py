"""One trapezoidal frame to a height map: :func:`measure_frame`, the NumPy reference chain, and its result."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe.colour import hue as hue_of
from huefringe.colour import white_balance, white_gains
from huefringe.height import PlaneCalibration
from huefringe.huetable import HueTable
from huefringe import phase_error
from huefringe.phase import adaptive_kwargs, denoise_phase, denoise_weight_sums, unwrap, wrap
from huefringe.session import Predistortion
from huefringe.uncertainty import PixelBudget, edge_floor, height_uncertainty, pixel_budget, texture_delta, texture_term_phase
from ._edges import clipped_mask
from ._noise import (WEIGHT_BLUR_PX, WEIGHT_BLUR_SHAPE, capture_noise, frame_hue_noise, height_noise, noise_ratio2,
                     phase_sigma, ratio_over, sensor_model, weight_blur_angle, weight_noise)
from ._stats import frame_stats


class FrameError(ValueError):
    """A frame cannot be measured (lens cap, saturated sensor, no fringe); names the file."""


# --------------------------------------------------------------------------- per frame


@dataclass
class FrameResult:
    height: NDArray[np.float32]
    phase: NDArray[np.float32]
    """Corrected code phase of the object, wrapped, [0, 2 pi) (NaN invalid)."""
    hue: NDArray[np.float32]
    """Raw captured hue after white balance (NaN where undefined)."""
    valid: NDArray[np.bool_]
    stats: dict[str, Any] = field(default_factory=dict)
    uncertainty: NDArray[np.float32] | None = None
    """Standard uncertainty of the height (mm), NaN where the height is NaN (:mod:`huefringe.uncertainty`)."""
    support: NDArray[np.float32] | None = None
    """Number of pixels the phase filter averaged into each height (1 without the filter; 0 where
    the height is NaN): what a step's mean shares between neighbours (:func:`~huefringe.uncertainty.step_budget`)."""
    dphi: NDArray[np.float32] | None = None
    """The phase difference before the filter (float32, NaN where not valid)."""
    texture_u: NDArray[np.float32] | None = None
    """The texture term of the uncertainty (mm, NaN where the height is), with ``texture_rgb``
    (:func:`~huefringe.uncertainty.texture_term_phase`)."""
    noise: NDArray[np.float32] | None = None
    """Standard deviation (mm) of each height from the capture noise alone (:func:`height_noise`),
    NaN where the height is NaN: what the step-edge tests hold a jump against."""
    weight: NDArray[np.float32] | None = None
    """Each pixel's own filter weight ``1 / sigma^2`` before the filter (0 where no phase was
    decoded): where the filter's window has its centroid (:func:`huefringe.uncertainty.lateral_term`)."""
    bias2: NDArray[np.float32] | None = None
    """The sigma-adaptive filter's own squared bias (rad^2) where it grew the window, NaN where the
    first pass's fixed window stands or the plane was dropped at a step
    (:func:`huefringe.phase.denoise_phase`'s ``bias2``): in the uncertainty; the lateral term's
    centroid part is for the others (``grown``)."""


def measure_frame(
    rgb: NDArray[np.floating],
    white: NDArray[np.floating],
    table: HueTable,
    cal: PlaneCalibration,
    *,
    hue_model: str,
    min_saturation: float,
    shadow: NDArray[np.bool_] | None = None,
    unwrap_mode: str,
    bit_depth: int = 8,
    below_reference_mm: float = 0.25,
    denoise_radius: int,
    predistortion: Predistortion | None = None,
    denoise_adaptive: Mapping[str, Any] | None = None,
    budget: PixelBudget | None = None,
    own_noise: bool = False,
    texture_rgb: NDArray[np.floating] | None = None,
    weight_blur_px: float = WEIGHT_BLUR_PX,
    weight_blur_shape: str = WEIGHT_BLUR_SHAPE,
    phase_error_frequency: bool = False,
) -> FrameResult:
    """One trapezoidal frame to a height map: hue -> table -> code phase -> dphi -> height.

    Parameters
    ----------
    rgb, white : ndarray
        The frame and the object's white image, float (H, W, 3) in [0, 1].
    table : HueTable
        The object's per-pixel hue table (captured hue -> projected code phase).
    cal : PlaneCalibration
        Reference phase and the per-pixel phase-to-height model.
    below_reference_mm : float
        Heights below ``-below_reference_mm`` are flagged: objects stand on the plate, so a
        large negative height means the phase difference wrapped (a step too tall for the
        fringe period).
    denoise_radius : int
        Radius of the uncertainty-weighted, edge-preserving phase filter
        (:func:`huefringe.phase.denoise_phase`); 0 switches it off. Each pixel's phase
        uncertainty is its hue noise (from the repeats of the hue bands) divided by the local
        slope of its table, so pixels where projector gamma flattens the hue lean on their
        neighbours while steps stay sharp.
    predistortion : Predistortion, optional
        When the frames were projected through a pre-distortion (paper Fig. 6; the session's
        ``predistortion.csv``), the table gives the *emitted* phase, which is decoded back to
        the code phase.
    denoise_adaptive : mapping, optional
        ``measurement.denoise_adaptive`` (:func:`huefringe.phase.adaptive_kwargs`): the filter's
        sigma-adaptive support and the rejection of pixels no filter can save.
    own_noise : bool
        Each pixel's phase sigma from this frame's own signal, pixel by pixel, through the
        table's shot + read noise model (:func:`frame_hue_noise`) (``measurement.own_noise``;
        off by default: weights that follow each pixel's own noise bias the mean they weight,
        docs/uncertainty.md, "The filter's weights"). Overrides ``weight_blur_px``.
    weight_blur_px : float
        The filter's weights: the table's pooled per-pixel noise scaled by the frame's own-signal
        figure read from the capture smoothed by a Gaussian of this sigma (px)
        (:func:`weight_noise`; ``measurement.weight_blur_px``), the uncertainty's ratio ``r``
        then the unsmoothed own figure against that one; 0, or a table without a sensor model:
        the pooled figure weights the filter.
    weight_blur_shape : {"isotropic", "along_fringe"}
        That Gaussian isotropic, or along the fringe only (perpendicular to the reference phase's
        gradient, :func:`fringe_angle`; it keeps the pixel's hue) (``measurement.weight_blur_shape``).
    phase_error_frequency : bool
        With a phase-error table (``cal.phase_error``), after the filter its correction is scaled
        to each pixel's fringe frequency (:func:`huefringe.phase_error.correct_frequency`:
        ``measurement.phase_error_frequency``).
    budget : PixelBudget, optional
        Session inputs of the height uncertainty (:func:`huefringe.uncertainty.pixel_budget`,
        computed when not given); the result's ``uncertainty`` is the kernel's, bit for bit.
    texture_rgb : ndarray, optional
        The capture corrected with the texture blur moved by its uncertainty: its phase (this
        chain without the filter) changes by :func:`~huefringe.uncertainty.texture_delta`, which
        this frame's filter carries through; the result's ``texture_u`` is the kernel's.
    """
    moved_dphi = None
    if texture_rgb is not None:
        moved_dphi = measure_frame(texture_rgb, white, table, cal, hue_model=hue_model, min_saturation=min_saturation,
                                   shadow=shadow, unwrap_mode=unwrap_mode, bit_depth=bit_depth,
                                   below_reference_mm=below_reference_mm, denoise_radius=0, predistortion=predistortion,
                                   budget=budget, own_noise=own_noise,
                                   phase_error_frequency=False).dphi  # its raw phase difference
    balanced = white_balance(rgb, white)
    hue = hue_of(balanced, hue_model, min_saturation=min_saturation)
    emitted, slope = table.to_phase_and_slope(hue)  # the phase's uncertainty needs the table slope
    phase = emitted if predistortion is None else predistortion.decode(emitted)
    phase = phase_error.correct(phase, cal.phase_error)  # the planes' phase-error table (or none)
    clipped = clipped_mask(rgb, bit_depth)
    valid = np.isfinite(phase) & ~clipped
    if shadow is not None:
        valid &= ~shadow
    dphi = wrap(phase.astype(np.float64) - cal.phi_ref)
    un = unwrap(dphi, valid, unwrap_mode)  # type: ignore[arg-type]
    # this frame's own-signal hue noise: in the weights with own_noise, else in the uncertainty only
    gains = white_gains(white)
    pooled = capture_noise(table)
    own = (frame_hue_noise(table, rgb, gains, hue_model, pooled=pooled)
           if own_noise or sensor_model(table) is not None else None)
    ratio = noise_ratio2(own, pooled) if own is not None and not own_noise else None
    weighted = weight_noise(table, rgb, gains, hue_model, weight_blur_px,
                            angle=weight_blur_angle(cal.phi_ref, weight_blur_shape)) \
        if ratio is not None and denoise_radius > 0 else None
    if weighted is not None:  # the weights from the smoothed signal; u's ratio against them
        ratio = ratio_over(ratio, weighted[1])
    sigma = phase_sigma(table, slope, noise=own if own_noise else (weighted[0] if weighted is not None else pooled))
    if predistortion is not None:
        sigma = sigma * np.abs(predistortion.decode_slope(emitted))
    sumw = np.zeros(valid.shape, np.float32)
    rsum = np.zeros(valid.shape, np.float32)
    bias2 = None
    support = np.zeros(valid.shape, np.float32)
    raw_dphi = np.asarray(un.dphi, np.float32)
    delta = texture_delta(moved_dphi, raw_dphi) if moved_dphi is not None else None
    carried = np.empty(valid.shape, np.float32) if delta is not None and denoise_radius > 0 else delta
    weight = denoise_weight_sums(un.dphi, sigma, valid)  # each pixel's own 1 / sigma^2, before the filter
    if denoise_radius > 0:
        bias2 = np.empty(valid.shape, np.float32)
        un.dphi = denoise_phase(un.dphi, sigma, valid, radius=denoise_radius, weight_sum=sumw, ratio=ratio,
                                ratio_sum=rsum if ratio is not None else None, support=support,
                                carry=delta, carry_mean=carried, bias2=bias2, **adaptive_kwargs(denoise_adaptive))
    else:  # one pixel's weight 1 / sigma^2, in the filter's float32 arithmetic
        sumw = weight
        rsum = sumw * ratio if ratio is not None else rsum
        support = (sumw > 0).astype(np.float32)
    if phase_error_frequency and cal.phase_error is not None:
        un.dphi = phase_error.correct_frequency(un.dphi, valid, cal.phi_ref, cal.phase_error,
                                                phase_error.frequency_inputs(cal))
    height = cal.height(un.dphi)
    valid &= np.isfinite(height)
    height = np.where(valid, height, np.nan).astype(np.float32)
    if budget is None:
        budget = pixel_budget(table, cal)
    u_map = edge_floor(height, valid, height_uncertainty(np.asarray(un.dphi, np.float32), sumw, valid, cal.a, cal.b,
                                                         budget, ratio_sum=rsum if ratio is not None else None,
                                                         bias2=bias2))
    support = np.where(valid, support, np.float32(0.0)).astype(np.float32)
    tex_u = texture_term_phase(np.asarray(un.dphi, np.float32), carried, height, cal.a, cal.b) \
        if delta is not None else None
    noise_h = height_noise(np.asarray(un.dphi, np.float32), sumw, valid, cal.a, cal.b)
    stats = frame_stats(
        valid, height, un.flags,
        clipped_fraction=float(clipped.mean()),
        hue_undefined_fraction=float(np.mean(~np.isfinite(hue))),
        table_invalid_fraction=float(np.mean(~table.valid)),
        shadow_fraction=float(shadow.mean()) if shadow is not None else 0.0,
        hue_model=hue_model, unwrap_mode=unwrap_mode, below_reference_mm=below_reference_mm,
    )
    return FrameResult(height, np.where(valid, phase, np.nan).astype(np.float32), hue.astype(np.float32), valid, stats,
                       u_map, support, raw_dphi, tex_u, noise_h, weight, bias2)
