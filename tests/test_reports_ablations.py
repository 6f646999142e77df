"""The ablation figures (:mod:`vpr_uncertainty.reports.plots`): one panel per VPR method for α, one line per
VPR method for k, each panel's best α marked."""

from __future__ import annotations

import struct
from pathlib import Path
from types import SimpleNamespace

import matplotlib

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


def _png_size(path: Path) -> tuple[int, int]:
    with open(path, "rb") as file:
        header = file.read(24)
    return struct.unpack(">II", header[16:24])


def test_alpha_figure_has_one_panel_per_vpr_method_with_its_best_alpha_starred(tmp_path, figures):
    peaks = {"APGeM": 1.0, "EigenPlaces": 0.0, "NetVLAD": 0.5}
    cells = [_cell(name, "corridor", peak) for name, peak in peaks.items()]
    path = plots.plot_alpha_ablation(cells, tmp_path / "alpha.png")
    (figure,) = figures
    panels = [axis for axis in figure.axes if axis.get_visible()]
    assert len(panels) == len(peaks)
    for axis, (name, peak) in zip(panels, peaks.items(), strict=True):
        assert axis.get_title().startswith(f"{name}\nbest α = {peak:g} (0.800)")
        stars = [line for line in axis.get_lines() if line.get_marker() == "*"]
        assert len(stars) == 1 and list(stars[0].get_xdata()) == [peak]
    width, height = plots.ablation_figsize(3, None, 1)
    assert _png_size(path) == (round(width * plots.DPI), round(height * plots.DPI))


def test_alpha_figure_wraps_ten_methods_in_three_rows_and_draws_one_line_per_dataset(tmp_path, figures):
    cells = [_cell(f"M{i}", dataset, i / 10) for i in range(10) for dataset in ("corridor", "CALC")]
    plots.plot_alpha_ablation(cells, tmp_path / "alpha.png")
    (figure,) = figures
    panels = [axis for axis in figure.axes if axis.get_visible()]
    assert len(panels) == 10
    assert {round(axis.get_position().y0, 3) for axis in panels}.__len__() == 3  # rows of 4 in a page width
    for axis in panels:
        curves = [line for line in axis.get_lines() if line.get_marker() != "*"]
        assert [line.get_label() for line in curves] == ["corridor", "CALC"]
    assert [text.get_text() for text in figure.legends[0].get_texts()] == ["corridor", "CALC", "best α (star)"]


def test_k_figure_has_one_line_per_vpr_method_in_an_rs_and_an_sd_panel(tmp_path, figures):
    cells = [_cell(name, "corridor", 0.5, shift) for shift, name in enumerate(["A", "B", "C", "D"])]
    plots.plot_k_ablation(cells, tmp_path / "k.png")
    (figure,) = figures
    panels = [axis for axis in figure.axes if axis.get_visible()]
    assert [axis.get_title() for axis in panels] == ["RS · corridor", "SD · corridor"]
    for axis in panels:
        assert [line.get_label() for line in axis.get_lines()] == ["A", "B", "C", "D"]
        styles = {(line.get_color(), line.get_linestyle(), line.get_marker()) for line in axis.get_lines()}
        assert len(styles) == 4


def test_undefined_alpha_curves_are_left_out_and_ties_pick_the_smallest_alpha():
    cells = [
        _cell("A", "d", 0.5),
        SimpleNamespace(vpr_method="B", dataset="d", ablation_alpha={0.0: None}, ablation_k={}),
    ]
    assert list(plots.alpha_panels(cells)) == ["A"]
    assert plots.best_alpha({0.0: 0.7, 0.5: 0.7, 1.0: 0.6}) == 0.0
    assert plots.best_alpha({}) is None


def test_k_panels_per_dataset_and_metric():
    cells = [_cell("A", "d1", 0.5), _cell("B", "d1", 0.5), _cell("A", "d2", 0.5)]
    panels = plots.k_panels(cells)
    assert list(panels) == [("d1", "RS"), ("d1", "SD"), ("d2", "RS"), ("d2", "SD")]
    assert list(panels[("d1", "SD")]) == ["A", "B"]
