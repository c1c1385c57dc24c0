"""huefringe: one-shot trapezoidal HSI fringe-projection profilometry.

``huefringe.measure(session, config=None)`` measures a capture session in memory (see
:func:`huefringe.api.measure`); the modules hold the rest (``docs/design.md``).
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"
__all__ = ["__version__", "measure"]


def __getattr__(name: str) -> Any:
    # PEP 562: `huefringe.measure` loads the measuring stack on first use, so that importing a
    # light module (huefringe.io, huefringe.session) does not import numba, OpenCV and the kernel.
    if name in ("measure", "Measurement"):
        from huefringe import api

        return getattr(api, name)
    raise AttributeError(f"module 'huefringe' has no attribute {name!r}")
