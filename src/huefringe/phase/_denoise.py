"""The uncertainty-weighted edge-preserving phase filter: :func:`denoise_phase` and its prepared-input form, and the adaptive window's keywords."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from huefringe.settings import defaults

from ._passes import _adaptive_pass, _denoise_kernel, _denoise_kernel_carry, _denoise_weights, _own_side, window_sums


#: The values of ``lacking_probe_bias`` (``measurement.denoise_adaptive.lacking_probe_bias``).
LACKING_PROBE_BIAS = ("posterior", "unbiased")


def denoise_phase(dphi: NDArray[np.floating], sigma: NDArray[np.floating], valid: NDArray[np.bool_],
                  *, radius: int = 2, k: float = 3.0, max_radius: int = 0, target_sigma: float = 0.0,
                  reject_sigma: float = 0.0, weight_sum: NDArray[np.float32] | None = None,
                  ratio: NDArray[np.float32] | None = None, ratio_sum: NDArray[np.float32] | None = None,
                  support: NDArray[np.float32] | None = None, box_chi_z: float = 0.0,
                  plane_kink_sigma: float = 3.0, carry: NDArray[np.float32] | None = None,
                  carry_mean: NDArray[np.float32] | None = None,
                  bias2: NDArray[np.float32] | None = None,
                  lacking_probe_bias: str = "unbiased") -> NDArray[np.float32]:
    """Edge-preserving, uncertainty-weighted local mean of a phase map.

    Each valid pixel becomes the inverse-variance weighted mean of itself and the valid pixels
    in its ``(2 radius + 1)^2`` window whose phase agrees within ``k`` combined standard
    deviations with an estimate of the pixel's own side of any step (:func:`first_pass`; a
    bilateral filter whose range term is the known per-pixel uncertainty).
    Differences are taken modulo 2 pi, so wrapped maps are fine. Steps taller than ``k`` sigma
    (a 1 mm step is tens of sigma) are not blurred; flat regions gain up to
    ``2 radius + 1`` in precision. Pixels where the hue hardly changes with the code phase
    (projector gamma flattens the trapezoid's ramps near 0, 2 pi/3 and 4 pi/3) carry large
    ``sigma`` and are pulled toward their better-determined neighbours.

    Parameters
    ----------
    dphi : ndarray
        Phase (difference) map in radians; NaN where invalid.
    sigma : ndarray
        Per-pixel standard deviation of ``dphi`` in radians (finite, > 0 where valid).
    valid : ndarray of bool
    max_radius, target_sigma : int, float
        Sigma-adaptive support: a pixel whose filtered sigma (``1 / sqrt`` of its accepted
        inverse variances) is above ``target_sigma`` gets a window grown ring by ring up to
        ``max_radius``, its neighbours tested against the local plane through its first-pass
        estimate (that estimate plus the local phase slope times the neighbour's offset) and
        averaged as the values the plane carries back to the pixel: a step is never crossed, and
        on a ramp neither the accepted set nor the mean follows the noise or the texture's
        weights (:func:`_adaptive_pass`); 0 = fixed window.
    reject_sigma : float
        Pixels whose filtered sigma stays above this become NaN (invalid); 0 = never.
    box_chi_z : float
        > 0: the adaptive support grows by whole boxes, O(1) per pixel and radius from
        summed-area tables of the weighted phase, its square and their moments in x and y,
        wherever the box lies on the local plane the rings use (its scatter about the plane within
        this many standard deviations of its chi-square, the plane's rise across it within the
        rings' band; :func:`_adaptive_pass`); the pixels where it does not (steps, outliers, steep
        ramps) grow ring by ring. 0 = rings everywhere.
    plane_kink_sigma : float
        The grown rings' local plane (its slope from the first-pass estimates ``max_radius`` px
        either side of the pixel) is dropped, the pixel's level used instead, where the two
        one-sided slopes disagree by more than this many standard deviations of their difference:
        a step, an edge or a kink between the sides. 3 (the default) keeps blurred steps out of
        the plane; larger keeps the plane on curved reliefs (docs/uncertainty.md, "The plane's
        kink test").
    bias2 : float32 ndarray, optional
        Receives, per pixel whose window the sigma-adaptive pass grew, the squared bias (rad^2) of
        its weighted mean at the pixel: the accepted neighbours' values (less the local plane where
        it has one) modelled as a plane in their offsets plus the surface's curvature ``H`` (the
        first-pass map's second differences ``2 max_radius`` px either side, shrunk by their own
        noise), the plane's slope ``d`` fitted by least squares; the mean errs by ``d . c +
        mean(o^T H o) / 2`` (``c`` the weights' centroid, ``o`` the accepted offsets): a window
        with weight on one side on a surface the plane does not follow, and any grown window on a
        curved surface. Less the fitted slope's noise variance (0 if negative), plus it instead
        where the plane lacked one of its probes and nothing says the surface is flat there
        (``lacking_probe_bias``); NaN where the first
        pass's fixed window stands (its centroid is the lateral term's) and where the pass dropped
        its plane at a kink of 5 sigma or more (a step between its probes: the lateral term's step
        part). A flat side next to a step has no slope: no bias.
    lacking_probe_bias : {"posterior", "unbiased"}
        ``bias2`` where the local plane lacked a probe (outside the image or not valid) along an
        axis and nothing says the surface is flat there (both probes missing, or the one there
        with a significant one-sided slope): ``"unbiased"`` (the default) ``max(b^2 - var(b), 0)``
        as everywhere else; ``"posterior"`` the estimate's posterior mean square under a flat prior,
        ``b^2 + var(b)``, no plane test having stood for a slope the noise alone could make.
        The phase is the same either way (docs/uncertainty.md, "The grown windows' bias").
    carry, carry_mean : float32 ndarray, optional
        ``carry_mean`` receives each pixel's weighted mean of ``carry`` (finite everywhere) over
        the neighbours its final window accepted, ``sum(w carry) / sum(w)`` (0 where not valid):
        another map filtered with this phase's weights and decisions, i.e. the filtered change of
        a phase change too small to move them (accumulated beside the weights; the filtered phase
        and the other sums are the same bits with or without it).
    weight_sum : float32 ndarray, optional
        Receives each pixel's sum of the weights ``1 / sigma^2`` of the neighbours it averaged
        (0 where not valid): the filtered phase's variance from independent pixel noise is
        exactly ``1 / weight_sum`` (:mod:`huefringe.uncertainty`).
    ratio, ratio_sum : float32 ndarray, optional
        When the pixels' actual noise variance is ``ratio`` times the ``sigma^2`` that weights
        them (e.g. the frame's own-signal noise against the pooled one), ``ratio_sum`` receives
        each pixel's ``sum w ratio``: the filtered phase's variance is then
        ``ratio_sum / weight_sum^2`` (``sum w^2 sigma_true^2 / (sum w)^2``).
    support : float32 ndarray, optional
        Receives the number of pixels each pixel averaged (itself included; 0 where not valid),
        counted in equal-weight pixels over its final window (:func:`window_sums`): the window's
        accepted neighbours where none was rejected, and the adaptive pass may grow it far
        beyond ``(2 radius + 1)^2``.

    Returns
    -------
    ndarray, float32
        The filtered phase, NaN where not valid. Computed in float32 (vectorised; about 7 ms
        for 640 x 480 at radius 2 on one core).
    """
    d = np.asarray(dphi)
    s = np.asarray(sigma)
    valid = np.asarray(valid, bool)
    if not d.shape == s.shape == valid.shape or d.ndim != 2:
        raise ValueError(f"dphi {d.shape}, sigma {s.shape} and valid {valid.shape} must be the same 2-D shape")
    if d.dtype not in (np.float32, np.float64):
        d = d.astype(np.float64)
    if s.dtype not in (np.float32, np.float64):
        s = s.astype(np.float64)
    # float32 throughout (SIMD); sigma clipped so that its square and inverse stay finite
    dz, s2, inv = (np.empty(d.shape, np.float32) for _ in range(3))
    _denoise_weights(d, s, valid, dz, s2, inv)
    return denoise_weighted(dz, s2, inv, radius=radius, k=k, max_radius=max_radius, target_sigma=target_sigma,
                            reject_sigma=reject_sigma, weight_sum=weight_sum, ratio=ratio, ratio_sum=ratio_sum,
                            support=support, box_chi_z=box_chi_z, plane_kink_sigma=plane_kink_sigma, carry=carry,
                            carry_mean=carry_mean, bias2=bias2, lacking_probe_bias=lacking_probe_bias)


def denoise_weight_sums(dphi: NDArray[np.floating], sigma: NDArray[np.floating],
                        valid: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Each pixel's own weight ``1 / sigma^2`` as :func:`denoise_phase` computes it (0 where
    not valid): the weight sum of an unfiltered phase (radius 0)."""
    d = np.asarray(dphi)
    d = d if d.dtype in (np.float32, np.float64) else d.astype(np.float64)
    s = np.asarray(sigma)
    s = s if s.dtype in (np.float32, np.float64) else s.astype(np.float64)
    dz, s2, inv = (np.empty(d.shape, np.float32) for _ in range(3))
    _denoise_weights(d, s, np.asarray(valid, bool), dz, s2, inv)
    return inv


def denoise_weighted(dz: NDArray[np.float32], s2: NDArray[np.float32], inv: NDArray[np.float32], *,
                     radius: int = 2, k: float = 3.0, max_radius: int = 0, target_sigma: float = 0.0,
                     reject_sigma: float = 0.0, weight_sum: NDArray[np.float32] | None = None,
                     ratio: NDArray[np.float32] | None = None, ratio_sum: NDArray[np.float32] | None = None,
                     support: NDArray[np.float32] | None = None, box_chi_z: float = 0.0,
                     plane_kink_sigma: float = 3.0, carry: NDArray[np.float32] | None = None,
                     carry_mean: NDArray[np.float32] | None = None,
                     bias2: NDArray[np.float32] | None = None,
                     lacking_probe_bias: str = "unbiased") -> NDArray[np.float32]:
    """:func:`denoise_phase` on its prepared float32 inputs (for callers that compute them on
    the fly, like the fused kernel): ``ok = valid & finite(dphi) & finite(sigma) & sigma > 0``,
    ``dz = ok ? dphi : 0``, ``s2 = float32(clip(ok ? sigma : 1, 1e-9, 1e9)) ** 2`` and
    ``inv = ok ? 1 / s2 : 0``. Returns the filtered phase, NaN where ``inv == 0``;
    ``weight_sum``, ``ratio_sum`` and ``support`` (float32, C-contiguous, optional) receive the
    sums of the weights used, of the weights times ``ratio`` and the number of pixels averaged
    (:func:`denoise_phase`). The phase and ``weight_sum`` do not depend on whether the other
    two are asked for.
    """
    if lacking_probe_bias not in LACKING_PROBE_BIAS:
        raise ValueError(f"lacking_probe_bias must be one of {', '.join(LACKING_PROBE_BIAS)}, got {lacking_probe_bias!r}")
    arrays = [np.ascontiguousarray(x, dtype=np.float32) for x in (dz, s2, inv)]
    if not arrays[0].shape == arrays[1].shape == arrays[2].shape or arrays[0].ndim != 2:
        raise ValueError("dz, s2 and inv must be 2-D arrays of the same shape")
    out = np.empty(arrays[0].shape, np.float32)
    for name, x in (("weight_sum", weight_sum), ("ratio_sum", ratio_sum), ("support", support), ("bias2", bias2)):
        if x is not None and (x.shape != out.shape or x.dtype != np.float32 or not x.flags.c_contiguous):
            raise ValueError(f"{name} must be a C-contiguous float32 array of the phase's shape")
    if (carry is None) != (carry_mean is None):
        raise ValueError("carry and carry_mean go together")
    if carry_mean is not None and (carry_mean.shape != out.shape or carry_mean.dtype != np.float32
                                   or not carry_mean.flags.c_contiguous):
        raise ValueError("carry_mean must be a C-contiguous float32 array of the phase's shape")
    full = ratio_sum is not None or support is not None
    if ratio_sum is not None and ratio is None:
        raise ValueError("ratio_sum needs ratio")
    r2 = (np.ascontiguousarray(ratio, np.float32) if ratio is not None else np.ones(out.shape, np.float32)) \
        if full else np.empty((1, 1), np.float32)
    if r2.shape != out.shape and full:
        raise ValueError(f"ratio has shape {r2.shape}, the phase {out.shape}")
    wsum = np.empty(out.shape, np.float32)
    k2 = np.float32(float(k) ** 2)
    c = np.empty((1, 1), np.float32)
    cfirst = np.empty((1, 1), np.float32)
    if carry is not None:  # carried beside the weights, over the accepted neighbours
        c = np.ascontiguousarray(carry, np.float32)
        if c.shape != out.shape:
            raise ValueError(f"carry has shape {c.shape}, the phase {out.shape}")
        cfirst = np.empty(out.shape, np.float32)
        first_pass(*arrays, int(radius), k2, out, wsum, c, cfirst)
    else:
        first_pass(*arrays, int(radius), k2, out, wsum)
    if (max_radius > radius and target_sigma > 0) or reject_sigma > 0:
        final = np.empty_like(out)
        wfinal = weight_sum if weight_sum is not None else np.empty_like(wsum)
        target_w = np.float32(1.0 / target_sigma**2) if target_sigma > 0 else np.float32(0.0)
        reject_w = np.float32(1.0 / reject_sigma**2) if reject_sigma > 0 else np.float32(0.0)
        rad = np.empty(out.shape if full else (1, 1), np.float32)
        grows = max_radius > radius and target_sigma > 0 and box_chi_z > 0
        cfinal = carry_mean if carry is not None else np.empty((1, 1), np.float32)
        s2min = band_floor(arrays[1], int(max_radius)) if grows else np.empty((1, 1), np.float32)
        _adaptive_pass(*arrays, out, wsum, int(radius), int(max(max_radius, radius)), k2, target_w, reject_w, final,
                       wfinal, rad, full, float(box_chi_z) if grows else 0.0, s2min, carry is not None, c, cfirst,
                       cfinal, np.empty((1, 1), np.float32), np.float32(float(plane_kink_sigma) ** 2),
                       bias2 if bias2 is not None else np.empty((1, 1), np.float32),
                       lacking_probe_bias == "posterior")
        out, wsum = final, wfinal
    else:
        rad = np.float32(radius)
        if weight_sum is not None:
            weight_sum[...] = wsum
        if carry is not None:
            carry_mean[...] = cfirst
        if bias2 is not None:  # the fixed window everywhere (its centroid: the lateral term's)
            bias2[...] = np.nan
    if full:
        rsum, cnt = window_sums(arrays[2], r2, rad, wsum)
        for dst, src in ((ratio_sum, rsum), (support, cnt)):
            if dst is not None:
                dst[...] = src
    return out


def first_pass(dz: NDArray[np.float32], s2: NDArray[np.float32], inv: NDArray[np.float32], radius: int,
               k2: np.float32, out: NDArray[np.float32], wout: NDArray[np.float32],
               carry: NDArray[np.float32] | None = None, carry_out: NDArray[np.float32] | None = None) -> None:
    """The fixed window's pass on prepared inputs (:func:`denoise_weighted`), into ``out`` (the
    filtered phase) and ``wout`` (its weight sums); with ``carry``, ``carry_out`` receives the
    carried map's mean over the same neighbours.

    Two passes over the ``(2 radius + 1)^2`` window. The first (``_own_side``) estimates each
    pixel's own side of any step: the weighted mean of the neighbours within ``k`` sigma of the
    pixel by the less noisy of the two, ``wrap(d_j - d_i)^2 <= 2 k2 min(s_i^2, s_j^2)`` (a noisy
    pixel beside a step does not take the precise far side its own noise cannot tell apart), with
    variance ``1 / sum w``. The second keeps the pixel itself and each neighbour that agrees with
    that estimate, ``(wrap(d_j - d_i) - off_i)^2 <= k2 (s_j^2 + var_i)``, and averages them with
    weights ``1 / s_j^2``. Against an estimate of the pixel's side rather than its single value,
    the accepted set hardly follows the pixel's own noise, so that ``1 / sum w`` stays the
    filtered variance on textured sigma too (``benchmarks/coverage_bins.py --filter-check``).

    Parameters
    ----------
    dz, s2, inv : float32 ndarray
        The prepared phase, sigma squared and weight ``1 / s2`` (0 where not valid), as
        :func:`denoise_weighted` takes them.
    radius : int
        The window's half side (px).
    k2 : float32
        The test's ``k`` squared.
    out, wout : float32 ndarray
        Receive the filtered phase (NaN where not valid) and each pixel's sum of accepted weights.
    carry, carry_out : float32 ndarray, optional
        A map to average over the same accepted neighbours, and where its mean goes.
    """
    off, var = np.empty(out.shape, np.float32), np.empty(out.shape, np.float32)
    _own_side(dz, s2, inv, int(radius), k2, off, var)
    if carry is None:
        _denoise_kernel(dz, s2, inv, off, var, int(radius), k2, out, wout)
    else:
        _denoise_kernel_carry(dz, s2, inv, off, var, carry, int(radius), k2, out, wout, carry_out)


def band_floor(s2: NDArray[np.float32], max_radius: int) -> NDArray[np.float32]:
    """The smallest ``s2`` within ``max_radius`` px (Chebyshev) of each pixel (OpenCV's ``erode``
    with a square of side ``2 max_radius + 1``; outside the image counts as no pixel): the floor of
    the ring pass's band ``k2 (s_j^2 + 1 / wfirst)`` over any box the adaptive pass tries
    (:func:`_adaptive_pass`)."""
    side = 2 * int(max_radius) + 1
    return np.ascontiguousarray(cv2.erode(np.ascontiguousarray(s2, np.float32), np.ones((side, side), np.uint8),
                                          borderType=cv2.BORDER_CONSTANT, borderValue=float(np.finfo(np.float32).max)))


def adaptive_kwargs(opts: dict | None) -> dict:
    """:func:`denoise_phase` / :func:`denoise_weighted` keywords of a ``measurement.denoise_adaptive``
    block (``enabled``, ``max_radius``, ``target_sigma_rad``, ``reject_sigma_rad``, ``box_chi_z``,
    ``plane_kink_sigma``, ``lacking_probe_bias``); ``{}`` when
    absent or disabled (the fixed window). Keys the block leaves out take their value from
    ``defaults.yaml`` (:func:`huefringe.settings.defaults`)."""
    if opts is None or opts is False:
        return {}
    o = dict(opts) if opts is not True else {}
    if not {"enabled", "max_radius", "target_sigma_rad", "reject_sigma_rad", "box_chi_z", "plane_kink_sigma",
            "lacking_probe_bias"} <= o.keys():
        o = {**defaults()["measurement"]["denoise_adaptive"], **o}  # a configured block is complete
    if not o["enabled"]:
        return {}
    return {"max_radius": int(o["max_radius"]), "target_sigma": float(o["target_sigma_rad"]),
            "reject_sigma": float(o["reject_sigma_rad"]), "box_chi_z": float(o["box_chi_z"]),
            "plane_kink_sigma": float(o["plane_kink_sigma"]), "lacking_probe_bias": str(o["lacking_probe_bias"])}
