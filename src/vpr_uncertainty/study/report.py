"""What the grid writes: ``results.json`` and ``results.csv`` (:func:`write_results`), then the selected report
figures (Table 1, the ΔAUC-PR heatmaps, the ablations, the PR curves, the qualitative figures and any registered
one, see :mod:`vpr_uncertainty.reports.figures`) and ``report.html`` (:func:`write_reports`).

Both receive the typed results (:class:`~vpr_uncertainty.study.cell.Cell`, whose evaluations hold the stored
uncertainties); nothing is recomputed or read back from disk.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vpr_uncertainty.cache import atomic_write, write_text
from vpr_uncertainty.study.cell import CSV_FIELDS, Cell
from vpr_uncertainty.study.config import GridConfig

__all__ = ["write_reports", "write_results"]


def write_results(cells: Sequence[Cell], config: GridConfig) -> dict[str, Path]:
    """Write ``results.json`` (every cell's evaluation and ablations) and the long-format ``results.csv``.

    With the grid's calibration option, ``results.json`` records it (``"calibration": {fraction, repeats, seed}``)
    and each cell's held-out means and standard deviations (``"held_out"``).

    Parameters
    ----------
    cells : sequence of Cell
        The grid's results (see :func:`vpr_uncertainty.study.run_grid`).
    config : GridConfig
        The grid's settings and output folder.

    Returns
    -------
    dict of str to Path
        ``results_json`` and ``results_csv``.
    """
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    document: dict[str, Any] = {"settings": config.settings()}
    if config.calibration is not None:  # the held-out option: each cell then holds "held_out"
        document["calibration"] = dict(config.calibration)
    document["cells"] = [cell.to_dict() for cell in cells]
    json_path = out / "results.json"
    write_text(json_path, json.dumps(document, indent=2) + "\n")
    rows = [row for cell in cells for row in cell.rows()]
    recall_fields = sorted({key for row in rows for key in row if key.startswith("recall@")}, key=lambda s: int(s[7:]))
    csv_path = out / "results.csv"
    with atomic_write(csv_path, newline="") as file:
        writer = csv.DictWriter(file, fieldnames=[*CSV_FIELDS, *recall_fields])
        writer.writeheader()
        writer.writerows(rows)
    return {"results_json": json_path, "results_csv": csv_path}


def write_reports(
    cells: Sequence[Cell], config: GridConfig, *, html: bool = True, figures: Sequence[str] | None = None
) -> dict[str, Any]:
    """Every selected report figure (:data:`~vpr_uncertainty.reports.figures.REPORT_FIGURES`), then ``report.html``.

    The built-in figures are Table 1 (md, csv, tex), the ΔAUC-PR heatmaps, the ablations, the PR curves and the
    qualitative figures; a registered figure (:func:`~vpr_uncertainty.reports.register_report_figure`) is written
    after them and gets its own section of ``report.html``. A figure whose needs the cells do not meet (no
    images, no ablation) is not written; its section says why.

    Parameters
    ----------
    cells : sequence of Cell
        The grid's results; the figures receive them with their stored uncertainties.
    config : GridConfig
        The grid's settings and output folder; ``config.report`` selects the figures (default: every registered
        one) and ``config.qualitative`` the VPR methods with a qualitative figure.
    html : bool, default=True
        Also write ``report.html``.
    figures : sequence of str, optional
        Figure names or specs (``"qualitative:rank_by=RS"``) to write instead of ``config.report``.

    Returns
    -------
    dict of str to list of Path or Path
        The files each figure wrote, by figure name; each file other than a figure (PNG, PDF, SVG) also under
        ``<name>_<suffix>`` when it is the figure's only file of that suffix (``table1_md``, ``table1_csv``,
        ``table1_tex``); and ``report_html``.

    Raises
    ------
    KeyError
        For an unknown figure name (naming the closest one and listing the available ones).
    ValueError
        For an unknown option of a figure, or a bad value.
    """
    from html import escape

    from vpr_uncertainty.reports.figures import REPORT_FIGURES, parse_figure_spec, unmet_figure_needs
    from vpr_uncertainty.reports.html import Section, figure_caption, settings_table, write_report

    specs = figures if figures is not None else config.report
    selected = [parse_figure_spec(spec) for spec in (REPORT_FIGURES.names() if specs is None else specs)]
    out = Path(config.out)
    available = _available_needs(cells)
    paths: dict[str, Any] = {}
    sections = []
    for name, options in selected:
        entry = REPORT_FIGURES.get(name)
        note = unmet_figure_needs(entry, available)
        written = [] if note else entry.write(cells, config, out, **options)
        paths[name] = written
        suffixes = [path.suffix for path in written]
        for path in written:
            if path.suffix not in (".png", ".pdf", ".svg") and suffixes.count(path.suffix) == 1:
                paths[f"{name}_{path.suffix.lstrip('.')}"] = path
        body = "" if note else entry.section_html(cells, config, written, **options)
        if entry.title and entry.description:
            body = f'<p class="note">{escape(entry.description)}</p>' + body
        if note:
            body += f'<p class="note">Not written: {escape(note)}.</p>'
        pngs = [(figure_caption(name, path, cells), path) for path in written if path.suffix.lower() == ".png"]
        sections.append(Section(entry.heading, body, figures=pngs))
    if html:
        intro = settings_table(cells, config)
        paths["report_html"] = write_report(
            out / "report.html", "vpr-uncertainty: reproduction report", sections, intro=intro
        )
    return paths


def _available_needs(cells: Sequence[Cell]) -> set[str]:
    """The needs of report figures (:data:`~vpr_uncertainty.reports.figures.FIGURE_NEEDS`) the cells meet."""
    available = {"evaluation", "uncertainties"}
    if any(cell.query_paths and cell.database_paths for cell in cells):
        available.add("images")
    if any(cell.ablation_alpha for cell in cells) or any(curve for c in cells for curve in c.ablation_k.values()):
        available.add("ablations")
    if any("CAL" in (cell.held_out or {}).get("calibration_quality", {}) for cell in cells):
        available.add("calibration")
    from vpr_uncertainty.reports.plots import cascades

    if cascades(cells):
        available.add("cascade")
    return available
