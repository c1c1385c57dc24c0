"""A measured frame's statistics and QA record, and the reference frame's."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray


def frame_stats(valid: NDArray[np.bool_], height: NDArray[np.float32], flags: Mapping[str, NDArray[np.bool_]], *,
                clipped_fraction: float, hue_undefined_fraction: float, table_invalid_fraction: float,
                shadow_fraction: float, hue_model: str, unwrap_mode: str,
                below_reference_mm: float = 0.25) -> dict[str, Any]:
    """The QA figures of one frame (``qa/frames/frame_NNNN.json``).

    ``phase_ambiguity_suspected`` is set when more than 0.1 % of the pixels lie below
    ``-below_reference_mm`` (objects stand on the plate, so a large negative height means the
    phase difference wrapped) or sit on a wrap edge.
    """
    counts = {k: int(np.count_nonzero(v)) for k, v in flags.items()}
    counts["below_reference"] = int(np.count_nonzero(valid & (height < -below_reference_mm)))
    return _qa_record(np.count_nonzero(valid) / valid.size, counts, valid.size,
                      float(np.median(height[valid])) if valid.any() else None,
                      clipped_fraction=clipped_fraction, hue_undefined_fraction=hue_undefined_fraction,
                      table_invalid_fraction=table_invalid_fraction, shadow_fraction=shadow_fraction,
                      hue_model=hue_model, unwrap_mode=unwrap_mode)


def _qa_record(valid_fraction: float, counts: dict[str, int], pixels: int, median_height_mm: float | None, *,
               clipped_fraction: float, hue_undefined_fraction: float, table_invalid_fraction: float,
               shadow_fraction: float, hue_model: str, unwrap_mode: str) -> dict[str, Any]:
    """The QA record of :func:`frame_stats` and :func:`reference_frame_stats`, from their counts."""
    suspect = (counts["below_reference"] + counts["wrap_edge"]) > 0.001 * pixels
    return {
        "valid_fraction": valid_fraction,
        "clipped_fraction": clipped_fraction,
        "hue_undefined_fraction": hue_undefined_fraction,
        "table_invalid_fraction": table_invalid_fraction,
        "shadow_fraction": shadow_fraction,
        "flags": counts,
        "phase_ambiguity_suspected": bool(suspect),
        "median_height_mm": median_height_mm,
        "hue_model": hue_model,
        "unwrap": unwrap_mode,
    }


def reference_frame_stats(dphi: NDArray[np.float32], valid: NDArray[np.bool_], height: NDArray[np.float32], *,
                          clipped_fraction: float, hue_undefined_fraction: float, table_invalid_fraction: float,
                          shadow_fraction: float, hue_model: str, near_wrap: float = 0.9 * np.pi,
                          below_reference_mm: float = 0.25, flag_valid: NDArray[np.bool_] | None = None) -> dict[str, Any]:
    """:func:`frame_stats` of a reference-relative frame, flags included, in one compiled pass.

    Equals ``frame_stats(valid, height, phase.unwrap(dphi, flag_valid, "reference").flags, ...,
    unwrap_mode="reference")`` value for value (the flag counts, the valid fraction and the
    median height, NumPy's ``np.median`` of the float32 heights: the middle value, or the
    float32 mean of the two middle ones), without the flag maps, the unwrapped copy and the
    sort: what the kernel's measurement loop needs per frame (``dphi`` is the phase difference
    before the filter, ``valid`` and ``height`` the final ones).

    ``flag_valid`` (default ``valid``) are the pixels the wrap flags are counted on: for
    :func:`measure_frame`'s figures, the pixels valid *before* the phase filter (its ``unwrap``
    call), i.e. ``np.isfinite(dphi)`` of the kernel's ``dphi``. The filter's rejection of noisy
    pixels (``measurement.denoise_adaptive``) and a non-finite height drop pixels from ``valid``
    only; counting the flags on the final ``valid`` instead under-counts ``near_wrap`` and
    ``wrap_edge`` wherever the dropped pixels sit near a wrap (the texture-edge correction's case).
    """
    d = np.ascontiguousarray(dphi)
    ok = np.ascontiguousarray(valid, dtype=bool)
    fv = ok if flag_valid is None else np.ascontiguousarray(flag_valid, dtype=bool)
    z = np.ascontiguousarray(height, dtype=np.float32)
    if not d.shape == ok.shape == z.shape == fv.shape or d.ndim != 2:
        raise ValueError(f"dphi {d.shape}, valid {ok.shape}, flag_valid {fv.shape} and height {z.shape} "
                         "must be the same 2-D shape")
    edge = np.empty((3, d.shape[1]), np.uint8)
    keys = np.empty(d.size + 1, np.uint32)
    n_valid, n_edge, n_near, n_below, n_keys = _reference_counts(d, ok, fv, z, float(near_wrap),
                                                                 np.float32(below_reference_mm), edge, keys)
    counts = {"wrap_edge": int(n_edge), "near_wrap": int(n_near), "isolated": 0, "below_reference": int(n_below)}
    median = (None if n_valid == 0 else float("nan") if n_keys < n_valid  # NaN among them: np.median's NaN
              else float(_median_keys(keys, int(n_keys))))
    return _qa_record(int(n_valid) / ok.size, counts, ok.size, median, clipped_fraction=clipped_fraction,
                      hue_undefined_fraction=hue_undefined_fraction, table_invalid_fraction=table_invalid_fraction,
                      shadow_fraction=shadow_fraction, hue_model=hue_model, unwrap_mode="reference")


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _reference_counts(d, valid, flag_valid, height, near_wrap, below, edge, keys):  # pragma: no cover - numba
    """``phase._wrap_flags`` counted (on ``flag_valid & finite(d)``, differences in float64), the
    pixels below ``-below`` among ``valid``, and the valid heights as order-preserving uint32
    keys (for :func:`_median_keys`). Returns (valid, wrap_edge, near_wrap, below, keys).

    Row by row in branch-free loops (LLVM vectorises them): a pixel is on a wrap edge when one
    of its four neighbour pairs is; ``edge`` is scratch ``(3, W)`` uint8 (the pairs to the right,
    to the row above and to the row below)."""
    h, w = d.shape
    n_valid = 0
    n_near = 0
    n_below = 0
    n_keys = 0
    n_edge = 0
    pi = np.pi
    zb = height.reshape(-1).view(np.uint32)
    right = edge[0]
    up = edge[1]
    down = edge[2]
    up[:] = 0
    for v in range(h):
        dv = d[v]
        okv = valid[v]
        fvv = flag_valid[v]
        hv = height[v]
        zv = zb[v * w : v * w + w]
        for u in range(w):
            ok = okv[u]
            hh = hv[u]
            n_valid += ok
            n_below += ok & (hh < -below)
            b = zv[u]
            keys[n_keys] = b ^ (np.uint32(0xFFFFFFFF) if b >> np.uint32(31) else np.uint32(0x80000000))
            n_keys += ok & (hh == hh)
            x = np.float64(dv[u])
            n_near += fvv[u] & (x - x == 0) & (abs(x) > near_wrap)
        for u in range(w - 1):
            x = np.float64(dv[u])
            y = np.float64(dv[u + 1])
            right[u] = fvv[u] & fvv[u + 1] & (x - x == 0) & (y - y == 0) & (abs(y - x) > pi)
        right[w - 1] = 0
        if v + 1 < h:
            dn = d[v + 1]
            fvn = flag_valid[v + 1]
            for u in range(w):
                x = np.float64(dv[u])
                y = np.float64(dn[u])
                down[u] = fvv[u] & fvn[u] & (x - x == 0) & (y - y == 0) & (abs(y - x) > pi)
        else:
            down[:] = 0
        n_edge += right[0] | up[0] | down[0]
        for u in range(1, w):
            n_edge += right[u] | right[u - 1] | up[u] | down[u]
        for u in range(w):
            up[u] = down[u]
    return n_valid, n_edge, n_near, n_below, n_keys


@numba.njit(cache=True, nogil=True)
def _select_key(keys, n, k, hist):  # pragma: no cover - numba
    """The ``k``-th smallest of ``keys[:n]`` (radix select: top 16 bits, then the low 16)."""
    hist[:] = 0
    for i in range(n):
        hist[keys[i] >> np.uint32(16)] += 1
    top = 0
    while hist[top] <= k:
        k -= hist[top]
        top += 1
    hist[:] = 0
    for i in range(n):
        x = keys[i]
        if (x >> np.uint32(16)) == top:
            hist[x & np.uint32(0xFFFF)] += 1
    low = 0
    while hist[low] <= k:
        k -= hist[low]
        low += 1
    return np.uint32((top << 16) | low)


@numba.njit(cache=True, nogil=True)
def _key_value(key):  # pragma: no cover - numba
    b = key ^ (np.uint32(0x80000000) if key >> np.uint32(31) else np.uint32(0xFFFFFFFF))
    return np.array([b], dtype=np.uint32).view(np.float32)[0]


@numba.njit(cache=True, nogil=True)
def _median_keys(keys, n):  # pragma: no cover - numba
    """``np.median`` of the float32 values of ``keys[:n]``: the middle one, or for even ``n``
    the float32 mean of the two middle ones (``np.mean`` of two float32: sum, then / 2)."""
    hist = np.empty(65536, np.int64)
    hi = _key_value(_select_key(keys, n, n // 2, hist))
    if n % 2:
        return np.float64(hi)
    lo = _key_value(_select_key(keys, n, n // 2 - 1, hist))
    return np.float64((lo + hi) / np.float32(2.0))
