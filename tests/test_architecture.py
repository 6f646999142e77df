"""Layout rules: no import cycle at any level, no private name imported across modules, modules sized by concept.

The import graph is built from the source with :mod:`ast` (nothing is imported), with an edge ``a -> b`` for every
``import``/``from ... import`` in ``a`` that names module ``b`` of the package, wherever it stands: at module level,
inside a function, or under ``if TYPE_CHECKING:``. A lazy import hides a cycle from the interpreter, not from a
reader, so it counts. ``from package import name`` is an edge to ``package.name`` when that is a module, else to
the package's ``__init__``; a module's imports of its own parent packages are not edges (Python initialises the
parents before the module).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

SOURCE = Path(__file__).resolve().parents[1] / "src"
PACKAGE = "vpr_uncertainty"
#: A module holds one concept; above this many lines it almost surely holds two.
SOFT_MAX_LINES = 800


def _modules() -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, whether it is a package ``__init__``)."""
    modules = {}
    for path in sorted((SOURCE / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(SOURCE).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        modules[".".join(parts[:-1] if is_package else parts)] = (path, is_package)
    return modules


def _imports(name: str, path: Path, is_package: bool):
    """(imported module or package, imported names) for every import statement of the module, at any depth."""
    package = name if is_package else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, ()
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                source = ".".join([*base, *([node.module] if node.module else [])])
            else:
                source = node.module or ""
            yield source, tuple(alias.name for alias in node.names)


def import_graph() -> dict[str, set[str]]:
    """Module -> the modules of the package it imports, at any level."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, (path, is_package) in modules.items():
        edges: set[str] = set()
        for source, names in _imports(name, path, is_package):
            targets = [f"{source}.{alias}" for alias in names if f"{source}.{alias}" in modules] or [source]
            for target in targets:
                while target not in modules and "." in target:
                    target = target.rpartition(".")[0]
                edges.add(target)
        graph[name] = {t for t in edges if t in modules and t != name and not name.startswith(t + ".")}
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


def private_imports() -> list[str]:
    """Imports of a private name (``_x``) from another module, or of a private module from outside its package."""
    modules = _modules()
    found = []
    for name, (path, is_package) in modules.items():
        for source, names in _imports(name, path, is_package):
            if not source.startswith(PACKAGE):
                continue
            for alias in names:
                private = alias.startswith("_") and not alias.startswith("__")
                if private and f"{source}.{alias}" not in modules:
                    found.append(f"{name} imports {alias} from {source}")
            for target in [source, *(f"{source}.{alias}" for alias in names if f"{source}.{alias}" in modules)]:
                parts = target.split(".")
                for depth, part in enumerate(parts):
                    owner = ".".join(parts[:depth])
                    if (
                        part.startswith("_")
                        and not part.startswith("__")
                        and name != owner
                        and not name.startswith(owner + ".")
                    ):
                        found.append(f"{name} imports the private module {target}")
    return sorted(set(found))


def test_the_graph_sees_the_package():
    graph = import_graph()
    assert len(graph) > 20
    assert "vpr_uncertainty.plugins" in graph["vpr_uncertainty.methods.entries"]
    assert "vpr_uncertainty.scores" in graph["vpr_uncertainty.methods"] or any(
        "vpr_uncertainty.scores" in graph[m] for m in graph if m.startswith("vpr_uncertainty.methods.")
    )


def test_find_cycles_on_a_small_graph():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert find_cycles(graph) == [("a", "b", "c")]


def test_function_level_imports_are_edges(tmp_path, monkeypatch):
    package = tmp_path / PACKAGE
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("def f():\n    from vpr_uncertainty import b\n")
    (package / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .a import f\n")
    monkeypatch.setattr(sys.modules[__name__], "SOURCE", tmp_path)
    graph = import_graph()
    assert find_cycles(graph) == [(f"{PACKAGE}.a", f"{PACKAGE}.b")]


def test_no_import_cycles():
    graph = import_graph()
    cycles = find_cycles(graph)
    described = [
        "; ".join(f"{module} -> {', '.join(sorted(graph[module] & set(cycle)))}" for module in cycle)
        for cycle in cycles
    ]
    assert not cycles, "import cycles (function-level imports included):\n" + "\n".join(described)


def test_no_private_name_imported_across_modules():
    assert not private_imports(), "\n".join(private_imports())


@pytest.mark.parametrize(
    "path", sorted((SOURCE / PACKAGE).rglob("*.py")), ids=lambda path: str(path.relative_to(SOURCE / PACKAGE))
)
def test_modules_are_sized_by_concept(path):
    lines = len(path.read_text(encoding="utf-8").splitlines())
    assert lines <= SOFT_MAX_LINES, f"{path.relative_to(SOURCE)} has {lines} lines; does it hold two concepts?"
