"""The reliability diagram of a calibrated P(correct) (matplotlib, drawn off-screen)."""

from __future__ import annotations

from pathlib import Path

from vpr_uncertainty.cache import atomic_path
from vpr_uncertainty.calibration.quality import Reliability
from vpr_uncertainty.reports.display import ReliabilityDisplay

__all__ = ["plot_reliability"]


def plot_reliability(reliability: Reliability, path: str | Path, *, title: str | None = None) -> Path:
    """Draw observed accuracy against mean P per bin (with the count of each bin) and save it.

    The drawing is :class:`~vpr_uncertainty.reports.display.ReliabilityDisplay` (to draw on your own axis).

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
        ReliabilityDisplay.from_reliability(reliability, ax=axes, title=title)
        figure.tight_layout()
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as temporary:
            figure.savefig(temporary)
    finally:
        plt.close(figure)
    return path
