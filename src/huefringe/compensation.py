"""The compensation loop of paper Fig. 6 and the calibration QA (Fig. 7), built on hue tables.

:func:`compensate_pattern` pre-distorts the projected pattern with the median plate transfer
function (captured hue vs code phase, :func:`plate_transfer` of the plate's
:class:`~huefringe.huetable.HueTable`) so that the hue captured on the plate becomes linear;
:func:`predistortion` is the emitted-versus-code phase curve it applies. :func:`projector_gamma`
reads the projector's per-channel response off the same transfer function (each hue band has one
channel on a ramp) and :func:`linearised_levels` inverts it, for grey phase-shift sinusoids whose
captured intensity is a sinusoid again. :func:`qa_stats`,
:func:`hue_cross_section_figure` and :func:`residual_map_figure` are the QA of a calibrated
reference plane.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import colour
from .huetable import RAD_PER_COUNT, HueTable
from .io import write_figure_png
from .patterns import RAMP_SEXTANTS, TWO_PI, projector_image, trapezoid_rgb

__all__ = [
    "GammaFit",
    "GammaFitError",
    "compensate_pattern",
    "emitted_columns",
    "linearised_levels",
    "projector_gamma",
    "hue_cross_section_figure",
    "plate_transfer",
    "predistortion",
    "qa_stats",
    "residual_map_figure",
]


def plate_transfer(table: HueTable) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Median plate transfer function: captured hue vs projected code phase.

    Returns
    -------
    code : ndarray, shape (N,)
        Band code phases ``2 pi i / N``.
    distortion : ndarray, shape (N,)
        ``median over valid pixels of wrap(T_i - c_i)`` in [-pi, pi): the captured hue of code
        ``c`` is ``c + distortion(c)``. Computed band by band (one contiguous plane at a time).
    """
    n = table.n_bands
    if not np.any(table.valid):
        raise ValueError("the table has no valid pixel")
    code = TWO_PI * np.arange(n) / n
    dist = np.empty(n)
    for i in range(n):
        x = table.table[i][table.valid].astype(np.float64) * RAD_PER_COUNT
        dist[i] = np.median(colour.wrap_pi(x - code[i]))
    # unwrap so that the curve is continuous (medians are taken per band)
    return code, np.unwrap(dist)


def _periodic_interp(x: NDArray[np.float64], xp: NDArray[np.float64], fp: NDArray[np.float64]) -> NDArray[np.float64]:
    """Linear interpolation of a 2 pi periodic function (defined modulo 2 pi) sampled at ``xp``.

    The closing sample at ``xp[0] + 2 pi`` continues ``fp[-1]`` by the wrapped difference, so a
    curve whose unwrapped samples end one turn away from where they start stays continuous.
    """
    close = fp[-1] + colour.wrap_pi(fp[0] - fp[-1])
    return np.interp(np.mod(x, TWO_PI), np.concatenate([xp, [xp[0] + TWO_PI]]), np.concatenate([fp, [close]]))


def predistortion(
    code: NDArray[np.float64],
    distortion: NDArray[np.float64],
    *,
    threshold_rad: float = 2e-3,
    max_iter: int = 50,
    gain: float = 0.8,
    n_grid: int = 4096,
) -> tuple[NDArray[np.float64], NDArray[np.float64], list[dict[str, float]]]:
    """Iterate a pre-distortion ``p(c)`` so that the transfer function maps ``p(c)`` to ``c``.

    The predicted captured hue of emitting code ``p`` is ``F(p) = p + distortion(p)`` (periodic
    linear interpolation of the plate transfer). Starting from ``p = c``, each iteration computes
    the residual ``e = wrap(F(p(c)) - c)`` and updates ``p <- p - gain * e / F'(p)``: a damped
    Newton step, ``F'`` the secant slope over +-2 bands clamped to [0.2, 5] (so the flat
    stretches that gamma leaves in the transfer function neither stall the loop nor make it
    overshoot). ``gain = 1`` is a full Newton step. It stops when ``std(e) < threshold_rad`` or
    after ``max_iter`` updates.

    Returns
    -------
    c : ndarray, shape (n_grid,)
        Code phase grid ``2 pi k / n_grid``.
    p : ndarray, shape (n_grid,)
        Code phase to emit for each ``c`` (``p - c`` is periodic).
    history : list of dict
        ``{"iteration", "std_rad", "max_rad"}`` per evaluated iterate, iteration 0 = no
        compensation.
    """
    if not 0.0 < gain <= 1.5:
        raise ValueError("gain must be in (0, 1.5]")
    code = np.asarray(code, dtype=np.float64)
    dist = np.asarray(distortion, dtype=np.float64)
    c = TWO_PI * np.arange(n_grid) / n_grid
    p = c.copy()
    eps = 2.0 * TWO_PI / len(code)  # slope over +-2 bands: blind to flat steps of the table

    def transfer(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return x + _periodic_interp(x, code, dist)

    history: list[dict[str, float]] = []
    for it in range(max_iter + 1):
        e = colour.wrap_pi(transfer(p) - c)
        history.append({"iteration": it, "std_rad": float(np.std(e)), "max_rad": float(np.max(np.abs(e)))})
        if history[-1]["std_rad"] < threshold_rad or it == max_iter:
            break
        slope = (transfer(p + eps) - transfer(p - eps)) / (2 * eps)
        p = p - gain * e / np.clip(slope, 0.2, 5.0)
    return c, p, history


def emitted_columns(code: NDArray[np.float64], emitted: NDArray[np.float64], width: int,
                    period_px_projector: float) -> NDArray[np.float64]:
    """Phase to emit at each projector column ``x`` of a pre-distorted trapezoid: ``p(2 pi x / T)``.

    ``code``, ``emitted`` are the curve of :func:`predistortion` (``p - c`` periodic, interpolated
    linearly between its samples, as :meth:`huefringe.session.Predistortion.decode` inverts it).
    """
    phase_x = TWO_PI * np.arange(width) / float(period_px_projector)
    return phase_x + _periodic_interp(phase_x, np.asarray(code, np.float64),
                                      np.asarray(emitted, np.float64) - np.asarray(code, np.float64))


def compensate_pattern(
    table: HueTable,
    *,
    period_px_projector: float,
    projector_size: tuple[int, int] = (1024, 768),
    threshold_rad: float = 2e-3,
    max_iter: int = 50,
    gain: float = 0.8,
    bit_depth: int = 8,
) -> tuple[NDArray[np.uint8] | NDArray[np.uint16], list[dict[str, float]]]:
    """Pre-distorted trapezoidal projector pattern that makes the plate's captured hue linear.

    Parameters
    ----------
    table : HueTable
        Table of the plate (or the surface to compensate for); its median transfer function
        (:func:`plate_transfer`) drives the loop.
    period_px_projector : float
        Fringe period ``T`` in projector pixels.
    projector_size : (int, int)
        ``(width, height)`` of the projector (paper: 1024 x 768 DMD).
    threshold_rad, max_iter, gain
        See :func:`predistortion`.
    bit_depth : {8, 16}
        Code depth of the image (``uint8`` or ``uint16``).

    Returns
    -------
    pattern : ndarray of uint8 or uint16, shape (height, width, 3)
        ``trapezoid_rgb(p(2 pi x / T))`` per column (constant along rows, :func:`emitted_columns`).
    history : list of dict
        ``{"iteration", "std_rad", "max_rad"}``: std and max of the predicted
        (captured - projected code) residual at each iteration.
    """
    width, height = projector_size
    code, dist = plate_transfer(table)
    c, p, history = predistortion(code, dist, threshold_rad=threshold_rad, max_iter=max_iter, gain=gain)
    emit = emitted_columns(c, p, width, period_px_projector)
    return projector_image(width, height, period_px_projector, phase_map=emit, bit_depth=bit_depth), history


# =============================================================================================
# The projector's per-channel response, for pre-compensated phase-shift sinusoids
# =============================================================================================
#: Eq. 3 sextant by sextant (code ``c`` in ``[k pi / 3, (k + 1) pi / 3)``): the channel on a ramp
#: (0 R, 1 G, 2 B; :data:`~huefringe.patterns.RAMP_SEXTANTS`); it rises in even sextants and falls in
#: odd ones, the other two sit at 0 and 1.
SEXTANT_CHANNEL: tuple[int, ...] = tuple(ch for ch, _ in RAMP_SEXTANTS)

#: :func:`projector_gamma` refuses fits whose RMS residual (captured hue, rad) exceeds this: the
#: per-channel power law then does not describe the projector (bench tables: 0.001-0.005 rad).
MAX_GAMMA_RESIDUAL_RAD = 0.05

#: Plausible gammas; a fit outside is refused (a broken table, not a projector).
GAMMA_RANGE = (0.3, 5.0)

#: Fewest hue bands :func:`projector_gamma` fits (nine parameters), and fewest strictly inside
#: each channel's two ramp sextants.
MIN_GAMMA_BANDS = 12
MIN_RAMP_BANDS = 2


class GammaFitError(ValueError):
    """The hue table cannot give the projector's response (the message says why)."""


@dataclass(frozen=True)
class GammaFit:
    """The projector's per-channel response fitted to a plate transfer function (:func:`projector_gamma`)."""

    gamma: NDArray[np.float64]
    """``(3,)`` exponents of the normalised response ``(g_k(v) - g_k(0)) / (g_k(1) - g_k(0)) = v ** gamma_k``
    of R, G, B (``v`` the drive level in [0, 1])."""
    boundary_hue: NDArray[np.float64]
    """``(6,)`` fitted captured (hexcone) hue at the sextant boundaries ``c = k pi / 3`` (rad)."""
    residual_rms_rad: float
    """RMS of captured hue minus the fitted model over the bands (rad)."""
    residual_max_rad: float
    """Largest absolute residual (rad)."""
    ramp_bands: tuple[int, int, int]
    """Bands strictly inside each channel's ramp sextants (R, G, B)."""
    n_bands: int
    """Hue bands fitted."""
    model: str
    """Hue model of the table (``hsi`` hues are mapped to hexcone hues exactly first)."""


def _hexcone_from(hue: NDArray[np.float64], model: str) -> NDArray[np.float64]:
    """Hexcone hue of colours whose ``model`` hue is ``hue`` (exact: both hues depend only on the
    colour's chromatic direction, which eq. 3's saturated colours sweep once)."""
    if model == "hexcone":
        return hue
    if model not in colour.HUE_MODELS:
        raise GammaFitError(f"unknown hue model {model!r}")
    grid = TWO_PI * np.arange(6 * 1024 + 1) / (6 * 1024)  # hexcone hue of trapezoid_rgb(c) is c
    other = np.unwrap(colour.hue(trapezoid_rgb(grid).astype(np.float64), model).astype(np.float64))
    other -= TWO_PI * np.floor(other[0] / TWO_PI + 0.5)  # starts at 0 (red)
    turns = np.floor(hue / TWO_PI)
    return np.interp(hue - TWO_PI * turns, other, grid) + TWO_PI * turns


def _gamma_model(params: NDArray[np.float64], code: NDArray[np.float64]) -> NDArray[np.float64]:
    """Captured hue of code ``c``: the boundary hues joined by each sextant's ramp ``v ** gamma``."""
    hb = np.append(params[:6], params[0] + TWO_PI)
    s = 3.0 * np.mod(code, TWO_PI) / np.pi
    k = np.minimum(s.astype(np.intp), 5)
    t = s - k
    rising = k % 2 == 0
    f = np.where(rising, t, 1.0 - t) ** params[6:][np.asarray(SEXTANT_CHANNEL)[k]]
    return hb[k] + (hb[k + 1] - hb[k]) * np.where(rising, f, 1.0 - f)


def projector_gamma(code: ArrayLike, hue: ArrayLike, *, model: str = "hexcone") -> GammaFit:
    """Fit the projector's per-channel gamma to a plate transfer function (captured hue vs code).

    Hue band ``i`` (code ``c_i``) holds one channel on a ramp at drive level ``v`` (``t`` or
    ``1 - t``, ``t`` the position in the sextant) while the other two sit at 0 and 1, so its
    captured hexcone hue is ``H_k + (H_{k+1} - H_k) f_ch(v)`` (``1 - f`` on falling ramps):
    ``f_ch`` the channel's normalised response ``(g(v) - g(0)) / (g(1) - g(0))``, ``H_k`` the
    captured hue of the boundary colours (primaries and secondaries). White balance, reflectance
    and projector power cancel in the ratio; the boundary hues absorb what ambient light, black
    level and camera crosstalk do to the end points. With ``f_ch(v) = v ** gamma_ch`` the nine
    parameters (six ``H_k``, three gammas; each channel ramps in two sextants) are fitted by
    least squares (:func:`scipy.optimize.least_squares`).

    Parameters
    ----------
    code : array_like, shape (N,)
        Band code phases ``2 pi i / N``.
    hue : array_like, shape (N,)
        Captured hue of each band, unwrapped along the bands (``code + distortion`` of
        :func:`plate_transfer`).
    model : {"hexcone", "hsi"}
        The hue model of ``hue``.

    Returns
    -------
    GammaFit

    Raises
    ------
    GammaFitError
        Too few bands (``N < 12``, or fewer than two inside a channel's ramps), a captured hue that does not rise
        by about one turn, a gamma outside :data:`GAMMA_RANGE`, or a residual above
        :data:`MAX_GAMMA_RESIDUAL_RAD` (the power law does not describe the projector).

    Notes
    -----
    Camera crosstalk that survives the demixing makes the captured hue a slightly non-affine
    (Moebius) function of ``f``; on the bench's crosstalk (off-diagonal 0.02-0.10) the fitted
    gammas stay within 0.03 of the truth.
    """
    c = np.asarray(code, np.float64).ravel()
    h = _hexcone_from(np.asarray(hue, np.float64).ravel(), model)
    if c.shape != h.shape or c.size < 6:
        raise GammaFitError(f"need one hue per band code (at least 6), got {c.size} codes and {h.size} hues")
    s = 3.0 * np.mod(c, TWO_PI) / np.pi
    k = np.minimum(s.astype(np.intp), 5)
    inside = (s - k) > 1e-9
    ramp = tuple(int(np.count_nonzero(inside & (np.asarray(SEXTANT_CHANNEL)[k] == ch))) for ch in range(3))
    if c.size < MIN_GAMMA_BANDS or min(ramp) < MIN_RAMP_BANDS:
        raise GammaFitError(f"{c.size} hue bands leave {ramp[0]}, {ramp[1]}, {ramp[2]} band(s) on the R, G, B "
                            f"ramps: fitting the projector's response (six boundary hues, three gammas) needs "
                            f"at least {MIN_GAMMA_BANDS} bands, {MIN_RAMP_BANDS} on each channel's ramps")
    span = (h[-1] - h[0]) * c.size / max(c.size - 1, 1)
    if not np.all(np.isfinite(h)) or abs(span - TWO_PI) > 0.5 * np.pi:
        raise GammaFitError(f"the captured hue does not wind once round the circle over the bands "
                            f"(it spans {span:.2f} rad)")
    p0 = np.concatenate([np.arange(6) * np.pi / 3.0 + (h[0] - c[0]), np.full(3, 2.2)])
    lo = np.concatenate([np.full(6, -np.inf), np.full(3, 0.1)])
    hi = np.concatenate([np.full(6, np.inf), np.full(3, 10.0)])
    from scipy.optimize import least_squares  # here, not at import: the calibration jobs load no optimiser

    fit = least_squares(lambda p: _gamma_model(p, c) - h, p0, bounds=(lo, hi), x_scale="jac")
    gamma = fit.x[6:].copy()
    res = fit.fun
    rms, mx = float(np.sqrt(np.mean(res**2))), float(np.max(np.abs(res)))
    if np.any(gamma < GAMMA_RANGE[0]) or np.any(gamma > GAMMA_RANGE[1]):
        raise GammaFitError(f"fitted gammas R, G, B = {gamma[0]:.2f}, {gamma[1]:.2f}, {gamma[2]:.2f} leave the "
                            f"plausible range {GAMMA_RANGE[0]:g}..{GAMMA_RANGE[1]:g}")
    if np.any(np.diff(np.append(fit.x[:6], fit.x[0] + TWO_PI)) < 0.2):
        raise GammaFitError("a sextant of the captured hue collapses (boundary hues less than 0.2 rad apart)")
    if rms > MAX_GAMMA_RESIDUAL_RAD:
        raise GammaFitError(f"a per-channel power law does not describe the captured hue: RMS residual "
                            f"{rms:.3f} rad (limit {MAX_GAMMA_RESIDUAL_RAD:g}, max {mx:.3f} rad)")
    return GammaFit(gamma=gamma, boundary_hue=fit.x[:6].copy(), residual_rms_rad=rms, residual_max_rad=mx,
                    ramp_bands=ramp, n_bands=int(c.size), model=model)  # type: ignore[arg-type]


def linearised_levels(level: ArrayLike, gamma: ArrayLike) -> NDArray[np.float64]:
    """Drive levels that make a projector of per-channel ``gamma`` emit ``level``: ``level ** (1 / gamma_k)``.

    Parameters
    ----------
    level : array_like
        Wanted normalised output in [0, 1] (clipped), e.g. a phase-shift sinusoid.
    gamma : array_like, shape (3,)
        R, G, B exponents (:attr:`GammaFit.gamma`).

    Returns
    -------
    ndarray, shape ``level.shape + (3,)``
        With ``g_k(v) = g_k(0) + (g_k(1) - g_k(0)) v ** gamma_k`` every channel's output is then
        affine in ``level``, so the captured intensity (any linear mix of the channels) is too.
    """
    g = np.asarray(gamma, np.float64).reshape(3)
    lv = np.clip(np.asarray(level, np.float64), 0.0, 1.0)
    return lv[..., None] ** (1.0 / g)


# =============================================================================================
# QA
# =============================================================================================
def _row_linear_fit_residual(phase: NDArray[np.floating]) -> NDArray[np.float64]:
    """Residual of a per-row straight-line fit of the unwrapped phase along x (NaN-aware)."""
    ph = np.asarray(phase, dtype=np.float64)
    res = np.full(ph.shape, np.nan)
    x = np.arange(ph.shape[1], dtype=np.float64)
    for v in range(ph.shape[0]):
        ok = np.isfinite(ph[v])
        if np.count_nonzero(ok) < 3:
            continue
        y = np.unwrap(ph[v, ok])
        a, b = np.polyfit(x[ok], y, 1)
        res[v, ok] = colour.wrap_pi(y - (a * x[ok] + b))
    return res


def _err_stats(err: NDArray[np.float64]) -> dict[str, float | None]:
    e = err[np.isfinite(err)]
    if e.size == 0:
        return {"rms_rad": None, "max_rad": None, "n": 0}
    return {"rms_rad": float(np.sqrt(np.mean(e**2))), "max_rad": float(np.max(np.abs(e))), "n": int(e.size)}


def qa_stats(
    raw_hue: NDArray[np.floating],
    corrected_phase: NDArray[np.floating],
    *,
    true_phase: NDArray[np.floating] | None = None,
    table: HueTable | None = None,
    raw_rgb: NDArray[np.floating] | None = None,
    valid: NDArray[np.bool_] | None = None,
) -> dict[str, Any]:
    """Calibration QA numbers for a plane (e.g. the flat plate of paper Fig. 7).

    Parameters
    ----------
    raw_hue : ndarray (H, W)
        Captured hue before calibration (white-balanced frame, table model).
    corrected_phase : ndarray (H, W)
        Table-corrected code phase (``HueTable.to_phase``).
    true_phase : ndarray (H, W), optional
        Known code phase. Without it, each image is compared with its own per-row straight-line
        fit of the unwrapped phase along x (``reference = "row_linear_fit"``), which measures the
        ripples (non-linearity) but not an offset.
    table : HueTable, optional
        Adds valid fraction and masked counts by reason.
    raw_rgb : ndarray (H, W, 3), optional
        White-balanced frame; adds the error of *both* hue models on this data.
    valid : ndarray of bool (H, W), optional
        Restricts all statistics (default: where the corrected phase is finite).

    Returns
    -------
    dict
        ``before`` / ``after`` ``{rms_rad, max_rad, n}``, ``improvement`` (rms ratio),
        ``reference``, ``valid_fraction``, ``masked_by_reason``, ``linearity`` (ideal-pattern
        error of both models), ``data_linearity`` and ``better_model`` when ``raw_rgb`` is given.
    """
    raw = np.asarray(raw_hue, dtype=np.float64)
    cor = np.asarray(corrected_phase, dtype=np.float64)
    sel = np.isfinite(cor) if valid is None else np.asarray(valid, dtype=bool) & np.isfinite(cor)

    def errors(x: NDArray[np.float64]) -> NDArray[np.float64]:
        x = np.where(sel, x, np.nan)
        if true_phase is not None:
            return colour.wrap_pi(x - np.asarray(true_phase, dtype=np.float64))
        return _row_linear_fit_residual(x)

    before, after = _err_stats(errors(raw)), _err_stats(errors(cor))
    out: dict[str, Any] = {
        "reference": "true_phase" if true_phase is not None else "row_linear_fit",
        "before": before,
        "after": after,
        "improvement": (before["rms_rad"] / after["rms_rad"]) if before["rms_rad"] and after["rms_rad"] else None,
        "linearity": {m: colour.hue_linearity(m) for m in colour.HUE_MODELS},
    }
    if table is not None:
        out["valid_fraction"] = float(table.stats.get("valid_fraction", np.mean(table.valid)))
        out["masked_by_reason"] = dict(table.stats.get("masked_by_reason", {}))
    else:
        out["valid_fraction"] = float(np.mean(sel))
    if raw_rgb is not None:
        dl = {m: _err_stats(errors(colour.hue(raw_rgb, m).astype(np.float64))) for m in colour.HUE_MODELS}
        out["data_linearity"] = dl
        rms = {m: dl[m]["rms_rad"] for m in dl if dl[m]["rms_rad"] is not None}
        out["better_model"] = min(rms, key=rms.get) if rms else None
    return out


def hue_cross_section_figure(
    raw_hue_row: NDArray[np.floating],
    corrected_phase_row: NDArray[np.floating],
    true_phase_row: NDArray[np.floating] | None,
    out_png: str | os.PathLike[str],
    *,
    title: str = "Hue along a row of the flat plate",
) -> Path:
    """Paper Fig. 7 (c, d): captured hue along one row before and after calibration.

    Top panel: raw captured hue (ripples) and the true code phase; bottom: the calibrated phase.
    A thin lower strip in each panel shows the wrapped error in mrad against the true phase (or,
    if ``true_phase_row`` is None, against a straight-line fit), with its RMS in the strip's
    title; the legends sit above the panels, off the data. Written atomically.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    raw = np.asarray(raw_hue_row, dtype=np.float64)
    cor = np.asarray(corrected_phase_row, dtype=np.float64)
    x = np.arange(raw.size)
    if true_phase_row is None:
        ref_raw = raw - _row_linear_fit_residual(raw[None])[0]
        ref_cor = cor - _row_linear_fit_residual(cor[None])[0]
        truth = None
    else:
        truth = np.mod(np.asarray(true_phase_row, dtype=np.float64), TWO_PI)
        ref_raw = ref_cor = truth
    fig, axes = plt.subplots(4, 1, figsize=(8, 7), sharex=True, gridspec_kw={"height_ratios": [3, 1, 3, 1]})
    for k, (y, ref, name) in enumerate(((raw, ref_raw, "(c) before calibration: captured hue"),
                                        (cor, ref_cor, "(d) after calibration: code phase"))):
        ax, axe = axes[2 * k], axes[2 * k + 1]
        if truth is not None:
            ax.plot(x, truth, color="0.6", lw=1.0, label="true code phase")
        ax.plot(x, y, ".", ms=2.5, color="C0" if k == 0 else "C2", label=name.split(": ")[1])
        ax.set_ylabel("phase (rad)")
        ax.set_ylim(-0.1, TWO_PI + 0.1)
        ax.set_title(name, fontsize=9, loc="left")
        # above the panel, right of its title: the ramps fill the whole panel, so no corner is free
        ax.legend(fontsize=7, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=2, frameon=False, borderaxespad=0.1)
        err = colour.wrap_pi(y - ref)
        axe.plot(x, 1e3 * err, lw=0.8, color="C3")
        axe.axhline(0, color="0.5", lw=0.5)
        axe.set_ylabel("error\n(mrad)", fontsize=8)
        rms = float(np.sqrt(np.nanmean(err**2))) if np.any(np.isfinite(err)) else float("nan")
        against = "true code phase" if truth is not None else "straight-line fit of the row"
        axe.set_title(f"error against the {against}: RMS {1e3 * rms:.1f} mrad", fontsize=7, loc="left")
    axes[-1].set_xlabel("image column u (px)")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    out = write_figure_png(fig, out_png, dpi=120)
    plt.close(fig)
    return out


def residual_map_figure(residual: NDArray[np.floating], out_png: str | os.PathLike[str], *,
                        title: str = "Phase residual (rad)", limit: float | None = None) -> Path:
    """Image of a residual map in rad (diverging colours, NaN grey), written atomically."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    res = np.asarray(residual, dtype=np.float64)
    if limit is None:
        fin = np.abs(res[np.isfinite(res)])
        limit = float(np.percentile(fin, 99)) if fin.size else 1.0
        limit = limit if limit > 0 else 1.0
    cmap = plt.get_cmap("RdBu_r").copy()
    cmap = cmap.with_extremes(bad="0.7")
    fig, ax = plt.subplots(figsize=(7, 5))
    im = ax.imshow(np.ma.masked_invalid(res), cmap=cmap, vmin=-limit, vmax=limit, interpolation="nearest")
    fig.colorbar(im, ax=ax, label="rad")
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    fig.tight_layout()
    out = write_figure_png(fig, out_png, dpi=110)
    plt.close(fig)
    return out

