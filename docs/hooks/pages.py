"""MkDocs hook: pages generated at build time from the sources they describe, never copied by hand.

* ``index.md`` is the README (the front door), its ``docs/...`` links made relative to the site.
* ``api/index.md`` lists each public top-level name of ``vpr_uncertainty`` (its ``__all__``; the package imports
  each on first use, PEP 562) with a link to its documentation on the page of the module that defines it.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def use_this_checkout() -> None:
    """Import ``vpr_uncertainty`` from this checkout's ``src``, not from whichever one the environment installed.

    Done at call time: MkDocs restores ``sys.path`` after loading a hook module.
    """
    src = str(ROOT / "src")
    if src not in sys.path:
        sys.path.insert(0, src)
    module = sys.modules.get("vpr_uncertainty")
    if module is not None and not Path(module.__file__).is_relative_to(ROOT / "src"):
        raise RuntimeError(f"vpr_uncertainty was imported from {module.__file__}, not from this checkout's {src}")


README_MARKER = "<!-- generated: README.md -->"
API_MARKER = "<!-- generated: top-level API -->"


def readme_page() -> str:
    """The README with its links into ``docs/`` relative to the docs folder (``docs/x.md`` -> ``x.md``)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    return re.sub(r"\]\(docs/", "](", text)


def top_level_api() -> str:
    """A table of the public top-level names: each links to its documentation on the page of its module."""
    import inspect

    use_this_checkout()
    import vpr_uncertainty

    rows = ["| name | defined in | what it is |", "|---|---|---|"]
    for name in vpr_uncertainty.__all__:
        value = getattr(vpr_uncertainty, name)
        module = value.__module__
        summary = (inspect.getdoc(value) or "").split("\n\n")[0].replace("\n", " ").replace("|", "\\|")
        summary = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", summary)  # Sphinx roles as code (the link is the name's)
        rows.append(f"| [`{name}`][{module}.{name}] | `{module}` | {summary} |")
    return "\n".join(rows) + "\n"


def on_page_markdown(markdown: str, page, config, files) -> str:  # MkDocs hook signature
    if README_MARKER in markdown:
        markdown = markdown.replace(README_MARKER, readme_page())
    if API_MARKER in markdown:
        markdown = markdown.replace(API_MARKER, top_level_api())
    return markdown
