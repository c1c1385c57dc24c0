"""Validation of the predicted uncertainty against ground truth (:func:`reliability`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["reliability"]


def reliability(errors: NDArray[np.floating], u: NDArray[np.floating], *, bins: int = 12) -> dict[str, Any]:
    """Coverage of ``|error| <= 2 u`` and the binned reliability curve (observed rms error, and the
    68.27th percentile of ``|error|`` — the robust one-sigma, equal to u for Gaussian errors —
    against predicted u, bins of equal count). NaN pixels (either) are left out."""
    e = np.asarray(errors, np.float64).ravel()
    s = np.asarray(u, np.float64).ravel()
    ok = np.isfinite(e) & np.isfinite(s) & (s > 0)
    e, s = e[ok], s[ok]
    if e.size == 0:
        return {"pixels": 0, "coverage_2u": None, "bins": []}
    edges = np.unique(np.quantile(s, np.linspace(0, 1, bins + 1)))
    idx = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, max(edges.size - 2, 0))
    rows = []
    for i in range(max(edges.size - 1, 1)):
        m = idx == i
        if m.sum() < 10:
            continue
        rows.append({"u_mm": float(np.sqrt(np.mean(s[m] ** 2))), "observed_rms_mm": float(np.sqrt(np.mean(e[m] ** 2))),
                     "observed_p68_mm": float(np.percentile(np.abs(e[m]), 68.27)),
                     "coverage_2u": float(np.mean(np.abs(e[m]) <= 2 * s[m])), "pixels": int(m.sum())})
    return {"pixels": int(e.size), "coverage_2u": float(np.mean(np.abs(e) <= 2 * s)),
            "median_u_mm": float(np.median(s)), "rms_error_mm": float(np.sqrt(np.mean(e**2))),
            "rms_u_mm": float(np.sqrt(np.mean(s**2))), "bins": rows}
