"""The figures of a grid, drawn from the cells' stored results (no uncertainty is recomputed): the α and k ablations,
the ΔAUC-PR heatmaps, the cascade and the qualitative examples, each with a ``*_spec`` function returning the
:class:`~vpr_uncertainty.reports.style.FigureSpec` its caption comes from (see docs/explanation/reports.md).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.cache import slug
from vpr_uncertainty.evaluation import auc_pr
from vpr_uncertainty.evaluation.bootstrap import evaluation_distributions, holm_against
from vpr_uncertainty.methods.cascade import combine_cascade, most_uncertain, split_cascade_name
from vpr_uncertainty.reports.html import averaged_over
from vpr_uncertainty.reports.style import (
    DPI,
    OKABE_ITO,
    FigureSpec,
    SeriesSpec,
    capped_height,
    figure_rc,
    figure_width,
    method_styles,
    pyplot,
    save_figure,
)

# --- ablations ---

#: Room in inches for the title above the panels, and for each row of the legend below them.
_TITLE_HEIGHT, _LEGEND_ROW = 0.35, 0.17
#: Most panels per row, by figure width.
_MAX_COLUMNS = {"column": 2, "page": 4}
#: Panel height / panel width.
_PANEL_ASPECT = 0.8


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


def _layout(n_panels: int, columns: int | None = None, width: str = "page") -> tuple[int, int]:
    columns = min(max(n_panels, 1), _MAX_COLUMNS[width]) if columns is None else columns
    return math.ceil(max(n_panels, 1) / columns), columns


def _legend_columns(n_entries: int, width: str = "page", labels: Sequence[str] = ()) -> int:
    """Legend entries per row: two (column width) or four (page width), fewer when there are fewer or when the
    longest label would not fit that many side by side (a handle and 8-pt text, :data:`_CHARACTER_INCHES` each)."""
    entry = 0.55 + _CHARACTER_INCHES * max((len(label) for label in labels), default=0)
    fitting = max(1, int(figure_width(width) // entry))
    return max(1, min(n_entries, 2 if width == "column" else 4, fitting))


def ablation_figsize(
    n_panels: int, columns: int | None = None, legend_entries: int = 1, *, width: str = "page", aspect: float = 0.8
) -> tuple[float, float]:
    """Size in inches of a figure of ``n_panels`` small multiples (at most 2 per row in a column, 4 in a page, or
    ``columns`` per row), ``width`` wide, with room for the title above and a legend of ``legend_entries`` entries
    below; at most :data:`~vpr_uncertainty.reports.style.MAX_HEIGHTS` tall.

    Examples
    --------
    >>> ablation_figsize(10)
    (7.16, 6.42)
    >>> ablation_figsize(10, width="column")
    (3.5, 7.0)
    """
    inches = figure_width(width)
    rows, columns = _layout(n_panels, columns, width)
    legend_rows = math.ceil(max(legend_entries, 1) / _legend_columns(legend_entries, width))
    panel_height = max(1.3, aspect * inches / columns) + 0.45  # + a two-line title and the tick labels
    return inches, capped_height(panel_height * rows + _TITLE_HEIGHT + _LEGEND_ROW * legend_rows + 0.25, width)


def _subplots(plt, n_panels: int, columns: int | None, legend_entries: int, width: str, aspect: float = 0.8):
    """Constrained-layout small multiples sharing one y range (call inside :func:`figure_rc`)."""
    rows, columns = _layout(n_panels, columns, width)
    size = ablation_figsize(n_panels, columns, legend_entries, width=width, aspect=aspect)
    figure, axes = plt.subplots(rows, columns, figsize=size, dpi=DPI, squeeze=False, sharey=True, layout="constrained")
    for axis in axes.ravel()[n_panels:]:
        axis.set_visible(False)
    for axis in axes.ravel()[:n_panels]:
        axis.tick_params(labelleft=True)  # each panel keeps its labels: panels may wrap unevenly
    return figure, axes


def _finish(plt, figure, axes, spec: FigureSpec, width: str, title: str | None = None, legend: str = "") -> None:
    """Label the y axes of the first column, draw the legend of ``spec``'s series below the panels and the title."""
    for axis in axes[:, 0]:
        axis.set_ylabel(spec.y)
    styles = {s.label: {"markersize": 8 if s.style is _STAR else 4, **s.style} for s in spec.series}
    if styles:  # one legend for the whole figure, below the panels (outside the data)
        _legend(plt, figure, styles, width, title=legend or None)
    figure.suptitle(_fitted(title or spec.what, figure))


def _legend(plt, target, styles: dict[str, dict], width: str, title: str | None = None) -> None:
    """A legend of ``styles`` (label -> line style) below ``target``'s panels, as many entries a row as fit."""
    handles = [plt.Line2D([], [], **style) for style in styles.values()]
    ncol = _legend_columns(len(styles), width, list(styles))
    target.legend(handles, list(styles), loc="outside lower center", ncol=ncol, frameon=False, title=title)


_STAR = {"marker": "*", "linestyle": "none", "color": "0.3"}
#: Most lines in one panel of the k figure (more VPR methods: several panels).
MAX_SERIES = 8


def alpha_deltas(cells: Sequence, reference: float = 0.5) -> dict[str, dict[float, float]]:
    """VPR method -> {α: AUC-PR of SU at α minus at α = ``reference`` (interpolated between the αs run)}, the mean
    over the datasets of that VPR method where the curve is defined."""
    deltas = {}
    for vpr_method, lines in alpha_panels(cells).items():
        curves = [
            {a: v - float(np.interp(reference, list(c), list(c.values()))) for a, v in c.items()}
            for c in lines.values()
        ]
        alphas = sorted({a for curve in curves for a in curve})
        deltas[vpr_method] = {a: float(np.mean([c[a] for c in curves if a in c])) for a in alphas}
    return deltas


def alpha_ablation_spec(cells: Sequence, reference: float = 0.5) -> FigureSpec:
    """What :func:`plot_alpha_ablation` draws: one axis, a line per VPR method (its best α in its label)."""
    deltas = alpha_deltas(cells, reference)
    styles = method_styles(list(deltas))
    series = [SeriesSpec(f"{m} ({best_alpha(c):g})", "VPR method (best α)", styles[m]) for m, c in deltas.items()]
    series.append(SeriesSpec("best α (star)", "the highest AUC-PR of each line", _STAR))
    return FigureSpec(
        what=f"SU = α·RS + (1−α)·SD, {averaged_over([c for c in cells if c.ablation_alpha])}: ΔAUC-PR against α",
        series=tuple(series),
        x="α (0: SD, 1: RS)",
        y=f"AUC-PR(α) − AUC-PR(α = {reference:g})",
        notes=(f"Each line is a VPR method's AUC-PR of SU relative to SU at α = {reference:g} (Table 1's SU)",),
    )


def plot_alpha_ablation(cells: Sequence, path: str | Path, *, width: str = "page", reference: float = 0.5) -> Path:
    """ΔAUC-PR of SU (against α = ``reference``) versus α: one axis, one line per VPR method (the mean over its
    datasets), a star on each line's best α; ``width`` "page" (7.16 in) or "column" (3.5 in). Described by
    :func:`alpha_ablation_spec`."""
    plt = pyplot()
    spec = alpha_ablation_spec(cells, reference)
    with figure_rc(width):
        figure, axes = _subplots(plt, 1, 1, len(spec.series), width, aspect=0.55 if width == "page" else 0.75)
        try:
            axis = axes[0, 0]
            for series, curve in zip(spec.series, alpha_deltas(cells, reference).values(), strict=False):
                axis.plot(list(curve), list(curve.values()), label=series.label, markersize=3, **series.style)
                best = best_alpha(curve)
                axis.plot([best], [curve[best]], markersize=9, zorder=3, **{**_STAR, "color": series.style["color"]})
            axis.axhline(0, color="0.5", linewidth=0.6)
            axis.set(xlim=(-0.03, 1.03), xlabel=spec.x)
            axis.set_xticks([0, 0.25, 0.5, 0.75, 1], ["0\nSD", "0.25", "0.5", "0.75", "1\nRS"])
            axis.grid(alpha=0.3)
            _finish(plt, figure, axes, spec, width, legend="VPR method (best α)")
            return save_figure(figure, path, tight=False)[0]  # and a PDF beside it
        finally:
            plt.close(figure)


def k_rows(cells: Sequence, width: str = "page") -> list[tuple[str, list[tuple[str, list[str]]]]]:
    """The rows of the k figure: (dataset, [(part, VPR methods)]): the VPR methods of a dataset in groups of at most
    :data:`MAX_SERIES` (as even as possible; ``part`` "1/2", or "" for one group), one RS and SD pair of panels per
    group, one pair per row in a column width and two in a page width."""
    rows = []
    for dataset in dict.fromkeys(c.dataset for c in cells):
        methods = list(
            dict.fromkeys(c.vpr_method for c in cells if c.dataset == dataset and any(c.ablation_k.values()))
        )
        n = -(-len(methods) // MAX_SERIES)
        size = -(-len(methods) // max(n, 1))
        groups = [
            (f"{i // size + 1}/{n}" if n > 1 else "", methods[i : i + size]) for i in range(0, len(methods), size)
        ]
        per_row = 1 if width == "column" else 2
        rows += [(dataset, groups[i : i + per_row]) for i in range(0, len(groups), per_row)]
    return rows


def k_ablation_spec(cells: Sequence, width: str = "page") -> FigureSpec:
    """What :func:`plot_k_ablation` draws: per dataset and group of VPR methods a panel for RS and one for SD."""
    rows = k_rows(cells, width)
    methods = list(dict.fromkeys(m for _, groups in rows for _, group in groups for m in group))
    styles = method_styles(methods)
    return FigureSpec(
        what="RS and SD: AUC-PR against k, the candidates used, per VPR method",
        panels=tuple(
            f"{n} · {d}{f' ({part})' if part else ''}" for d, gs in rows for part, _ in gs for n in ("RS", "SD")
        ),
        panel_rule=f"per dataset, an RS and an SD panel for each group of at most {MAX_SERIES} VPR methods",
        series=tuple(SeriesSpec(m, "VPR method", styles[m]) for m in methods),
        x="k (candidates used)",
        y="AUC-PR",
        shared_y=True,
    )


def plot_k_ablation(cells: Sequence, path: str | Path, *, width: str = "page") -> Path:
    """AUC-PR of RS and SD versus k: per dataset and group of at most :data:`MAX_SERIES` VPR methods an RS and an
    SD panel (one shared y range), one line per VPR method, each row's legend below it; ``width`` "page" or
    "column". Described by :func:`k_ablation_spec`."""
    import matplotlib.ticker

    plt = pyplot()
    spec, rows = k_ablation_spec(cells, width), k_rows(cells, width)
    styles = {s.label: s.style for s in spec.series}
    curves = {(c.dataset, n, c.vpr_method): _defined(c.ablation_k.get(n, {})) for c in cells for n in ("RS", "SD")}
    values = [v for curve in curves.values() for v in curve.values()]
    low, high = min(values, default=0.0), max(values, default=1.0)
    ticks = sorted({k for curve in curves.values() for k in curve})
    legends = [[m for _, group in groups for m in group] for _, groups in rows]
    columns = 2 * max(len(groups) for _, groups in rows)
    height = len(rows) * (max(1.3, _PANEL_ASPECT * figure_width(width) / columns) + 0.6) + _TITLE_HEIGHT
    height += _LEGEND_ROW * sum(math.ceil(len(e) / _legend_columns(len(e), width, e)) for e in legends)
    with figure_rc(width):
        figure = plt.figure(figsize=(figure_width(width), capped_height(height, width)), dpi=DPI, layout="constrained")
        try:
            titles = iter(spec.panels)
            subfigures = figure.subfigures(len(rows), 1, squeeze=False)[:, 0]
            for row, (dataset, groups), entries in zip(subfigures, rows, legends, strict=True):
                axes = row.subplots(1, columns, sharey=True)
                for axis, (group, name) in zip(axes, [(g, n) for _, g in groups for n in ("RS", "SD")], strict=False):
                    for vpr_method in group:
                        curve = curves[(dataset, name, vpr_method)]
                        axis.plot(list(curve), list(curve.values()), label=vpr_method, **styles[vpr_method])
                    axis.set_xscale("log")
                    axis.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
                    axis.set_xticks(
                        ticks,
                        [f"{t}" if width == "page" or f"{t}".rstrip("0") in ("1", "2", "5") else "" for t in ticks],
                    )
                    margin = 0.05 * (high - low or 1)
                    axis.set(xlabel=spec.x, title=next(titles), ylim=(low - margin, high + margin))
                    axis.tick_params(labelleft=True)
                    axis.grid(alpha=0.3)
                for axis in axes[2 * len(groups) :]:
                    axis.set_visible(False)
                axes[0].set_ylabel(spec.y)
                _legend(plt, row, {m: styles[m] for m in entries}, width)
            figure.suptitle(_fitted(spec.what, figure))
            return save_figure(figure, path, tight=False)[0]  # and a PDF beside it
        finally:
            plt.close(figure)


# --- ΔAUC-PR heatmaps ---

PROPOSED: tuple[str, ...] = ("RS", "SD", "SU")


def heatmap_layout(
    vpr_methods: Sequence[str], column_labels: Sequence[str], titles: Sequence[str], *, width: str = "page"
) -> tuple[int, int, tuple[float, float]]:
    """(rows, columns) of the panel grid and the figure size in inches: as many panels side by side as fit
    ``width`` at 8 pt (the VPR-method names on the left; the colour bar on the right, or below in a column), the
    others wrapped below. ``column_labels``: the columns of one panel (the datasets, or the baselines).

    Examples
    --------
    >>> names, titles = ["NetVLAD"] * 10, ["vs BM = L2", "vs PA", "vs margin", "vs GV-SIFT"]
    >>> heatmap_layout(names, ["corridor"], titles), heatmap_layout(names, ["corridor"], titles, width="column")
    ((1, 4, (7.16, 3.04)), (2, 3, (3.5, 6.48)))
    """
    total = figure_width(width)
    bar = 0.8 if _colour_bar_side(width) == "right" else 0.0
    names = max((len(name) for name in vpr_methods), default=4) * _CHARACTER_INCHES + 0.25
    title = max((len(text) for text in titles), default=4) * _CHARACTER_INCHES + 0.15
    panel = max(0.45 * len(column_labels), title, 0.5)
    columns = max(1, min(len(titles), int((total - names - bar) // panel)))
    rows = -(-len(titles) // columns)
    labels = 0.15 + 0.5 * _CHARACTER_INCHES * max((len(name) for name in column_labels), default=4)  # rotated 30°
    panel_height = 0.2 * len(vpr_methods) + 0.25 + labels  # cells, title, column labels
    return rows, columns, (total, capped_height(0.4 + rows * panel_height + (0.8 if not bar else 0.0), width))


def _fitted(title: str, figure: Any) -> str:
    """``title`` wrapped onto as many lines as the figure's width needs at 9 pt (suptitles are not clipped)."""
    return textwrap.fill(title, max(20, int(figure.get_figwidth() / (1.25 * _CHARACTER_INCHES))))


def _colour_bar_side(width: str) -> str:
    """Where a heatmap's colour bar goes: below the panels in a column (the width is for the cells), else right."""
    return "bottom" if width == "column" else "right"


#: Width of one character of 8-pt text, in inches (about 0.55 of the point size).
_CHARACTER_INCHES = 0.06


def delta_matrix(
    cells: Sequence, proposed: str, baseline: str, distributions: dict | None = None
) -> tuple[list[str], list[str], np.ndarray, np.ndarray]:
    """(VPR methods, datasets, Δ of shape (V, D), significant of shape (V, D)); Δ is NaN where a cell or an AUC-PR is
    missing; significant: Table 1's rule, Holm over ``proposed`` against each other method of its cell (holm_against;
    ``distributions``: (VPR method, dataset) -> method -> resampled AUC-PR, :func:`heatmap_distributions`)."""
    vpr_methods, datasets = (list(dict.fromkeys(getattr(c, key) for c in cells)) for key in ("vpr_method", "dataset"))
    shape = (len(vpr_methods), len(datasets))
    delta, significant = np.full(shape, np.nan), np.zeros(shape, bool)
    for cell in cells:
        methods, at = cell.evaluation.methods, (vpr_methods.index(cell.vpr_method), datasets.index(cell.dataset))
        if proposed in methods and baseline in methods:
            a, b = methods[proposed].auc_pr, methods[baseline].auc_pr
            if a is not None and b is not None:
                delta[at] = a - b
            resampled = (distributions or {}).get((cell.vpr_method, cell.dataset))
            adjusted = holm_against(resampled, proposed, [n for n in resampled if n != proposed]) if resampled else {}
            significant[at] = adjusted.get(baseline, 1.0) <= 0.05
    return vpr_methods, datasets, delta, significant


def heatmap_distributions(cells: Sequence, bootstrap: int, seed: int) -> dict | None:
    """(VPR method, dataset) -> method -> AUC-PR on ``bootstrap`` paired resamples of its queries (None for 0)."""
    if not bootstrap:
        return None
    return {(c.vpr_method, c.dataset): evaluation_distributions(c.evaluation, bootstrap, seed)["auc_pr"] for c in cells}


def _signed(value: float) -> str:
    """``+0.12``, ``-0.05``, and ``0.00`` for anything that rounds to zero (never "-0.00")."""
    return "0.00" if round(value, 2) == 0 else f"{value:+.2f}"


def _heatmap_panels(cells: Sequence, proposed: str, distributions: dict | None = None) -> tuple[list[str], list]:
    """(panel titles, :func:`delta_matrix` of each): one panel per baseline; baselines with the same Δ everywhere
    share one."""
    names = list(dict.fromkeys(name for c in cells for name in c.evaluation.methods))
    matrices: list[tuple[list[str], list[str], np.ndarray, np.ndarray]] = []
    titles: list[str] = []
    for baseline in (n for n in names if n not in PROPOSED):
        matrix = delta_matrix(cells, proposed, baseline, distributions)
        same = [i for i, m in enumerate(matrices) if np.array_equal(m[2], matrix[2], equal_nan=True)]
        if same:
            titles[same[0]] += f" = {baseline}"
        else:
            matrices.append(matrix)
            titles.append(f"vs {baseline}")
    return titles, matrices


def heatmap_spec(cells: Sequence, proposed: str, *, bootstrap: int = 0, seed: int = 0) -> FigureSpec:
    """What the heatmap of ``proposed`` (RS, SD or SU) draws: one panel per baseline, rows VPR methods, columns
    datasets; with a single dataset, one panel whose columns are the baselines (a column of one cell per panel
    would not fit a paper's column). With ``bootstrap`` resamples, the caption says what the * marks mean."""
    return _heatmap_spec(proposed, *_heatmap_panels(cells, proposed), _marks_note(bootstrap, seed))


def _marks_note(bootstrap: int, seed: int) -> str:
    return (
        f"*: significant, as in Table 1: Holm-adjusted p <= 0.05 over the method's comparisons with every other "
        f"method of its cell (paired bootstrap over the cell's queries, {bootstrap} resamples, seed {seed})"
        if bootstrap
        else "No significance marks (bootstrap = 0)"
    )


def _heatmap_spec(proposed: str, titles: list[str], matrices: list, marks: str = "") -> FigureSpec:
    n_vpr = len(matrices[0][0]) if matrices else 0
    datasets = matrices[0][1] if matrices else []
    notes = (
        f"Each cell is AUC-PR({proposed}) − AUC-PR(baseline), printed in the cell and coloured on one diverging "
        f"scale{' for all panels' if len(datasets) > 1 else ''}: blue > 0 ({proposed} predicts correct answers "
        "better), red < 0",
        marks,
    )
    one = len(datasets) == 1  # one panel, whose columns are the baselines
    return FigureSpec(
        what=f"{proposed}: Δ AUC-PR against each baseline (> 0: {proposed} better) on "
        f"{', '.join(datasets) or 'no dataset'}",
        panels=(datasets[0],) if one else tuple(titles),
        panel_rule=(
            "one panel (one dataset); one column per baseline, baselines with the same Δ in every cell sharing one, "
            "e.g. “BM = L2”"
            if one
            else "one per baseline; baselines with the same Δ in every cell share one, e.g. “vs BM = L2”"
        ),
        x="baseline (" + ", ".join(title.removeprefix("vs ") for title in titles) + ")" if one else "dataset",
        y=f"VPR method ({n_vpr})",
        notes=notes,
    )


def _heatmap(cells: Sequence, proposed: str, distributions: dict | None = None, marks: str = "") -> tuple | None:
    """The spec, the VPR methods (rows) and, per panel, (column labels, Δ and significant of shape (rows, columns))
    of the heatmap of ``proposed``, from one computation of the Δ matrices; None without a baseline."""
    titles, matrices = _heatmap_panels(cells, proposed, distributions)
    if not matrices:
        return None
    spec = _heatmap_spec(proposed, titles, matrices, marks)
    datasets = matrices[0][1]
    if len(datasets) == 1:  # one panel: rows VPR methods, columns the baselines
        columns = [title.removeprefix("vs ") for title in titles]
        panels = [(columns, *(np.column_stack([m[part][:, 0] for m in matrices]) for part in (2, 3)))]
    else:  # one panel per baseline, columns the datasets
        panels = [(datasets, delta, significant) for _, _, delta, significant in matrices]
    return spec, matrices[0][0], panels


def heatmap_figure_size(cells: Sequence, proposed: str, *, width: str = "page") -> tuple[float, float]:
    """The size in inches of the heatmap :func:`plot_delta_heatmaps` draws for ``proposed``."""
    found = _heatmap(cells, proposed)
    if found is None:
        raise ValueError(f"no heatmap of {proposed}: the cells hold no baseline beside it")
    spec, vpr_methods, panels = found
    return heatmap_layout(vpr_methods, panels[0][0], spec.panels, width=width)[2]


def plot_delta_heatmaps(
    cells: Sequence, out_dir: str | Path, *, width: str = "page", bootstrap: int = 0, seed: int = 0
) -> list[Path]:
    """Write ``delta_<RS|SD|SU>.png`` for each proposed method present with at least one baseline; ``width``
    "page" (7.16 in) or "column" (3.5 in); with ``bootstrap`` resamples, a * after each Δ significant by Table 1's
    rule (:func:`delta_matrix`). Described by :func:`heatmap_spec`."""
    plt = pyplot()
    figure_width(width)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = list(dict.fromkeys(name for c in cells for name in c.evaluation.methods))
    paths, distributions = [], heatmap_distributions(cells, bootstrap, seed)
    for proposed in (p for p in PROPOSED if p in names):
        found = _heatmap(cells, proposed, distributions, _marks_note(bootstrap, seed))
        if found is None:
            break
        spec, vpr_methods, panels = found
        finite = np.concatenate([delta[np.isfinite(delta)] for _, delta, _ in panels])
        limit = max(float(np.abs(finite).max()) if finite.size else 0.0, 1e-3)
        rows, columns, size = heatmap_layout(vpr_methods, panels[0][0], spec.panels, width=width)
        with figure_rc(width):
            figure, grid = plt.subplots(rows, columns, figsize=size, dpi=DPI, squeeze=False, layout="constrained")
            axes = [axis for row in grid for axis in row]
            try:
                for axis in axes[len(panels) :]:  # the last row's unused places
                    axis.set_axis_off()
                for position, (axis, title, (labels, delta, marked)) in enumerate(
                    zip(axes, spec.panels, panels, strict=False)
                ):
                    image = axis.imshow(delta, cmap="RdBu", vmin=-limit, vmax=limit, aspect="auto")
                    for (i, j), value in np.ndenumerate(delta):
                        if np.isfinite(value):
                            colour = "white" if abs(value) > 0.6 * limit else "black"
                            text = _signed(value) + ("*" if marked[i, j] else "")
                            axis.text(j, i, text, ha="center", va="center", color=colour)
                    axis.set_xticks(range(len(labels)), labels, rotation=30, ha="right")
                    axis.set_yticks(range(len(vpr_methods)), vpr_methods if position % columns == 0 else [])
                    axis.set_title(title)
                label = "Δ AUC-PR" + ("   * Holm-adjusted p ≤ 0.05" if bootstrap else "")
                figure.colorbar(image, ax=axes, shrink=0.8, label=label, location=_colour_bar_side(width))
                figure.suptitle(_fitted(spec.what.split(" on ")[0], figure))
                paths.append(save_figure(figure, out_dir / f"delta_{proposed}.png", tight=False)[0])
            finally:
                plt.close(figure)
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
    """AUC-PR of the cascade at each fraction verified (NaN when undefined: one class only), from the stored
    uncertainties of SCORE and GV: verifying a pair gives the same inliers whichever other queries are verified."""
    correct = np.asarray(correct, dtype=bool)
    if correct.all() or not correct.any():
        return np.full(len(fractions), np.nan)
    verified = [most_uncertain(score, fraction) for fraction in fractions]
    return np.array([auc_pr(correct, combine_cascade(score, rows, np.asarray(gv)[rows])) for rows in verified])


_ONE_VPR = {"color": "0.7", "linestyle": "-", "marker": "None", "linewidth": 0.8}
_MEAN = {"color": OKABE_ITO[0], "linestyle": "-", "marker": "o", "linewidth": 1.6}
_AS_RUN = {"color": OKABE_ITO[1], "linestyle": "None", "marker": "D", "markersize": 6}


def _cascade_datasets(cells: Sequence[Any], score: str, gv: str) -> tuple[list[Any], list[str]]:
    usable = [c for c in cells if {score, gv} <= set(c.evaluation.methods)]
    return usable, list(dict.fromkeys(c.dataset for c in usable))


def cascade_spec(cells: Sequence[Any], name: str, score: str, gv: str) -> FigureSpec:
    """What the cascade figure of ``name`` (= ``score`` + ``gv``) draws: one panel per dataset."""
    usable, datasets = _cascade_datasets(cells, score, gv)
    counts = {d: sum(c.dataset == d for c in usable) for d in datasets}
    return FigureSpec(
        what=f"{score}+{gv}: AUC-PR of the cascade against the fraction of queries verified (0 = {score} alone, "
        f"1 = {gv} on every query)",
        panels=tuple(f"{d} ({counts[d]} VPR methods)" for d in datasets),
        panel_rule="one per dataset",
        series=(
            SeriesSpec("one VPR method", "grey, thin", _ONE_VPR),
            SeriesSpec("mean over VPR methods", "", _MEAN),
            SeriesSpec(f"{name} as run (mean)", "its measured fraction verified and AUC-PR", _AS_RUN),
        ),
        x=f"fraction verified by {gv} (most uncertain by {score} first)",
        y="AUC-PR of the cascade",
        shared_y=True,
    )


def plot_cascade(cells: Sequence[Any], out_dir: str | Path, *, width: str = "page") -> list[Path]:
    """``cascade__<SCORE>_<GV>.png`` (and ``.pdf``) for each cascade of :func:`cascades`; one panel per dataset
    (one shared y range), ``width`` "page" or "column". Described by :func:`cascade_spec`."""
    plt = pyplot()
    figure_width(width)
    paths = []
    for name, score, gv in cascades(cells):
        spec = cascade_spec(cells, name, score, gv)
        usable, datasets = _cascade_datasets(cells, score, gv)
        with figure_rc(width):
            figure, axes = _subplots(plt, len(datasets), None, len(spec.series), width)
            try:
                for axis, title, dataset in zip(axes.ravel(), spec.panels, datasets, strict=False):
                    here = [c for c in usable if c.dataset == dataset]
                    curves = []
                    for cell in here:
                        methods = cell.evaluation.methods
                        curve = cascade_curve(
                            cell.evaluation.correct, methods[score].uncertainty, methods[gv].uncertainty, FRACTIONS
                        )
                        curves.append(curve)
                        axis.plot(FRACTIONS, curve, zorder=1, **_ONE_VPR)
                    axis.plot(FRACTIONS, np.nanmean(np.array(curves), axis=0), markersize=3, **_MEAN)
                    run_methods = [c.evaluation.methods[name] for c in here if name in c.evaluation.methods]
                    measured = [
                        (m.details["verified_fraction"], m.auc_pr)
                        for m in run_methods
                        if m.auc_pr is not None and m.details.get("verified_fraction") is not None
                    ]
                    if measured:
                        x, y = (float(np.mean(values)) for values in zip(*measured, strict=True))
                        axis.plot([x], [y], zorder=3, **_AS_RUN)
                    axis.set_title(title)
                    axis.set(xlabel=spec.x if width == "page" else f"fraction verified by {gv}", xlim=(0, 1))
                    axis.grid(alpha=0.3)
                title = spec.what.split(": ")[0] + f": 0 = {score} alone, 1 = {gv} on every query"
                _finish(plt, figure, axes, spec, width, title)
                paths += save_figure(figure, Path(out_dir) / f"cascade__{slug(score)}_{slug(gv)}.png", tight=False)
            finally:
                plt.close(figure)
    return paths


# --- qualitative examples ---

CATEGORIES: tuple[str, ...] = ("confident correct", "confident wrong", "uncertain correct", "uncertain wrong")
#: Relative widths of the query's column, then of its top answers', by figure width (each image ≥ 1 in wide).
COLUMNS: dict[str, tuple[float, ...]] = {"page": (1.4, 1, 1, 1, 1), "column": (1, 1, 1)}
#: The uncertainty methods shown under each query, when the cell has them.
SHOWN: tuple[str, ...] = ("RS", "SD", "SU")


def qualitative_figsize(n_rows: int, *, width: str = "page") -> tuple[float, float]:
    """Figure size in inches for ``n_rows`` queries (``DPI`` pixels per inch): ``width`` wide, each row as tall as
    the query's image (4:3) plus five lines of 8-pt text (two above the images, the query's RS, SD and SU below).

    Examples
    --------
    >>> qualitative_figsize(4), qualitative_figsize(4, width="column")
    ((7.16, 9.0), (3.5, 7.0))
    """
    inches = figure_width(width)
    query = COLUMNS[width][0] * inches / sum(COLUMNS[width])  # the query's image sets the row's height (4:3)
    return inches, capped_height(n_rows * (0.75 * query + 0.8) + 0.45, width)


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


#: How an answer's correctness is drawn: a symbol in its title, a frame colour and a frame dash.
_HIT = {True: ("✓", OKABE_ITO[2], "-"), False: ("✗", OKABE_ITO[1], "--")}


def _qualitative_rank_by(cell: Any, rank_by: str, shown: Sequence[str]) -> tuple[str | None, list[str]]:
    names = list(cell.evaluation.methods)
    labels = [name for name in shown if name in names]
    if rank_by not in names:
        rank_by = next(iter(labels or names), None)
    return rank_by, labels or ([rank_by] if rank_by else [])


def qualitative_spec(
    cell: Any, *, rank_by: str = "SU", shown: Sequence[str] = SHOWN, alpha: float | None = None, width: str = "page"
) -> FigureSpec | None:
    """What :func:`plot_qualitative` draws for ``cell`` at ``width``: one row per category (panels: the query
    images), or None when it draws nothing."""
    rank_by, labels = _qualitative_rank_by(cell, rank_by, shown)
    if rank_by is None:
        return None
    chosen = choose_queries(np.asarray(cell.evaluation.correct, bool), cell.evaluation.methods[rank_by].uncertainty)
    if not chosen:
        return None
    settings = [f"k={cell.evaluation.k}"] if cell.evaluation.k is not None else []
    settings += [f"α={alpha:g}"] if alpha is not None and rank_by.startswith("SU") else []
    suffix = f" ({', '.join(settings)})" if settings else ""
    return FigureSpec(
        what=f"{cell.vpr_method} on {cell.dataset}: answers ranked by {rank_by}{suffix}",
        panels=tuple(f"{category.replace(' ', chr(10), 1)}, q{query}" for category, query in chosen.items()),
        panel_rule=f"one row per query: the most confident and the most uncertain by {rank_by}, with a correct and "
        f"with a wrong top-1 answer; the query, then its top-{len(COLUMNS[width]) - 1} answers",
        series=(
            SeriesSpec("✓", "a positive: solid green frame", {"linestyle": "-"}),
            SeriesSpec("✗", "not a positive: dashed red frame", {"linestyle": "--"}),
        ),
        notes=(
            "Above each answer: its rank, ✓ or ✗, and its similarity s; under each query: its uncertainties by "
            + ", ".join(labels),
        ),
    )


def plot_qualitative(
    cell: Any,
    path: str | Path,
    *,
    rank_by: str = "SU",
    shown: Sequence[str] = SHOWN,
    alpha: float | None = None,
    width: str = "page",
) -> Path | None:
    """Draw the figure for one grid cell from its stored uncertainties (described by :func:`qualitative_spec`).

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
    width : {"page", "column"}, default="page"
        7.16 or 3.5 inches wide (the top 4 or the top 2 answers, :data:`COLUMNS`), 8-pt fonts.

    Returns
    -------
    Path or None
        ``path``, or None when the cell has no image paths or no uncertainties.
    """
    if not cell.query_paths or not cell.database_paths:
        return None
    spec = qualitative_spec(cell, rank_by=rank_by, shown=shown, alpha=alpha, width=width)
    if spec is None:
        return None
    rank_by, labels = _qualitative_rank_by(cell, rank_by, shown)
    uncertainties = {name: np.asarray(m.uncertainty, dtype=np.float64) for name, m in cell.evaluation.methods.items()}
    plt = pyplot()
    scores = np.asarray(cell.scores, dtype=np.float64)
    chosen = choose_queries(np.asarray(cell.evaluation.correct, dtype=bool), uncertainties[rank_by])
    path = Path(path)
    with figure_rc(width):
        figure, axes = plt.subplots(
            len(chosen),
            len(COLUMNS[width]),
            figsize=qualitative_figsize(len(chosen), width=width),
            dpi=DPI,
            squeeze=False,
            layout="constrained",
            gridspec_kw={"width_ratios": COLUMNS[width]},
        )
        try:
            for row, (title, query) in enumerate(zip(spec.panels, chosen.values(), strict=True)):
                axis = axes[row][0]
                axis.imshow(plt.imread(cell.query_paths[query]))
                axis.set_title(title)
                axis.set_xlabel("\n".join(f"{name} {uncertainties[name][query]:.3f}" for name in labels))
                for column in range(1, len(COLUMNS[width])):
                    axis = axes[row][column]
                    rank = column - 1
                    index = int(cell.indices[query, rank]) if rank < cell.indices.shape[1] else -1
                    if index < 0:
                        axis.set_axis_off()
                        continue
                    axis.imshow(plt.imread(cell.database_paths[index]))
                    symbol, colour, dash = _HIT[bool(cell.hits[query, rank])]
                    for spine in axis.spines.values():
                        spine.set(edgecolor=colour, linewidth=3, linestyle=dash)
                    axis.set_title(f"#{rank + 1} {symbol}\ns={scores[query, rank]:.3f}", color=colour)
                for axis in axes[row]:
                    axis.set(xticks=[], yticks=[])
            figure.suptitle(_fitted(spec.what, figure))
            return save_figure(figure, path, tight=False)[0]
        finally:
            plt.close(figure)
