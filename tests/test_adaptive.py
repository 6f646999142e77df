"""SU-adaptive (:mod:`vpr_uncertainty.scores`): the vectorised α_q against a plain loop, its edge cases, and the
registered method."""

from __future__ import annotations

import math
import statistics

import numpy as np
import pytest

from vpr_uncertainty.methods import get_method
from vpr_uncertainty.retrieval import Retrieval
from vpr_uncertainty.scores import NO_EVIDENCE_ALPHA, adaptive_alpha, adaptive_statistical_uncertainty


def _reference(row: list[float], k: int) -> tuple[float, float]:
    """(α_q, SU-adaptive) of one query by the formulas of the docstring, in plain Python."""
    values = [v for v in row[:k] if v != -math.inf]
    best, runners_up = values[0], values[1:]
    mean, median = statistics.fmean(runners_up), statistics.median(runners_up)
    spread = statistics.pstdev(runners_up)
    alpha = NO_EVIDENCE_ALPHA if spread <= 1e-12 * abs(mean) else min(1.0, max(0.0, 1 - abs(mean - median) / spread))
    if best <= 0:
        return alpha, 1 - best
    rs = statistics.fmean(runners_up) / best
    sd = statistics.median(values) / best
    return alpha, alpha * rs + (1 - alpha) * sd


@pytest.mark.parametrize("k", [2, 3, 4, 10, 25])
def test_matches_a_loop_reference_on_random_scores(k):
    rng = np.random.default_rng(k)
    scores = -np.sort(-rng.random((300, 20)), axis=1)
    scores[::7] **= 4  # skewed cohorts
    scores[5, 3:] = -np.inf  # fewer candidates
    scores[6, 2:] = -np.inf
    scores[8] = -scores[8][::-1]  # best similarity <= 0
    expected = np.array([_reference(row.tolist(), k) for row in scores])
    np.testing.assert_allclose(adaptive_alpha(scores, k), expected[:, 0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(adaptive_statistical_uncertainty(scores, k), expected[:, 1], rtol=1e-12)


def test_float32_matches_the_float64_reference():
    rng = np.random.default_rng(1)
    scores = -np.sort(-rng.random((200, 10)), axis=1).astype(np.float32)
    expected = np.array([_reference(row.astype(np.float64).tolist(), 10)[1] for row in scores])
    result = adaptive_statistical_uncertainty(scores)
    assert result.dtype == np.float32
    np.testing.assert_allclose(result, expected, rtol=1e-5)


def test_alpha_bounds_and_meaning():
    scores = np.array(
        [
            [0.9, 0.5, 0.4, 0.3],  # symmetric runners-up: RS
            [0.9, 0.5, 0.5, 0.5],  # no spread: the default
            [0.9, 0.8, 0.3, 0.3],  # one strong runner-up pulls the mean: mostly SD
            [0.9, 0.2, -np.inf, -np.inf],  # one runner-up: the default
        ]
    )
    alpha = adaptive_alpha(scores, 4)
    assert alpha[0] == pytest.approx(1.0, rel=1e-12) and alpha[1] == alpha[3] == NO_EVIDENCE_ALPHA
    assert 0 <= alpha[2] < 0.5
    su = adaptive_statistical_uncertainty(scores, 4)
    assert su[0] == pytest.approx((0.4) / 0.9, rel=1e-12)  # RS


def test_invariant_to_the_scale_and_offset_of_the_runners_up():
    rng = np.random.default_rng(2)
    scores = -np.sort(-rng.random((50, 10)), axis=1)
    np.testing.assert_allclose(adaptive_alpha(3 * scores + 1, 10), adaptive_alpha(scores, 10), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize(
    ("scores", "message"),
    [
        (np.array([[0.5, 0.7]]), "descending"),
        (np.array([[0.5, np.nan]]), "NaN"),
        (np.array([[0.5, -np.inf]]), "fewer than 2 candidates"),
        (np.array([0.5, 0.4]), "2-D"),
    ],
)
def test_bad_input_is_one_clear_error(scores, message):
    with pytest.raises(ValueError, match=message):
        adaptive_statistical_uncertainty(scores)


def test_empty_and_sorted_input():
    assert adaptive_statistical_uncertainty(np.empty((0, 5))).shape == (0,)
    scores = np.array([[0.3, 0.9, 0.5, 0.4]])
    np.testing.assert_allclose(adaptive_statistical_uncertainty(scores, 4, sort=True), [0.4 / 0.9], rtol=1e-12)


def test_registered_method_calls_the_rule():
    rng = np.random.default_rng(3)
    scores = -np.sort(-rng.random((40, 10)), axis=1).astype(np.float32)
    retrieval = Retrieval(scores=scores, indices=np.tile(np.arange(10), (40, 1)))
    entry = get_method("SU-adaptive")
    assert entry.kind == "score" and not entry.default
    np.testing.assert_array_equal(entry(retrieval, k=5), adaptive_statistical_uncertainty(scores, 5))
