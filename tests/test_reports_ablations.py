"""The ablation figures (:mod:`vpr_uncertainty.reports.plots`): α as one panel of ΔAUC-PR against α = 0.5 with a
line per VPR method and its best α marked; k with at most eight VPR methods per panel, each row's legend below."""

from __future__ import annotations

from types import SimpleNamespace

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")

from vpr_uncertainty.reports import plots

ALPHAS = [0.0, 0.25, 0.5, 0.75, 1.0]


def _cell(vpr_method: str, dataset: str, alpha_peak: float, k_shift: float = 0.0) -> SimpleNamespace:
    """A stand-in for a grid Cell: an α curve peaking at ``alpha_peak`` and k curves for RS and SD."""
    alpha_curve = {a: 0.8 - (a - alpha_peak) ** 2 for a in ALPHAS}
    k_curve = {
        name: {k: 0.5 + k_shift + 0.01 * k + offset for k in (2, 5, 10)} for name, offset in (("RS", 0), ("SD", 0.1))
    }
    return SimpleNamespace(vpr_method=vpr_method, dataset=dataset, ablation_alpha=alpha_curve, ablation_k=k_curve)


def test_alpha_figure_is_one_panel_of_deltas_with_one_line_per_vpr_method_and_its_best_alpha_starred(tmp_path, figures):
    peaks = {"APGeM": 1.0, "EigenPlaces": 0.0, "NetVLAD": 0.5}
    cells = [_cell(name, dataset, peak) for name, peak in peaks.items() for dataset in ("corridor", "CALC")]
    plots.plot_alpha_ablation(cells, tmp_path / "alpha.png", width="column")
    (figure,) = figures
    (axis,) = [axis for axis in figure.axes if axis.get_visible()]
    curves = [line for line in axis.get_lines() if line.get_marker() != "*" and line.get_label()[0] != "_"]
    assert [line.get_label() for line in curves] == ["APGeM (1)", "EigenPlaces (0)", "NetVLAD (0.5)"]
    for line, peak in zip(curves, peaks.values(), strict=True):
        # by hand: the mean over the two datasets of 0.8 - (a - peak)^2 minus its value at α = 0.5
        expected = [(0.8 - (a - peak) ** 2) - (0.8 - (0.5 - peak) ** 2) for a in ALPHAS]
        np.testing.assert_allclose(line.get_ydata(), expected, atol=1e-12)
    stars = [line for line in axis.get_lines() if line.get_marker() == "*"]
    assert [list(star.get_xdata()) for star in stars] == [[peak] for peak in peaks.values()]
    assert [star.get_color() for star in stars] == [line.get_color() for line in curves]
    assert "α = 0.5" in axis.get_ylabel()
    assert figure.get_size_inches()[0] == 3.5
    spec = plots.alpha_ablation_spec(cells)
    assert "averaged over the 2 datasets (corridor and CALC)" in spec.caption() and "Table 1's SU" in spec.caption()


def test_alpha_deltas_interpolate_the_reference_between_the_alphas_run():
    cell = SimpleNamespace(vpr_method="A", dataset="d", ablation_alpha={0.0: 0.6, 1.0: 0.8}, ablation_k={})
    assert plots.alpha_deltas([cell]) == {"A": {0.0: pytest.approx(-0.1), 1.0: pytest.approx(0.1)}}


def test_k_figure_has_at_most_eight_lines_per_panel_and_the_legend_outside(tmp_path, figures):
    names = [f"M{i}" for i in range(10)]
    cells = [_cell(name, "corridor", 0.5, shift) for shift, name in enumerate(names)]
    plots.plot_k_ablation(cells, tmp_path / "k.png", width="column")
    (figure,) = figures
    panels = [axis for axis in figure.axes if axis.get_visible()]
    assert [axis.get_title() for axis in panels] == [
        "RS · corridor (1/2)",
        "SD · corridor (1/2)",
        "RS · corridor (2/2)",
        "SD · corridor (2/2)",
    ]
    lines = [[line.get_label() for line in axis.get_lines()] for axis in panels]
    assert lines == [names[:5], names[:5], names[5:], names[5:]]
    legends = [legend for row in figure.subfigs for legend in row.legends]
    assert [[text.get_text() for text in legend.get_texts()] for legend in legends] == [names[:5], names[5:]]
    figure.canvas.draw()
    for legend, row in zip(legends, figure.subfigs, strict=True):  # below the panels of its row, not on them
        assert all(legend.get_window_extent().y1 <= axis.get_window_extent().y0 for axis in row.axes)
    styles = {(line.get_color(), line.get_linestyle(), line.get_marker()) for line in panels[0].get_lines()}
    assert len(styles) == 5 and len({style[0] for style in styles}) == 5  # five colours in one panel


def test_undefined_alpha_curves_are_left_out_and_ties_pick_the_smallest_alpha():
    cells = [
        _cell("A", "d", 0.5),
        SimpleNamespace(vpr_method="B", dataset="d", ablation_alpha={0.0: None}, ablation_k={}),
    ]
    assert list(plots.alpha_panels(cells)) == ["A"]
    assert plots.best_alpha({0.0: 0.7, 0.5: 0.7, 1.0: 0.6}) == 0.0
    assert plots.best_alpha({}) is None
