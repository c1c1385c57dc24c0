"""Per-pixel height uncertainty (GUM), and its propagation into step heights.

The height of a pixel is ``h = dphi / (a + b dphi)`` with ``dphi = phi - phi_ref`` (filtered).
Its standard uncertainty combines five terms (``docs/uncertainty.md`` has the formulas and their
sizes on the demo), kept in three groups because they average differently:

=============  =================================================  ==================================
group          terms                                              averages over
=============  =================================================  ==================================
independent    ``noise``: sensor (shot + read) noise of the       pixels (by the effective number of
               frame through the hue, the table slope and the     independent pixels) and frames
               phase filter (``1 / sum w``)
pixel          ``table``: noise of the smoothed table entries;    pixels, not frames (the table is
               ``interpolation``: linear interpolation            the same for every frame)
               between bands
correlated     ``reference``: the z = 0 plane's smoothed          neither (shared by the pixels of a
               phase; ``model``: the (a, b) fit of the planes     region and by every frame)
=============  =================================================  ==================================

With the height's sensitivity ``G = dh/ddphi = a / (a + b dphi)^2`` and the parameter
sensitivities ``J = (dh/da, dh/db) = -(dphi, dphi^2) / (a + b dphi)^2``::

    u_noise = G sqrt(sum w r) / sum w  the filter's weights w = 1/sigma^2 it used (pooled
                                       noise), r = own-signal / pooled noise variance
    u_table = u_noise sqrt(f_table)    f_table = smoothed entry variance / one capture's
    u_interp = G u_interp_rad          rms linear-interpolation error of the pixel's table in
                                       the code-phase bin of its own phase (12 bins), from the
                                       curvature its noise does not explain, less the plate's
                                       shared curvature where a phase-error table takes it out
    u_ref = G u_ref_rad                smoothed-reference error (fit noise + unmodelled misfit)
    u_model = sqrt(J C J^T)            C = covariance of (a, b) from the planes' errors

The frame's hue noise (behind ``r``) comes from its own RGB signal through a shot + read noise
model fitted on the hue bands' captured hue (:func:`huefringe.perframe.frame_hue_noise`,
:func:`huefringe.huetable.fit_hue_noise`); the weights
stay the table's pooled noise, so that the heights do not depend on it. After the
root sum of squares, :func:`edge_floor` raises mixed pixels (steps, shadow borders) to the local
scatter of the heights about their 3 x 3 plane.

This package is pure: it never reads files and never imports the bench. Its topics:
:mod:`~huefringe.uncertainty.calibration` (once per session), :mod:`~huefringe.uncertainty.frame`
(per frame), :mod:`~huefringe.uncertainty.steps` (step heights and the ISO 14253-1 decision) and
:mod:`~huefringe.uncertainty.validation` (against ground truth); their public names are
importable from here.
"""

from __future__ import annotations

from huefringe.uncertainty.calibration import (
    GROUPS, INTERP_BINS, PixelBudget, RESIDUAL_BOX_PX, TERMS, calibration_terms, common_interpolation,
    curvature_noise_factors, interpolation_at, interpolation_bins, interval_curvature, noise_correlation,
    phase_error_residual_rad, pixel_budget, systematic_rms, table_interpolation_rad, table_variance_factor,
)
from huefringe.uncertainty.frame import (
    EDGE_SIGNIFICANCE, LATERAL_COARSE_PX, LATERAL_PX, LATERAL_SMOOTH_PX, LATERAL_STEP_PX, add_lateral,
    edge_floor, filter_centroid, height_uncertainty, lateral_term, split_terms, texture_delta, texture_term,
    texture_term_phase,
)
from huefringe.uncertainty.steps import coating_term, conformance, step_budget
from huefringe.uncertainty.validation import reliability

