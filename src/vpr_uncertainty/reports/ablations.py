"""Ablation figures: AUC-PR of SU versus α (Figure 5) and of RS and SD versus k (Figure 6), per dataset.

Each line is one dataset, its AUC-PR averaged over the VPR methods of the grid. α = 1 is RS and α = 0 is SD.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_uncertainty.reports.style import DPI, legend_outside, save_figure

__all__ = ["ABLATION_SIZE", "DPI", "ablation_alpha_means", "ablation_k_means", "plot_alpha_ablation", "plot_k_ablation"]

#: Figure size in inches (the PNGs, cropped to their content with the legend outside, at DPI = 300).
ABLATION_SIZE: tuple[float, float] = (6.4, 4.0)


def _mean_curves(curves: Sequence[dict]) -> dict:
    values: dict = {}
    for curve in curves:
        for x, y in curve.items():
            if y is not None:
                values.setdefault(x, []).append(y)
    return {x: float(np.mean(ys)) for x, ys in sorted(values.items())}


def ablation_alpha_means(cells: Sequence) -> dict[str, dict[float, float]]:
    """dataset -> {α: AUC-PR of SU averaged over VPR methods}."""
    datasets = dict.fromkeys(c.dataset for c in cells)
    return {d: _mean_curves([c.ablation_alpha for c in cells if c.dataset == d]) for d in datasets}


def ablation_k_means(cells: Sequence) -> dict[str, dict[str, dict[int, float]]]:
    """method (RS, SD) -> dataset -> {k: AUC-PR averaged over VPR methods}."""
    datasets = dict.fromkeys(c.dataset for c in cells)
    return {
        name: {d: _mean_curves([c.ablation_k.get(name, {}) for c in cells if c.dataset == d]) for d in datasets}
        for name in ("RS", "SD")
    }


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _ticker():
    import matplotlib.ticker

    return matplotlib.ticker


def plot_alpha_ablation(cells: Sequence, path: str | Path) -> Path:
    """AUC-PR of SU versus α, one line per dataset."""
    plt = _pyplot()
    path = Path(path)
    figure, axis = plt.subplots(figsize=ABLATION_SIZE, dpi=DPI)
    try:
        for dataset, curve in ablation_alpha_means(cells).items():
            axis.plot(list(curve), list(curve.values()), marker="o", label=dataset)
        axis.set_xlabel("α (weight of RS in SU; 0 = SD, 1 = RS)")
        axis.set_ylabel("AUC-PR (mean over VPR methods)")
        axis.set_xlim(-0.02, 1.02)
        axis.grid(alpha=0.3)
        legend_outside(axis)
        axis.set_title("SU: AUC-PR versus α")
        figure.tight_layout()
        save_figure(figure, path)  # and a PDF beside it
    finally:
        plt.close(figure)
    return path


def plot_k_ablation(cells: Sequence, path: str | Path) -> Path:
    """AUC-PR of RS (solid) and SD (dashed) versus k, one colour per dataset."""
    plt = _pyplot()
    path = Path(path)
    figure, axis = plt.subplots(figsize=ABLATION_SIZE, dpi=DPI)
    try:
        means = ablation_k_means(cells)
        for index, dataset in enumerate(means["RS"]):
            for name, style in (("RS", "-"), ("SD", "--")):
                curve = means[name][dataset]
                axis.plot(
                    list(curve),
                    list(curve.values()),
                    style,
                    marker="o",
                    color=f"C{index % 10}",
                    label=f"{name} · {dataset}",
                )
        axis.set_xscale("log")
        ticks = sorted({k for c in cells for curve in c.ablation_k.values() for k in curve})
        axis.xaxis.set_minor_locator(_ticker().NullLocator())
        if ticks:
            axis.set_xticks(ticks, [str(t) for t in ticks])
        axis.set_xlabel("k (candidates used)")
        axis.set_ylabel("AUC-PR (mean over VPR methods)")
        axis.grid(alpha=0.3)
        legend_outside(axis)
        axis.set_title("RS and SD: AUC-PR versus k")
        figure.tight_layout()
        save_figure(figure, path)  # and a PDF beside it
    finally:
        plt.close(figure)
    return path
