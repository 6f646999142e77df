"""The built-in report figures of a grid (registered in :mod:`vpr_uncertainty.reports.figures`).

Each is ``write(cells, config, out_dir, **options) -> list[Path]``: it receives the typed results
(:class:`~vpr_uncertainty.study.Cell`, whose evaluations hold the stored uncertainties) and recomputes nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from vpr_uncertainty.cache import write_text
from vpr_uncertainty.reports.ablations import plot_alpha_ablation, plot_k_ablation
from vpr_uncertainty.reports.heatmaps import plot_delta_heatmaps
from vpr_uncertainty.reports.held_out import table1_cells, table1_note
from vpr_uncertainty.reports.plots import plot_rejection_curves
from vpr_uncertainty.reports.qualitative import plot_qualitative
from vpr_uncertainty.reports.table1 import build_table1, table1_csv, table1_html, table1_latex, table1_markdown
from vpr_uncertainty.study.config import slug

if TYPE_CHECKING:
    from vpr_uncertainty.study import Cell, GridConfig

__all__ = [
    "table1_section",
    "write_ablations",
    "write_heatmaps",
    "write_pr_curves",
    "write_qualitative",
    "write_table1",
]


def write_table1(cells: Sequence[Cell], config: GridConfig, out_dir: Path) -> list[Path]:
    """``table1.md``, ``table1.csv`` and ``table1.tex`` (booktabs) in ``out_dir``; held-out means with the grid's
    calibration option (:mod:`vpr_uncertainty.reports.held_out`), which ``table1.md`` then states."""
    table = build_table1(table1_cells(cells))
    note = table1_note(cells)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for suffix, render in (("md", table1_markdown), ("csv", table1_csv), ("tex", table1_latex)):
        path = out_dir / f"table1.{suffix}"
        write_text(path, render(table) + (f"\n{note}\n" if note and suffix == "md" else ""))
        paths.append(path)
    return paths


def table1_section(cells: Sequence[Cell], config: GridConfig, written: list[Path]) -> str:
    """Table 1 as HTML, with its note."""
    note = '<p class="note">Best per column in bold. ms/query: mean time per query.</p>'
    held_out = table1_note(cells)
    if held_out:
        note += f'<p class="note">{held_out}</p>'
    return table1_html(build_table1(table1_cells(cells))) + note


def write_heatmaps(cells: Sequence[Cell], config: GridConfig, out_dir: Path) -> list[Path]:
    """``figures/delta_<RS|SD|SU>.png``: ΔAUC-PR against each baseline."""
    return plot_delta_heatmaps(cells, out_dir / "figures")


def write_ablations(cells: Sequence[Cell], config: GridConfig, out_dir: Path) -> list[Path]:
    """``figures/ablation_alpha.png`` and ``figures/ablation_k.png``, for the ablations the cells hold."""
    paths = []
    if any(cell.ablation_alpha for cell in cells):
        paths.append(plot_alpha_ablation(cells, out_dir / "figures" / "ablation_alpha.png"))
    if any(curve for cell in cells for curve in cell.ablation_k.values()):
        paths.append(plot_k_ablation(cells, out_dir / "figures" / "ablation_k.png"))
    return paths


def write_pr_curves(cells: Sequence[Cell], config: GridConfig, out_dir: Path) -> list[Path]:
    """``figures/pr/<vpr method>__<dataset>.png`` for every cell."""
    return [
        plot_rejection_curves(
            cell.evaluation,
            out_dir / "figures" / "pr" / f"{slug(cell.vpr_method)}__{slug(cell.dataset)}.png",
            title=f"{cell.vpr_method} on {cell.dataset}",
        )
        for cell in cells
    ]


def write_qualitative(cells: Sequence[Cell], config: GridConfig, out_dir: Path, *, rank_by: str = "SU") -> list[Path]:
    """``figures/qualitative__<vpr method>__<dataset>.png`` for the cells of ``config.qualitative`` (default: the
    first cell with images); queries chosen by the uncertainties of ``rank_by``."""
    chosen = [c for c in cells if c.query_paths and (config.qualitative is None or c.vpr_method in config.qualitative)]
    if config.qualitative is None:
        chosen = chosen[:1]
    paths = []
    for cell in chosen:
        path = out_dir / "figures" / f"qualitative__{slug(cell.vpr_method)}__{slug(cell.dataset)}.png"
        written = plot_qualitative(cell, path, rank_by=rank_by, alpha=config.alpha)
        if written is not None:
            paths.append(written)
    return paths
