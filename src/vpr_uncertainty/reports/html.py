"""``report.html``: one self-contained file (tables inline, figures as base64 PNG, opens offline), the caption of
each figure (what it shows, on which data) and the grid's settings as a table."""

from __future__ import annotations

import base64
from collections.abc import Sequence
from html import escape
from pathlib import Path
from typing import Any

from vpr_uncertainty.cache import slug, write_text

_STYLE = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1200px;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:0.9em}th,td{border:1px solid #ccc;padding:3px 8px}
td{text-align:right}thead th{background:#f0f0f0}figure{margin:1em 0}img{max-width:100%;height:auto}
figcaption{font-size:0.9em;color:#333;max-width:900px}.note{font-size:0.85em;color:#555}
img.figure{max-width:100%}table.settings td{text-align:left}
"""


#: After loading, appends a hidden ``<p id="render-check">figures rendered: N/M</p>``: N of the M figures decoded
#: (read from the DOM by the headless-browser test; not shown to a reader).
_RENDER_CHECK = (
    '<script>window.addEventListener("load",function(){var all=document.querySelectorAll("img.figure"),n=0;'
    "all.forEach(function(e){if(e.complete&&e.naturalWidth>0)n++;});"
    'var p=document.createElement("p");p.id="render-check";p.hidden=true;'
    'p.textContent="figures rendered: "+n+"/"+all.length;document.body.appendChild(p);});</script>'
)


class Section:
    """A report section: a title, optional HTML (tables, text) and figures as (caption, PNG path).

    The caption is the figure's text for a reader (what it shows, on which data); it is also its ``alt`` text.
    """

    def __init__(self, title: str, html: str = "", figures: Sequence[tuple[str, str | Path]] = ()) -> None:
        self.title = title
        self.html = html
        self.figures = list(figures)


def embed_png(path: str | Path) -> str:
    """A ``data:`` URI of a PNG file."""
    data = Path(path).read_bytes()
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        raise ValueError(f"{path} is not a PNG file")
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def png_display_width(path: str | Path) -> int | None:
    """CSS pixels (96 per inch) of a PNG's width at its stored resolution (pHYs), or None without one."""
    data = Path(path).read_bytes()
    width = int.from_bytes(data[16:20], "big")
    at = data.find(b"pHYs")
    if at < 0 or data[at + 12] != 1:  # unit 1: pixels per metre
        return None
    per_metre = int.from_bytes(data[at + 4 : at + 8], "big")
    return round(width / (per_metre * 0.0254) * 96) if per_metre else None


def render_report(title: str, sections: Sequence[Section], *, intro: str = "") -> str:
    """The HTML text; every ``<img>`` has the class ``figure`` and an inline PNG."""
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{escape(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{escape(title)}</h1>",
    ]
    if intro:
        parts.append(intro if intro.lstrip().startswith("<") else f'<p class="note">{intro}</p>')
    parts.append("<ul>" + "".join(f'<li><a href="#s{i}">{escape(s.title)}</a></li>' for i, s in enumerate(sections)))
    parts.append("</ul>")
    for number, section in enumerate(sections):
        parts.append(f'<section id="s{number}"><h2>{escape(section.title)}</h2>{section.html}')
        for number_in_section, (caption, path) in enumerate(section.figures, 1):
            label = f"Figure {number + 1}" + (f".{number_in_section}" if len(section.figures) > 1 else "") + ". "
            width = png_display_width(path)
            size = f' style="width:{width}px"' if width else ""
            parts.append(
                f'<figure><img class="figure"{size} alt="{escape(caption)}" src="{embed_png(path)}">'
                f"<figcaption><b>{label}</b>{escape(caption)}</figcaption></figure>"
            )
        parts.append("</section>")
    parts += [_RENDER_CHECK, "</body></html>"]
    return "\n".join(parts) + "\n"


def write_report(path: str | Path, title: str, sections: Sequence[Section], *, intro: str = "") -> Path:
    """Write :func:`render_report` to ``path`` (UTF-8) and return it."""
    return write_text(path, render_report(title, sections, intro=intro))


def _names(values: Sequence[str]) -> str:
    values = list(dict.fromkeys(values))
    return values[0] if len(values) == 1 else ", ".join(values[:-1]) + " and " + values[-1]


def averaged_over(cells: Sequence[Any]) -> str:
    """What a number of several cells is: ``"on corridor"`` (one dataset), else ``"averaged over the 2 datasets (a
    and b)"``."""
    datasets = list(dict.fromkeys(cell.dataset for cell in cells))
    return (
        f"on {datasets[0]}"
        if len(datasets) == 1
        else f"averaged over the {len(datasets)} datasets ({_names(datasets)})"
    )


def html_table(head: Sequence[str], rows: Sequence[Sequence[Any]], css: str = "") -> str:
    """A ``<table>``: the ``head`` texts escaped; in each row the first value (escaped) a header, the others HTML."""
    body = "".join(
        f"<tr><th>{escape(str(row[0]))}</th>" + "".join(f"<td>{value}</td>" for value in row[1:]) + "</tr>"
        for row in rows
    )
    heads = "".join(f"<th>{escape(text)}</th>" for text in head)
    css = f' class="{css}"' if css else ""
    return f"<table{css}><thead><tr>{heads}</tr></thead><tbody>{body}</tbody></table>"


def cell_stem(cell: Any) -> str:
    """``<vpr method>__<dataset>`` (slugged): how the file names of a cell's figures end."""
    return f"{slug(cell.vpr_method)}__{slug(cell.dataset)}"


def figure_caption(name: str, path: Path, cells: Sequence[Any]) -> str:
    """A generic caption of the figure file ``path`` written by the report figure ``name``: for a figure without a
    ``caption`` hook (the built-in figures caption themselves from the spec they are drawn from,
    :meth:`~vpr_uncertainty.reports.style.FigureSpec.caption`)."""
    datasets = _names([cell.dataset for cell in cells]) if cells else "no dataset"
    return f"{name}: {path.stem.replace('__', ' on ').replace('_', ' ')} ({datasets})"


def settings_table(cells: Sequence[Any], config: Any) -> str:
    """The grid's settings and data as an HTML table (the introduction of ``report.html``)."""
    settings = config.settings()
    rows = [
        ("datasets", _names([cell.dataset for cell in cells]) if cells else "none"),
        ("VPR methods", _names([cell.vpr_method for cell in cells]) if cells else "none"),
        ("cells (VPR method × dataset)", str(len(cells))),
        ("queries per cell", _names([str(cell.evaluation.n_queries) for cell in cells]) if cells else "none"),
        ("uncertainty methods", ", ".join(settings["methods"])),
        ("k (candidates of RS, SD, SU)", str(settings["k"])),
        ("α (weight of RS in SU)", f"{settings['alpha']:g}"),
        ("α ablation", ", ".join(f"{a:g}" for a in settings["alphas"]) or "none"),
        ("k ablation", ", ".join(str(k) for k in settings["ks"]) or "none"),
    ]
    if settings.get("verify_fraction") is not None:
        rows.append(("fraction verified by cascades", f"{settings['verify_fraction']:g}"))
    shown = {"methods", "k", "alpha", "alphas", "ks", "verify_fraction"}  # later settings (bootstrap, ...) too:
    rows += [(key, str(value)) for key, value in settings.items() if key not in shown]
    body = "".join(f"<tr><th>{escape(key)}</th><td>{escape(value)}</td></tr>" for key, value in rows)
    return f'<table class="settings"><caption>Settings of this run</caption><tbody>{body}</tbody></table>'
