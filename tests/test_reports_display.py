"""Display objects in scikit-learn's style (vpr_uncertainty.reports.display): drawn on a given axis, exposing
``ax_``/``figure_``, redrawable with ``plot``; the file writers draw with them."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pytest

from vpr_uncertainty import Retrieval, calibrate, evaluate
from vpr_uncertainty.calibration.quality import reliability_diagram
from vpr_uncertainty.reports import RejectionCurveDisplay, ReliabilityDisplay, plot_rejection_curves
from vpr_uncertainty.reports.display import plot_reliability


@pytest.fixture(scope="module")
def retrieval() -> Retrieval:
    rng = np.random.default_rng(1)
    scores = -np.sort(-rng.random((400, 10)), axis=1)
    correct_first = rng.random(400) < scores[:, 0] - scores[:, 1] + 0.3  # SU-like signal: informative gaps
    indices = np.tile(np.arange(10), (400, 1))
    return Retrieval(scores=scores, indices=indices, positives=[[0] if c else [5] for c in correct_first])


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def test_rejection_curves_on_a_given_axis(retrieval):
    evaluation = evaluate(retrieval, ["SU", "BM", "RS"], k=10)
    figure, (left, right) = plt.subplots(1, 2)
    display = RejectionCurveDisplay.from_evaluation(evaluation, ax=right, methods=["BM", "SU"], title="mine")
    assert display.ax_ is right and display.figure_ is figure
    assert list(display.lines_) == ["BM", "SU"] and not left.lines
    np.testing.assert_array_equal(display.lines_["SU"].get_xdata(), evaluation.methods["SU"].curve.recall)
    np.testing.assert_array_equal(display.lines_["SU"].get_ydata(), evaluation.methods["SU"].curve.precision)
    # the legend's number is the area under the curve drawn, unless asked for the uncertainty's AUC-PR
    curve = evaluation.methods["SU"].curve
    assert display.lines_["SU"].get_label() == f"SU (area {np.trapezoid(curve.precision, curve.recall):.3f})"
    other = RejectionCurveDisplay.from_evaluation(evaluation, methods=["SU"], number="auc_pr")
    assert other.lines_["SU"].get_label() == f"SU {evaluation.methods['SU'].auc_pr:.3f}"  # named by the title:
    assert other.ax_.get_legend().get_title().get_text() == "uncertainty method (AUC-PR, Table 1)"
    assert right.get_title() == "mine"
    again = display.plot(left)  # the same data drawn again elsewhere
    assert again is display and display.ax_ is left and len(left.lines) == 3  # two curves + accept-all line


def test_without_ax_a_new_figure_is_made(retrieval):
    display = RejectionCurveDisplay.from_evaluation(evaluate(retrieval, ["SU"], k=10))
    assert display.figure_ is display.ax_.figure
    assert display.ax_.get_title() == "Rejecting uncertain answers (400 queries)"


def test_from_predictions_draws_one_curve():
    display = RejectionCurveDisplay.from_predictions([True, False, True], [0.1, 0.9, 0.2], name="mine")
    assert list(display.lines_) == ["mine"] and display.lines_["mine"].get_ydata().tolist() == [1.0, 1.0, 2 / 3]


def test_bad_arguments_are_named(retrieval):
    evaluation = evaluate(retrieval, ["SU"], k=10)
    with pytest.raises(ValueError, match=r"methods \['XX'\] are not in the evaluation; it has SU"):
        RejectionCurveDisplay.from_evaluation(evaluation, methods=["XX"])
    with pytest.raises(TypeError, match="ax must be a matplotlib Axes"):
        RejectionCurveDisplay.from_evaluation(evaluation, ax="left")
    with pytest.raises(TypeError, match="reliability must be a Reliability"):
        ReliabilityDisplay({"counts": []})


def test_reliability_from_predictions_and_from_a_gate(retrieval):
    probability = np.linspace(0.05, 0.95, 50)
    correct = np.arange(50) % 3 > 0
    figure, ax = plt.subplots()
    display = ReliabilityDisplay.from_predictions(correct, probability, n_bins=5, ax=ax, title="held out")
    expected = reliability_diagram(probability, correct, n_bins=5)
    assert display.ax_ is ax and display.figure_ is figure and ax.get_title() == "held out"
    assert display.line_.get_ydata().tolist() == [value for value in expected.accuracy if value is not None]

    gate = calibrate(retrieval, k=10)
    labels = retrieval.indices[:, 0] == retrieval.positives.indices  # one positive per query
    figure, ax = plt.subplots()
    display = ReliabilityDisplay.from_gate(gate, retrieval.scores, labels, n_bins=4, ax=ax)
    expected = reliability_diagram(gate.probability_correct(retrieval.scores), labels, n_bins=4)
    assert (
        display.ax_ is ax
        and display.reliability == expected
        and display.line_.get_label().startswith("gate P(correct) (ECE ")
    )


def test_file_writers_draw_with_the_displays(retrieval, tmp_path, monkeypatch):
    evaluation = evaluate(retrieval, ["SU", "BM"], k=10)
    drawn = []
    original = RejectionCurveDisplay.plot

    def spy(self, ax=None, **options):
        drawn.append(type(self).__name__)
        return original(self, ax, **options)

    monkeypatch.setattr(RejectionCurveDisplay, "plot", spy)
    assert plot_rejection_curves(evaluation, tmp_path / "pr.png").stat().st_size > 0
    original_reliability = ReliabilityDisplay.plot
    monkeypatch.setattr(
        ReliabilityDisplay, "plot", lambda self, ax=None, **o: drawn.append("R") or original_reliability(self, ax, **o)
    )
    reliability = reliability_diagram(np.linspace(0, 1, 20), np.arange(20) % 2 == 0, n_bins=4)
    assert plot_reliability(reliability, tmp_path / "rel.png", title="t").stat().st_size > 0
    assert drawn == ["RejectionCurveDisplay", "R"]
