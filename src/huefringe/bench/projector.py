"""The bench as a real rig: it shows the image files of a patterns folder and saves camera files.

``huefringe patterns`` writes the projector images of a session and ``manifest.csv`` (capture
order, ``docs/capture.md``); a technician shows each row's image and saves one camera file per
row; ``huefringe session`` assembles them. :func:`capture_patterns` is that technician and rig on
the virtual bench: it walks the manifest in order, projects each row's *file*
(:meth:`~huefringe.bench.radiometry.Pattern.image`: the file's pixels as boxes on the plate, its
codes through the bench's DMD quantisation, gamma and defocus), puts the plate at the plane or the
object at the frame's instant that the row's ``session_path`` names, and writes the camera image as
``IMG_0001.png``, ``IMG_0002.png``, ... (8 or 16 bit as ``session.bit_depth``).

Placement (:func:`image_placement`): one projector pixel is ``P / T`` mm on the reference plane
(``P`` the bench's period, ``session.period_px * pixel_pitch_mm``; ``T`` the file's period in
projector pixels), so the file's trapezoid carries the same code phase as the bench's analytic
one; the image is shifted by a whole number of periods so that the camera's field sits in its
middle, and centred along y. A patterns folder whose period disagrees with the bench's projector
pixel (``projector.pixel_mm``) by more than 1 %, or whose images do not cover what the camera
sees, is refused before anything is written.

Each capture's noise stream is the one the bench's own session gives the same ``session_path``
(:func:`~huefringe.bench.simulator.noise_rng`), so a session made this way differs from the
bench's direct session only by what was projected.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from huefringe.assemble import read_patterns
from huefringe.io import publish_dir, write_png_rgb
from huefringe.session import SessionError

from .config import validate_bench_config
from .geometry import projector_ray_x0
from .radiometry import Pattern
from .simulator import Bench, noise_rng
from .writer import run_jobs

__all__ = ["ProjectionError", "capture_patterns", "image_placement"]

#: Largest relative disagreement between the patterns' pixel size on the plate and projector.pixel_mm.
PIXEL_TOLERANCE = 0.01

_PATH = re.compile(r"^(?:(?P<part>reference|object)/(?:white|hue/band_\d{3}_r\d+)"
                   r"|reference/planes/z_(?P<z>-?\d+\.\d{3})"
                   r"|object/frames/frame_(?P<frame>\d{4})"
                   r"|object/phase_shift/frame_(?P<ps>\d{4})_s(?P<s>[0-2]))\.png$")


class ProjectionError(ValueError):
    """A patterns folder the bench cannot project: ``path`` names the file, ``problem`` says why."""

    def __init__(self, path: str | os.PathLike[str], problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


def image_placement(bench: Bench, width: int, height: int, period_px: float, *,
                    planes_mm: tuple[float, ...] = (), where: str | os.PathLike[str] = "patterns.yaml"
                    ) -> tuple[float, float]:
    """Where a ``width`` x ``height`` projector image of period ``period_px`` lands on the bench.

    Returns
    -------
    col_shift : float
        The projector column on which the code origin (``projector.x_origin_mm``) lands: a whole
        number of periods, chosen so that the columns the camera needs sit in the image's middle.
    y_centre_mm : float
        The plate ``Y`` of the image's centre row: the middle of the rows the camera needs.

    Raises
    ------
    ProjectionError
        (naming ``where``) the period puts projector pixels of another size on the plate than the
        bench's ``projector.pixel_mm``, or the image does not cover every reference-plane point the
        camera sees on the planes ``planes_mm`` and the object (defocus margin included).
    """
    rig, cfg = bench.rig, bench.cfg
    s = cfg["session"]
    scale = rig.period_mm / float(period_px)
    pitch = float(s["pixel_pitch_mm"])
    pix = rig.projector_pixel_mm
    if pix is not None and abs(scale - pix) > PIXEL_TOLERANCE * pix:
        raise ProjectionError(where, f"period_px {period_px:g} projector px spans the bench's period of {rig.period_mm:g} mm "
                                     f"(session.period_px {float(s['period_px']):g} x pixel_pitch_mm {pitch:g}), i.e. "
                                     f"{scale:.4g} mm per projector pixel, but the bench's projector pixel is {pix:g} mm "
                                     f"(projector.pixel_mm): write the patterns with --period-px {rig.period_mm / pix:g} "
                                     f"(or --camera-period-px {float(s['period_px']):g} --magnification {pix / pitch:g})")
    obj = bench.object_surface(None, fine=True).height
    amp = float(cfg["vibration"]["amplitude_mm"])
    heights = [*planes_mm, float(obj.min()) - amp, float(obj.max()) + amp]
    lo_h, hi_h = min(heights), max(heights)
    big_h = rig.projector_height_mm
    sigma = rig.defocus_sigma_mm / scale
    pad = 5.0 * sigma + 1.0  # projector px beyond the outermost ray: defocus and pixel rounding

    def span(axis: NDArray[np.float64], centre: float) -> tuple[float, float]:
        ends = projector_ray_x0(np.array([axis.min(), axis.max()])[:, None], np.array([lo_h, hi_h])[None, :],
                                centre, big_h)
        return float(ends.min()), float(ends.max())

    x_lo, x_hi = span(bench._xf, rig.projector_x_mm)
    c_lo, c_hi = (x_lo - rig.x_origin_mm) / scale - pad, (x_hi - rig.x_origin_mm) / scale + pad
    k = round((0.5 * (width - 1) - 0.5 * (c_lo + c_hi)) / period_px)
    shift = k * float(period_px)
    if c_lo + shift < -0.5 or c_hi + shift > width - 0.5:
        raise ProjectionError(where, f"the projector image is {width} px = {width * scale:.1f} mm wide on the bench's "
                                     f"plate ({scale:.4g} mm per pixel), but the camera sees reference-plane points "
                                     f"X0 from {x_lo:.1f} to {x_hi:.1f} mm on the planes and the object: at least "
                                     f"{math.ceil(c_hi - c_lo) + 1} projector columns are needed (defocus margin included)")
    y_lo, y_hi = span(bench._yf, rig.projector_y_mm)
    need = (y_hi - y_lo) / scale + 2.0 * pad + 1.0
    if need > height:
        raise ProjectionError(where, f"the projector image is {height} px = {height * scale:.1f} mm high on the bench's "
                                     f"plate, but the camera sees Y0 from {y_lo:.1f} to {y_hi:.1f} mm: at least "
                                     f"{math.ceil(need)} projector rows are needed")
    return shift, 0.5 * (y_lo + y_hi)


def _read_patterns(patterns_dir: Path) -> tuple[dict[str, Any], list[Any]]:
    """``patterns.yaml`` and the manifest's rows, read and checked as ``huefringe session`` reads
    them (:func:`huefringe.assemble.read_patterns`), plus the keys the projection needs."""
    spec, manifest = patterns_dir / "patterns.yaml", patterns_dir / "manifest.csv"
    if not patterns_dir.is_dir():
        raise ProjectionError(patterns_dir, "not a patterns folder (written by huefringe patterns)")
    for p in (spec, manifest):
        if not p.is_file():
            raise ProjectionError(p, "missing: not a patterns folder written by huefringe patterns")
    try:
        meta, rows = read_patterns(patterns_dir)
    except SessionError as exc:
        problem = exc.problems[0]
        raise ProjectionError(problem.path, problem.message) from exc
    missing = [k for k in ("width", "height", "period_px", "bit_depth") if k not in meta]
    if missing:
        raise ProjectionError(spec, f"lacks {', '.join(missing)}")
    if not rows:
        raise ProjectionError(manifest, "lists no capture")
    return meta, rows


def _read_image(path: Path, meta: dict[str, Any]) -> NDArray[np.integer]:
    if not path.is_file():
        raise ProjectionError(path, "missing: named by manifest.csv")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.ndim != 3 or raw.shape[2] != 3:
        raise ProjectionError(path, "not an RGB PNG")
    want = (int(meta["height"]), int(meta["width"]))
    dtype = np.uint8 if int(meta["bit_depth"]) == 8 else np.uint16
    if raw.shape[:2] != want or raw.dtype != dtype:
        raise ProjectionError(path, f"{raw.shape[1]} x {raw.shape[0]} px, {raw.dtype.itemsize * 8}-bit, but "
                                    f"patterns.yaml says {want[1]} x {want[0]} px, {meta['bit_depth']}-bit")
    return np.ascontiguousarray(raw[..., ::-1])


def capture_patterns(config: dict[str, Any], patterns_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str],
                     *, progress: bool = False, workers: int | None = None) -> Path:
    """Show every image of a patterns folder on the bench, in manifest order, and save the camera files.

    Parameters
    ----------
    config : dict
        Bench configuration (validated here). Its scene, rig, camera, noise seed and timing are
        used; its ``session`` counts (bands, planes, frames) are not: the manifest decides.
    patterns_dir : path
        A folder written by ``huefringe patterns`` (``manifest.csv``, ``patterns.yaml``, images).
    out_dir : path
        New (or empty) folder for the camera files ``IMG_0001.png`` ... (row ``k`` -> number ``k + 1``).
    progress : bool
        Show a progress bar.
    workers : int, optional
        Threads (default: up to 2); the bytes do not depend on it.

    Returns
    -------
    Path
        ``out_dir``, ready for ``huefringe session out_dir patterns_dir spec.yaml SESSION``.

    Raises
    ------
    ProjectionError
        Before anything is written: a missing or bad patterns file (named), or patterns whose
        period or size cannot land on the bench's plate (:func:`image_placement`).
    FileExistsError
        ``out_dir`` exists and is not an empty folder.
    """
    cfg = validate_bench_config(config)
    pat, out = Path(patterns_dir), Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise FileExistsError(f"{out}: exists and is not an empty folder")
    meta, rows = _read_patterns(pat)
    bench = Bench(cfg)
    planes = tuple(float(m["z"]) for r in rows if (m := _PATH.match(r.session_path)) and m["z"] is not None)
    shift, y_centre = image_placement(bench, int(meta["width"]), int(meta["height"]), float(meta["period_px"]),
                                      planes_mm=planes, where=pat / "patterns.yaml")
    patterns: dict[str, Pattern] = {}
    for name in dict.fromkeys(r.image for r in rows):
        codes = _read_image(pat / name, meta)
        patterns[name] = Pattern.image(codes, float(meta["period_px"]), bit_depth=int(meta["bit_depth"]),
                                       col_shift=shift, y_centre_mm=y_centre)
    seed = int(cfg["session"]["seed"])
    ext = ".png" if cfg["session"]["image_format"] == "png" else ".tiff"
    digits = max(4, len(str(len(rows))))
    uniform = {"reference": bench.uniform_capturer(plane_z=0.0), "object": bench.uniform_capturer(None)}

    def shoot(pattern: Pattern, session_path: str, ph: float | None) -> Callable[[np.random.Generator], NDArray[Any]]:
        # ph: the colour-cycle start phase of a colour-sequential projector (None without one)
        m = _PATH.match(session_path)
        assert m is not None
        if m["z"] is not None:
            return lambda rng: bench.capture(pattern, plane_z=float(m["z"]), rng=rng, colour_phase=ph)
        if m["frame"] is not None:
            return lambda rng: bench.capture(pattern, t=bench.frame_time(int(m["frame"])), rng=rng, colour_phase=ph)
        if m["ps"] is not None:
            return lambda rng: bench.capture(pattern, t=bench.phase_shift_time(int(m["ps"]), int(m["s"])), rng=rng,
                                             colour_phase=ph)
        if pattern.kind == "uniform":
            return lambda rng: uniform[m["part"]](pattern, rng, ph)
        z = 0.0 if m["part"] == "reference" else None
        return lambda rng: bench.capture(pattern, plane_z=z, rng=rng, colour_phase=ph)

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent))
    try:
        jobs = []
        for row in rows:
            rel = row.session_path.removesuffix(".png") + ext  # the bench session's noise stream of this file
            make = shoot(patterns[row.image], row.session_path, bench.colour_phase(rel))
            target = tmp / f"IMG_{row.order + 1:0{digits}d}.png"

            def run(make: Callable[[np.random.Generator], NDArray[Any]] = make, rel: str = rel,
                    target: Path = target) -> None:
                write_png_rgb(target, make(noise_rng(seed, rel)))

            jobs.append((target.name, run))
        run_jobs(bench, jobs, workers, f"bench capture {pat.name}", progress)
        publish_dir(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
