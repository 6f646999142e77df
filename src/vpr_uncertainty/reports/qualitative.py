"""Qualitative figure (the study's Figures 2 and 4): queries, their top-4 answers, and RS, SD, SU.

Four queries are chosen automatically by SU among the cell's answers: the most confident correct one, the most
confident wrong one, the most uncertain correct one and the most uncertain wrong one (a category without any
query is left out). Each row shows the query, with RS, SD and SU under it, then its top-4 database images with
their similarity scores, in a green frame when the image is a positive and red otherwise.

The uncertainties are those the grid stored in the cell's evaluation (nothing is recomputed): the figure shows
those of RS, SD and SU that the grid computed, and ranks by SU (or, without SU, by the first of them, or by the
first method of the cell).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.reports.style import DPI, save_figure

__all__ = ["CATEGORIES", "DPI", "SHOWN", "TOP", "choose_queries", "plot_qualitative", "qualitative_figsize"]

CATEGORIES: tuple[str, ...] = ("confident correct", "confident wrong", "uncertain correct", "uncertain wrong")
TOP = 4
#: The uncertainty methods shown under each query, when the cell has them.
SHOWN: tuple[str, ...] = ("RS", "SD", "SU")


def qualitative_figsize(n_rows: int) -> tuple[float, float]:
    """Figure size in inches for ``n_rows`` queries (``DPI`` pixels per inch)."""
    return (2.0 * (TOP + 1), 2.2 * n_rows)


def choose_queries(correct: np.ndarray, uncertainty: np.ndarray) -> dict[str, int]:
    """Category -> query index; confident = lowest uncertainty, uncertain = highest (ties: lowest index).

    Examples
    --------
    >>> choose_queries(np.array([True, False, True, False]), np.array([0.1, 0.2, 0.9, 0.8]))
    {'confident correct': 0, 'confident wrong': 1, 'uncertain correct': 2, 'uncertain wrong': 3}
    """
    correct = np.asarray(correct, dtype=bool)
    uncertainty = np.asarray(uncertainty, dtype=np.float64)
    chosen = {}
    for category in CATEGORIES:
        pool = np.flatnonzero(correct if category.endswith("correct") else ~correct)
        if pool.size:
            values = uncertainty[pool]
            pick = np.argmin(values) if category.startswith("confident") else np.argmax(values)
            chosen[category] = int(pool[pick])
    return chosen


def _image(path: str) -> np.ndarray:
    from matplotlib.image import imread

    return imread(path)


def plot_qualitative(
    cell: Any,
    path: str | Path,
    *,
    rank_by: str = "SU",
    shown: Sequence[str] = SHOWN,
    alpha: float | None = None,
) -> Path | None:
    """Draw the figure for one grid cell from its stored uncertainties.

    Parameters
    ----------
    cell : vpr_uncertainty.pipeline.grid_report.Cell
        The cell: its images, top-k scores, indices, hits and its evaluation's uncertainties.
    path : str or Path
        The PNG to write.
    rank_by : str, default="SU"
        The method whose uncertainties choose the queries; without it in the cell, the first of ``shown`` that
        the cell has, else its first method.
    shown : sequence of str, default=("RS", "SD", "SU")
        The methods whose uncertainties are written under each query (those the cell has).
    alpha : float, optional
        The α of SU, for the title.

    Returns
    -------
    Path or None
        ``path``, or None when the cell has no image paths or no uncertainties.
    """
    if not cell.query_paths or not cell.database_paths:
        return None
    uncertainties = {name: np.asarray(m.uncertainty, dtype=np.float64) for name, m in cell.evaluation.methods.items()}
    labels = [name for name in shown if name in uncertainties]
    if rank_by not in uncertainties:
        rank_by = next(iter(labels or uncertainties), None)
    if rank_by is None:
        return None
    labels = labels or [rank_by]
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    scores = np.asarray(cell.scores, dtype=np.float64)
    correct = np.asarray(cell.evaluation.correct, dtype=bool)
    chosen = choose_queries(correct, uncertainties[rank_by])
    if not chosen:
        return None
    path = Path(path)
    figure, axes = plt.subplots(len(chosen), TOP + 1, figsize=qualitative_figsize(len(chosen)), dpi=DPI, squeeze=False)
    try:
        for row, (category, query) in enumerate(chosen.items()):
            axis = axes[row][0]
            axis.imshow(_image(cell.query_paths[query]))
            axis.set_title(f"{category}\nquery {query}", fontsize=8)
            values = [f"{name} {uncertainties[name][query]:.3f}" for name in labels]
            axis.set_xlabel("  ".join(values[:2]) + ("\n" + "  ".join(values[2:]) if values[2:] else ""), fontsize=8)
            for column in range(1, TOP + 1):
                axis = axes[row][column]
                rank = column - 1
                index = int(cell.indices[query, rank]) if rank < cell.indices.shape[1] else -1
                if index < 0:
                    axis.set_axis_off()
                    continue
                axis.imshow(_image(cell.database_paths[index]))
                hit = bool(cell.hits[query, rank])
                colour = "tab:green" if hit else "tab:red"
                for spine in axis.spines.values():
                    spine.set_edgecolor(colour)
                    spine.set_linewidth(4)
                axis.set_title(f"#{rank + 1}  db {index}  s={scores[query, rank]:.3f}", fontsize=8)
            for axis in axes[row]:
                axis.set_xticks([])
                axis.set_yticks([])
        settings = [f"k={cell.evaluation.k}"] if cell.evaluation.k is not None else []
        settings += [f"α={alpha:g}"] if alpha is not None and rank_by.startswith("SU") else []
        suffix = f" ({', '.join(settings)})" if settings else ""
        figure.suptitle(f"{cell.vpr_method} on {cell.dataset}: answers ranked by {rank_by}{suffix}", fontsize=10)
        figure.tight_layout()
        save_figure(figure, path, tight=False)  # and a PDF beside it
    finally:
        plt.close(figure)
    return path
