"""Figures a paper can take (issue 23): at column (3.5 in) and page (7.16 in) width every figure has that width,
fonts of at least 8 pt, a marker or dash per legend entry (not colour alone), one y range across compared panels,
and a caption made from the same FigureSpec that draws it (every panel and legend entry named, nothing else)."""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.text import Text
from matplotlib.transforms import Bbox

from vpr_uncertainty import Retrieval, evaluate, register_method
from vpr_uncertainty.methods import METHODS
from vpr_uncertainty.reports import display, plots, style
from vpr_uncertainty.reports.display import RecallAtNDisplay, draw_rejection_curves, rejection_curves_spec
from vpr_uncertainty.reports.style import FIGURE_WIDTHS, MAX_HEIGHTS

WIDTHS = ("column", "page")
ALPHAS = [0.0, 0.25, 0.5, 0.75, 1.0]


def _retrieval(n_queries: int = 40, seed: int = 0) -> Retrieval:
    rng = np.random.default_rng(seed)
    scores = np.sort(rng.uniform(0.2, 1.0, (n_queries, 10)), axis=1)[:, ::-1]
    positives = np.zeros((n_queries, 10), dtype=bool)
    positives[np.arange(n_queries), np.where(rng.random(n_queries) < 0.6, 0, 1)] = True
    return Retrieval(
        scores=scores, indices=np.tile(np.arange(10), (n_queries, 1)), positives=positives, distances=2 - 2 * scores
    )


def _cell(vpr_method: str, dataset: str, seed: int, *, images: tuple[list[str], list[str]] | None = None):
    """A stand-in for a grid Cell with a real evaluation (SU, RS, SD, BM, L2, PA, GV stand-in) and ablations."""
    retrieval = _retrieval(seed=seed)
    evaluation = evaluate(retrieval, ["RS", "SD", "SU", "BM", "L2", "PA"], k=5)
    peak = seed / 10
    return SimpleNamespace(
        vpr_method=vpr_method,
        dataset=dataset,
        evaluation=evaluation,
        scores=retrieval.scores,
        indices=retrieval.indices,
        hits=retrieval.positives[:, :4],
        query_paths=images[0] if images else None,
        database_paths=images[1] if images else None,
        ablation_alpha={a: 0.8 - 0.001 * (a - peak) ** 2 for a in ALPHAS},  # differences of ~0.001
        ablation_k={name: {k: 0.5 + 0.01 * k + seed * 0.001 for k in (2, 5, 10)} for name in ("RS", "SD")},
    )


def _cells(n_methods: int = 3, datasets: tuple[str, ...] = ("corridor", "CALC")):
    return [_cell(f"M{i}", dataset, i) for i in range(n_methods) for dataset in datasets]


def _png_size(path: Path) -> tuple[int, int]:
    return struct.unpack(">II", Path(path).read_bytes()[16:24])


def _texts(figure) -> list[Text]:
    return [t for t in figure.findobj(Text) if t.get_visible() and t.get_text().strip()]


def _panels(figure) -> list:
    """The visible data axes (not colour bars)."""
    return [a for a in figure.axes if a.get_visible() and a.get_label() != "<colorbar>"]


def _legend_entries(figure) -> list[tuple[str, object]]:
    legends = [*figure.legends, *(legend for row in figure.subfigs for legend in row.legends)]
    legends += [a.get_legend() for a in figure.axes if a.get_legend() is not None]
    entries = {  # a row's legend (k ablation) repeats the VPR methods of another dataset's row
        text.get_text(): handle
        for legend in legends
        for text, handle in zip(legend.get_texts(), legend.legend_handles, strict=True)
    }
    return list(entries.items())


def _check_paper_figure(figure, png: Path, width: str) -> None:
    inches = figure.get_size_inches()
    assert inches[0] == pytest.approx(FIGURE_WIDTHS[width])
    assert 1.5 <= inches[1] <= MAX_HEIGHTS[width]
    assert _png_size(png) == (round(inches[0] * style.DPI), round(inches[1] * style.DPI))
    small = [(t.get_text(), t.get_fontsize()) for t in _texts(figure) if t.get_fontsize() < 8]
    assert not small, f"texts under 8 pt: {small[:5]}"
    handles = [handle for _, handle in _legend_entries(figure)]  # a bar (no marker) is told apart by its shape
    shapes = [(getattr(h, "get_marker", type(h).__name__.lower)(), str(h.get_linestyle())) for h in handles]
    assert len(set(shapes)) == len(shapes), f"legend entries told apart by colour only: {shapes}"


def _check_caption(figure, spec: style.FigureSpec, caption: str) -> None:
    titles = [a.get_title() for a in _panels(figure)]
    if spec.panels:
        assert titles == list(spec.panels)
        assert ("Panels" in caption) and "; ".join(spec.panels).replace("\n", " ") in caption
    assert [label for label, _ in _legend_entries(figure)] == spec.labels
    for label in spec.labels:
        assert label in caption
    assert caption.count("Legend:") == (1 if spec.series else 0)
    if spec.shared_y and len(titles) > 1:
        assert "the same y range in every panel" in caption


@pytest.mark.parametrize("width", WIDTHS)
def test_alpha_ablation_at_paper_width_is_one_panel_and_matches_its_caption(tmp_path, figures, width):
    cells = _cells(10)
    path = plots.plot_alpha_ablation(cells, tmp_path / "alpha.png", width=width)
    (figure,) = figures
    _check_paper_figure(figure, path, width)
    (panel,) = _panels(figure)
    low, high = panel.get_ylim()
    assert high - low < 0.01  # differences of ~0.001 fill the axis: one Δ axis, not 0.5-1.0
    spec = plots.alpha_ablation_spec(cells)
    _check_caption(figure, spec, spec.caption())


@pytest.mark.parametrize("width", WIDTHS)
def test_k_ablation_at_paper_width(tmp_path, figures, width):
    cells = _cells(11)
    path = plots.plot_k_ablation(cells, tmp_path / "k.png", width=width)
    (figure,) = figures
    _check_paper_figure(figure, path, width)
    assert len({a.get_ylim() for a in _panels(figure)}) == 1
    assert max(len(a.get_lines()) for a in _panels(figure)) <= plots.MAX_SERIES
    spec = plots.k_ablation_spec(cells, width)
    _check_caption(figure, spec, spec.caption())
    assert spec.panels[:4] == (
        "RS · corridor (1/2)",
        "SD · corridor (1/2)",
        "RS · corridor (2/2)",
        "SD · corridor (2/2)",
    )


@pytest.mark.parametrize("width", WIDTHS)
@pytest.mark.parametrize("datasets", [("corridor",), ("corridor", "CALC")], ids=["one_dataset", "two_datasets"])
def test_heatmaps_at_paper_width_name_their_panels(tmp_path, figures, width, datasets):
    cells = _cells(10, datasets)
    paths = plots.plot_delta_heatmaps(cells, tmp_path, width=width)
    assert [p.name for p in paths] == ["delta_RS.png", "delta_SD.png", "delta_SU.png"]
    for figure, path in zip(figures, paths, strict=True):
        _check_paper_figure(figure, path, width)
        spec = plots.heatmap_spec(cells, path.stem.removeprefix("delta_"))
        if len(datasets) == 1:  # one panel whose columns are the baselines: a one-cell-wide panel per baseline
            assert spec.panels == ("corridor",)  # would not fit a paper's column
            (axis,) = _panels(figure)
            assert [label.get_text() for label in axis.get_xticklabels()] == ["BM = L2", "PA"]
        else:
            assert spec.panels == ("vs BM = L2", "vs PA")  # BM and L2 have the same Δ everywhere
        _check_caption(figure, spec, spec.caption())
        assert "No significance marks" in spec.caption()


def test_heatmaps_print_no_negative_zero_and_mark_significant_deltas(tmp_path, figures):
    cells = _cells(3, ("corridor",))
    for cell in cells:  # PA = SU shifted by a hair: Δ rounds to zero from below
        methods = cell.evaluation.methods
        methods["PA"] = dataclasses.replace(methods["SU"], name="PA", auc_pr=methods["SU"].auc_pr + 0.001)
    plots.plot_delta_heatmaps(cells, tmp_path, bootstrap=200, seed=0)
    texts = [text.get_text() for figure in figures for text in figure.axes[0].texts]
    assert texts and not any(text.startswith(("-0.00", "−0.00", "+0.00")) for text in texts)
    assert "0.00" in texts  # the PA column: SU − (SU + 0.001)
    distributions = plots.heatmap_distributions(cells, 200, 0)
    _, _, _, significant = plots.delta_matrix(cells, "SU", "BM", distributions)
    su = [text for text in figures[-1].axes[0].texts]
    assert [text.get_text().endswith("*") for text in su[::2]] == list(significant[:, 0])  # the BM = L2 column
    assert not significant.all()  # random scores: Holm stars none here; test_significance_rule stars real ones
    assert "* Holm-adjusted p ≤ 0.05" in figures[-1].axes[-1].get_xlabel() + figures[-1].axes[-1].get_ylabel()
    assert (
        "*: significant, as in Table 1: Holm-adjusted p <= 0.05"
        in plots.heatmap_spec(cells, "SU", bootstrap=200).caption()
    )


@pytest.mark.parametrize("width", WIDTHS)
def test_pr_curves_at_paper_width_legend_table1s_auc_pr_and_say_so(tmp_path, width):
    """The legend gave the area of the curve drawn (0.491 beside Table 1's 0.828, unnamed): now Table 1's AUC-PR,
    named by the legend's title; the caption says it is not the area drawn."""
    evaluation = evaluate(_retrieval(), ["SU", "BM", "L2", "PA"], k=5)
    figure = draw_rejection_curves(evaluation, title="t", width=width)
    try:
        png, _ = style.save_figure(figure, tmp_path / "pr.png", tight=False)
        _check_paper_figure(figure, png, width)
        spec = rejection_curves_spec(evaluation, title="t")
        caption = spec.caption()
        _check_caption(figure, spec, caption)
        auc_pr = {name: evaluation.methods[name].auc_pr for name in ("SU", "BM", "PA")}
        assert [f"SU {auc_pr['SU']:.3f}", f"BM = L2 {auc_pr['BM']:.3f}", f"PA {auc_pr['PA']:.3f}"] == spec.labels[:3]
        assert figure.legends[0].get_title().get_text() == "uncertainty method (AUC-PR, Table 1)"
        recall_at_1 = max(float(m.curve.recall.max()) for m in evaluation.methods.values())
        assert figure.axes[0].get_xlim() == (0, recall_at_1)  # the x axis ends where the curves do
        assert "the AUC-PR of the uncertainty (Table 1), not the area of the curve drawn" in caption
        assert not figure.axes[0].texts  # no footnote inside the figure
    finally:
        plt.close(figure)


def _column_score(column: int):
    def uncertainty(retrieval, *, k=10):
        return retrieval.scores[:, column]

    return uncertainty


def test_pr_legend_of_eleven_methods_is_compact_at_column_width():
    """At column width the legend of eleven methods, one per row, took 40 % of the figure's height."""
    register = {f"X{j}": _column_score(j) for j in range(1, 6)}  # five more rankings
    for name, function in register.items():
        register_method(name, function, description="a stand-in")
    try:
        evaluation = evaluate(_retrieval(), ["RS", "SD", "SU", "BM", "PA", "margin", *register], k=5)
    finally:
        for name in register:
            METHODS.unregister(name)
    figure = draw_rejection_curves(evaluation, title="t", width="column")
    try:
        figure.canvas.draw()
        (legend,) = figure.legends
        assert len(legend.get_texts()) >= 11
        share = legend.get_window_extent().height / figure.bbox.height
        assert share < 0.3, f"the legend takes {share:.0%} of the height"
        assert legend.get_window_extent().y1 <= figure.axes[0].get_window_extent().y0  # below the axes
    finally:
        plt.close(figure)


#: CAL's held-out reliability on the corridor (CALC, 20 splits of 0.3): n=266/n=277 and n=56/n=11 overlapped.
CORRIDOR_BINS = {
    "counts": [266, 277, 276, 251, 138, 99, 109, 77, 56, 11],
    "mean_probability": [0.0482, 0.1515, 0.2493, 0.3465, 0.4477, 0.5523, 0.6382, 0.7412, 0.8468, 0.9233],
    "accuracy": [0.0113, 0.1047, 0.2283, 0.2749, 0.5, 0.6465, 0.7798, 0.8182, 0.8036, 0.9091],
}


@pytest.mark.parametrize("width", WIDTHS)
@pytest.mark.parametrize("n_bins", [10, 20])
def test_reliability_counts_overlap_nothing_and_the_legend_covers_no_point(tmp_path, figures, width, n_bins):
    from vpr_uncertainty.calibration.quality import Reliability

    bins = {key: [v for v in values for _ in range(n_bins // 10)] for key, values in CORRIDOR_BINS.items()}
    edges = np.linspace(0, 1, n_bins + 1)
    mean = edges[:-1] + np.asarray(bins["mean_probability"]) % 0.1 * 10 / n_bins  # the corridor's, inside its bin
    reliability = Reliability(edges.tolist(), bins["counts"], mean.tolist(), bins["accuracy"])
    path = display.plot_reliability(reliability, tmp_path / "r.png", width=width, label="CAL (ECE 0.105, mean ...)")
    figure = figures[-1]
    _check_paper_figure(figure, path, width)
    figure.draw_without_rendering()
    (axis,) = figure.axes
    counts = [text.get_window_extent() for text in axis.texts]
    assert [text.get_text().removeprefix("n=") for text in axis.texts] == [str(n) for n in bins["counts"]]
    assert not [(a, b) for i, a in enumerate(counts) for b in counts[i + 1 :] if a.overlaps(b)]
    ticks = [label.get_window_extent() for label in axis.get_xticklabels() + axis.get_yticklabels()]
    points = axis.transData.transform(np.column_stack([mean, bins["accuracy"]]))
    radius = axis.get_lines()[1].get_markersize() / 72 * figure.dpi / 2
    dots = [Bbox.from_extents(x - radius, y - radius, x + radius, y + radius) for x, y in points]
    assert not [(c, other) for c in counts for other in ticks + dots if c.overlaps(other)]
    assert all(axis.bbox.contains(c.x0, c.y0) and axis.bbox.contains(c.x1, c.y1) for c in counts)
    legend = (figure.legends or [axis.get_legend()])[0].get_window_extent()
    assert not legend.overlaps(axis.bbox) and not any(legend.overlaps(dot) for dot in dots)


def test_reliability_and_cascade_at_column_width(tmp_path, figures):
    from vpr_uncertainty.calibration.quality import expected_calibration_error, reliability_diagram

    rng = np.random.default_rng(0)
    p = rng.random(200)
    correct = rng.random(200) < p
    reliability = reliability_diagram(p, correct)
    path = display.plot_reliability(reliability, tmp_path / "r.png", width="column", threshold=0.8)
    _check_paper_figure(figures[-1], path, "column")
    axis = figures[-1].axes[0]
    labels = [text.get_text() for text in figures[-1].legends[0].get_texts()]
    assert f"observed (ECE {expected_calibration_error(p, correct):.3f})" in labels
    assert "gate threshold P ≥ 0.800" in labels
    (threshold,) = [line for line in axis.get_lines() if line.get_label().startswith("gate threshold")]
    assert list(threshold.get_xdata()) == [0.8, 0.8]
    cells = []
    for i, dataset in enumerate(("corridor", "CALC", "corridor")):
        cell = _cell(f"M{i}", dataset, i)
        methods = cell.evaluation.methods
        methods["GV"] = methods["BM"]  # a stand-in GV: any uncertainty of the cell
        cells.append(cell)
    cell = cells[0]
    su = cell.evaluation.methods["SU"]
    cell.evaluation.methods["SU+GV"] = dataclasses.replace(su, name="SU+GV", details={"verified_fraction": 0.3})
    paths = plots.plot_cascade(cells, tmp_path, width="column")
    figure = figures[-1]
    _check_paper_figure(figure, paths[0], "column")
    assert len({a.get_ylim() for a in _panels(figure)}) == 1
    spec = plots.cascade_spec(cells, "SU+GV", "SU", "GV")
    _check_caption(figure, spec, spec.caption())


@pytest.mark.parametrize("width", WIDTHS)
def test_qualitative_marks_answers_by_symbol_and_dash_not_colour_only(tmp_path, figures, width):
    images = []
    for i in range(10):
        image = np.full((30, 40, 3), i / 10)
        plt.imsave(tmp_path / f"{i}.png", image)
        images.append(str(tmp_path / f"{i}.png"))
    cell = _cell("NetVLAD", "corridor", 0, images=(images * 4, images))
    cell.query_paths = [images[i % 10] for i in range(40)]
    path = plots.plot_qualitative(cell, tmp_path / "q.png", width=width)
    figure = figures[-1]
    _check_paper_figure(figure, path, width)
    spec = plots.qualitative_spec(cell, width=width)
    rows = np.array(figure.axes).reshape(-1, len(plots.COLUMNS[width]))
    assert [a.get_title() for a in rows[:, 0]] == list(spec.panels)
    answers = list(rows[:, 1:].ravel())
    figure.draw_without_rendering()  # every image at least 1 in wide (0.65 in with the top 4 at column width)
    assert min(axis.get_window_extent().width for axis in figure.axes) / figure.dpi >= 1.0
    boxes = [(t.get_text(), t.get_window_extent()) for t in _texts(figure)] + [("", a.bbox) for a in figure.axes]
    overlaps = [(a, b) for i, (a, one) in enumerate(boxes) for b, two in boxes[i + 1 :] if one.overlaps(two)]
    assert not [pair for pair in overlaps if any(pair)]  # no text on another or on an image (images may touch)
    for axis in answers:
        hit = "✓" in axis.get_title()
        assert hit != ("✗" in axis.get_title())
        dash = axis.spines["top"].get_linestyle()
        assert (dash == "-") == hit  # a wrong answer's frame is dashed
    caption = spec.caption()
    assert "✓" in caption and "✗" in caption and "dashed" in caption


def test_recall_at_n_display_draws_the_hand_computed_points():
    scores = np.sort(np.random.default_rng(0).uniform(0.2, 1, (4, 10)), axis=1)[:, ::-1]
    positives = np.zeros((4, 10), dtype=bool)
    positives[0, 0] = positives[1, 1] = positives[2, 4] = True  # query 3 has no positive: not answerable
    retrieval = Retrieval(
        scores=scores, indices=np.tile(np.arange(10), (4, 1)), positives=positives, distances=2 - 2 * scores
    )
    evaluation = evaluate(retrieval, ["SU"], k=5)
    other = {1: 0.5, 5: 0.9, 10: 1.0}
    figure, ax = plt.subplots(figsize=(3.5, 2.5))
    try:
        shown = RecallAtNDisplay.from_evaluation({"A": evaluation, "B": SimpleNamespace(recall_at_n=other)}, ax=ax)
        assert shown.ax_ is ax and shown.figure_ is figure
        # the retrieval's 10 candidates are the whole database: recall@20 is exact, so the evaluation holds it
        assert shown.lines_["A"].get_xdata().tolist() == [1, 5, 10, 20]
        np.testing.assert_allclose(shown.lines_["A"].get_ydata(), [1 / 3, 1.0, 1.0, 1.0], rtol=1e-12)
        assert shown.lines_["B"].get_ydata().tolist() == [0.5, 0.9, 1.0]
        assert ax.get_xscale() == "log" and ax.get_ylabel() == "recall@N"
        assert [t.get_text() for t in ax.get_legend().get_texts()] == ["A", "B"]
        a, b = shown.lines_["A"], shown.lines_["B"]
        assert (a.get_marker(), a.get_linestyle()) != (b.get_marker(), b.get_linestyle())
        single = RecallAtNDisplay.from_evaluation(evaluation, name="NetVLAD")
        assert list(single.lines_) == ["NetVLAD"]
        plt.close(single.figure_)
    finally:
        plt.close(figure)
    with pytest.raises(ValueError, match="empty"):
        RecallAtNDisplay({})


def test_figure_width_is_checked_and_rc_is_not_changed_globally(tmp_path):
    before = dict(matplotlib.rcParams)
    with pytest.raises(ValueError, match="must be one of"):
        plots.plot_alpha_ablation(_cells(1), tmp_path / "a.png", width="a4")
    plots.plot_alpha_ablation(_cells(1), tmp_path / "a.png", width="column")
    assert matplotlib.rcParams["font.size"] == before["font.size"]


def test_figure_width_option_reaches_the_commands():
    import argparse

    from vpr_uncertainty.pipeline import calibrate, grid, run
    from vpr_uncertainty.pipeline import evaluate as evaluate_stage

    subparsers = argparse.ArgumentParser().add_subparsers()
    for module in (calibrate, evaluate_stage, grid, run):
        module.add_cli(subparsers)
    for name in ("reproduce", "run", "demo", "evaluate", "calibrate"):
        parser = subparsers.choices[name]
        flags = {flag: action for action in parser._actions for flag in action.option_strings}
        assert flags["--figure-width"].choices is not None and set(flags["--figure-width"].choices) == set(WIDTHS)
        assert flags["--figure-width"].default == "page"
