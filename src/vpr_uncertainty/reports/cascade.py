"""The cascade figure: AUC-PR of ``SCORE+GV`` against the fraction of queries verified (0: SCORE alone, 1: GV on
every query), one panel per dataset, for each cascade evaluated beside its two methods.

The curve is computed from the stored uncertainties of SCORE and GV (verifying a pair gives the same inliers
whichever other queries are verified, so the cascade at fraction f is :func:`combine_cascade` of the two), and the
cascade's measured point (its ``verified_fraction`` and AUC-PR) is marked on it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.evaluation import auc_pr
from vpr_uncertainty.methods.cascade import combine_cascade, most_uncertain, split_cascade_name
from vpr_uncertainty.reports.style import legend_outside, pyplot, save_figure

__all__ = ["FRACTIONS", "cascade_curve", "cascades", "plot_cascade"]

#: Fractions verified at which the curve is drawn.
FRACTIONS: tuple[float, ...] = tuple(round(0.05 * i, 2) for i in range(21))


def cascades(cells: Sequence[Any]) -> list[tuple[str, str, str]]:
    """(cascade name, SCORE, GV) of each cascade evaluated beside SCORE and GV in at least one cell."""
    found = []
    for name in dict.fromkeys(n for cell in cells for n in cell.evaluation.methods):
        parts = split_cascade_name(name.split(":")[0]) if "+" in name else None
        if parts and any(set(parts) <= set(cell.evaluation.methods) for cell in cells):
            found.append((name, *parts))
    return found


def cascade_curve(correct: np.ndarray, score: np.ndarray, gv: np.ndarray, fractions: Sequence[float]) -> np.ndarray:
    """AUC-PR of the cascade at each fraction verified (NaN when undefined: one class only)."""
    correct = np.asarray(correct, dtype=bool)
    if correct.all() or not correct.any():
        return np.full(len(fractions), np.nan)
    values = []
    for fraction in fractions:
        verified = most_uncertain(score, fraction)
        values.append(auc_pr(correct, combine_cascade(score, verified, np.asarray(gv)[verified])))
    return np.array(values)


def plot_cascade(cells: Sequence[Any], out_dir: str | Path) -> list[Path]:
    """``cascade__<SCORE>_<GV>.png`` (and ``.pdf``) for each cascade of :func:`cascades`."""
    from vpr_uncertainty.reports.figures import slug

    plt = pyplot()
    paths = []
    for name, score, gv in cascades(cells):
        usable = [c for c in cells if {score, gv} <= set(c.evaluation.methods)]
        datasets = list(dict.fromkeys(c.dataset for c in usable))
        figure, axes = plt.subplots(1, len(datasets), figsize=(4.2 * len(datasets) + 2.2, 3.6), squeeze=False)
        try:
            for axis, dataset in zip(axes[0], datasets, strict=True):
                here = [c for c in usable if c.dataset == dataset]
                curves = []
                for cell in here:
                    methods = cell.evaluation.methods
                    curve = cascade_curve(
                        cell.evaluation.correct, methods[score].uncertainty, methods[gv].uncertainty, FRACTIONS
                    )
                    curves.append(curve)
                    axis.plot(FRACTIONS, curve, color="0.75", linewidth=0.8, zorder=1)
                mean = np.nanmean(np.array(curves), axis=0)
                axis.plot(
                    FRACTIONS, mean, color="C0", linewidth=2, marker="o", markersize=3, label="mean over VPR methods"
                )
                measured = [
                    (c.evaluation.methods[name].details.get("verified_fraction"), c.evaluation.methods[name].auc_pr)
                    for c in here
                    if name in c.evaluation.methods and c.evaluation.methods[name].auc_pr is not None
                ]
                if measured:
                    x = float(np.mean([m[0] for m in measured]))
                    y = float(np.mean([m[1] for m in measured]))
                    axis.plot([x], [y], "D", color="C3", markersize=7, zorder=3, label=f"{name} as run (mean)")
                axis.plot([], [], color="0.75", linewidth=0.8, label="one VPR method")
                axis.set_title(f"{dataset} ({len(here)} VPR methods)", fontsize=10)
                axis.set_xlabel(f"fraction of queries verified by {gv} (most uncertain by {score} first)")
                axis.set_xlim(0, 1)
                axis.grid(alpha=0.3)
            axes[0][0].set_ylabel("AUC-PR of the cascade")
            legend_outside(axes[0][-1])
            figure.suptitle(f"{score}+{gv}: 0 = {score} alone, 1 = {gv} on every query", fontsize=10)
            paths += save_figure(figure, Path(out_dir) / f"cascade__{slug(score)}_{slug(gv)}.png")
        finally:
            plt.close(figure)
    return paths
