"""Figures of evaluation results (matplotlib, drawn off-screen)."""

from __future__ import annotations

from pathlib import Path

from vpr_uncertainty.cache import atomic_path
from vpr_uncertainty.evaluation import Evaluation

__all__ = ["plot_rejection_curves"]


def plot_rejection_curves(evaluation: Evaluation, path: str | Path, *, title: str | None = None) -> Path:
    """Draw the end-to-end precision-recall curves of all methods in one figure and save it.

    Each curve is the VPR system's precision and recall as the uncertainty threshold for accepting an answer
    is relaxed; the legend gives each method's AUC-PR.

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
        # Methods can rank queries identically (BM and L2 for normalised descriptors): vary the line style so
        # that overlapping curves stay visible.
        styles = ("-", "--", "-.", ":")
        for index, method in enumerate(evaluation.methods.values()):
            label = method.name if method.auc_pr is None else f"{method.name} (AUC-PR {method.auc_pr:.3f})"
            axes.plot(
                method.curve.recall,
                method.curve.precision,
                label=label,
                linewidth=1.5,
                linestyle=styles[(index // 10 + index) % len(styles)],
            )
        accept_all = float(evaluation.correct.mean())
        axes.axhline(accept_all, color="grey", linestyle=":", linewidth=1, label=f"accept all ({accept_all:.3f})")
        axes.set_xlabel("recall (correct accepted / answerable queries)")
        axes.set_ylabel("precision (correct accepted / accepted)")
        axes.set_xlim(0, 1.0)
        axes.set_ylim(0, 1.02)
        axes.grid(alpha=0.3)
        axes.legend(loc="lower left", fontsize="small")
        axes.set_title(title or f"Rejecting uncertain answers ({evaluation.n_queries} queries)")
        figure.tight_layout()
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as temporary:
            figure.savefig(temporary)
    finally:
        plt.close(figure)
    return path
