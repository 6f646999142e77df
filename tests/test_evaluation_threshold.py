"""``threshold_at_precision``: the most lenient uncertainty threshold with empirical precision >= the target
(vpr_uncertainty.evaluation.metrics), checked against a brute-force search."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vpr_uncertainty import threshold_at_precision
from vpr_uncertainty.evaluation import ThresholdChoice


def brute_force(uncertainty, correct, target):
    """Try every distinct value as a threshold; keep the largest whose precision reaches the target."""
    uncertainty, correct = np.asarray(uncertainty, float), np.asarray(correct, bool)
    best = None
    for threshold in np.unique(uncertainty):
        accepted = uncertainty <= threshold
        if correct[accepted].mean() >= target:
            best = threshold
    return best


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 8), st.booleans()), min_size=1, max_size=40),
    st.sampled_from([0.5, 0.75, 0.9, 1.0]),
)
def test_matches_a_brute_force_search(rows, target):
    uncertainty = [value / 8 for value, _ in rows]  # few distinct values: ties are common
    correct = [label for _, label in rows]
    expected = brute_force(uncertainty, correct, target)
    if expected is None:
        with pytest.warns(RuntimeWarning, match="no uncertainty threshold reaches"):
            choice = threshold_at_precision(uncertainty, correct, target)
        assert choice.threshold == -math.inf and choice.n_accepted == 0 and not choice.reached
        assert choice.precision is None and choice.recall == 0.0 and choice.coverage == 0.0
        return
    choice = threshold_at_precision(uncertainty, correct, target)
    accepted = np.asarray(uncertainty) <= expected
    assert choice.threshold == expected and choice.reached
    assert choice.n_accepted == int(accepted.sum())
    assert choice.precision == pytest.approx(np.asarray(correct)[accepted].mean(), rel=1e-12)
    assert choice.precision >= target
    assert choice.recall == pytest.approx(np.asarray(correct)[accepted].sum() / len(rows), rel=1e-12)
    assert choice.coverage == pytest.approx(accepted.mean(), rel=1e-12)
    assert choice.accept(uncertainty).tolist() == accepted.tolist()


def test_recall_uses_the_answerable_queries_and_the_result_is_a_small_dataclass():
    choice = threshold_at_precision(np.array([0.1, 0.2, 0.3, 0.9]), np.array([1, 1, 0, 0]), 0.6, n_answerable=3)
    assert isinstance(choice, ThresholdChoice)
    assert (choice.threshold, choice.precision, choice.n_accepted) == (0.3, 2 / 3, 3)
    assert choice.recall == pytest.approx(2 / 3, rel=1e-12) and choice.coverage == 0.75
    assert isinstance(choice.threshold, float) and choice.target_precision == 0.6


@pytest.mark.parametrize(
    ("arguments", "error", "message"),
    [
        (([0.1, 0.2], [True, False], 0.0), ValueError, r"precision must lie in \(0, 1\]"),
        (([0.1, 0.2], [True, False], 1.5), ValueError, r"precision must lie in \(0, 1\]"),
        (([0.1, 0.2], [True, False], float("nan")), ValueError, r"precision must lie in \(0, 1\]"),
        (([0.1, 0.2], [True, False], True), TypeError, "precision must be a number"),
        (([0.1, 0.2], [True, False], "0.9"), TypeError, "precision must be a number"),
        (([True, False], [0.1, 0.2], 0.9), ValueError, "uncertainty and correct swapped"),
        (([0.1, 0.2, 0.3], [True, False], 0.9), ValueError, r"must both have shape \(n_queries,\)"),
        (([], [], 0.9), ValueError, "no queries"),
        (([0.1, float("nan")], [True, False], 0.9), ValueError, "NaN or inf"),
        (([0.1, 0.2], [0.3, 1], 0.9), ValueError, "correct must be boolean"),
    ],
    ids=["zero", "above 1", "nan", "bool", "string", "swapped", "shapes", "empty", "nan uncertainty", "labels"],
)
def test_invalid_input_names_the_argument(arguments, error, message):
    with pytest.raises(error, match=message):
        threshold_at_precision(*arguments)


def test_docstring_points_to_the_guaranteed_threshold():
    assert "vpr_uncertainty.calibrate" in threshold_at_precision.__doc__
    assert "no guarantee" in threshold_at_precision.__doc__


def test_str_says_what_to_accept():
    choice = threshold_at_precision([0.1, 0.2, 0.3], [True, True, False], 0.9)
    assert str(choice) == "accept uncertainty <= 0.2: precision 1.000, recall 0.667, coverage 0.667 (2 queries)"
    with pytest.warns(RuntimeWarning):
        nothing = threshold_at_precision([0.1, 0.2], [False, True], 0.9)
    assert str(nothing) == "no threshold reaches precision 0.9: accept nothing"
