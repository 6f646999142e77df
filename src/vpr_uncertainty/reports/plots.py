"""Figures of evaluation results (matplotlib, drawn off-screen): the end-to-end precision-recall curves."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.cache import atomic_path
from vpr_uncertainty.evaluation import Evaluation
from vpr_uncertainty.reports.style import DPI, coinciding, legend_outside, method_styles, pyplot, save_figure

__all__ = ["AREA_NOTE", "draw_rejection_curves", "plot_rejection_curves", "write_rejection_curves"]

#: What the area under an end-to-end curve is (and is not); written under the plot and in report.html.
AREA_NOTE = (
    "Area under a curve ≠ the AUC-PR in the legend: the AUC-PR is the area of precision against the recall of "
    "correct answers; here recall counts all answerable queries, so the x axis is shrunk by recall@1 "
    "({recall:.2f}) and the area is about AUC-PR × recall@1."
)


def draw_rejection_curves(evaluation: Evaluation, *, title: str | None = None) -> Any:
    """The figure of :func:`plot_rejection_curves` (the caller closes it).

    Methods whose curves coincide (the same ranking of the queries, e.g. BM and L2 on L2-normalised descriptors)
    are drawn once, labelled ``"BM = L2"``; every other method has its own colour, dash and marker.
    """
    plt = pyplot()
    figure, axes = plt.subplots(figsize=(6.4, 4.2))
    methods = evaluation.methods
    groups = coinciding({name: (m.curve.recall, m.curve.precision) for name, m in methods.items()})
    styles = method_styles([" = ".join(group) for group in groups])
    for group in groups:
        label = " = ".join(group)
        method = methods[group[0]]
        text = label if method.auc_pr is None else f"{label} (AUC-PR {method.auc_pr:.3f})"
        points = len(method.curve.recall)
        axes.plot(
            method.curve.recall,
            method.curve.precision,
            label=text,
            linewidth=1.4,
            markersize=4,
            markevery=max(points // 8, 1),
            **styles[label],
        )
    accept_all = float(evaluation.correct.mean())
    axes.axhline(accept_all, color="grey", linestyle=":", linewidth=1, label=f"accept all ({accept_all:.3f})")
    axes.set_xlabel("recall: correct answers accepted / answerable queries")
    axes.set_ylabel("precision: correct answers / accepted answers")
    axes.set_xlim(0, 1.0)
    lowest = min([accept_all, *(float(m.curve.precision.min()) for m in methods.values() if len(m.curve.precision))])
    axes.set_ylim(max(0.0, np.floor((lowest - 0.05) * 10) / 10), 1.02)
    axes.grid(alpha=0.3)
    legend_outside(axes, title="uncertainty method")
    axes.set_title(title or f"Rejecting uncertain answers ({evaluation.n_queries} queries)", fontsize=10)
    recall_at_1 = evaluation.recall_at_n.get(1, accept_all)
    axes.text(
        0.0,
        -0.16,
        AREA_NOTE.format(recall=recall_at_1),
        transform=axes.transAxes,
        fontsize=7,
        va="top",
        wrap=True,
        color="0.3",
    )
    return figure


def plot_rejection_curves(evaluation: Evaluation, path: str | Path, *, title: str | None = None) -> Path:
    """Draw the end-to-end precision-recall curves of all methods in one figure and save it.

    Each curve is the VPR system's precision and recall as the uncertainty threshold for accepting an answer
    is relaxed; the legend, outside the axes, gives each method's AUC-PR, and a note under the axes says why the
    area under a curve is not that AUC-PR.

    Parameters
    ----------
    evaluation : Evaluation
        The result of :func:`vpr_uncertainty.evaluate`.
    path : str or Path
        Output file; the format follows its suffix (``.png`` at 300 dpi, ``.pdf``, ``.svg``).
    title : str, optional
        Figure title.
    """
    plt = pyplot()
    path = Path(path)
    figure = draw_rejection_curves(evaluation, title=title)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as temporary:
            figure.savefig(temporary, dpi=DPI, bbox_inches="tight", format=path.suffix.lstrip(".") or "png")
    finally:
        plt.close(figure)
    return path


def write_rejection_curves(evaluation: Evaluation, path: str | Path, *, title: str | None = None) -> list[Path]:
    """:func:`plot_rejection_curves` as a 300-dpi PNG (``path``) and a PDF beside it; returns both."""
    plt = pyplot()
    figure = draw_rejection_curves(evaluation, title=title)
    try:
        return save_figure(figure, path)
    finally:
        plt.close(figure)
