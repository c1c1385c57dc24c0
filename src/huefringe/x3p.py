"""Height maps as X3P files (ISO 25178-72), the exchange format of areal surface software.

One file per height map, ``results/<id>/x3p/frame_NNNN.x3p``, written by ``x3pio`` (MIT; the
reading and writing library made for the format, which checks what it writes against the
standard and stores MD5 checksums of ``main.xml`` and of the binary data):

- the grid: a surface (``SUR``) of ``W x H`` points, x along image columns ``u`` and y along rows
  ``v`` (``X = u * pitch``, ``Y = v * pitch`` of the results contract), both incremental axes
  whose increment is the session's pixel pitch **in metres**;
- the heights: ``z`` in **metres** (mm / 1000), ``float64`` (every ``float32`` mm value of the
  height TIFF is kept exactly: ``float32(z * 1000)`` gives it back), the height above the
  reference plane, positive towards the camera;
- the points not measured: ``NaN`` (for floating-point data the standard marks an invalid point
  by NaN; its validity file ``bindata/valid.bin`` is for integer data, so none is written);
- ``Record2`` (the metadata): ``Date`` the session's ``provenance.captured_at`` (else
  ``SOURCE_DATE_EPOCH``, else the placeholder 1980-01-01T00:00:00Z, which the comment names as
  one), ``Creator`` the operator, ``Instrument`` the rig (``Model``: ``provenance.instrument``)
  with ``Version`` the software that computed the heights (``huefringe <version>``), the probing
  system ``NonContacting`` identified as huefringe's colour fringe projection, and a ``Comment``
  with the session, the frame, the coordinate convention, huefringe's address and whether the
  data are simulated. No calibration date: the rig's calibration is not in the session.

The clock never enters a file: ``x3pio`` stamps its ZIP members with the ZIP epoch and the
record's date comes from the session, so the same height map and session give the same bytes.
"""

from __future__ import annotations

import datetime as dt
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import x3pio
from numpy.typing import ArrayLike

from huefringe.io import atomic_path, source_date_epoch
from huefringe.settings import SoftwareIdentity, software_identity

__all__ = ["PLACEHOLDER_DATE", "X3PError", "record_date", "write_height_x3p"]

#: Date of a record whose session gives no capture date and no SOURCE_DATE_EPOCH is set
PLACEHOLDER_DATE = dt.datetime(1980, 1, 1, tzinfo=dt.UTC)
METHOD = "colour fringe projection, trapezoidal HSI phase shifting with multi-band hue calibration"


class X3PError(ValueError):
    """A height map cannot be written as X3P; the message names the file and the problem."""


def record_date(provenance: Mapping[str, Any] | None = None) -> tuple[dt.datetime, str]:
    """The date of an X3P record and where it comes from (a note for the comment).

    In order: the session's ``provenance.captured_at`` (a date alone is taken as 00:00 UTC, a
    time without a zone as UTC, so that the file does not depend on the machine's zone);
    ``SOURCE_DATE_EPOCH``; else :data:`PLACEHOLDER_DATE`. Never the clock.

    Raises
    ------
    X3PError
        ``captured_at`` is not ISO 8601, or ``SOURCE_DATE_EPOCH`` is not a Unix time.
    """
    when = (provenance or {}).get("captured_at")
    if when:
        try:
            t = dt.datetime.fromisoformat(str(when))
        except ValueError as exc:
            raise X3PError(f"provenance.captured_at {when!r} is not an ISO 8601 date or date-time") from exc
        note = "the capture date (provenance.captured_at of session.yaml)"
        if t.tzinfo is None:
            t = t.replace(tzinfo=dt.UTC)
            note += ", without a time zone: taken as UTC"
        return t, note
    try:
        epoch = source_date_epoch()
    except ValueError as exc:
        raise X3PError(str(exc)) from exc
    if epoch is not None:
        return epoch, "SOURCE_DATE_EPOCH given when the file was written"
    return PLACEHOLDER_DATE, ("a placeholder: the session has no provenance.captured_at and SOURCE_DATE_EPOCH "
                              "was not set (the clock is not used, so the same inputs give the same file)")


def _metadata(provenance: Mapping[str, Any], software: SoftwareIdentity, session_id: str | None,
              frame: int | None) -> x3pio.Metadata:
    date, note = record_date(provenance)
    who = f"{software.name} {software.version}" + (f", {software.url}" if software.url else "")
    what = "height map" + (f" of frame {frame:04d}" if frame is not None else "")
    what += f" of capture session '{session_id}'" if session_id else ""
    parts = [
        f"{what[0].upper()}{what[1:]}, computed by {who} ({METHOD}).",
        "Z: height above the reference plane, positive towards the camera; X = u * pitch along image "
        "columns, Y = v * pitch along rows (huefringe results contract); NaN: not measured.",
    ]
    if provenance.get("simulated"):
        parts.append("SIMULATED data: the capture session was written by a virtual bench, not measured.")
    elif "simulated" in provenance:
        parts.append("Captured by a physical rig (not simulated).")
    if provenance.get("notes"):
        parts.append(f"Notes: {provenance['notes']}")
    parts.append(f"Date: {note}.")
    return x3pio.Metadata(
        date=date,
        creator=str(provenance["operator"]) if provenance.get("operator") else None,
        instrument=x3pio.Instrument(
            manufacturer="",
            model=str(provenance.get("instrument") or "not given (session.yaml has no provenance.instrument)"),
            serial="",
            version=f"{software.name} {software.version}",
        ),
        calibration_date=None,
        probing_system=x3pio.ProbingSystem(x3pio.ProbingType.NON_CONTACTING, f"{METHOD} ({who})"),
        comment=" ".join(parts),
    )


def write_height_x3p(
    path: str | os.PathLike[str],
    height_mm: ArrayLike,
    pitch_mm: float,
    *,
    provenance: Mapping[str, Any] | None = None,
    session_id: str | None = None,
    frame: int | None = None,
    software: SoftwareIdentity | None = None,
) -> Path:
    """Write a height map as an X3P surface file (ISO 25178-72), atomically and reproducibly.

    Parameters
    ----------
    path : path
        The ``.x3p`` file to write.
    height_mm : array_like, shape (H, W)
        Heights in mm above the reference plane, NaN where not measured (a height TIFF).
    pitch_mm : float
        The session's pixel pitch in mm (x and y increments; written in metres).
    provenance : mapping, optional
        The session's ``provenance`` block (``captured_at``, ``operator``, ``instrument``,
        ``simulated``, ``notes``), written into ``Record2`` (see the module docstring).
    session_id, frame : optional
        Named in the record's comment.
    software : SoftwareIdentity, optional
        The software named in the record; by default huefringe's
        (:func:`huefringe.settings.software_identity`).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    X3PError
        The pitch is missing, not finite or not positive; the map is not 2-D or holds an
        infinite value; a date in the provenance cannot be read. The message names ``path``.
    """
    path = Path(path)
    try:
        pitch = float(pitch_mm)
    except (TypeError, ValueError):
        raise X3PError(f"{path}: the pixel pitch {pitch_mm!r} is not a number (pixel_pitch_mm of session.yaml)") from None
    if not (math.isfinite(pitch) and pitch > 0):
        raise X3PError(f"{path}: the pixel pitch must be a positive finite number of mm, got {pitch_mm!r}")
    z = np.asarray(height_mm)
    if z.ndim != 2 or 0 in z.shape:
        raise X3PError(f"{path}: a height map must be a non-empty 2-D array, got shape {z.shape}")
    if not np.issubdtype(z.dtype, np.floating):
        raise X3PError(f"{path}: heights must be floating point (mm, NaN where not measured), got {z.dtype}")
    if np.isinf(z).any():
        raise X3PError(f"{path}: the height map holds {int(np.isinf(z).sum())} infinite values (only NaN marks a "
                       "point not measured)")
    try:
        meta = _metadata(dict(provenance or {}), software or software_identity(), session_id, frame)
    except X3PError as exc:
        raise X3PError(f"{path}: {exc}") from exc
    metres = z.astype(np.float64) * 1e-3
    surface = x3pio.Surface.from_array(metres, x_scale=pitch * 1e-3, y_scale=pitch * 1e-3,
                                       z_type=x3pio.DataType.FLOAT64, metadata=meta)
    with atomic_path(path) as tmp:
        surface.save(tmp)
    return path
