"""A capture session in memory: the :class:`Session`, its problems and error, the projector predistortion."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


FORMAT = "capture-session/1"


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a session: the file it concerns and what is wrong."""

    path: Path
    message: str

    def __str__(self) -> str:
        return f"{self.path}: {self.message}"


class SessionError(ValueError):
    """A capture session (or one of its files) breaks the capture-session format.

    ``problems`` lists every problem found; ``str()`` names each file and what is wrong.
    """

    def __init__(self, problems: list[Problem] | Problem):
        self.problems = [problems] if isinstance(problems, Problem) else list(problems)
        lines = [str(p) for p in self.problems[:20]]
        if len(self.problems) > 20:
            lines.append(f"... and {len(self.problems) - 20} more problems")
        super().__init__("\n".join(lines))

    @classmethod
    def at(cls, path: str | Path, message: str) -> SessionError:
        return cls(Problem(Path(path), message))


class SessionMeta:
    """What both session formats' ``session.yaml`` say alike: the id and the camera's image."""

    meta: dict[str, Any]

    @property
    def id(self) -> str:
        return str(self.meta["id"])

    @property
    def width(self) -> int:
        return int(self.meta["camera"]["width"])

    @property
    def height(self) -> int:
        return int(self.meta["camera"]["height"])

    @property
    def bit_depth(self) -> int:
        return int(self.meta["camera"]["bit_depth"])


@dataclass(frozen=True)
class Session(SessionMeta):
    """A validated capture session: its metadata and the paths of all its files."""

    root: Path
    meta: dict[str, Any]
    reference_white: Path
    reference_bands: tuple[tuple[Path, ...], ...]
    planes: dict[float, Path]
    object_white: Path
    object_bands: tuple[tuple[Path, ...], ...]
    frames: dict[int, Path]
    phase_shift: dict[int, tuple[Path, Path, Path]] = field(default_factory=dict)
    ground_truth: dict[int, Path] = field(default_factory=dict)
    predistortion: Predistortion | None = None
    """Extension: the pre-distortion the planes and frames were projected with (``predistortion.csv``)."""
    ground_truth_xy: dict[int, Path] = field(default_factory=dict)
    """Extension (bench sessions): the true X, Y of each pixel, ``ground_truth/xy/frame_NNNN.tiff``,
    float32 (H, W, 2) in mm, NaN where unseen."""

    @property
    def pixel_pitch_mm(self) -> float:
        return float(self.meta["camera"]["pixel_pitch_mm"])

    @property
    def period_px(self) -> float:
        return float(self.meta["pattern"]["period_px"])

    @property
    def hue_bands(self) -> int:
        return int(self.meta["pattern"]["hue_bands"])

    @property
    def repeats(self) -> int:
        return int(self.meta["pattern"]["repeats"])

    @property
    def planes_mm(self) -> list[float]:
        return [float(z) for z in self.meta["planes_mm"]]

    @property
    def specimen(self) -> dict[str, Any] | None:
        return self.meta.get("specimen")

    @property
    def provenance(self) -> dict[str, Any]:
        """The optional ``provenance`` block (``captured_at`` as an ISO 8601 string); ``{}`` if absent."""
        return dict(self.meta.get("provenance") or {})

    @property
    def frame_ids(self) -> list[int]:
        return sorted(self.frames)

    def all_images(self) -> list[Path]:
        """Every image path of the session (ground truth excluded)."""
        out = [self.reference_white, self.object_white, *self.planes.values(), *self.frames.values()]
        for bands in (self.reference_bands, self.object_bands):
            out.extend(p for reps in bands for p in reps)
        for triple in self.phase_shift.values():
            out.extend(triple)
        return out

    def input_files(self) -> list[Path]:
        """Every file of the session, session.yaml and ground truth included, sorted."""
        extra = [self.predistortion.path] if self.predistortion is not None else []
        return sorted([self.root / "session.yaml", *self.all_images(), *self.ground_truth.values(),
                       *self.ground_truth_xy.values(), *extra])


@dataclass(frozen=True)
class Predistortion:
    """A pre-distorted trapezoid (paper Fig. 6): code phase ``c`` was projected as phase ``p(c)``.

    huefringe extension of capture-session/1: an optional ``predistortion.csv`` at the session
    root (comment lines ``#``, a header ``code_phase_rad,emitted_phase_rad``, then rows with
    ``c`` ascending over [0, 2 pi) and ``p`` strictly increasing, ``p(c) - c`` periodic). It
    applies to the reference planes and the object frames; hue bands, white images and
    phase-shift captures are never pre-distorted. Readers of plain capture-session/1 ignore it.
    """

    path: Path
    code: np.ndarray
    emitted: np.ndarray

    def decode(self, emitted_phase: np.ndarray) -> np.ndarray:
        """Invert ``p``: the code phase (position) whose pre-distorted trapezoid was captured."""
        two_pi = 2.0 * np.pi
        e = np.concatenate([self.emitted - two_pi, self.emitted, self.emitted + two_pi])
        c = np.concatenate([self.code - two_pi, self.code, self.code + two_pi])
        x = np.mod(np.asarray(emitted_phase, np.float64) - self.emitted[0], two_pi) + self.emitted[0]
        return np.mod(np.interp(x, e, c), two_pi).astype(np.float32)

    def decode_slope(self, emitted_phase: np.ndarray) -> np.ndarray:
        """``d decode / d emitted`` at each emitted phase: the slope of the piecewise-linear
        segment :meth:`decode` interpolates on (scales phase uncertainties)."""
        two_pi = 2.0 * np.pi
        e = np.concatenate([self.emitted - two_pi, self.emitted, self.emitted + two_pi])
        c = np.concatenate([self.code - two_pi, self.code, self.code + two_pi])
        x = np.mod(np.asarray(emitted_phase, np.float64) - self.emitted[0], two_pi) + self.emitted[0]
        j = np.clip(np.searchsorted(e, x, side="right") - 1, 0, e.size - 2)
        slopes = (c[1:] - c[:-1]) / (e[1:] - e[:-1])
        return np.where(np.isfinite(x), slopes[j], np.nan)


def format_predistortion(code: np.ndarray, emitted: np.ndarray, *, source: str | None = None) -> str:
    """The text of a ``predistortion.csv`` (:class:`Predistortion`, read by :func:`read_predistortion`):
    the header comments, ``# written by ...`` when ``source`` is given, the column header and one
    row per code phase, 9 decimals."""
    lines = ["# huefringe predistortion/1: the trapezoidal planes and frames of this session were projected",
             "# with code phase c emitting the trapezoid of phase p(c) (paper Fig. 6); uniform bands were not."]
    if source is not None:
        lines.append(f"# written by {source}")
    lines.append("code_phase_rad,emitted_phase_rad")
    lines += [f"{c:.9f},{e:.9f}" for c, e in zip(code, emitted, strict=True)]
    return "\n".join(lines) + "\n"


def read_predistortion(path: str | Path) -> Predistortion:
    """Read and check ``predistortion.csv``; raise :class:`SessionError` naming the file."""
    path = Path(path)
    try:
        lines = [ln.strip() for ln in path.read_text(encoding="utf-8").splitlines()]
    except (OSError, UnicodeDecodeError) as exc:
        raise SessionError.at(path, f"cannot read ({exc})") from exc
    rows = [ln for ln in lines if ln and not ln.startswith("#")]
    if not rows or rows[0].replace(" ", "") != "code_phase_rad,emitted_phase_rad":
        raise SessionError.at(path, "header 'code_phase_rad,emitted_phase_rad' expected")
    try:
        data = np.array([[float(v) for v in r.split(",")] for r in rows[1:]], dtype=np.float64)
    except ValueError as exc:
        raise SessionError.at(path, f"not numeric ({exc})") from exc
    if data.ndim != 2 or data.shape[1] != 2 or data.shape[0] < 16:
        raise SessionError.at(path, "at least 16 rows of two numbers are needed")
    code, emitted = data[:, 0], data[:, 1]
    two_pi = 2.0 * np.pi
    if not np.all(np.isfinite(data)) or code[0] < 0 or code[-1] >= two_pi or np.any(np.diff(code) <= 0):
        raise SessionError.at(path, "code_phase_rad must rise strictly within [0, 2 pi)")
    if np.any(np.diff(emitted) <= 0) or emitted[-1] >= emitted[0] + two_pi:
        raise SessionError.at(path, "emitted_phase_rad must rise strictly by less than one turn (invertible)")
    if np.any(np.abs(emitted - code) >= np.pi):
        raise SessionError.at(path, "emitted_phase_rad departs from code_phase_rad by pi or more")
    return Predistortion(path, code, emitted)
