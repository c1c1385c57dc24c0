"""Every docstring example of the library runs and gives what it shows."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import huefringe

MODULES = sorted(m.name for m in pkgutil.walk_packages(huefringe.__path__, "huefringe."))


@pytest.mark.parametrize("name", [n for n in MODULES if ">>>" in (importlib.util.find_spec(n).loader.get_source(n) or "")])
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed"
