"""Figures of evaluation results (matplotlib, drawn off-screen): the end-to-end precision-recall curves."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vpr_uncertainty.cache import atomic_path
from vpr_uncertainty.evaluation import Evaluation
from vpr_uncertainty.reports.display import AREA_NOTE, RejectionCurveDisplay
from vpr_uncertainty.reports.style import DPI, pyplot, save_figure

__all__ = ["AREA_NOTE", "draw_rejection_curves", "plot_rejection_curves", "write_rejection_curves"]


def draw_rejection_curves(evaluation: Evaluation, *, title: str | None = None) -> Any:
    """The figure of :func:`plot_rejection_curves` (the caller closes it).

    Methods whose curves coincide (the same ranking of the queries, e.g. BM and L2 on L2-normalised descriptors)
    are drawn once, labelled ``"BM = L2"``; every other method has its own colour, dash and marker.
    """
    plt = pyplot()
    figure, axes = plt.subplots(figsize=(6.4, 4.2))
    RejectionCurveDisplay.from_evaluation(evaluation, ax=axes, title=title)
    return figure


def plot_rejection_curves(evaluation: Evaluation, path: str | Path, *, title: str | None = None) -> Path:
    """Draw the end-to-end precision-recall curves of all methods in one figure and save it.

    Each curve is the VPR system's precision and recall as the uncertainty threshold for accepting an answer
    is relaxed; the legend, outside the axes, gives each method's AUC-PR, and a note under the axes says why the
    area under a curve is not that AUC-PR. The drawing is
    :meth:`~vpr_uncertainty.reports.display.RejectionCurveDisplay.from_evaluation` (to draw on your own axis).

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
