"""2-D figures of a measurement: height map, wrapped phase, profiles, uncertainty and reliability maps."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from huefringe.io import write_figure_png

if TYPE_CHECKING:
    from matplotlib.figure import Figure


# --------------------------------------------------------------------------------------------
# 2-D figures (matplotlib)
# --------------------------------------------------------------------------------------------
def _as_map(x: ArrayLike, name: str) -> NDArray[np.float64]:
    """``x`` as a float64 2-D map, or ValueError naming it."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2:
        raise ValueError(f"{name} must be 2-D, got {a.shape}")
    return a


def _new_figure(figsize: tuple[float, float]) -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: PLC0415
    from matplotlib.figure import Figure  # noqa: PLC0415

    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save_figure(fig: Figure, out_png: str | os.PathLike[str], dpi: int) -> Path:
    return write_figure_png(fig, out_png, dpi)


def _image_extent(shape: tuple[int, ...], pitch_mm: float | None) -> tuple[float, float, float, float]:
    """imshow extent (left, right, bottom, top) with pixel centres at ``u * pitch``, rows down."""
    p = 1.0 if pitch_mm is None else float(pitch_mm)
    H, W = shape[:2]
    return (-0.5 * p, (W - 0.5) * p, (H - 0.5) * p, -0.5 * p)


def height_map_figure(
    height: ArrayLike,
    pitch_mm: float,
    out_png: str | os.PathLike[str],
    *,
    clim: tuple[float, float] | None = None,
    title: str | None = "Height map",
    cmap: str = "viridis",
    figsize: tuple[float, float] = (6.4, 4.8),
    dpi: int = 150,
) -> Path:
    """Height map as an image with axes in mm and a colour bar in mm (Fig. 10 d).

    Parameters
    ----------
    height : array_like, shape (H, W)
        Height in mm, NaN where invalid (drawn light grey).
    pitch_mm : float
        Pixel pitch; the axes show ``X = u * pitch`` and ``Y = v * pitch`` (rows downwards).
    out_png : path-like
        Output PNG.
    clim : (float, float), optional
        Colour limits in mm; default the finite range.
    title : str, optional
        Axes title.
    cmap : str, default "viridis"
    figsize : (float, float), default (6.4, 4.8)
        Inches.
    dpi : int, default 150

    Returns
    -------
    pathlib.Path
        ``out_png``.
    """
    h = _as_map(height, "height")
    if clim is None:
        finite = h[np.isfinite(h)]
        clim = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    return _map_figure(h, pitch_mm, out_png, cmap=cmap, clim=clim, title=title, label="Height (mm)",
                       figsize=figsize, dpi=dpi)


def _map_figure(values: NDArray[np.floating], pitch_mm: float, out_png: str | os.PathLike[str], *, cmap: str,
                clim: tuple[float, float], title: str | None, label: str, figsize: tuple[float, float],
                dpi: int) -> Path:
    """A map in mm axes (X = u pitch, Y = v pitch, rows downwards), NaN light grey, with a colour bar."""
    import matplotlib as mpl  # noqa: PLC0415

    fig = _new_figure(figsize)
    ax = fig.add_subplot()
    cm = mpl.colormaps[cmap].with_extremes(bad="0.85")
    im = ax.imshow(
        np.ma.masked_invalid(values), cmap=cm, vmin=clim[0], vmax=clim[1],
        extent=_image_extent(values.shape, pitch_mm), interpolation="nearest", origin="upper",
    )  # fmt: skip
    ax.set_xlabel("X (mm)")
    ax.set_ylabel("Y (mm)")
    ax.set_aspect("equal")
    if title:
        ax.set_title(title)
    fig.colorbar(im, ax=ax, label=label)
    return _save_figure(fig, out_png, dpi)


def wrapped_phase_figure(
    phase: ArrayLike,
    out_png: str | os.PathLike[str],
    *,
    pitch_mm: float | None = None,
    title: str | None = "Wrapped phase",
    figsize: tuple[float, float] = (6.4, 4.8),
    dpi: int = 150,
) -> Path:
    """Wrapped phase with the cyclic ``twilight`` colour map over [0, 2 pi) (Fig. 10 c).

    Parameters
    ----------
    phase : array_like, shape (H, W)
        Phase in radians (any range; shown modulo 2 pi), NaN where invalid.
    out_png : path-like
        Output PNG.
    pitch_mm : float, optional
        If given, axes in mm; otherwise in pixels.
    title : str, optional
    figsize : (float, float), default (6.4, 4.8)
    dpi : int, default 150

    Returns
    -------
    pathlib.Path
        ``out_png``.
    """
    import matplotlib as mpl  # noqa: PLC0415

    ph = _as_map(phase, "phase")
    two_pi = 2.0 * np.pi
    fig = _new_figure(figsize)
    ax = fig.add_subplot()
    cm = mpl.colormaps["twilight"].with_extremes(bad="0.5")
    im = ax.imshow(
        np.ma.masked_invalid(np.mod(ph, two_pi)), cmap=cm, vmin=0.0, vmax=two_pi,
        extent=_image_extent(ph.shape, pitch_mm), interpolation="nearest", origin="upper",
    )  # fmt: skip
    unit = "mm" if pitch_mm is not None else "px"
    ax.set_xlabel(f"X ({unit})" if pitch_mm is not None else "u (px)")
    ax.set_ylabel(f"Y ({unit})" if pitch_mm is not None else "v (px)")
    ax.set_aspect("equal")
    if title:
        ax.set_title(title)
    cbar = fig.colorbar(im, ax=ax, label="Wrapped phase (rad)")
    cbar.set_ticks([0.0, np.pi / 2, np.pi, 1.5 * np.pi, two_pi], labels=["0", "π/2", "π", "3π/2", "2π"])
    return _save_figure(fig, out_png, dpi)


def profile_figure(
    height: ArrayLike,
    row: int,
    pitch_mm: float,
    out_png: str | os.PathLike[str],
    *,
    reference: ArrayLike | None = None,
    reference_label: str = "reference",
    title: str | None = None,
    ylim: tuple[float, float] | None = None,
    figsize: tuple[float, float] = (6.4, 3.6),
    dpi: int = 150,
) -> Path:
    """Cross-section of a height map along one image row (Fig. 9 d).

    Parameters
    ----------
    height : array_like, shape (H, W)
        Height in mm, NaN where invalid (gaps in the line).
    row : int
        Image row ``v`` (``Y = row * pitch``); negative values count from the end.
    pitch_mm : float
        Pixel pitch; the abscissa is ``X = u * pitch`` in mm.
    out_png : path-like
        Output PNG.
    reference : array_like, shape (W,), optional
        A profile to overlay (e.g. the nominal or a ground-truth profile), dashed.
    reference_label : str, default "reference"
    title : str, optional
        Default ``"Profile"``; the row is always added (``"...\\nat image row v = 247 px
        (Y = 49.40 mm)"``) and also named on the X axis, so the figure says which row it cuts.
    ylim : (float, float), optional
        Height axis limits in mm.
    figsize : (float, float), default (6.4, 3.6)
    dpi : int, default 150

    Returns
    -------
    pathlib.Path
        ``out_png``.
    """
    h = _as_map(height, "height")
    H, W = h.shape
    if not -H <= row < H:
        raise IndexError(f"row {row} outside 0..{H - 1}")
    row = row % H
    x = np.arange(W) * float(pitch_mm)
    fig = _new_figure(figsize)
    ax = fig.add_subplot()
    ax.plot(x, h[row], lw=1.2, color="C0", label="measured")
    if reference is not None:
        ref = np.asarray(reference, dtype=np.float64)
        if ref.shape != (W,):
            raise ValueError(f"reference must have shape ({W},), got {ref.shape}")
        ax.plot(x, ref, lw=1.0, ls="--", color="C3", label=reference_label)
        ax.legend(loc="best")
    where = f"row v = {row} px (Y = {row * float(pitch_mm):.2f} mm)"
    ax.set_xlabel(f"X = u · pitch (mm), along image {where}")
    ax.set_ylabel("Height (mm)")
    ax.set_xlim(x[0], x[-1] if W > 1 else x[0] + 1.0)
    if ylim is not None:
        ax.set_ylim(*ylim)
    ax.grid(True, alpha=0.3)
    ax.set_title(f"Profile at image {where}" if title is None else f"{title}\nat image {where}", fontsize=10)
    return _save_figure(fig, out_png, dpi)


def uncertainty_map_figure(
    u: ArrayLike,
    pitch_mm: float,
    out_png: str | os.PathLike[str],
    *,
    title: str | None = "Height uncertainty",
    clim: tuple[float, float] | None = None,
    dpi: int = 150,
) -> Path:
    """Standard-uncertainty map (mm) beside the height figure: same axes, colour bar in µm.

    ``clim`` defaults to [0, 99th percentile] so a few edge pixels do not wash the map out;
    NaN (no height) is drawn light grey.
    """
    s = _as_map(u, "uncertainty") * 1000.0
    finite = s[np.isfinite(s)]
    if clim is None:
        clim = (0.0, float(np.percentile(finite, 99)) if finite.size else 1.0)
    else:
        clim = (clim[0] * 1000.0, clim[1] * 1000.0)
    return _map_figure(s, pitch_mm, out_png, cmap="magma", clim=clim, title=title, label="u (µm)",
                       figsize=(6.4, 4.8), dpi=dpi)


def reliability_figure(rel: Mapping[str, Any], out_png: str | os.PathLike[str], *, title: str | None = None,
                       dpi: int = 150) -> Path:
    """Reliability plot of a predicted uncertainty: observed rms error against predicted rms u per
    bin of u (:func:`huefringe.uncertainty.reliability`), with the line of perfect calibration."""
    bins = rel.get("bins", [])
    fig = _new_figure((5.2, 4.4))
    ax = fig.add_subplot()
    if bins:
        x = np.array([b["u_mm"] for b in bins]) * 1000
        y = np.array([b["observed_rms_mm"] for b in bins]) * 1000
        lo, hi = float(min(x.min(), y.min())) * 0.8, float(max(x.max(), y.max())) * 1.25
        ax.plot([lo, hi], [lo, hi], color="0.5", lw=1, label="observed = predicted")
        ax.plot(x, y, "o-", label="rms |error| per bin of u")
        if all("observed_p68_mm" in b for b in bins):
            ax.plot(x, np.array([b["observed_p68_mm"] for b in bins]) * 1000, "s--",
                    label="68th percentile of |error| (robust 1 sigma)")
        ax.set_xscale("log")
        ax.set_yscale("log")
    cov = rel.get("coverage_2u")
    ax.set_xlabel("predicted u (µm, rms in bin)")
    ax.set_ylabel("observed |error| in bin (µm)")
    ax.legend(title=None if cov is None else f"|error| ≤ 2u: {100 * cov:.1f} % of pixels", fontsize=8)
    if title:
        ax.set_title(title, fontsize=9)
    return _save_figure(fig, out_png, dpi)
