"""Proposal: ``pipeline.measure_frames`` on top of the kernel (a drop-in, same outputs).

``pipeline.py`` is not owned by the kernel's author, so the proposed stage lives here, where the
workflow benchmark can measure it; moving it into :mod:`huefringe.pipeline` (replacing the body
of ``measure_frames``) is the proposed change. Differences from the current stage:

* the calibration (hue table, plane model, white gains, shadow mask) is prepared once per job
  (:func:`huefringe.kernel.prepare`) and each frame goes through the fused kernel, read as uint8
  straight from the PNG (no float conversion pass);
* heights, phase and hue maps, the QA JSON and the stats are the same as
  ``pipeline.measure_frame`` gives (``unwrap: reference``; ``spatial`` falls back to the
  reference implementation);
* the point cloud is optional (``clouds=None``): writing it with Open3D costs more than the
  measurement itself, so the proposal is to make clouds their own rule, built on request.

Run as a script it measures one batch, like ``scripts/measure_frames.py`` does for Snakemake::

    python benchmarks/proposed_measure.py ARGS.json
"""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np


def frame_stats(m: Any, prep: Any, phase_ref: np.ndarray, measurement: Mapping[str, Any], hue_model: str) -> dict:
    """``measure_frame``'s stats from the kernel's maps (reference-relative unwrapping)."""
    from huefringe.phase import unwrap, wrap

    n = m.valid.size
    valid = m.valid
    dphi = wrap(m.phase.astype(np.float64) - phase_ref)
    flags = {k: int(v.sum()) for k, v in unwrap(dphi, valid, "reference").flags.items()}
    below = valid & (m.height < -0.25)
    flags["below_reference"] = int(below.sum())
    suspect = (flags["below_reference"] + flags["wrap_edge"]) > 0.001 * n
    return {
        "valid_fraction": m.counts["valid"] / n,
        "clipped_fraction": m.counts["clipped"] / n,
        "hue_undefined_fraction": m.counts["hue_undefined"] / n,
        "table_invalid_fraction": prep.stats["table_invalid_fraction"],
        "shadow_fraction": prep.stats["shadow_fraction"],
        "flags": flags,
        "phase_ambiguity_suspected": bool(suspect),
        "median_height_mm": float(np.median(m.height[valid])) if valid.any() else None,
        "hue_model": hue_model,
        "unwrap": measurement["unwrap"],
    }


def measure_frames_kernel(session: str, frames: Sequence[int], table: str, model: str, hue_model: str,
                          measurement: Mapping[str, Any], calibration: Mapping[str, Any],
                          heights: Sequence[str], clouds: Sequence[str] | None, phases: Sequence[str],
                          hues: Sequence[str], qa: Sequence[str]) -> None:
    """Measure a batch of frames with the kernel: height, phase and hue TIFFs, QA (cloud optional)."""
    import cv2

    from huefringe import kernel, pipeline
    from huefringe.calibration import HueTable
    from huefringe.height import PlaneCalibration
    from huefringe.io import write_json, write_tiff
    from huefringe.session import load_session, read_rgb

    if measurement["unwrap"] != "reference":
        pipeline.measure_frames(session, frames, table, model, hue_model, measurement, calibration,
                                heights, clouds or [], phases, hues, qa)
        return
    s = load_session(session)
    t = HueTable.load(table)
    cal = PlaneCalibration.load(model)
    white = read_rgb(s.object_white)
    shadow = pipeline.shadow_mask(white, measurement["shadow_fraction"])
    prep = kernel.prepare(t, cal, white, hue_model=hue_model, min_saturation=measurement["min_saturation"],
                          shadow=shadow, bit_depth=s.bit_depth, predistortion=s.predistortion)
    del t  # the prepared layout replaces the band-major table
    phase_ref = cal.phi_ref.astype(np.float64)
    for i, n in enumerate(frames):
        path = s.frames[n]
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if raw is None or raw.ndim != 3 or raw.shape[2] != 3:
            rgb = read_rgb(path)  # the reference reader's checks and messages
        else:
            rgb = np.ascontiguousarray(raw[..., ::-1])
        m = kernel.frame_maps(prep, rgb, denoise_radius=measurement["denoise_radius"], want_maps=True)
        stats = frame_stats(m, prep, phase_ref, measurement, hue_model)
        pipeline._refuse_bad_frame(path, stats, measurement)
        write_tiff(heights[i], m.height)
        write_tiff(phases[i], m.phase)
        write_tiff(hues[i], m.hue)
        if clouds:
            from huefringe.cloud import height_to_cloud, write_cloud

            write_cloud(clouds[i], height_to_cloud(m.height, s.pixel_pitch_mm, colours=white))
        write_json(qa[i], {"frame": n, "file": str(path), **stats})


if __name__ == "__main__":
    args = json.loads(Path(sys.argv[1]).read_text())
    measure_frames_kernel(**args)
