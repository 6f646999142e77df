"""The figures of a grid: ablations (the paper's Figures 5 and 6), ΔAUC-PR heatmaps (Figure 3), the cascade, and
qualitative examples (Figures 2 and 4). Each reads the cells' stored results and recomputes no uncertainty.

- Ablations: AUC-PR of SU versus α (α = 1 is RS, α = 0 is SD) with one panel per VPR method (each with its own y
  range: the preference for RS or SD depends on the VPR method, and an average hides it), one line per dataset, a
  star on each line's best α; RS and SD versus k with one panel per (dataset, method), one line per VPR method.
- Heatmaps: Δ = AUC-PR(RS, SD or SU) − AUC-PR(baseline), > 0 (blue) when the proposed method is better; one panel
  per baseline (baselines with the same Δ everywhere, such as BM and L2, share one), rows = VPR methods, columns =
  datasets.
- Cascade: AUC-PR of ``SCORE+GV`` against the fraction verified (0: SCORE alone, 1: GV on every query), computed from
  the stored uncertainties of SCORE and GV (verifying a pair gives the same inliers whichever other queries are
  verified), with the cascade's measured point marked.
- Qualitative: the most confident and most uncertain correct and wrong queries (by SU), each with its top-4 answers
  (green frame: positive, red: not) and RS, SD, SU.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.cache import slug
from vpr_uncertainty.evaluation import auc_pr
from vpr_uncertainty.methods.cascade import combine_cascade, most_uncertain, split_cascade_name
from vpr_uncertainty.reports.display import DPI, legend_outside, method_styles, pyplot, save_figure

__all__ = [
    "CATEGORIES",
    "FRACTIONS",
    "PANEL_SIZE",
    "PROPOSED",
    "SHOWN",
    "TOP",
    "ablation_figsize",
    "alpha_panels",
    "best_alpha",
    "cascade_curve",
    "cascades",
    "choose_queries",
    "delta_matrix",
    "heatmap_figsize",
    "k_panels",
    "plot_alpha_ablation",
    "plot_cascade",
    "plot_delta_heatmaps",
    "plot_k_ablation",
    "plot_qualitative",
    "qualitative_figsize",
]

# --- ablations ---

#: Size in inches of one panel of the small multiples.
PANEL_SIZE: tuple[float, float] = (2.8, 2.3)
#: Room in inches for the title above the panels, and for each row of the legend below them.
_TITLE_HEIGHT, _LEGEND_ROW = 0.55, 0.22
_MAX_COLUMNS = 5


def _defined(curve: dict) -> dict:
    """The points of a curve whose value is defined (not None), sorted by x."""
    return {x: y for x, y in sorted(curve.items()) if y is not None}


def best_alpha(curve: dict[float, float | None]) -> float | None:
    """The α of the highest AUC-PR of a curve (the smallest such α on a tie), or None when no point is defined.

    Examples
    --------
    >>> best_alpha({0.0: 0.61, 0.5: 0.70, 1.0: 0.70})
    0.5
    >>> best_alpha({0.0: None}) is None
    True
    """
    defined = _defined(curve)
    if not defined:
        return None
    top = max(defined.values())
    return min(a for a, value in defined.items() if value == top)


def alpha_panels(cells: Sequence) -> dict[str, dict[str, dict[float, float]]]:
    """VPR method -> dataset -> {α: AUC-PR of SU}: the panels of the α figure, in the order of the cells.

    VPR methods whose α curves are all undefined (every answer correct, or none) are left out.
    """
    panels: dict[str, dict[str, dict[float, float]]] = {}
    for cell in cells:
        curve = _defined(cell.ablation_alpha)
        if curve:
            panels.setdefault(cell.vpr_method, {})[cell.dataset] = curve
    return panels


def k_panels(cells: Sequence) -> dict[tuple[str, str], dict[str, dict[int, float]]]:
    """(dataset, "RS" or "SD") -> VPR method -> {k: AUC-PR}: the panels of the k figure, in the order of the cells."""
    panels: dict[tuple[str, str], dict[str, dict[int, float]]] = {}
    for dataset in dict.fromkeys(c.dataset for c in cells):
        for name in ("RS", "SD"):
            lines = {
                c.vpr_method: curve
                for c in cells
                if c.dataset == dataset and (curve := _defined(c.ablation_k.get(name, {})))
            }
            if lines:
                panels[(dataset, name)] = lines
    return panels


def _layout(n_panels: int, columns: int | None = None) -> tuple[int, int]:
    columns = min(max(n_panels, 1), _MAX_COLUMNS) if columns is None else columns
    return math.ceil(max(n_panels, 1) / columns), columns


def _legend_columns(n_entries: int, columns: int) -> int:
    """Legend entries per row: about two per panel column, at most five."""
    return max(1, min(n_entries, 2 * columns, 5))


def ablation_figsize(n_panels: int, columns: int | None = None, legend_entries: int = 1) -> tuple[float, float]:
    """Size in inches of a figure of ``n_panels`` small multiples (at most five per row, or ``columns`` per row),
    with room for the title above and a legend of ``legend_entries`` entries below.

    Examples
    --------
    >>> ablation_figsize(10)
    (14.0, 5.57)
    """
    rows, columns = _layout(n_panels, columns)
    legend_rows = math.ceil(max(legend_entries, 1) / _legend_columns(legend_entries, columns))
    return (
        round(PANEL_SIZE[0] * columns, 2),
        round(PANEL_SIZE[1] * rows + _TITLE_HEIGHT + _LEGEND_ROW * legend_rows + 0.2, 2),
    )


def _subplots(plt, n_panels: int, columns: int | None, legend_entries: int):
    """Constrained-layout small multiples, each panel with its own y range."""
    rows, columns = _layout(n_panels, columns)
    size = ablation_figsize(n_panels, columns, legend_entries)
    figure, axes = plt.subplots(rows, columns, figsize=size, dpi=DPI, squeeze=False, layout="constrained")
    for axis in axes.ravel()[n_panels:]:
        axis.set_visible(False)
    return figure, axes


def _legend_below(figure, handles: dict, columns: int) -> None:
    """One legend for the whole figure, below the panels (outside the data)."""
    if handles:
        figure.legend(
            list(handles.values()),
            list(handles),
            loc="outside lower center",
            ncol=_legend_columns(len(handles), columns),
            fontsize="small",
            frameon=False,
        )


def _save(figure, path: Path) -> Path:
    """The PNG and a PDF beside it, uncropped (the constrained layout keeps the legend inside); the PNG's path."""
    save_figure(figure, path, tight=False)
    return path


def plot_alpha_ablation(cells: Sequence, path: str | Path) -> Path:
    """AUC-PR of SU versus α: one panel per VPR method, one line per dataset, a star on each line's best α."""
    plt = pyplot()
    path = Path(path)
    panels = alpha_panels(cells)
    datasets = list(dict.fromkeys(d for lines in panels.values() for d in lines))
    entries = 1 + (len(datasets) if len(datasets) > 1 else 0)
    figure, axes = _subplots(plt, len(panels), None, entries)
    styles = method_styles(datasets)
    try:
        handles: dict = {}
        for axis, (vpr_method, lines) in zip(axes.ravel(), panels.items(), strict=False):
            bests = []
            for dataset, curve in lines.items():
                style = styles[dataset]
                (line,) = axis.plot(list(curve), list(curve.values()), markersize=3, label=dataset, **style)
                handles.setdefault(dataset, line)
                best = best_alpha(curve)
                axis.plot([best], [curve[best]], marker="*", markersize=12, color=style["color"], linestyle="none")
                bests.append(f"{best:g} ({curve[best]:.3f})")
            best_text = bests[0] if len(bests) == 1 else ", ".join(bests)
            axis.set_title(f"{vpr_method}\nbest α = {best_text}", fontsize="small")
            axis.set_xlim(-0.05, 1.05)
            axis.set_xticks([0, 0.5, 1], ["0\nSD", "0.5", "1\nRS"])
            axis.tick_params(labelsize="small")
            axis.grid(alpha=0.3)
        for axis in axes[:, 0]:
            axis.set_ylabel("AUC-PR of SU", fontsize="small")
        star = plt.Line2D([], [], marker="*", markersize=10, color="0.3", linestyle="none")
        shown = dict(handles) if len(datasets) > 1 else {}
        _legend_below(figure, {**shown, "best α (star)": star}, axes.shape[1])
        where = f" on {datasets[0]}" if len(datasets) == 1 else ""
        figure.suptitle(f"SU = α·RS + (1−α)·SD: AUC-PR versus α, per VPR method{where}", fontsize="medium")
        return _save(figure, path)
    finally:
        plt.close(figure)


def plot_k_ablation(cells: Sequence, path: str | Path) -> Path:
    """AUC-PR of RS and SD versus k: per dataset a panel for RS and one for SD, one line per VPR method."""
    import matplotlib.ticker

    plt = pyplot()
    path = Path(path)
    panels = k_panels(cells)
    methods = list(dict.fromkeys(m for lines in panels.values() for m in lines))
    figure, axes = _subplots(plt, len(panels), min(max(len(panels), 1), 2), len(methods))
    styles = method_styles(methods)
    try:
        handles: dict = {}
        ticks = sorted({k for lines in panels.values() for curve in lines.values() for k in curve})
        for axis, ((dataset, name), lines) in zip(axes.ravel(), panels.items(), strict=False):
            for vpr_method, curve in lines.items():
                (line,) = axis.plot(
                    list(curve),
                    list(curve.values()),
                    markersize=3,
                    label=vpr_method,
                    **styles[vpr_method],
                )
                handles.setdefault(vpr_method, line)
            axis.set_xscale("log")
            axis.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
            axis.set_xticks(ticks, [str(t) for t in ticks])
            axis.tick_params(labelsize="small")
            axis.set_xlabel("k (candidates used)", fontsize="small")
            axis.set_title(f"{name} · {dataset}", fontsize="small")
            axis.grid(alpha=0.3)
        for axis in axes[:, 0]:
            axis.set_ylabel("AUC-PR", fontsize="small")
        _legend_below(figure, handles, axes.shape[1])
        figure.suptitle("RS and SD: AUC-PR versus k, per VPR method", fontsize="medium")
        return _save(figure, path)
    finally:
        plt.close(figure)


# --- ΔAUC-PR heatmaps ---

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
    plt = pyplot()
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


# --- cascade ---

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


# --- qualitative examples ---

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
    cell : Cell
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
    plt = pyplot()
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
