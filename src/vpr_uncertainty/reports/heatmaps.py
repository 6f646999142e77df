"""ΔAUC-PR heatmaps (the study's Figure 3): RS, SD and SU against each baseline, per VPR method × dataset.

Δ = AUC-PR(proposed) − AUC-PR(baseline); positive (blue) means the proposed method predicts correct answers
better. One figure per proposed method, one panel per baseline (baselines with the same Δ in every cell, such
as BM and L2 on L2-normalised descriptors, share a panel titled "vs BM = L2"); rows = VPR methods, columns =
datasets.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_uncertainty.reports.style import DPI, save_figure

__all__ = ["DPI", "PROPOSED", "delta_matrix", "heatmap_figsize", "plot_delta_heatmaps"]

PROPOSED: tuple[str, ...] = ("RS", "SD", "SU")


def heatmap_figsize(n_vpr: int, n_datasets: int, n_baselines: int) -> tuple[float, float]:
    """Figure size in inches (the PNG is ``DPI`` times larger, in pixels)."""
    # At least 6 inches wide so that the title and the method names fit beside a single column.
    return (max(6.0, 2.2 + n_baselines * (1.2 + 0.7 * n_datasets)), 1.6 + 0.35 * n_vpr)


def delta_matrix(cells: Sequence, proposed: str, baseline: str) -> tuple[list[str], list[str], np.ndarray]:
    """(VPR methods, datasets, Δ of shape (V, D)); NaN where a cell or an AUC-PR is missing."""
    vpr_methods = list(dict.fromkeys(c.vpr_method for c in cells))
    datasets = list(dict.fromkeys(c.dataset for c in cells))
    delta = np.full((len(vpr_methods), len(datasets)), np.nan)
    for cell in cells:
        methods = cell.evaluation.methods
        if proposed in methods and baseline in methods:
            a, b = methods[proposed].auc_pr, methods[baseline].auc_pr
            if a is not None and b is not None:
                delta[vpr_methods.index(cell.vpr_method), datasets.index(cell.dataset)] = a - b
    return vpr_methods, datasets, delta


def plot_delta_heatmaps(cells: Sequence, out_dir: str | Path) -> list[Path]:
    """Write ``delta_<RS|SD|SU>.png`` for each proposed method present with at least one baseline."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = list(dict.fromkeys(name for c in cells for name in c.evaluation.methods))
    baselines = [n for n in names if n not in PROPOSED]
    paths = []
    for proposed in (p for p in PROPOSED if p in names):
        if not baselines:
            break
        matrices, titles = [], []
        for baseline in baselines:  # baselines with the same Δ everywhere (BM and L2) share one panel
            matrix = delta_matrix(cells, proposed, baseline)
            same = [i for i, m in enumerate(matrices) if np.array_equal(m[2], matrix[2], equal_nan=True)]
            if same:
                titles[same[0]] += f" = {baseline}"
            else:
                matrices.append(matrix)
                titles.append(baseline)
        vpr_methods, datasets = matrices[0][0], matrices[0][1]
        finite = np.concatenate([m[2][np.isfinite(m[2])] for m in matrices])
        limit = max(float(np.abs(finite).max()) if finite.size else 0.0, 1e-3)
        figure, axes = plt.subplots(
            1,
            len(matrices),
            figsize=heatmap_figsize(len(vpr_methods), len(datasets), len(matrices)),
            dpi=DPI,
            squeeze=False,
            layout="constrained",
        )
        try:
            for axis, baseline, (_, _, delta) in zip(axes[0], titles, matrices, strict=True):
                image = axis.imshow(delta, cmap="RdBu", vmin=-limit, vmax=limit, aspect="auto")
                for (i, j), value in np.ndenumerate(delta):
                    if np.isfinite(value):
                        colour = "white" if abs(value) > 0.6 * limit else "black"
                        axis.text(j, i, f"{value:+.2f}", ha="center", va="center", fontsize=7, color=colour)
                axis.set_xticks(range(len(datasets)), datasets, rotation=30, ha="right", fontsize=8)
                axis.set_yticks(range(len(vpr_methods)), vpr_methods if axis is axes[0][0] else [], fontsize=8)
                axis.set_title(f"vs {baseline}", fontsize=9)
            figure.colorbar(image, ax=list(axes[0]), shrink=0.8, label="Δ AUC-PR")
            figure.suptitle(f"{proposed}: Δ AUC-PR against each baseline (> 0: {proposed} better)", fontsize=10)
            path = out_dir / f"delta_{proposed}.png"
            save_figure(figure, path, tight=False)  # and a PDF beside it
        finally:
            plt.close(figure)
        paths.append(path)
    return paths
