"""What the grid writes: ``results.json`` and ``results.csv`` (:func:`write_results`), then Table 1, the ΔAUC-PR
heatmaps, the ablations, the PR curves, the qualitative figures and ``report.html`` (:func:`write_reports`).

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
from vpr_uncertainty.study.config import GridConfig, slug

__all__ = ["write_reports", "write_results"]


def write_results(cells: Sequence[Cell], config: GridConfig) -> dict[str, Path]:
    """Write ``results.json`` (every cell's evaluation and ablations) and the long-format ``results.csv``.

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
    document = {"settings": config.settings(), "cells": [cell.to_dict() for cell in cells]}
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


def write_reports(cells: Sequence[Cell], config: GridConfig, *, html: bool = True) -> dict[str, Any]:
    """Table 1 (md, csv, tex), ΔAUC-PR heatmaps, ablations, PR curves, qualitative figures and ``report.html``.

    Parameters
    ----------
    cells : sequence of Cell
        The grid's results; the qualitative figures show their stored uncertainties.
    config : GridConfig
        The grid's settings and output folder; ``config.qualitative`` picks the VPR methods with a qualitative
        figure (default: the first cell with images).
    html : bool, default=True
        Also write ``report.html``.

    Returns
    -------
    dict of str to Path or list of Path
        Every file written, by kind.
    """
    from html import escape

    from vpr_uncertainty.reports import plot_rejection_curves
    from vpr_uncertainty.reports.ablations import plot_alpha_ablation, plot_k_ablation
    from vpr_uncertainty.reports.heatmaps import plot_delta_heatmaps
    from vpr_uncertainty.reports.html import Section, write_report
    from vpr_uncertainty.reports.qualitative import plot_qualitative
    from vpr_uncertainty.reports.table1 import build_table1, table1_csv, table1_html, table1_latex, table1_markdown

    out = Path(config.out)
    figures = out / "figures"
    paths: dict[str, Any] = {}
    table = build_table1(cells)
    for suffix, render in (("md", table1_markdown), ("csv", table1_csv), ("tex", table1_latex)):
        paths[f"table1_{suffix}"] = out / f"table1.{suffix}"
        write_text(paths[f"table1_{suffix}"], render(table))
    paths["heatmaps"] = plot_delta_heatmaps(cells, figures)
    paths["ablations"] = []
    if any(c.ablation_alpha for c in cells):
        paths["ablations"].append(plot_alpha_ablation(cells, figures / "ablation_alpha.png"))
    if any(curve for c in cells for curve in c.ablation_k.values()):
        paths["ablations"].append(plot_k_ablation(cells, figures / "ablation_k.png"))
    paths["pr_curves"] = [
        plot_rejection_curves(
            cell.evaluation,
            figures / "pr" / f"{slug(cell.vpr_method)}__{slug(cell.dataset)}.png",
            title=f"{cell.vpr_method} on {cell.dataset}",
        )
        for cell in cells
    ]
    chosen = [c for c in cells if c.query_paths and (config.qualitative is None or c.vpr_method in config.qualitative)]
    if config.qualitative is None:
        chosen = chosen[:1]
    paths["qualitative"] = [
        p
        for c in chosen
        if (
            p := plot_qualitative(
                c,
                figures / f"qualitative__{slug(c.vpr_method)}__{slug(c.dataset)}.png",
                alpha=config.alpha,
            )
        )
        is not None
    ]
    if html:
        settings = escape(json.dumps(config.settings()))
        sections = [
            Section(
                "Table 1: AUC-PR averaged over datasets",
                table1_html(table) + '<p class="note">Best per column in bold. ms/query: mean time per query.</p>',
            ),
            Section("ΔAUC-PR of RS, SD and SU against each baseline", figures=[(p.stem, p) for p in paths["heatmaps"]]),
            Section("Ablations", figures=[(p.stem, p) for p in paths["ablations"]]),
            Section("End-to-end precision-recall with rejection", figures=[(p.stem, p) for p in paths["pr_curves"]]),
            Section("Qualitative examples", figures=[(p.stem, p) for p in paths["qualitative"]]),
        ]
        intro = f"{len(cells)} cells (VPR method × dataset). Settings: <code>{settings}</code>"
        paths["report_html"] = write_report(
            out / "report.html", "vpr-uncertainty: reproduction report", sections, intro=intro
        )
    return paths
