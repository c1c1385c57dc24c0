"""numba's threading layer is chosen by the library: running its parallel kernels logs nothing about it."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

_RUN = """
import json, numba, numpy as np
from huefringe import texture
from huefringe.phase import denoise_phase
rng = np.random.default_rng(0)
d = rng.normal(0, 0.01, (60, 80))
s = np.full((60, 80), 0.01)
c = np.empty((60, 80), np.float32)
denoise_phase(d, s, np.ones((60, 80), bool), radius=2, max_radius=6, target_sigma=0.002,
              carry=np.zeros((60, 80), np.float32), carry_mean=c)  # parallel rows (prange)
texture.correct_pair(rng.random((60, 80, 3)), rng.random((60, 80, 3)), 0.4, 0.5)
print(json.dumps({"layer": numba.threading_layer(), "configured": numba.config.THREADING_LAYER}))
"""


def _run(env: dict[str, str]) -> subprocess.CompletedProcess:
    # every warning printed (-W default), two threads so that the parallel launches start the pool
    return subprocess.run([sys.executable, "-W", "default", "-c", _RUN], capture_output=True, text=True, timeout=600,
                          env={**env, "NUMBA_NUM_THREADS": "2"})


def test_parallel_kernels_run_on_the_chosen_layer_without_a_warning() -> None:
    """Importing the library and running its parallel kernels in a fresh process: numba runs them on
    the layer the library named (OpenMP where it loads, else workqueue), and stderr holds no
    warning (numba's own search tries TBB first and warns that an old TBB is disabled)."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    r = _run(env)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["configured"] in ("omp", "workqueue")
    assert out["layer"] == out["configured"]
    assert "Warning" not in r.stderr and "TBB" not in r.stderr, r.stderr


@pytest.mark.parametrize("layer", ["workqueue"])
def test_a_layer_named_in_the_environment_wins(layer: str) -> None:
    r = _run({**os.environ, "NUMBA_THREADING_LAYER": layer})
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.strip().splitlines()[-1])["layer"] == layer
