"""The hue table on disk and in use: its format, the memory-mapped reader, and the per-pixel hue -> phase lookup."""

from __future__ import annotations

import json
import math
import os
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numba
import numpy as np
from numpy.typing import NDArray

from .. import colour
from ..io import atomic_path, json_default
from ..patterns import TWO_PI


class HueTableError(ValueError):
    """Hue-table calibration failed: the bands or white image of a session cannot give a usable
    table (names the folder or file). Plane calibration has its own:
    :class:`huefringe.height.PlaneCalibrationError`."""


COUNTS = 65536
"""Table counts per 2 pi (uint16 full range)."""
RAD_PER_COUNT = TWO_PI / COUNTS
REASONS: tuple[str, ...] = ("valid", "low_signal", "low_saturation", "noise", "coverage", "order")
"""Mask reasons; the index is the code stored in ``HueTable.reason`` (0 = valid)."""
_R_LOW_SIGNAL, _R_LOW_SAT = 1, 2  # the kernels use the codes 3 (noise), 4 (coverage), 5 (order)
_FORMAT = "huefringe-hue-table/1"
NOISE_SOURCES: tuple[str, ...] = ("repeats", "band_difference")
"""How a table's per-pixel noise was found (``stats["noise_rad"]["source"]``): the spread of the
band repeats (``R >= 2``), or the third difference along the bands of the single repeat."""
_TWO_PI_F32 = np.float32(TWO_PI)


def table_nbytes(n_bands: int, height: int, width: int) -> int:
    """Bytes of the ``(N, H, W)`` uint16 table: ``2 N H W`` (403 MB for 256 x 1024 x 768)."""
    return 2 * int(n_bands) * int(height) * int(width)


def hue_band_paths(hue_dir: str | os.PathLike[str], n_bands: int, repeats: int, suffix: str = ".png") -> list[list[Path]]:
    """``[[band_000_r0, band_000_r1, ...], ...]`` paths of a session's ``hue/`` folder."""
    d = Path(hue_dir)
    return [[d / f"band_{i:03d}_r{r}{suffix}" for r in range(repeats)] for i in range(n_bands)]


@numba.njit(cache=True, inline="always")
def _column_entry(table, s0, k, v, u):  # pragma: no cover - numba
    """Entry ``k`` (any integer) of a pixel's rotated, sorted column continued periodically:
    ``table[(s0 + k) mod N] + 65536 floor(k / N)`` (float64 counts)."""
    n = table.shape[0]
    q = k // n
    i = s0 + k - q * n
    if i >= n:
        i -= n
    return np.float64(table[i, v, u]) + 65536.0 * q


@numba.njit(cache=True, parallel=False)
def _to_phase_kernel(table, start, valid, hue, out, out_slope):  # pragma: no cover - numba
    """Inverse lookup: binary search of each pixel's hue in its rotated sorted table column.

    ``out_slope`` (or None): the slope d(hue)/d(code phase) of the table averaged over one band
    width centred on the hue (see :meth:`HueTable.hue_slope`).
    """
    n, h, w = table.shape
    two_pi = 2.0 * np.pi
    scale = 65536.0 / two_pi
    step = two_pi / n
    two_pi_f32 = np.float32(two_pi)
    for v in range(h):
        for u in range(w):
            x = hue[v, u]
            if not valid[v, u] or not math.isfinite(x):
                out[v, u] = np.nan
                if out_slope is not None:
                    out_slope[v, u] = np.nan
                continue
            hq = (np.float64(x) * scale) % 65536.0  # float modulo; math.floor gives an int64 (overflows)
            if hq >= 65536.0:  # -tiny % 65536 rounds to 65536
                hq -= 65536.0
            s0 = np.int64(start[v, u])
            lo = 0
            hi = n
            while lo < hi:
                mid = (lo + hi) >> 1
                k = s0 + mid
                if k >= n:
                    k -= n
                if np.float64(table[k, v, u]) <= hq:
                    lo = mid + 1
                else:
                    hi = mid
            p = lo - 1
            if p < 0:
                b = s0 - 1 if s0 > 0 else n - 1
                lo_val = np.float64(table[b, v, u]) - 65536.0
                hi_val = np.float64(table[s0, v, u])
            else:
                b = s0 + p
                if b >= n:
                    b -= n
                lo_val = np.float64(table[b, v, u])
                if p == n - 1:
                    hi_val = np.float64(table[s0, v, u]) + 65536.0
                else:
                    k = b + 1
                    if k >= n:
                        k -= n
                    hi_val = np.float64(table[k, v, u])
            if out_slope is not None:
                f = (hq - lo_val) / (hi_val - lo_val)
                if f < 0.5:
                    sc = (0.5 - f) * (lo_val - _column_entry(table, s0, p - 1, v, u)) + (0.5 + f) * (hi_val - lo_val)
                else:
                    sc = (1.5 - f) * (hi_val - lo_val) + (f - 0.5) * (_column_entry(table, s0, p + 2, v, u) - hi_val)
                out_slope[v, u] = sc * n / 65536.0
            c = (b + (hq - lo_val) / (hi_val - lo_val)) * step
            if c >= two_pi:
                c -= two_pi
            r = np.float32(c)
            if r >= two_pi_f32:
                r = np.float32(0.0)
            out[v, u] = r


# =============================================================================================
# the table
# =============================================================================================
@dataclass(eq=False)
class HueTable:
    """Per-pixel hue table of one scene (reference plate or object).

    Attributes
    ----------
    model : {"hexcone", "hsi"}
        Hue model the table was built with (decode frames with the same model).
    n_bands : int
        ``N``; band ``i`` has code phase ``2 pi i / N``.
    table : ndarray of uint16, shape (N, H, W)
        Captured (white-balanced) hue of band ``i`` at each pixel, ``count * 2 pi / 65536``.
        Valid pixels: smoothed and circularly sorted from band ``start``; masked pixels: the raw
        circular means (for QA).
    valid : ndarray of bool, shape (H, W)
    start : ndarray of uint16, shape (H, W)
        Band index where the circularly sorted column has its minimum (its single wrap).
    reason : ndarray of uint8, shape (H, W)
        Mask reason code, index into :data:`REASONS` (0 = valid).
    noise_rad : ndarray of float32, shape (H, W)
        Standard error of the per-band mean hue: from the repeats, or with one repeat from the
        third difference along the bands (``stats["noise_rad"]["source"]``); NaN where masked.
    stats : dict
        Counts per reason, valid fraction, noise statistics, build parameters.
    """

    model: str
    n_bands: int
    table: NDArray[np.uint16]
    valid: NDArray[np.bool_]
    start: NDArray[np.uint16]
    reason: NDArray[np.uint8]
    noise_rad: NDArray[np.float32]
    stats: dict[str, Any] = field(default_factory=dict)

    # ------------------------------------------------------------------ basic properties
    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(H, W)``."""
        return (int(self.table.shape[1]), int(self.table.shape[2]))

    @property
    def nbytes(self) -> int:
        """Bytes of the table and its per-pixel maps."""
        return int(self.table.nbytes + self.valid.nbytes + self.start.nbytes + self.reason.nbytes + self.noise_rad.nbytes)

    def band_hue(self, i: int) -> NDArray[np.float32]:
        """Captured hue of band ``i`` as float32 radians (H, W)."""
        return (self.table[i].astype(np.float32) * np.float32(RAD_PER_COUNT)).astype(np.float32)

    # ------------------------------------------------------------------ inverse lookup
    def to_phase(self, hue: NDArray[np.floating], *, method: Literal["numba", "numpy"] = "numba") -> NDArray[np.float32]:
        """Code phase projected at each pixel, from the captured hue (inverse table lookup).

        Parameters
        ----------
        hue : ndarray, shape (H, W)
            Captured hue in radians (any real value, taken modulo 2 pi; NaN allowed), computed
            with the table's model from a frame white-balanced like the bands (see
            :meth:`phase_from_rgb`).
        method : {"numba", "numpy"}
            ``"numba"`` (default): per-pixel binary search, compiled; ``"numpy"``: the vectorised
            reference (counting comparisons, row chunks). They agree to float32 rounding.

        Returns
        -------
        ndarray of float32, shape (H, W)
            Code phase in [0, 2 pi) by circular piecewise-linear interpolation between the
            bracketing bands; NaN where the pixel is invalid or ``hue`` is NaN.
        """
        hue = np.asarray(hue)
        if hue.shape != self.shape:
            raise ValueError(f"hue has shape {hue.shape}, table expects {self.shape}")
        if method == "numba":
            out = np.empty(self.shape, dtype=np.float32)
            _to_phase_kernel(np.asarray(self.table), self.start, self.valid, np.ascontiguousarray(hue), out, None)
            return out
        if method == "numpy":
            return _to_phase_numpy(np.asarray(self.table), self.start, self.valid, hue)
        raise ValueError(f"unknown method {method!r}")

    def hue_slope(self, hue: NDArray[np.floating]) -> NDArray[np.float64]:
        """Local slope d(captured hue)/d(code phase) of each pixel's table at ``hue``.

        The central difference of the piecewise-linear table over one band width centred on the
        code phase :meth:`to_phase` gives (``[H(c + pi/N) - H(c - pi/N)] / (2 pi/N)``): the
        slopes of the bracketing band and of its nearer neighbour, weighted by how much of the
        window each covers. 1 for an undistorted table, below 1 where projector gamma flattens
        the captured hue. NaN where :meth:`to_phase` is NaN.
        """
        return self.to_phase_and_slope(hue)[1]

    def to_phase_and_slope(self, hue: NDArray[np.floating]) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
        """:meth:`to_phase` and :meth:`hue_slope` from one search of each pixel's column."""
        hue = np.asarray(hue)
        if hue.shape != self.shape:
            raise ValueError(f"hue has shape {hue.shape}, table expects {self.shape}")
        phase = np.empty(self.shape, dtype=np.float32)
        slope = np.empty(self.shape, dtype=np.float64)
        _to_phase_kernel(np.asarray(self.table), self.start, self.valid, np.ascontiguousarray(hue), phase, slope)
        return phase, slope

    def from_phase(self, phase: NDArray[np.floating]) -> NDArray[np.float32]:
        """Forward table: expected captured hue at each pixel for a projected code ``phase``.

        Circular piecewise-linear interpolation between bands; NaN where invalid or phase NaN.
        """
        phase = np.asarray(phase, dtype=np.float64)
        if phase.shape != self.shape:
            raise ValueError(f"phase has shape {phase.shape}, table expects {self.shape}")
        n = self.n_bands
        ok = self.valid & np.isfinite(phase)
        pos = np.mod(np.where(ok, phase, 0.0), TWO_PI) * (n / TWO_PI)
        b = np.minimum(np.floor(pos).astype(np.int64), n - 1)
        frac = pos - b
        tab = np.asarray(self.table)
        lo = np.take_along_axis(tab, b[None], axis=0)[0].astype(np.float64)
        hi = np.take_along_axis(tab, ((b + 1) % n)[None], axis=0)[0].astype(np.float64)
        step = np.mod(hi - lo, COUNTS)
        out = colour.wrap_2pi((lo + frac * step) * RAD_PER_COUNT)
        out[~ok] = np.nan
        return out

    def phase_from_rgb(self, rgb: NDArray[np.floating], white: NDArray[np.floating]) -> NDArray[np.float32]:
        """Decode a captured frame: white balance, hue (table's model) and inverse lookup."""
        p = self.stats.get("params", {})
        bal = colour.white_balance(rgb, white, floor=p.get("floor", 1.0 / 255.0))
        h = colour.hue(bal, self.model, min_saturation=p.get("min_saturation", 0.0))  # type: ignore[arg-type]
        return self.to_phase(h)

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the table as three files beside ``path`` (suffix ignored), each atomically.

        ``<stem>.npy`` the ``(N, H, W)`` uint16 table (memory-mappable), ``<stem>.maps.npz`` the
        per-pixel maps, ``<stem>.json`` the metadata, written last. A CRC-32 of the table is
        stored in both the JSON and the npz, so :meth:`load` detects a mixed set from an
        interrupted overwrite. Returns the JSON path.
        """
        base = _base(path)
        tab = np.ascontiguousarray(self.table)
        token = f"{zlib.crc32(memoryview(tab).cast('B')) & 0xFFFFFFFF:08x}"
        with atomic_path(base.with_suffix(".npy")) as tmp:
            np.save(tmp, tab, allow_pickle=False)
        with atomic_path(base.with_suffix(".maps.npz")) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, valid=self.valid, start=self.start, reason=self.reason,
                                    noise_rad=self.noise_rad, token=np.array(token))
        meta = {
            "format": _FORMAT,
            "model": self.model,
            "n_bands": int(self.n_bands),
            "shape": [int(s) for s in tab.shape],
            "dtype": "uint16",
            "rad_per_count": RAD_PER_COUNT,
            "token": token,
            "stats": self.stats,
        }
        text = json.dumps(meta, indent=2, sort_keys=True, allow_nan=False, default=json_default)
        with atomic_path(base.with_suffix(".json")) as tmp:
            tmp.write_text(text + "\n", encoding="utf-8")
        return base.with_suffix(".json")

    @classmethod
    def load(cls, path: str | os.PathLike[str], *, mmap: bool = True, verify: bool = False) -> HueTable:
        """Read a table written by :meth:`save`; the big array is memory-mapped read-only by default.

        ``verify=True`` recomputes the CRC-32 of the table (reads it all).
        """
        base = _base(path)
        meta = json.loads(base.with_suffix(".json").read_text(encoding="utf-8"))
        if meta.get("format") != _FORMAT:
            raise ValueError(f"{base}.json: not a {_FORMAT} file")
        tab = np.load(base.with_suffix(".npy"), mmap_mode="r" if mmap else None, allow_pickle=False)
        with np.load(base.with_suffix(".maps.npz"), allow_pickle=False) as z:
            maps = {k: z[k] for k in ("valid", "start", "reason", "noise_rad", "token")}
        if list(tab.shape) != meta["shape"] or tab.dtype != np.uint16:
            raise ValueError(f"{base}.npy: shape/dtype {tab.shape}/{tab.dtype} differ from the JSON")
        if str(maps["token"]) != meta["token"]:
            raise ValueError(f"{base}: maps and metadata come from different saves")
        if verify:
            crc = f"{zlib.crc32(memoryview(np.ascontiguousarray(tab)).cast('B')) & 0xFFFFFFFF:08x}"
            if crc != meta["token"]:
                raise ValueError(f"{base}.npy: CRC mismatch (table from another save or damaged)")
        return cls(model=meta["model"], n_bands=int(meta["n_bands"]), table=tab, valid=maps["valid"],
                   start=maps["start"], reason=maps["reason"], noise_rad=maps["noise_rad"], stats=meta["stats"])


def _base(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    for suf in (".json", ".npy", ".npz"):
        if p.name.endswith(suf):
            p = p.with_name(p.name[: -len(suf)])
    if p.name.endswith(".maps"):
        p = p.with_name(p.name[: -len(".maps")])
    return p


def _to_phase_numpy(table: NDArray[np.uint16], start: NDArray[np.uint16], valid: NDArray[np.bool_],
                    hue: NDArray[np.floating], rows_per_chunk: int | None = None) -> NDArray[np.float32]:
    """Vectorised reference of the inverse lookup (counts entries <= hue instead of bisecting)."""
    n, h, w = table.shape
    out = np.full((h, w), np.nan, dtype=np.float32)
    if rows_per_chunk is None:
        rows_per_chunk = max(1, (1 << 22) // max(1, n * w))
    ar = np.arange(n)[:, None, None]
    for v0 in range(0, h, rows_per_chunk):
        sl = slice(v0, min(h, v0 + rows_per_chunk))
        st = start[sl].astype(np.int64)
        hq = np.asarray(hue[sl], dtype=np.float64) * (COUNTS / TWO_PI)
        ok = valid[sl] & np.isfinite(hq)
        hq = np.where(ok, hq - COUNTS * np.floor(hq / COUNTS), 0.0)
        rot = np.take_along_axis(table[:, sl], (st[None] + ar) % n, axis=0).astype(np.float64)  # sorted
        p = np.count_nonzero(rot <= hq[None], axis=0) - 1
        b = np.where(p < 0, (st - 1) % n, (st + p) % n)
        lo_val = np.take_along_axis(rot, np.maximum(p, 0)[None], axis=0)[0]
        lo_val = np.where(p < 0, rot[n - 1] - COUNTS, lo_val)
        hi_val = np.take_along_axis(rot, np.minimum(p + 1, n - 1)[None], axis=0)[0]
        hi_val = np.where(p == n - 1, rot[0] + COUNTS, hi_val)
        with np.errstate(divide="ignore", invalid="ignore"):
            c = (b + (hq - lo_val) / (hi_val - lo_val)) * (TWO_PI / n)
        c = np.where(c >= TWO_PI, c - TWO_PI, c)
        r = c.astype(np.float32)
        r[r >= _TWO_PI_F32] = 0.0
        r[~ok] = np.nan
        out[sl] = r
    return out


# =============================================================================================
# building (streamed)
# =============================================================================================
class _Reader:
    """Images of the bands in order: read on demand, or ``prefetch`` bands ahead in threads."""

    def __init__(self, read: Callable[[Any], Any], band_paths: Sequence[Sequence[Any]], prefetch: int):
        self.read, self.paths, self.prefetch = read, band_paths, max(0, int(prefetch))
        self.pool: Any = None
        self.pending: dict[tuple[int, int], Any] = {}
        self.next_band = 0

    def __enter__(self) -> _Reader:
        if self.prefetch:
            from concurrent.futures import ThreadPoolExecutor

            reps = len(self.paths[0]) if len(self.paths) else 1
            self.pool = ThreadPoolExecutor(max_workers=min(4, self.prefetch * reps), thread_name_prefix="hue-read")
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.pool is not None:
            for f in self.pending.values():
                f.cancel()
            self.pool.shutdown(wait=True)
        self.pending.clear()

    def get(self, i: int, r: int) -> Any:
        if self.pool is None:
            return self.read(self.paths[i][r])
        while self.next_band < len(self.paths) and self.next_band <= i + self.prefetch:
            for rr, p in enumerate(self.paths[self.next_band]):
                self.pending[(self.next_band, rr)] = self.pool.submit(self.read, p)
            self.next_band += 1
        return self.pending.pop((i, r)).result()
