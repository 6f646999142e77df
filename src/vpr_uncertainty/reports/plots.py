"""Figures of evaluation results (matplotlib, drawn off-screen)."""

from __future__ import annotations

from pathlib import Path

from vpr_uncertainty.cache import atomic_path
from vpr_uncertainty.evaluation import Evaluation
from vpr_uncertainty.reports.display import RejectionCurveDisplay

__all__ = ["plot_rejection_curves"]


def plot_rejection_curves(evaluation: Evaluation, path: str | Path, *, title: str | None = None) -> Path:
    """Draw the end-to-end precision-recall curves of all methods in one figure and save it.

    Each curve is the VPR system's precision and recall as the uncertainty threshold for accepting an answer
    is relaxed; the legend gives each method's AUC-PR. The drawing is
    :meth:`~vpr_uncertainty.reports.display.RejectionCurveDisplay.from_evaluation` (to draw on your own axis).

    Parameters
    ----------
    evaluation : Evaluation
        The result of :func:`vpr_uncertainty.evaluate`.
    path : str or Path
        Output file; the format follows its suffix (``.png``, ``.pdf``, ``.svg``).
    title : str, optional
        Figure title.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    path = Path(path)
    figure, axes = plt.subplots(figsize=(6.4, 4.8), dpi=120)
    try:
        RejectionCurveDisplay.from_evaluation(evaluation, ax=axes, title=title)
        figure.tight_layout()
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as temporary:
            figure.savefig(temporary)
    finally:
        plt.close(figure)
    return path
