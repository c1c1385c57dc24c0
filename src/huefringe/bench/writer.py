"""Write a complete capture session (``capture-session/1``) from a bench configuration.

The session is assembled in a hidden temporary folder beside the target, every file written
atomically (:mod:`huefringe.io`), ``session.yaml`` last; only then is the folder moved into
place. A killed run therefore never leaves a valid-looking half session.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
import yaml
from numpy.typing import NDArray
from scipy.ndimage import binary_dilation
from tqdm.auto import tqdm

from huefringe.io import atomic_path, write_json, write_png_rgb, write_tiff
from huefringe.session import format_predistortion

from .config import sweep_config, validate_bench_config
from .geometry import analytic_phase_difference, triangulation_angle_deg
from .radiometry import Pattern
from .scenes import base_rect, gauge_blocks
from .simulator import Bench, noise_rng

__all__ = ["period_sweep", "rig_summary", "session_document", "specimen_document", "write_session"]

Job = tuple[str, Callable[[], None]]


# ------------------------------------------------------------------------------ session.yaml
def specimen_document(cfg: dict[str, Any], bench: Bench | None = None) -> dict[str, Any] | None:
    """The ``specimen`` entry of session.yaml for a gauge-block scene (None otherwise).

    Step ROIs are the block tops inset by ``specimen.margin_px`` (plus the lateral vibration
    amplitude); base ROIs are strips of the base above and below the blocks, clear of blocks,
    cast shadows and the base's border by the same margin.
    """
    if cfg["scene"]["kind"] != "gauge_blocks":
        return None
    bench = bench if bench is not None else Bench(cfg)
    s = cfg["session"]
    pitch = float(s["pixel_pitch_mm"])
    w, h = int(s["width"]), int(s["height"])
    m = int(cfg["specimen"]["margin_px"]) + int(np.ceil(float(cfg["vibration"]["lateral_amplitude_mm"]) / pitch))

    def box(rect: Sequence[float]) -> tuple[int, int, int, int]:
        x0, y0, x1, y1 = rect  # pixel centres u * pitch in [x0, x1)
        u0, v0 = max(int(np.ceil(x0 / pitch - 1e-9)), 0), max(int(np.ceil(y0 / pitch - 1e-9)), 0)
        u1, v1 = min(int(np.ceil(x1 / pitch - 1e-9)), w), min(int(np.ceil(y1 / pitch - 1e-9)), h)
        return u0, v0, u1, v1

    surf = bench.object_surface(None)
    light = bench.lighting(surf)
    blocks = gauge_blocks(cfg)
    if bench.lens is not None:
        # the boxes as the image shows them: where the pixels' rays meet the block tops and base
        _, xy = bench.view_truth(None)

        def box(rect: Sequence[float]) -> tuple[int, int, int, int]:  # noqa: F811 - the lens's boxes
            return _inscribed_box(_seen_inside(xy, rect))

        shadow = bench.to_camera(np.repeat(light.shadow[..., None].astype(np.float32), 3, axis=2), surf)[..., 1] > 0.0
        blocked = np.zeros((h, w), bool)
        for b in blocks:
            blocked |= _seen_inside(xy, b.rect_mm)
    else:
        shadow = bench.grid.downsample(light.shadow.astype(np.float32)) > 0.0
        blocked = np.zeros((h, w), bool)
        for b in blocks:
            u0, v0, u1, v1 = box(b.rect_mm)
            blocked[v0:v1, u0:u1] = True
    struct = np.ones((2 * m + 1, 2 * m + 1), bool) if m > 0 else np.ones((1, 1), bool)
    bad_shadow = binary_dilation(shadow, struct)
    bad_base = binary_dilation(blocked, struct) | bad_shadow

    def free_runs(u0: int, v0: int, u1: int, v1: int, bad: NDArray[np.bool_]) -> list[list[int]]:
        if u1 - u0 < 3 or v1 - v0 < 3:
            return []
        ok = ~bad[v0:v1, u0:u1].any(axis=0)
        runs, start = [], None
        for i, good in enumerate(np.append(ok, False)):
            if good and start is None:
                start = i
            elif not good and start is not None:
                if i - start >= 3:
                    runs.append([u0 + start, v0, u0 + i, v1])
                start = None
        return runs

    steps = []
    for b in blocks:
        u0, v0, u1, v1 = box(b.rect_mm)
        runs = free_runs(u0 + m, v0 + m, u1 - m, v1 - m, bad_shadow)
        if not runs:
            raise ValueError(f"gauge block {b.name!r}: no shadow-free region of at least 3x3 pixels inside its top")
        roi = max(runs, key=lambda r: r[2] - r[0])
        steps.append({"name": b.name, "nominal_mm": float(b.nominal_mm), "roi": roi})
    bu0, bv0, bu1, bv1 = box(base_rect(cfg))
    top = min(box(b.rect_mm)[1] for b in blocks)
    bottom = max(box(b.rect_mm)[3] for b in blocks)
    base_rois = free_runs(bu0 + m, bv0 + m, bu1 - m, top - m, bad_base)
    base_rois += free_runs(bu0 + m, bottom + m, bu1 - m, bv1 - m, bad_base)
    if not base_rois:
        raise ValueError("gauge-block scene: no free strip of the base above or below the blocks for base_roi")
    return {
        "kind": "step_heights",
        "base_roi": base_rois,
        "steps": steps,
        "tolerance_mm": float(cfg["specimen"]["tolerance_mm"]),
    }


def _seen_inside(xy: NDArray[np.float32], rect: Sequence[float]) -> NDArray[np.bool_]:
    """Pixels whose centres see a plate point inside ``rect`` = ``[x0, y0, x1, y1)`` (mm)."""
    x, y = xy[..., 0], xy[..., 1]
    with np.errstate(invalid="ignore"):
        return (x >= rect[0]) & (x < rect[2]) & (y >= rect[1]) & (y < rect[3])


def _inscribed_box(mask: NDArray[np.bool_]) -> tuple[int, int, int, int]:
    """An axis-aligned box ``(u0, v0, u1, v1)`` inside a convex-ish mask (a lens's image of a
    rectangle): the rows that are at least half full, clipped to the columns all of them hold,
    then the rows all of those columns hold."""
    rows = mask.sum(axis=1)
    if not rows.any():
        return 0, 0, 0, 0
    vs = np.flatnonzero(rows >= 0.5 * rows.max())
    sub = mask[vs]
    first = np.argmax(sub, axis=1)
    last = sub.shape[1] - np.argmax(sub[:, ::-1], axis=1)
    u0, u1 = int(first.max()), int(last.min())
    if u1 <= u0:
        return 0, 0, 0, 0
    cols = mask[:, u0:u1]
    top = np.argmax(cols, axis=0)
    bottom = cols.shape[0] - np.argmax(cols[::-1], axis=0)
    return u0, int(top.max()), u1, int(bottom.min())


def session_document(cfg: dict[str, Any], bench: Bench | None = None) -> dict[str, Any]:
    """The content of ``session.yaml`` for a configuration, keys in the spec's order."""
    s = cfg["session"]
    period = float(s["period_px"])
    doc: dict[str, Any] = {
        "format": "capture-session/1",
        "id": s["id"],
        "camera": {
            "width": int(s["width"]),
            "height": int(s["height"]),
            "bit_depth": int(s["bit_depth"]),
            "pixel_pitch_mm": float(s["pixel_pitch_mm"]),
        },
        "pattern": {
            "period_px": int(period) if period.is_integer() else period,
            "hue_bands": int(s["hue_bands"]),
            "repeats": int(s["repeats"]),
        },
        "planes_mm": [float(z) for z in s["planes_mm"]],
    }
    sensor = cfg.get("camera", {}).get("sensor") or {}
    if sensor.get("kind") == "bayer":  # what the images were demosaiced from (docs/design.md, the camera block)
        doc["camera"]["bayer"] = str(sensor.get("pattern", "RGGB"))
    bench = bench if bench is not None else Bench(cfg)
    if bench.lens is not None:  # the lens model as a lab's checkerboard calibration gives it
        doc["camera"].update(bench.lens.session_camera())
    spec = specimen_document(cfg, bench)
    if spec is not None:
        doc["specimen"] = spec
    doc["provenance"] = provenance_document(cfg)
    return doc


def provenance_document(cfg: dict[str, Any]) -> dict[str, Any]:
    """The ``provenance`` entry of session.yaml: always ``simulated: true``.

    ``captured_at`` and ``operator`` are written only when the bench configuration's ``session``
    gives them; by default there is no capture date, so one configuration always writes the
    same bytes (the virtual bench has no moment of capture worth recording).
    """
    from huefringe import __version__

    s = cfg["session"]
    out: dict[str, Any] = {}
    if s.get("captured_at"):
        out["captured_at"] = str(s["captured_at"])
    if s.get("operator"):
        out["operator"] = str(s["operator"])
    proj, cam = cfg.get("projector", {}), cfg.get("camera", {})
    sensor = cam.get("sensor") or {}
    kind = "colour camera"
    if sensor.get("kind") == "bayer":
        kind = f"single-chip {sensor.get('pattern', 'RGGB')} Bayer colour camera, {sensor.get('demosaic', 'edge_aware')} demosaic"
    if cam.get("model") == "pinhole":
        kind += f", pinhole lens at {float(cam['working_distance_mm']):g} mm"
    out["instrument"] = (f"huefringe virtual bench {__version__} (simulated {proj.get('dmd_bits', 8)}-bit projector, "
                         f"{int(s['width'])}x{int(s['height'])} {int(s['bit_depth'])}-bit {kind})")
    out["simulated"] = True
    out["notes"] = "written by huefringe.bench from a bench configuration (virtual rig, no physical capture)"
    return out


class _FlowListDumper(yaml.SafeDumper):
    """Block-style mappings, flow-style lists of scalars (``roi: [u0, v0, u1, v1]``)."""


def _repr_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    flow = all(not isinstance(v, (dict, list)) for v in data) or all(
        isinstance(v, list) and all(not isinstance(x, (dict, list)) for x in v) for v in data
    )
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_FlowListDumper.add_representer(list, _repr_list)


def dump_session_yaml(doc: dict[str, Any]) -> str:
    """YAML text of a session document (stable key order, flow-style coordinate lists)."""
    return yaml.dump(doc, Dumper=_FlowListDumper, sort_keys=False, default_flow_style=False, width=120)


# ------------------------------------------------------------------------------ summary
def rig_summary(cfg: dict[str, Any], bench: Bench | None = None) -> dict[str, Any]:
    """Derived geometry of a configuration (for the report and the sanity checks).

    Returns the projector pose, triangulation angles across the field, the fringe period, the
    largest ``|dphi|`` of the scene at rest plus the vibration amplitude and of the highest plane.
    """
    bench = bench if bench is not None else Bench(cfg)
    rig = bench.rig
    s = cfg["session"]
    pitch = float(s["pixel_pitch_mm"])
    xs = np.arange(int(s["width"])) * pitch
    kw = {"projector_x_mm": rig.projector_x_mm, "projector_height_mm": rig.projector_height_mm, "period_mm": rig.period_mm}
    smp, _ = bench._object(None, fine=False)
    amp = float(cfg["vibration"]["amplitude_mm"])
    h_obj = np.where(smp.mask, smp.height + amp, 0.0)
    x2d = np.broadcast_to(xs, h_obj.shape)
    dphi_obj = float(np.abs(analytic_phase_difference(x2d, h_obj, **kw)).max())
    ztop = float(max(s["planes_mm"]))
    dphi_plane = float(np.abs(analytic_phase_difference(xs, np.full_like(xs, ztop), **kw)).max())
    ang = triangulation_angle_deg(xs, rig.projector_x_mm, rig.projector_height_mm)
    return {
        "projector_height_mm": rig.projector_height_mm,
        "projector_x_mm": rig.projector_x_mm,
        "triangulation_angle_deg": {
            "centre": float(triangulation_angle_deg(xs.mean(), rig.projector_x_mm, rig.projector_height_mm)),
            "min": float(ang.min()),
            "max": float(ang.max()),
        },
        "period_mm": rig.period_mm,
        "max_object_height_mm": float(h_obj.max()),
        "max_abs_dphi_object_rad": dphi_obj,
        "max_abs_dphi_object_over_pi": dphi_obj / np.pi,
        "max_abs_dphi_top_plane_rad": dphi_plane,
    }


# ------------------------------------------------------------------------------ writing
def _image_writer(fmt: str) -> tuple[str, Callable[[Path, NDArray[Any]], None]]:
    if fmt == "png":
        return ".png", write_png_rgb
    return ".tiff", write_tiff


def plate_predistortion(cfg: dict[str, Any], bench: Bench) -> tuple[NDArray[np.float64], NDArray[np.float64], list[dict[str, float]]]:
    """The pre-distortion an operator computes from the plate's hue bands (paper Fig. 6).

    The plate's median transfer function (captured hue of each uniform band, white-balanced,
    against its code phase) comes from noiseless captures of the bands: the median over every
    pixel of the plate removes the noise of real captures just as well. The loop itself is the
    measuring side's :func:`huefringe.compensation.predistortion`.

    Returns
    -------
    code, emitted : ndarray
        ``samples`` code phases ``2 pi k / M`` and the phase ``p(code)`` to emit for each.
    history : list of dict
        The loop's residual per iteration.
    """
    from huefringe import colour
    from huefringe.compensation import predistortion

    comp = cfg["projector"]["compensation"]
    n = int(cfg["session"]["hue_bands"])
    cap = bench.uniform_capturer(plane_z=0.0)
    scale = float((1 << int(cfg["session"]["bit_depth"])) - 1)
    # a colour-sequential projector: one start phase for all of them (a pre-distortion from bands of
    # different colour balances need not be invertible; the session's own bands carry the effect)
    phase = bench.colour_phase("predistortion")
    white = cap(Pattern.white(), None, phase).astype(np.float32) / np.float32(scale)
    code = 2.0 * np.pi * np.arange(n) / n
    dist = np.empty(n)
    for i in range(n):
        rgb = cap(Pattern.hue_band(i, n), None, phase).astype(np.float32) / np.float32(scale)
        h = colour.hue(colour.white_balance(rgb, white), "hexcone")
        dist[i] = np.nanmedian(colour.wrap_pi(h - code[i]))
    c, p, history = predistortion(code, np.unwrap(dist), threshold_rad=float(comp["threshold_rad"]),
                                  max_iter=int(comp["max_iter"]), gain=float(comp["gain"]))
    m = int(comp["samples"])
    cs = 2.0 * np.pi * np.arange(m) / m
    offset = np.interp(cs, np.append(c, 2.0 * np.pi), np.append(p - c, (p - c)[0]))
    return cs, cs + offset, history


def _jobs(cfg: dict[str, Any], bench: Bench, root: Path) -> list[Job]:
    """Every file of the session (except session.yaml) as (relative name, writer) pairs."""
    s = cfg["session"]
    ext, write_img = _image_writer(s["image_format"])
    seed = int(s["seed"])
    n_bands, repeats, frames = int(s["hue_bands"]), int(s["repeats"]), int(s["frames"])
    jobs: list[Job] = []

    def add_image(rel: str, make: Callable[[np.random.Generator, float | None], NDArray[Any]]) -> None:
        # make(noise generator, colour-cycle start phase: None without a colour-sequential projector)
        def run() -> None:
            write_img(root / rel, make(noise_rng(seed, rel), bench.colour_phase(rel)))

        jobs.append((rel, run))

    trapezoid = Pattern.trapezoid()
    if cfg["projector"]["compensation"]["enabled"]:
        code, emitted, _ = plate_predistortion(cfg, bench)
        trapezoid = Pattern.trapezoid(tuple(float(v) for v in emitted - code))
        text = format_predistortion(code, emitted)

        def write_predistortion() -> None:
            with atomic_path(root / "predistortion.csv") as tmp:
                tmp.write_text(text, encoding="utf-8")

        jobs.append(("predistortion.csv", write_predistortion))

    for where in ("reference", "object"):
        capturer = bench.uniform_capturer(plane_z=0.0 if where == "reference" else None)

        def uniform(pattern: Pattern, cap: Any = capturer) -> Callable[[np.random.Generator, float | None], NDArray[Any]]:
            return lambda rng, ph: cap(pattern, rng, ph)

        add_image(f"{where}/white{ext}", uniform(Pattern.white()))
        for r in range(repeats):
            for i in range(n_bands):
                add_image(f"{where}/hue/band_{i:03d}_r{r}{ext}", uniform(Pattern.hue_band(i, n_bands)))
        if where == "reference":
            for z in s["planes_mm"]:
                add_image(
                    f"reference/planes/z_{float(z):.3f}{ext}",
                    lambda rng, ph, z=float(z): bench.capture(trapezoid, plane_z=z, rng=rng, colour_phase=ph),
                )
    for n in range(frames):
        add_image(
            f"object/frames/frame_{n:04d}{ext}",
            lambda rng, ph, n=n: bench.capture(trapezoid, t=bench.frame_time(n), rng=rng, colour_phase=ph),
        )
    if cfg["phase_shift"]["enabled"]:
        for n in range(frames):
            for sidx in range(3):
                add_image(
                    f"object/phase_shift/frame_{n:04d}_s{sidx}{ext}",
                    lambda rng, ph, n=n, sidx=sidx: bench.capture(
                        Pattern.phase_shift(sidx), t=bench.phase_shift_time(n, sidx), rng=rng, colour_phase=ph
                    ),
                )
    if s["ground_truth"]:
        for n in range(frames):
            rel = f"ground_truth/frames/frame_{n:04d}.tiff"
            if bench.lens is None:
                jobs.append((rel, lambda rel=rel, n=n: write_tiff(root / rel, bench.ground_truth(bench.frame_time(n)))))
            else:  # with a lens also the plate X, Y each pixel sees (bench-only extension)
                def truth(rel: str = rel, n: int = n) -> None:
                    h, xy = bench.view_truth(bench.frame_time(n))
                    write_tiff(root / rel, h)
                    with atomic_path(root / f"ground_truth/xy/frame_{n:04d}.tiff") as tmp:
                        tifffile.imwrite(tmp, xy, photometric="minisblack", planarconfig="contig", software=False)

                jobs.append((rel, truth))

        def write_provenance() -> None:
            motion = [dict(zip(("dx_mm", "dz_mm"), bench.motion(bench.frame_time(n)), strict=True)) for n in range(frames)]
            write_json(
                root / "ground_truth/bench.json",
                {"bench_config": cfg, "summary": rig_summary(cfg, bench), "frame_motion": motion},
            )

        jobs.append(("ground_truth/bench.json", write_provenance))
    return jobs


def _prepare_target(out_dir: Path) -> None:
    if out_dir.exists():
        if not out_dir.is_dir():
            raise FileExistsError(f"{out_dir}: exists and is not a folder")
        if any(out_dir.iterdir()) and not (out_dir / "session.yaml").is_file():
            raise FileExistsError(f"{out_dir}: not empty and not a capture session; refusing to replace it")


def write_session(
    config: dict[str, Any], out_dir: str | os.PathLike[str], progress: bool = False, workers: int | None = None
) -> Path:
    """Simulate and write a complete capture session.

    Parameters
    ----------
    config : dict
        Bench configuration (validated here again, so a hand-built dict works too).
    out_dir : path
        The session folder to create. An existing session there (a folder with a session.yaml,
        or an empty folder) is replaced once the new one is complete; anything else is refused.
    progress : bool
        Show a tqdm progress bar.
    workers : int, optional
        Threads simulating and encoding images (default: up to 2). Every image has its own
        noise stream, so the bytes do not depend on this.

    Returns
    -------
    Path
        ``out_dir``.
    """
    cfg = validate_bench_config(config)
    out_dir = Path(out_dir)
    _prepare_target(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".partial", dir=out_dir.parent))
    try:
        bench = Bench(cfg)
        doc = session_document(cfg, bench)  # fails early on an impossible specimen layout
        jobs = _jobs(cfg, bench, tmp)
        run_jobs(bench, jobs, workers, f"bench {cfg['session']['id']}", progress)
        with atomic_path(tmp / "session.yaml") as p:
            p.write_text(dump_session_yaml(doc), encoding="utf-8")
        _swap_into_place(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out_dir


def run_jobs(bench: Bench, jobs: list[Job], workers: int | None, desc: str, progress: bool) -> None:
    """Run the capture jobs with a progress bar: serially with one worker, else on threads
    (default ``min(2, cpus)``), after warming the bench's caches that the threads share."""
    bench.object_surface(None, fine=False)  # warm the caches before the threads share them
    n_workers = max(1, int(workers if workers is not None else min(2, os.cpu_count() or 1)))
    bar = tqdm(total=len(jobs), desc=desc, unit="file", disable=not progress)
    if n_workers == 1:
        with bar:
            for _, run in jobs:
                run()
                bar.update(1)
    else:
        _run_threaded(jobs, n_workers, bar)


def _run_threaded(jobs: list[Job], n_workers: int, bar: Any) -> None:
    """Run the jobs on a thread pool (NumPy and OpenCV release the GIL)."""
    with bar, ThreadPoolExecutor(max_workers=n_workers) as pool:
            futures = [pool.submit(run) for _, run in jobs]
            try:
                for fut in as_completed(futures):
                    fut.result()
                    bar.update(1)
            except BaseException:
                for f in futures:
                    f.cancel()
                raise


def _swap_into_place(tmp: Path, out_dir: Path) -> None:
    """Move the finished folder onto ``out_dir``, replacing a previous session."""
    if out_dir.exists():
        _prepare_target(out_dir)  # re-check: it may have changed while we worked
        trash = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".old", dir=out_dir.parent))
        os.replace(out_dir, trash / "old")
        os.replace(tmp, out_dir)
        shutil.rmtree(trash, ignore_errors=True)
    else:
        os.replace(tmp, out_dir)


def period_sweep(
    config: dict[str, Any],
    periods: Iterable[float] = (20, 40, 60, 80, 100),
    out_root: str | os.PathLike[str] = ".",
    progress: bool = False,
) -> list[Path]:
    """The same bench at several fringe periods (paper Table 1).

    Each session gets ``session.period_px = p`` and the id ``<id>-p<p>`` and is written to
    ``out_root/<id>-p<p>``.
    """
    base = validate_bench_config(config)
    out = []
    for p in periods:
        cfg = sweep_config(base, p)
        out.append(write_session(cfg, Path(out_root) / cfg["session"]["id"], progress=progress))
    return out


