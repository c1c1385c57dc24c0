"""Decoded coordinates to files: TIFF maps, a validity PNG, a quality figure and a summary.

``huefringe decode CAPTURES SEQUENCE OUT`` (:func:`decode_folder`) writes into the new folder OUT:

``coord_<axis>.tif``
    Absolute projector coordinate (float64, projector px, NaN where not valid).
``sigma_<axis>.tif``
    Its standard uncertainty from the frames' noise (float64, projector px).
``modulation_<axis>.tif``
    Fringe amplitude of the axis' finest phase block (float32, camera DN).
``valid_<axis>.png``
    255 where valid.
``reasons_<axis>.png``
    8-bit grey: per pixel the bits of the validity tests that dropped it (0 where valid;
    :class:`~huefringe.codecs.Reason`: 1 shadow, 2 low signal, 4 saturated, 8 Gray code,
    16 fringe order, 32 outside the projector; 64, the ray test after triangulation, is never
    set by ``decode``, which does not triangulate).
``quality.png``
    Coordinate, modulation and uncertainty maps side by side, one row per axis.
``decode.json``
    The sequence, the projector gamma used (and how it was found), the thresholds, and per axis
    whether it is absolute, the valid fraction, the fraction each reason dropped and the median
    uncertainty.

The folder is written beside OUT under a temporary name and renamed when complete.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from huefringe.codecs.gamma import estimate_projector_gamma
from huefringe.codecs.sequence import Decoded, DecodeOptions, Reason, SequenceError, decode_sequence, load_sequence, read_captures
from huefringe.io import publish_dir, write_figure_png, write_json, write_png_rgb, write_tiff

__all__ = ["decode_folder", "dropped_by", "quality_figure"]


def _finite(obj: Any) -> Any:
    """NaN (a method that did not apply) as JSON null."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def dropped_by(reasons: Any) -> Any:
    """Per pixel, the index in :class:`~huefringe.codecs.Reason` (1 = shadow .. 7 = ray) of the first
    test that dropped it, 0 where valid (the reasons panel of :func:`quality_figure`)."""
    r = np.asarray(reasons, dtype=np.uint8)
    out = np.zeros(r.shape, dtype=np.uint8)
    for i, reason in reversed(list(enumerate(Reason, start=1))):
        out[(r & np.uint8(reason)) != 0] = i
    return out


def quality_figure(decoded: dict[str, Decoded], title: str, max_width_px: int = 900, *, reasons: bool = False) -> Any:
    """Coordinate, modulation and uncertainty maps, one row per axis (Matplotlib figure); with
    ``reasons``, a fourth map of the first test that dropped each pixel (:func:`dropped_by`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    rows = list(decoded.items())
    h, w = rows[0][1].coord.shape
    cols = 4 if reasons else 3
    step = max(1, math.ceil(w / (max_width_px / cols)))
    fig, axes = plt.subplots(len(rows), cols, figsize=(3.5 * cols, 2.6 * len(rows) * h / w + 0.6 * len(rows)), squeeze=False)
    names = ["valid", *(r.name.lower().replace("_", " ") for r in Reason)]
    palette = ListedColormap(["#ffffff", "#303030", "#7f7f7f", "#d62728", "#ff7f0e", "#9467bd", "#1f77b4", "#2ca02c"][: len(names)])
    for r, (axis, d) in enumerate(rows):
        sl = (slice(None, None, step), slice(None, None, step))
        name = "column" if axis == "x" else "row"
        panels = [
            (d.coord[sl], "viridis", f"projector {name} {'(absolute)' if d.absolute else '(within a period)'} [px]", None),
            (d.modulation[sl], "gray", f"modulation {axis} [DN]", (0, float(np.nanpercentile(d.modulation, 99.5)))),
            (d.sigma[sl], "magma", f"u({axis}) [projector px]", (0, float(np.nanpercentile(d.sigma, 99))) if d.valid.any() else None),
        ]
        if reasons:
            panels.append((dropped_by(d.reasons)[sl] if d.reasons.size else np.zeros(d.coord[sl].shape, np.uint8),
                           palette, f"dropped {axis} by (first failed test)", (-0.5, len(names) - 0.5)))
        for c, (img, cmap, label, lim) in enumerate(panels):
            ax = axes[r, c]
            im = ax.imshow(img, cmap=cmap, vmin=None if lim is None else lim[0], vmax=None if lim is None else lim[1], interpolation="nearest")
            ax.set_title(label, fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
            cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
            cb.ax.tick_params(labelsize=7)
            if cmap is palette:
                cb.set_ticks(range(len(names)), labels=names)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def decode_folder(
    captures: str | Path,
    sequence: str | Path,
    out: str | Path,
    *,
    projector_gamma: float | None = None,
    estimate_gamma: bool = False,
    options: DecodeOptions | None = None,
) -> dict[str, Any]:
    """Decode a folder of captures described by a sequence YAML into the new folder ``out``.

    Parameters
    ----------
    captures : path
        Folder holding the captures (``frames`` glob of the sequence).
    sequence : path
        Sequence YAML (:func:`~huefringe.codecs.sequence.load_sequence`).
    out : path
        Folder to write (must not exist, or be empty).
    projector_gamma : float, optional
        Overrides the sequence's projector gamma.
    estimate_gamma : bool
        Estimate the projector gamma from the captures (Gray code, else two periods) and decode
        with it.
    options : DecodeOptions, optional
        Default: the configuration's ``codecs`` block.

    Returns
    -------
    dict
        The summary written to ``decode.json``.

    Raises
    ------
    SequenceError
        Before anything is written: the sequence, the captures or ``out`` refused.
    """
    out = Path(out)
    problems = []
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        problems.append(f"{out}: exists and is not an empty folder (nothing is overwritten)")
    if projector_gamma is not None and estimate_gamma:
        problems.append("give a projector gamma or ask for its estimate, not both")
    spec = None
    try:
        spec = load_sequence(sequence, captures)
    except SequenceError as exc:
        problems.append(str(exc))
    images = None
    if spec is not None:
        try:
            images = read_captures(captures, spec)
        except SequenceError as exc:
            problems.append(str(exc))
    if problems:
        raise SequenceError("; ".join(problems))
    assert spec is not None and images is not None
    opts = options if options is not None else DecodeOptions.from_config()
    gamma_source = "sequence"
    t0 = time.perf_counter()
    if projector_gamma is not None:
        spec = dataclasses.replace(spec, projector_gamma=float(projector_gamma))
        gamma_source = "command line"
    estimate = None
    if estimate_gamma:
        first = decode_sequence(images, spec, opts)
        mask = np.logical_and.reduce([d.valid for d in first.values()])
        estimate = estimate_projector_gamma(images, spec, mask)
        g = estimate.gray if np.isfinite(estimate.gray) else estimate.periods
        if not np.isfinite(g):
            raise SequenceError(f"{sequence}: the projector gamma cannot be estimated (no fine Gray code, no two periods on one axis)")
        spec = dataclasses.replace(spec, projector_gamma=float(g))
        gamma_source = "estimated from the Gray code" if np.isfinite(estimate.gray) else "estimated from two periods"
    decoded = decode_sequence(images, spec, opts)
    seconds = time.perf_counter() - t0
    summary: dict[str, Any] = {
        "captures": str(Path(captures)),
        "sequence": str(Path(sequence)),
        "frames": spec.n_frames,
        "camera_shape": list(images[0].shape),
        "projector": {"width": spec.projector_width, "height": spec.projector_height, "gamma": spec.projector_gamma,
                      "gamma_source": gamma_source},
        "gamma_estimate": None if estimate is None else _finite(dataclasses.asdict(estimate)),
        "decode_seconds": round(seconds, 3),
        "thresholds": dataclasses.asdict(opts),
        "axes": {
            a: {
                "absolute": d.absolute,
                "valid_fraction": float(d.valid.mean()),
                "dropped_fraction": {r.name.lower(): float(((d.reasons & r) != 0).mean()) for r in Reason if r is not Reason.RAY},
                "median_sigma_px": float(np.nanmedian(d.sigma)) if d.valid.any() else None,
            }
            for a, d in decoded.items()
        },
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        for a, d in decoded.items():
            write_tiff(tmp / f"coord_{a}.tif", d.coord)
            write_tiff(tmp / f"sigma_{a}.tif", d.sigma)
            write_tiff(tmp / f"modulation_{a}.tif", d.modulation)
            write_png_rgb(tmp / f"valid_{a}.png", d.valid.astype(np.uint8) * 255)
            write_png_rgb(tmp / f"reasons_{a}.png", d.reasons.astype(np.uint8))
        fig = quality_figure(decoded, f"{Path(captures).name}: {spec.n_frames} frames, projector gamma {spec.projector_gamma:.3f}")
        write_figure_png(fig, tmp / "quality.png", dpi=90)
        import matplotlib.pyplot as plt

        plt.close(fig)
        write_json(tmp / "decode.json", summary)
        publish_dir(tmp, out)
    except BaseException:
        import shutil

        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return summary
