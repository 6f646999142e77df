"""The reliability diagram of a calibrated P(correct) (matplotlib, drawn off-screen)."""

from __future__ import annotations

from pathlib import Path

from vpr_uncertainty.cache import atomic_path
from vpr_uncertainty.calibration.quality import Reliability

__all__ = ["plot_reliability"]


def plot_reliability(reliability: Reliability, path: str | Path, *, title: str | None = None) -> Path:
    """Draw observed accuracy against mean P per bin (with the count of each bin) and save it.

    Parameters
    ----------
    reliability : Reliability
        From :func:`vpr_uncertainty.calibration.quality.reliability_diagram`.
    path : str or Path
        Output file; the format follows its suffix (``.png``, ``.pdf``, ``.svg``).
    title : str, optional
        Figure title.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    path = Path(path)
    figure, axes = plt.subplots(figsize=(5.2, 4.8), dpi=120)
    try:
        axes.plot([0, 1], [0, 1], ":", color="grey", label="perfect calibration")
        bins = [
            (mean, accuracy, count)
            for mean, accuracy, count in zip(
                reliability.mean_probability, reliability.accuracy, reliability.counts, strict=True
            )
            if count
        ]
        axes.plot([b[0] for b in bins], [b[1] for b in bins], "o-", label="observed")
        for mean, accuracy, count in bins:
            axes.annotate(f"n={count}", (mean, accuracy), textcoords="offset points", xytext=(4, -10), fontsize=7)
        axes.set_xlim(0, 1)
        axes.set_ylim(0, 1.02)
        axes.set_xlabel("predicted P(correct top-1), mean of the bin")
        axes.set_ylabel("share of correct top-1 answers")
        axes.legend(loc="upper left")
        if title:
            axes.set_title(title)
        figure.tight_layout()
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as temporary:
            figure.savefig(temporary)
    finally:
        plt.close(figure)
    return path
