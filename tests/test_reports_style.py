"""Publication figures (reports/style.py and the figures that use it): a vector PDF beside every 300-dpi PNG,
legends outside the axes, coinciding curves said to coincide, distinct styles, captions and settings in
report.html, no visible debug footer; the cascade figure (reports/cascade.py)."""

from __future__ import annotations

import struct
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from vpr_uncertainty import Retrieval, evaluate
from vpr_uncertainty.reports import plots
from vpr_uncertainty.reports.display import draw_rejection_curves, write_rejection_curves
from vpr_uncertainty.reports.html import Section, png_display_width, render_report
from vpr_uncertainty.reports.plots import FRACTIONS, cascade_curve
from vpr_uncertainty.reports.style import DPI, OKABE_ITO, coinciding, legend_outside, method_styles, pyplot, save_figure


def _dpi(path: Path) -> float:
    """Pixels per inch from the PNG's pHYs chunk."""
    data = path.read_bytes()
    at = data.index(b"pHYs")
    per_metre_x, per_metre_y, unit = struct.unpack(">IIB", data[at + 4 : at + 13])
    assert unit == 1 and per_metre_x == per_metre_y
    return per_metre_x * 0.0254


def _retrieval(n_queries: int = 40, seed: int = 0) -> Retrieval:
    rng = np.random.default_rng(seed)
    scores = np.sort(rng.uniform(0.2, 1.0, (n_queries, 10)), axis=1)[:, ::-1]
    indices = np.tile(np.arange(10), (n_queries, 1))
    positives = np.zeros((n_queries, 10), dtype=bool)
    positives[np.arange(n_queries), np.where(rng.random(n_queries) < 0.6, 0, 1)] = True
    return Retrieval(scores=scores, indices=indices, positives=positives, distances=2 - 2 * scores)


def test_save_figure_writes_a_300_dpi_png_and_a_pdf(tmp_path):
    plt = pyplot()
    figure, axis = plt.subplots(figsize=(3, 2))
    axis.plot([0, 1], [0, 1])
    try:
        png, pdf = save_figure(figure, tmp_path / "f.png", tight=False)
    finally:
        plt.close(figure)
    assert DPI == 300 and _dpi(png) == pytest.approx(300, rel=1e-3)
    assert struct.unpack(">II", png.read_bytes()[16:24]) == (900, 600)
    assert pdf == tmp_path / "f.pdf" and pdf.read_bytes().startswith(b"%PDF")
    assert png_display_width(png) == 288  # 3 inches at 96 CSS px per inch
    with pytest.raises(ValueError, match=r"writes a \.png"):
        save_figure(figure, tmp_path / "f.jpg")


def test_pr_curves_say_that_bm_and_l2_coincide_with_the_legend_outside_the_axes(tmp_path):
    evaluation = evaluate(_retrieval(), ["SU", "BM", "L2", "PA"], k=5)
    figure = draw_rejection_curves(evaluation, title="t")
    try:
        (axis,) = figure.axes
        (legend,) = figure.legends
        labels = [text.get_text() for text in legend.get_texts()]
        assert any(label.startswith("BM = L2 0.") for label in labels)  # Table 1's AUC-PR, named by the title
        assert not any(label.startswith(("BM 0", "L2 0")) for label in labels)  # no line hidden under another
        assert legend.get_title().get_text() == "uncertainty method (AUC-PR, Table 1)"
        figure.canvas.draw()
        box, frame = legend.get_window_extent(), axis.get_window_extent()
        assert box.y1 <= frame.y0  # outside the data, below
        lines = [line for line in axis.get_lines() if line.get_label() != "_nolegend_"][:-1]  # the methods
        styles = {(line.get_color(), line.get_linestyle(), line.get_marker()) for line in lines}
        assert len(styles) == len(lines) == 3
        assert "recall" in axis.get_xlabel() and "precision" in axis.get_ylabel()
        assert not axis.texts  # the note on the area is in the caption (rejection_curves_spec), not in the figure
    finally:
        pyplot().close(figure)
    png, pdf = write_rejection_curves(evaluation, tmp_path / "pr.png")
    assert _dpi(png) == pytest.approx(300, rel=1e-3) and pdf.suffix == ".pdf"


def test_method_styles_are_distinct_without_yellow_and_coinciding_groups_curves():
    styles = method_styles([f"m{i}" for i in range(35)])
    assert len({(s["color"], s["marker"]) for s in styles.values()}) == 35  # told apart in colour
    assert len({(s["marker"], str(s["linestyle"])) for s in styles.values()}) == 35  # and in grey
    assert "#F0E442" not in OKABE_ITO and len(OKABE_ITO) == 7  # Okabe-Ito without its yellow
    assert method_styles(["x", "m7"])["m7"] == method_styles(["m7"])["m7"]  # by name, not by position
    x = np.linspace(0, 1, 5)
    assert coinciding({"a": (x, x), "b": (x, x + 1), "c": (x.copy(), x.copy())}) == [["a", "c"], ["b"]]


def test_one_style_per_method_name_in_every_figure_of_every_command(tmp_path):
    """evaluate --plot drew PA pink and BM orange, reproduce the reverse: styles came from the position."""
    retrieval = _retrieval()
    as_evaluate = evaluate(retrieval, ["RS", "SD", "SU", "PA", "L2", "BM"], k=5)  # the evaluate command's order
    as_reproduce = evaluate(retrieval, ["SU", "BM", "L2", "PA", "margin"], k=5)  # a config's order
    colours = []
    for evaluation in (as_evaluate, as_reproduce):
        figure = draw_rejection_curves(evaluation)
        try:
            lines = {line.get_label().rsplit(" ", 1)[0]: line for line in figure.axes[0].get_lines()}
            colours.append({name: (line.get_color(), line.get_marker()) for name, line in lines.items()})
        finally:
            pyplot().close(figure)
    first, second = colours
    assert first["SU"] == second["SU"] and first["PA"] == second["PA"]
    assert first["L2 = BM"] == second["BM = L2"] == tuple(method_styles(["BM"])["BM"][k] for k in ("color", "marker"))
    # the VPR methods of the α and k ablations: the same name, the same style in both figures
    cells = [
        SimpleNamespace(
            vpr_method=name,
            dataset="d",
            ablation_alpha={0.0: 0.5 + i / 100, 0.5: 0.6, 1.0: 0.7},
            ablation_k={"RS": {2: 0.5, 5: 0.6 + i / 100}, "SD": {2: 0.5, 5: 0.6}},
        )
        for i, name in enumerate(["NetVLAD", "CosPlace", "HOG", "A", "B", "C", "D", "E", "F", "G"])
    ]
    alpha = {s.label.split(" (")[0]: s.style for s in plots.alpha_ablation_spec(cells).series}
    k = {s.label: s.style for s in plots.k_ablation_spec(cells, "column").series}
    assert all(alpha[name] == style for name, style in k.items())
    assert alpha["NetVLAD"] == method_styles(["NetVLAD"])["NetVLAD"]


def test_legend_outside_is_right_of_the_axes():
    plt = pyplot()
    figure, axis = plt.subplots()
    try:
        axis.plot([0, 1], [0, 1], label="a line")
        legend = legend_outside(axis)
        figure.canvas.draw()
        assert legend.get_window_extent().x0 >= axis.get_window_extent().x1
    finally:
        plt.close(figure)


def test_cascade_curve_ends_at_the_score_method_and_at_gv():
    from vpr_uncertainty.evaluation import auc_pr

    rng = np.random.default_rng(1)
    correct = rng.random(50) < 0.6
    score, gv = rng.random(50), -np.floor(rng.random(50) * 5)
    curve = cascade_curve(correct, score, gv, FRACTIONS)
    assert FRACTIONS[0] == 0.0 and FRACTIONS[-1] == 1.0 and len(FRACTIONS) == 21
    assert curve[0] == auc_pr(correct, score)
    assert curve[-1] == pytest.approx(auc_pr(correct, gv), rel=1e-12)
    assert np.isnan(cascade_curve(np.ones(5, bool), score[:5], gv[:5], (0.5,))).all()


def test_report_html_has_numbered_captions_and_a_hidden_render_check(tmp_path):
    plt = pyplot()
    figure, _ = plt.subplots(figsize=(2, 2))
    try:
        png, _ = save_figure(figure, tmp_path / "f.png")
    finally:
        plt.close(figure)
    html = render_report("t", [Section("s", "", figures=[("NetVLAD on corridor: what it shows", png)])])
    assert "<figcaption><b>Figure 1. </b>NetVLAD on corridor: what it shows</figcaption>" in html
    assert "p.hidden=true" in html and 'className="note"' not in html  # the check is not shown to a reader
