"""Ablation figures, as in the paper: AUC-PR of SU versus α (Figure 5) and of RS and SD versus k (Figure 6).

The α figure has **one panel per VPR method** (small multiples, each with its own y range), one line per dataset, and a
star on each line's best α: the paper shows APGeM and EigenPlaces separately because the preference for RS
(α → 1) or SD (α → 0) depends on the VPR method, and an average over methods hides it. The k figure has one panel
per (dataset, metric) pair, RS on the left and SD on the right, with **one line per VPR method**. α = 1 is RS and
α = 0 is SD. The averages over VPR methods are still available as numbers (:func:`ablation_alpha_means`,
:func:`ablation_k_means`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_uncertainty.reports.style import DPI, save_figure

__all__ = [
    "ABLATION_SIZE",
    "DPI",
    "PANEL_SIZE",
    "ablation_alpha_means",
    "ablation_figsize",
    "ablation_k_means",
    "alpha_panels",
    "best_alpha",
    "k_panels",
    "plot_alpha_ablation",
    "plot_k_ablation",
]

#: Size in inches of a figure of one panel (kept for callers of the former single-panel figures).
ABLATION_SIZE: tuple[float, float] = (6.4, 4.0)
#: Size in inches of one panel of the small multiples.
PANEL_SIZE: tuple[float, float] = (2.8, 2.3)
#: Room in inches for the title above the panels, and for each row of the legend below them.
_TITLE_HEIGHT, _LEGEND_ROW = 0.55, 0.22
_MAX_COLUMNS = 5
_LINE_STYLES = ("-", "--", "-.", ":")
_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "*")


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


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _ticker():
    import matplotlib.ticker

    return matplotlib.ticker


def _style(index: int) -> dict:
    """Colour, line style and marker of the index-th line: distinct for up to 40 lines."""
    return {
        "color": f"C{index % 10}",
        "linestyle": _LINE_STYLES[(index // 10) % len(_LINE_STYLES)],
        "marker": _MARKERS[index % len(_MARKERS)],
    }


def _subplots(plt, n_panels: int, columns: int | None, legend_entries: int):
    """Constrained-layout small multiples; each panel keeps its own y range (the differences between α or k
    within one VPR method are small next to those between methods)."""
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
    """The PNG at :data:`DPI` and a vector PDF beside it; the PNG's path. The constrained layout already keeps the
    legend below the panels inside the figure, so the figure keeps its size (no cropping)."""
    save_figure(figure, path, tight=False)
    return path


def plot_alpha_ablation(cells: Sequence, path: str | Path) -> Path:
    """AUC-PR of SU versus α: one panel per VPR method, one line per dataset, a star on each line's best α."""
    plt = _pyplot()
    path = Path(path)
    panels = alpha_panels(cells)
    datasets = list(dict.fromkeys(d for lines in panels.values() for d in lines))
    entries = 1 + (len(datasets) if len(datasets) > 1 else 0)
    figure, axes = _subplots(plt, len(panels), None, entries)
    try:
        handles: dict = {}
        for axis, (vpr_method, lines) in zip(axes.ravel(), panels.items(), strict=False):
            bests = []
            for dataset, curve in lines.items():
                style = _style(datasets.index(dataset))
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
    plt = _pyplot()
    path = Path(path)
    panels = k_panels(cells)
    methods = list(dict.fromkeys(m for lines in panels.values() for m in lines))
    figure, axes = _subplots(plt, len(panels), min(max(len(panels), 1), 2), len(methods))
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
                    **_style(methods.index(vpr_method)),
                )
                handles.setdefault(vpr_method, line)
            axis.set_xscale("log")
            axis.xaxis.set_minor_locator(_ticker().NullLocator())
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
