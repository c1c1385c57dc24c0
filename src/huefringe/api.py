"""One call for the common case: a capture session in, calibrated height maps out, in memory.

:func:`measure` (also ``huefringe.measure``) runs what the workflow's ``hue_table``,
``plane_calibration`` and ``measure_frames`` jobs run, with the same numbers, without writing
anything: the defaults come packaged with the library (:mod:`huefringe.settings`), ``config``
overrides them. Both call :mod:`huefringe.pipeline`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from huefringe.height import PlaneCalibration
from huefringe.huetable import HueTable
from huefringe.session import Session, load_session
from huefringe.settings import load_config
from huefringe.camera import CameraModel
from huefringe.pipeline import frame_results, prepare_session

__all__ = ["Measurement", "measure"]


@dataclass
class Measurement:
    """What :func:`measure` returns: per-frame heights and validity, and the calibration behind them."""

    session: Session
    frames: list[int]
    """Frame numbers, in the order of the first axis of ``heights`` and ``valid``."""
    heights: NDArray[np.float32]
    """``(F, H, W)`` heights (mm) above the reference plane, NaN where invalid."""
    valid: NDArray[np.bool_]
    """``(F, H, W)`` pixels with a height."""
    calibration: PlaneCalibration
    """The plane calibration (reference phase and per-pixel phase-to-height model)."""
    tables: dict[str, HueTable]
    """The hue tables of the ``"reference"`` plate and of the ``"object"``."""
    stats: list[dict[str, Any]] = field(default_factory=list)
    """Per-frame QA figures (as ``qa/frames/frame_NNNN.json``)."""
    uncertainty: NDArray[np.float32] | None = None
    """``(F, H, W)`` standard uncertainty of the heights (mm, NaN where the height is NaN;
    :mod:`huefringe.uncertainty`), as ``uncertainty/frame_NNNN.tiff``."""
    support: NDArray[np.uint16] | None = None
    """``(F, H, W)`` number of raw pixels the phase filter averaged into each height (0 where
    NaN), as ``support/frame_NNNN.tiff``."""
    config: dict[str, Any] = field(default_factory=dict)
    """The configuration used (packaged defaults with ``config`` over them)."""
    camera: CameraModel | None = None
    """The X, Y model (the session's ``camera`` block, or telecentric with ``camera.lens_model: false``)."""
    camera_record: dict[str, Any] = field(default_factory=dict)
    """What ``calib/camera.json`` would hold: the X, Y model and the channel registration."""

    def height(self, frame: int) -> NDArray[np.float32]:
        """The height map of frame number ``frame``."""
        return self.heights[self.frames.index(frame)]

    def xy(self, frame: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """X, Y (mm) of every pixel of frame ``frame`` at its own height (NaN where invalid):
        :meth:`huefringe.camera.CameraModel.xy`."""
        model = self.camera or CameraModel.from_meta(self.session.meta)
        return model.xy(self.height(frame))


def measure(session: str | os.PathLike[str] | Session,
            config: Mapping[str, Any] | str | os.PathLike[str] | None = None, *,
            frames: Sequence[int] | None = None) -> Measurement:
    """Measure a capture session in memory: hue tables, plane calibration, a height map per frame.

    Parameters
    ----------
    session : path or Session
        A ``capture-session/1`` folder (validated first; errors name the file).
    config : mapping or path to a YAML file, optional
        Overrides of the packaged defaults (``src/huefringe/defaults.yaml``), key by key, in the
        workflow's configuration format; only ``hue_model``, ``calibration``, ``measurement``
        and ``camera`` (the channel registration, the Bayer re-demosaic) are read.
    frames : sequence of int, optional
        Frame numbers to measure; default all.

    Returns
    -------
    Measurement
        Heights ``(F, H, W)``, validity, the plane calibration and both hue tables.

    Raises
    ------
    SessionError, HueTableError, PlaneCalibrationError, FrameError
        As the workflow's jobs do, naming the file.

    Examples
    --------
    >>> import huefringe
    >>> m = huefringe.measure("resources/demo/gauge-blocks-demo")  # doctest: +SKIP
    >>> m.heights.shape, float(np.nanmedian(m.height(0)))  # doctest: +SKIP
    """
    cfg = load_config(config)
    s = session if isinstance(session, Session) else load_session(Path(session))
    prepared = prepare_session(s, cfg)
    frames = s.frame_ids if frames is None else list(frames)
    heights = np.empty((len(frames), s.height, s.width), np.float32)
    u = np.empty_like(heights)
    support = np.empty(heights.shape, np.uint16)
    stats = []
    for i, r in enumerate(frame_results(s, prepared.tables["object"], prepared.calibration, frames, cfg["hue_model"],
                                        cfg["measurement"], map_frames=set(), reader=prepared.reader)):
        heights[i] = r.height  # copied: the kernel reuses its buffers
        u[i] = r.uncertainty
        support[i] = np.rint(r.support)
        stats.append(r.stats)
    return Measurement(session=s, frames=frames, heights=heights, valid=np.isfinite(heights),
                       calibration=prepared.calibration, tables=prepared.tables, stats=stats, config=cfg, uncertainty=u,
                       support=support, camera=prepared.camera, camera_record=prepared.camera_record)
