"""The import graph of ``huefringe.*`` runs in strict layers: no circle, and measuring modules never
import the simulator (``huefringe.bench``)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "huefringe"


def _module_name(path: Path, src: Path = SRC) -> str:
    """The module a file belongs to; a package's private modules (``stages/_run.py``) belong to the
    package (``huefringe.stages``), which is one topic split into files."""
    parts = list(path.relative_to(src.parent).with_suffix("").parts)
    if parts[-1] == "__init__" or (parts[-1].startswith("_") and (path.parent / "__init__.py").exists()):
        parts = parts[:-1]
    return ".".join(parts)


def import_graph(src: Path = SRC) -> dict[str, set[str]]:
    """``module -> huefringe modules it imports`` (module level and inside functions alike)."""
    files = sorted(src.rglob("*.py"))
    modules = {_module_name(p, src) for p in files}
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for path in files:
        name = _module_name(path, src)
        package = path.parent.relative_to(src.parent).as_posix().replace("/", ".")
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    base = ".".join(up + ([base] if base else []))
                targets = [base] + [f"{base}.{a.name}" for a in node.names]
            for t in targets:
                # the deepest huefringe module the import names (``from huefringe import io`` -> huefringe.io)
                while t and t not in modules:
                    t = t.rpartition(".")[0]
                if t and t != name and t != "huefringe":
                    graph[name].add(t)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``graph`` as a list of modules, or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return stack[stack.index(n):] + [n]
            if n not in state and (c := visit(n)):
                return c
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (c := visit(m)):
            return c
    return None


def test_graph_sees_known_edges() -> None:
    g = import_graph()
    assert "huefringe.perframe" in g["huefringe.kernel"]
    assert "huefringe.kernel" in g["huefringe.pipeline"]  # the pipeline chooses the chain
    assert {"huefringe.pipeline"} <= g["huefringe.stages"] and "huefringe.pipeline" in g["huefringe.api"]
    assert "huefringe.kernel" not in g["huefringe.stages"] and "huefringe.stages" not in g["huefringe.api"]
    assert "huefringe.huetable" in g["huefringe.compensation"]
    assert {"huefringe.io", "huefringe.settings"} <= g["huefringe.x3p"]  # x3p sits beside cloud, above io
    # above patterns and io, and (--compensated: the plate's hue table) above compensation and session
    assert g["huefringe.projection"] == {"huefringe.io", "huefringe.patterns", "huefringe.compensation",
                                         "huefringe.huetable", "huefringe.session"}
    assert "huefringe.assemble" in g["huefringe.bench.projector"]  # the bench reads the manifest as huefringe session does
    assert {"huefringe.session", "huefringe.camera"} <= g["huefringe.assemble"]  # assemble sits above both


def test_find_cycle_finds_a_circle() -> None:
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_circle() -> None:
    assert find_cycle(import_graph()) is None


@pytest.mark.parametrize("module", ["colour", "phase", "height", "huetable", "compensation", "perframe", "kernel",
                                    "mesh", "cloud", "metrology", "render", "session", "io", "patterns",
                                    "camera", "x3p", "projection", "assemble", "uncertainty", "pipeline", "api"])
def test_measuring_modules_do_not_reach_the_bench(module: str) -> None:
    g = import_graph()
    seen, todo = set(), [f"huefringe.{module}"]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo += g[m]
    assert not {m for m in seen if m.startswith("huefringe.bench")}, seen
