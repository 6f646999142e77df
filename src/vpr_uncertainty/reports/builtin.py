"""The built-in report figures of a grid (registered in :mod:`vpr_uncertainty.reports.figures`).

Each is ``write(cells, config, out_dir, **options) -> list[Path]``: it receives the typed results
(the grid cells, whose evaluations hold the stored uncertainties) and recomputes nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from html import escape
from pathlib import Path
from typing import Any

from vpr_uncertainty.cache import write_text
from vpr_uncertainty.reports.ablations import plot_alpha_ablation, plot_k_ablation
from vpr_uncertainty.reports.figures import slug
from vpr_uncertainty.reports.heatmaps import plot_delta_heatmaps
from vpr_uncertainty.reports.held_out import table1_cells, table1_note
from vpr_uncertainty.reports.plots import write_rejection_curves
from vpr_uncertainty.reports.qualitative import plot_qualitative
from vpr_uncertainty.reports.style import VECTOR_SUFFIX
from vpr_uncertainty.reports.table1 import (
    build_table1,
    marks_note,
    table1_csv,
    table1_html,
    table1_latex,
    table1_markdown,
)
from vpr_uncertainty.reports.ties import build_ties_table, ties_csv, ties_markdown

__all__ = [
    "cascade_section",
    "pr_curves_section",
    "table1_ap_section",
    "table1_aurc_section",
    "table1_section",
    "ties_section",
    "write_ablations",
    "write_cascade",
    "write_heatmaps",
    "write_pr_curves",
    "write_qualitative",
    "write_table1",
    "write_table1_ap",
    "write_table1_aurc",
    "write_ties",
]


def _with_vectors(pngs: Sequence[Path]) -> list[Path]:
    """Each PNG followed by the vector file written beside it (:func:`~vpr_uncertainty.reports.style.save_figure`)."""
    paths = []
    for png in pngs:
        paths.append(png)
        if png.with_suffix(VECTOR_SUFFIX).is_file():
            paths.append(png.with_suffix(VECTOR_SUFFIX))
    return paths


def _table1(cells: Sequence[Any], config: Any, metric: str):
    # With the calibration option, Table 1 (AUC-PR) holds the held-out means; AP and AURC stay on all queries.
    chosen = table1_cells(cells) if metric == "auc_pr" else cells
    return build_table1(chosen, metric, bootstrap=getattr(config, "bootstrap", 0), seed=getattr(config, "seed", 0))


def _write_table1(cells: Sequence[Any], config: Any, out_dir: Path, metric: str, stem: str) -> list[Path]:
    table = _table1(cells, config, metric)
    note = table1_note(cells) if metric == "auc_pr" else None
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for suffix, render in (("md", table1_markdown), ("csv", table1_csv), ("tex", table1_latex)):
        path = out_dir / f"{stem}.{suffix}"
        write_text(path, render(table) + (f"\n{note}\n" if note and suffix == "md" else ""))
        paths.append(path)
    return paths


def write_table1(cells: Sequence[Any], config: Any, out_dir: Path) -> list[Path]:
    """``table1.md``, ``table1.csv`` and ``table1.tex`` (booktabs): AUC-PR, with intervals when bootstrapped."""
    return _write_table1(cells, config, out_dir, "auc_pr", "table1")


def write_table1_ap(cells: Sequence[Any], config: Any, out_dir: Path) -> list[Path]:
    """``table1_ap.{md,csv,tex}``: Table 1 of average precision."""
    return _write_table1(cells, config, out_dir, "average_precision", "table1_ap")


def write_table1_aurc(cells: Sequence[Any], config: Any, out_dir: Path) -> list[Path]:
    """``table1_aurc.{md,csv,tex}``: Table 1 of AURC (lower is better)."""
    return _write_table1(cells, config, out_dir, "aurc", "table1_aurc")


def _section(metric: str):
    def section(cells: Sequence[Any], config: Any, written: list[Path]) -> str:
        table = _table1(cells, config, metric)
        html = table1_html(table) + f'<p class="note">{escape(marks_note(table))} ms/query: mean time per query.</p>'
        held_out = table1_note(cells) if metric == "auc_pr" else None
        return html + (f'<p class="note">{escape(held_out)}</p>' if held_out else "")

    section.__name__ = f"{metric}_section"
    return section


table1_section = _section("auc_pr")
table1_ap_section = _section("average_precision")
table1_aurc_section = _section("aurc")


def write_ties(cells: Sequence[Any], config: Any, out_dir: Path) -> list[Path]:
    """``ties.md`` and ``ties.csv``: the share of tied queries and the distinct values of every method."""
    table = build_ties_table(cells)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / "ties.md", out_dir / "ties.csv"]
    write_text(paths[0], ties_markdown(table))
    write_text(paths[1], ties_csv(table))
    return paths


def ties_section(cells: Sequence[Any], config: Any, written: list[Path]) -> str:
    """The ties table as preformatted Markdown."""
    return f"<pre>{escape(ties_markdown(build_ties_table(cells)))}</pre>"


def write_heatmaps(cells: Sequence[Any], config: Any, out_dir: Path) -> list[Path]:
    """``figures/delta_<RS|SD|SU>.png`` (and ``.pdf``): ΔAUC-PR against each baseline."""
    return _with_vectors(plot_delta_heatmaps(cells, out_dir / "figures"))


def write_ablations(cells: Sequence[Any], config: Any, out_dir: Path) -> list[Path]:
    """``figures/ablation_alpha.png`` and ``figures/ablation_k.png`` (and ``.pdf``), for the ablations the cells
    hold."""
    paths = []
    if any(cell.ablation_alpha for cell in cells):
        paths.append(plot_alpha_ablation(cells, out_dir / "figures" / "ablation_alpha.png"))
    if any(curve for cell in cells for curve in cell.ablation_k.values()):
        paths.append(plot_k_ablation(cells, out_dir / "figures" / "ablation_k.png"))
    return _with_vectors(paths)


def write_pr_curves(cells: Sequence[Any], config: Any, out_dir: Path) -> list[Path]:
    """``figures/pr/<vpr method>__<dataset>.png`` (and ``.pdf``) for every cell."""
    return [
        path
        for cell in cells
        for path in write_rejection_curves(
            cell.evaluation,
            out_dir / "figures" / "pr" / f"{slug(cell.vpr_method)}__{slug(cell.dataset)}.png",
            title=f"{cell.vpr_method} on {cell.dataset} ({cell.evaluation.n_queries} queries)",
        )
    ]


def pr_curves_section(cells: Sequence[Any], config: Any, written: list[Path]) -> str:
    """The note under the PR curves: what their axes and their area are."""
    return (
        '<p class="note">x: recall = correct answers accepted / answerable queries; y: precision = correct '
        "answers / accepted answers, as the most uncertain answers are rejected. The area under a curve is not "
        "the AUC-PR of the legend (which is over the correct answers only): the x axis is shrunk by recall@1. "
        "Methods that rank the queries identically share one line (e.g. “BM = L2”).</p>"
    )


def write_cascade(cells: Sequence[Any], config: Any, out_dir: Path) -> list[Path]:
    """``figures/cascade__<SCORE>_<GV>.png`` (and ``.pdf``): AUC-PR against the fraction verified."""
    from vpr_uncertainty.reports.cascade import plot_cascade

    return plot_cascade(cells, out_dir / "figures")


def cascade_section(cells: Sequence[Any], config: Any, written: list[Path]) -> str:
    """Each cascade's measured fraction verified, AUC-PR and time per query beside its two methods, as a table."""
    from html import escape

    from vpr_uncertainty.reports.cascade import cascades

    rows = []
    for name, score, gv in cascades(cells):
        for cell in cells:
            methods = cell.evaluation.methods
            if not {name, score, gv} <= set(methods):
                continue
            values = [methods[m] for m in (score, gv, name)]
            auc = ["n/a" if m.auc_pr is None else f"{m.auc_pr:.3f}" for m in values]
            rows.append(
                f"<tr><td>{escape(cell.vpr_method)} on {escape(cell.dataset)}</td><td>{escape(name)}</td>"
                f"<td>{methods[name].details.get('verified_fraction', float('nan')):.2f}</td>"
                + "".join(f"<td>{a}</td>" for a in auc)
                + f"<td>{values[1].time_per_query_ms:.3g}</td><td>{values[2].time_per_query_ms:.3g}</td></tr>"
            )
    if not rows:
        return ""
    head = (
        "<tr><th>cell</th><th>cascade</th><th>verified</th><th>AUC-PR score alone</th><th>AUC-PR GV alone</th>"
        "<th>AUC-PR cascade</th><th>ms/query GV</th><th>ms/query cascade</th></tr>"
    )
    return f"<table><thead>{head}</thead><tbody>{''.join(rows)}</tbody></table>"


def write_qualitative(cells: Sequence[Any], config: Any, out_dir: Path, *, rank_by: str = "SU") -> list[Path]:
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
    return _with_vectors(paths)
