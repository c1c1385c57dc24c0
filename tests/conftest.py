import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

_TESTS = Path(__file__).parent.resolve()


def _shares_a_built_fixture(item: pytest.Item) -> bool:
    """Whether ``item`` uses a module- or session-scoped fixture defined in this folder (a bench
    session written and measured once for its module, a cluster started once)."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return False
    for defs in info.name2fixturedefs.values():
        for d in defs:
            code = getattr(getattr(d, "func", None), "__code__", None)
            if d.scope in ("module", "session") and code is not None and Path(code.co_filename).resolve().parent == _TESTS:
                return True
    return False


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The order in which ``pytest -n 2`` hands out the test modules (pyproject: ``--dist loadfile
    --no-loadscope-reorder``: a module's tests run on one worker, so that a fixture it builds once
    is built once): first the modules with a test marked ``slow``, then those that build a fixture
    for the module or the session (a bench session written and measured, a cluster started), the
    many short ones last, so that the two workers end together."""
    rank: dict[str, int] = {}
    for item in items:
        key = str(item.path)
        r = 0 if item.get_closest_marker("slow") is not None else 1 if _shares_a_built_fixture(item) else 2
        rank[key] = min(rank.get(key, 2), r)
    items.sort(key=lambda item: rank[str(item.path)])  # stable: the collection's order within a rank
