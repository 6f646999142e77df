"""The layout rules of the package: no import cycles between modules, no module over 400 lines.

The import graph is built from the source with :mod:`ast` (nothing is imported): an edge ``a -> b`` for every
module-level ``import``/``from ... import`` in ``a`` that names module ``b`` of the package. Imports inside
functions (lazy imports of optional dependencies) and inside ``if TYPE_CHECKING:`` blocks are not edges: they do
not run when the module is imported. ``from package import name`` is an edge to ``package.name`` when that is a
module, else to the package's ``__init__``; importing ``a.b.c`` is not counted as importing ``a.b``'s
``__init__`` (it is already being initialised when one of its modules imports a sibling).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SOURCE = Path(__file__).resolve().parents[1] / "src"
PACKAGE = "vpr_uncertainty"
MAX_LINES = 400

#: Cycles accepted for now, each a sorted tuple of module names, with the reason. Empty: there are none.
KNOWN_CYCLES: dict[tuple[str, ...], str] = {}


def _modules() -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, whether it is a package ``__init__``)."""
    modules = {}
    for path in sorted((SOURCE / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(SOURCE).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        modules[".".join(parts[:-1] if is_package else parts)] = (path, is_package)
    return modules


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _module_level_imports(body: list[ast.stmt]):
    """The import statements that run when the module is imported (also inside if/try/with at module level)."""
    for node in body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, ast.If) and not _is_type_checking(node):
            yield from _module_level_imports(node.body)
            yield from _module_level_imports(node.orelse)
        elif isinstance(node, ast.Try):
            for block in (node.body, *(handler.body for handler in node.handlers), node.orelse, node.finalbody):
                yield from _module_level_imports(block)
        elif isinstance(node, ast.With):
            yield from _module_level_imports(node.body)


def import_graph() -> dict[str, set[str]]:
    """Module -> the modules of the package it imports at module level."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, (path, is_package) in modules.items():
        package = name if is_package else name.rpartition(".")[0]
        edges: set[str] = set()
        for node in _module_level_imports(ast.parse(path.read_text(encoding="utf-8"), str(path)).body):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    target = alias.name
                    while target not in modules and "." in target:
                        target = target.rpartition(".")[0]
                    edges.add(target)
                continue
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                source = ".".join([*base, *([node.module] if node.module else [])])
            else:
                source = node.module or ""
            for alias in node.names:
                edges.add(f"{source}.{alias.name}" if f"{source}.{alias.name}" in modules else source)
        graph[name] = {target for target in edges if target in modules and target != name}
    return graph


def find_cycles(graph: dict[str, set[str]]) -> list[tuple[str, ...]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[tuple[str, ...]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                cycles.append(tuple(sorted(component)))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return cycles


def test_the_graph_sees_the_package():
    graph = import_graph()
    assert len(graph) > 50
    assert "vpr_uncertainty.methods.entries" in graph["vpr_uncertainty.methods.builtin"]
    assert "vpr_uncertainty.evaluation" in graph[PACKAGE]  # from vpr_uncertainty.evaluation import (...)


def test_find_cycles_on_a_small_graph():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert find_cycles(graph) == [("a", "b", "c")]


def test_no_import_cycles():
    graph = import_graph()
    cycles = [cycle for cycle in find_cycles(graph) if cycle not in KNOWN_CYCLES]
    described = [
        "; ".join(f"{module} -> {', '.join(sorted(graph[module] & set(cycle)))}" for module in cycle)
        for cycle in cycles
    ]
    assert not cycles, "module-level import cycles:\n" + "\n".join(described)


@pytest.mark.parametrize(
    "path", sorted((SOURCE / PACKAGE).rglob("*.py")), ids=lambda path: str(path.relative_to(SOURCE / PACKAGE))
)
def test_no_module_over_400_lines(path):
    lines = len(path.read_text(encoding="utf-8").splitlines())
    assert lines <= MAX_LINES, f"{path.relative_to(SOURCE)} has {lines} lines; split it by responsibility"
