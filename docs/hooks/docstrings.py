"""Griffe extension: the package's reST-flavoured numpydoc docstrings as the Markdown mkdocstrings renders.

The docstrings stay as they are in ``src/`` (readable in ``help()`` and an editor); when the site is built:

* each Sphinx role (``:func:`x```, ``:class:``, ``:meth:``, ``:data:``, ``:attr:``, ``:mod:``, ``:exc:``,
  ``:obj:``) becomes a cross-reference to the object when it resolves in the package: names are looked up as
  Sphinx does, in the object's own scope, then its class, module and packages (a leading ``.`` from the module's
  package; ``~`` shows the last part only), and the top-level names (imported on first use) through
  ``vpr_uncertainty.__all__``. The reference is *optional*: an object that no API page renders (a private helper,
  ``numpy.memmap``) is shown as code, without a link and without a warning;
* a bullet (or numbered) list that follows its introducing line without a blank line (numpydoc's habit) gets the
  blank line, and is dedented to that line's indentation (indented by four, it would be a code block), so it
  renders as a list;
* a reST simple table (columns under ``=====  =====`` borders) becomes a Markdown table.

``mkdocs.yml`` loads it into mkdocstrings' Python handler (``extensions:``); ``tests/test_docs.py`` checks that the
built API pages hold no raw role and that the lists are lists.
"""

from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import griffe

ROOT = Path(__file__).resolve().parents[2]
ROLE = re.compile(r":(?:py:)?(?:func|class|meth|data|attr|mod|exc|obj|const):`(?P<target>[^`]+)`")
BULLET = re.compile(r"^(?P<indent> *)(?:[*-]|\d+\.) \S")
BORDER = re.compile(r"^ *=+(?: +=+)+ *$")


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip(" "))


def markdown_lists(text: str) -> str:
    """A blank line before each bullet list that directly follows a line of text, the list dedented to it."""
    out: list[str] = []
    base = 0  # indentation of the last line of text outside a list
    list_indent = shift = None  # the current list's bullet indentation, and how far it is moved left
    for line in text.split("\n"):
        if list_indent is not None:  # inside a list: blank lines, deeper lines and its further bullets stay in it
            if not line.strip():
                out.append(line)
                continue
            if _indent(line) > list_indent or (BULLET.match(line) and _indent(line) == list_indent):
                out.append(line[shift:])
                continue
        list_indent = None
        match = BULLET.match(line)
        if match and len(match["indent"]) >= base:
            list_indent, shift = len(match["indent"]), len(match["indent"]) - base
            if out and out[-1].strip():
                out.append("")
            out.append(line[shift:])
            continue
        if line.strip():
            base = _indent(line)
        out.append(line)
    return "\n".join(out)


def markdown_tables(text: str) -> str:
    """Each reST simple table as a Markdown table (a row whose first cell is empty continues the row above)."""
    lines, out, i = text.split("\n"), [], 0
    while i < len(lines):
        end = i + 1
        while end < len(lines) and lines[end].strip():  # a simple table holds no blank line
            end += 1
        borders = [k for k in range(i, end) if BORDER.match(lines[k])] if BORDER.match(lines[i]) else []
        if len(borders) not in (2, 3) or borders[-1] != end - 1:
            out.append(lines[i])
            i += 1
            continue
        starts = [match.start() for match in re.finditer(r"=+", lines[i])]
        rows: list[list[str]] = []
        for line in lines[i + 1 : end - 1]:
            if BORDER.match(line):
                rows.append([])  # the header's end
                continue
            cells = [line[a:b].strip().replace("|", "\\|") for a, b in zip(starts, [*starts[1:], None], strict=True)]
            if rows and rows[-1] and not cells[0]:
                rows[-1] = [f"{before} {after}".strip() for before, after in zip(rows[-1], cells, strict=True)]
            else:
                rows.append(cells)
        header = rows[: rows.index([])] if [] in rows else [[""] * len(starts)]
        body = rows[rows.index([]) + 1 :] if [] in rows else rows
        indent = " " * (len(lines[i]) - len(lines[i].lstrip()))
        table = [*header[:1], ["---"] * len(starts), *body]
        out += ["", *(indent + "| " + " | ".join(row) + " |" for row in table), ""]
        i = end
    return "\n".join(out)


class Docstrings(griffe.Extension):
    """Rewrite every docstring of the package once it is loaded (before mkdocstrings parses any)."""

    def on_package(self, *, pkg: griffe.Module, **kwargs) -> None:
        self.package = pkg
        stack: list[griffe.Object] = [pkg]
        while stack:
            obj = stack.pop()
            stack.extend(member for member in obj.members.values() if not member.is_alias)
            if obj.docstring is not None:
                text = markdown_lists(markdown_tables(obj.docstring.value))
                obj.docstring.value = ROLE.sub(lambda match, obj=obj: self.reference(obj, match["target"]), text)

    def reference(self, obj: griffe.Object, target: str) -> str:
        """An optional cross-reference to ``target`` as seen from ``obj``, or a code span when it does not resolve."""
        short = target.startswith("~")
        target = target.lstrip("~").removesuffix("()")
        title = target.rsplit(".", 1)[-1] if short else target
        path = self.resolve(obj, target)
        if path is None:
            return f"`{title}`"
        return f'<autoref identifier="{path}" optional><code>{title}</code></autoref>'

    def resolve(self, obj: griffe.Object, target: str) -> str | None:
        if target.startswith("."):
            module = obj.module
            scopes = [module if module.is_package else module.parent]
            target = target.lstrip(".")
        else:
            scopes = []
            scope: griffe.Object | None = obj
            while scope is not None:
                scopes.append(scope)
                scope = scope.parent
        for candidate in [f"{scope.path}.{target}" for scope in scopes] + [target]:
            path = self.lookup(candidate)
            if path is not None:
                return path
        return None

    def lookup(self, path: str) -> str | None:
        """The canonical path of the package's object at ``path``, or None."""
        root = self.package.path
        if path == root:
            return root
        if not path.startswith(root + "."):
            return None
        try:
            found = self.package[path[len(root) + 1 :]]
            return found.final_target.path if found.is_alias else found.path
        except (KeyError, griffe.AliasResolutionError, griffe.CyclicAliasError):
            pass
        name = path[len(root) + 1 :]
        if "." in name:
            head, rest = name.split(".", 1)
            top = self.top_level(head)
            return None if top is None else self.lookup(f"{top}.{rest}")
        return self.top_level(name)

    def top_level(self, name: str) -> str | None:
        """Where a top-level name (imported on first use, PEP 562) is defined."""
        src = str(ROOT / "src")
        if src not in sys.path:
            sys.path.insert(0, src)
        package = importlib.import_module(self.package.path)
        if name not in getattr(package, "__all__", ()):
            return None
        value = getattr(package, name)
        return f"{value.__module__}.{value.__qualname__}"
