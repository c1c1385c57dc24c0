"""numba's threading layer, chosen on purpose before any parallel kernel runs.

Left to itself numba tries TBB first and, where the installed TBB is older than it needs, warns
at the first parallel launch that the TBB layer is disabled, then falls back: a line in every
script's log that a user cannot act on. The modules with parallel kernels import this one, which
names the layer instead: OpenMP (``omp``), thread-safe (the step budget's and the bench writer's
worker threads may launch kernels concurrently), where numba's OpenMP pool loads; otherwise the
built-in ``workqueue`` (always present). A layer named in ``NUMBA_THREADING_LAYER`` wins.
"""

from __future__ import annotations

import os

import numba

__all__ = ["THREADING_LAYER", "choose_threading_layer"]


def choose_threading_layer() -> str:
    """Set ``numba.config.THREADING_LAYER`` (unless ``NUMBA_THREADING_LAYER`` names one) and
    return it: ``omp`` where numba's OpenMP pool imports (its runtime library loads), else
    ``workqueue``. Effective only before the first parallel launch of the process."""
    if os.environ.get("NUMBA_THREADING_LAYER"):
        return str(numba.config.THREADING_LAYER)
    try:
        from numba.np.ufunc import omppool  # noqa: F401  (fails without an OpenMP runtime)

        layer = "omp"
    except ImportError:
        layer = "workqueue"
    numba.config.THREADING_LAYER = layer
    return layer


#: The layer this process's parallel kernels run on.
THREADING_LAYER = choose_threading_layer()
