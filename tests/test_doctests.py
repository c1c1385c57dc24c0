"""Every docstring example of the library runs and gives what it shows."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import huefringe


def _runnable(name: str) -> bool:
    """Whether the module has an example that is not marked ``+SKIP``."""
    source = importlib.util.find_spec(name).loader.get_source(name) or ""
    if ">>>" not in source:
        return False
    tests = doctest.DocTestFinder().find(importlib.import_module(name))
    return any(not ex.options.get(doctest.SKIP, False) for t in tests for ex in t.examples)


MODULES = [m.name for m in pkgutil.walk_packages(huefringe.__path__, "huefringe.") if _runnable(m.name)]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed"
