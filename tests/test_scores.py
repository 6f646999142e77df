"""RS, SD, SU and the score-only baselines against slow, obviously-correct loop references."""

from __future__ import annotations

import math
import statistics

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from conftest import assert_close
from vpr_uncertainty import (
    StatisticalUncertainty,
    best_match,
    l2_distance,
    margin,
    perceptual_aliasing,
    ratio_spread,
    similarity_distribution,
    statistical_uncertainty,
)

# --- slow references: one query at a time, straight from the paper's formulas --------------------------------


def _candidates(row, k):
    values = [float(v) for v in row[:k]]
    return [v for v in values if v != -math.inf]


def reference_rs(row, k):
    s = _candidates(row, k)
    if s[0] <= 0:
        return 1 - s[0]
    return sum(s[i] / s[0] for i in range(1, len(s))) / (len(s) - 1)


def reference_sd(row, k):
    s = _candidates(row, k)
    if s[0] <= 0:
        return 1 - s[0]
    return statistics.median(s) / s[0]


def reference_su(row, k, alpha):
    s = _candidates(row, k)
    if s[0] <= 0:
        return 1 - s[0]
    return alpha * reference_rs(row, k) + (1 - alpha) * reference_sd(row, k)


def apply(reference, scores, *args):
    return np.array([reference(row, *args) for row in scores])


def sorted_rows(rng, n_queries, n_columns, low=0.05, high=1.0, dtype=np.float64):
    return -np.sort(-rng.uniform(low, high, size=(n_queries, n_columns)), axis=1).astype(dtype)


# --- property tests against the references ------------------------------------------------------------------

score_arrays = st.tuples(st.integers(1, 12), st.integers(2, 14)).flatmap(
    lambda shape: hnp.arrays(
        np.float64,
        shape,
        elements=st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False, allow_subnormal=False, width=32),
    )
)


@settings(max_examples=200, deadline=None)
@given(scores=score_arrays, k=st.integers(2, 16), alpha=st.floats(0.0, 1.0))
def test_metrics_match_loop_reference(scores, k, alpha):
    scores = -np.sort(-scores, axis=1)
    # Ratios explode as s_1 -> 0+ (the real behaviour of the formula); compare only well-conditioned rows there.
    scores = scores[(scores[:, 0] > 1e-3) | (scores[:, 0] <= 0)]
    if len(scores) == 0:
        return
    # float64, but the loop sums in another order and the ratios s_i / s_1 amplify rounding as s_1 -> 0: rtol 1e-9,
    # and an atol as the results can be ~0.
    assert_close(ratio_spread(scores, k), apply(reference_rs, scores, k), rtol=1e-9, atol=1e-9)
    assert_close(similarity_distribution(scores, k), apply(reference_sd, scores, k), rtol=1e-9, atol=1e-9)
    assert_close(statistical_uncertainty(scores, k, alpha), apply(reference_su, scores, k, alpha), rtol=1e-9, atol=1e-9)


def test_float32_matches_reference_on_paper_shape():
    rng = np.random.default_rng(0)
    scores = sorted_rows(rng, 500, 10, dtype=np.float32)
    result = statistical_uncertainty(scores)
    assert result.dtype == np.float32
    assert_close(result, apply(reference_su, scores, 10, 0.5))


# --- hand-computed cases ---------------------------------------------------------------------------------------


def test_hand_computed_k10():
    row = np.array([[1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1]])
    # RS = (0.9 + ... + 0.1) / 9 / 1.0 = 4.5 / 9 = 0.5; SD = median = (0.6 + 0.5) / 2 = 0.55
    assert_close(ratio_spread(row)[0], 0.5)
    assert_close(similarity_distribution(row)[0], 0.55)
    assert_close(statistical_uncertainty(row)[0], 0.525)
    assert_close(statistical_uncertainty(row, alpha=0.2)[0], 0.2 * 0.5 + 0.8 * 0.55)


def test_hand_computed_odd_k_and_more_columns_than_k():
    row = np.array([[0.8, 0.6, 0.4, 0.39, 0.1]])
    # k = 3 reads 0.8, 0.6, 0.4: RS = (0.6 + 0.4) / 2 / 0.8 = 0.625, SD = 0.6 / 0.8 = 0.75
    assert_close(ratio_spread(row, k=3)[0], 0.625)
    assert_close(similarity_distribution(row, k=3)[0], 0.75)


def test_alpha_limits_are_rs_and_sd():
    scores = sorted_rows(np.random.default_rng(1), 50, 10)
    assert_close(statistical_uncertainty(scores, alpha=1.0), ratio_spread(scores))
    assert_close(statistical_uncertainty(scores, alpha=0.0), similarity_distribution(scores))


def test_more_competition_means_more_uncertainty():
    confident = [[0.9, 0.3, 0.3, 0.2, 0.2, 0.2, 0.1, 0.1, 0.1, 0.1]]
    ambiguous = [[0.9, 0.89, 0.88, 0.87, 0.86, 0.85, 0.84, 0.83, 0.82, 0.81]]
    for metric in (ratio_spread, similarity_distribution, statistical_uncertainty):
        assert metric(np.array(confident))[0] < metric(np.array(ambiguous))[0]


def test_baselines_hand_computed():
    scores = np.array([[0.5, 0.0, -0.5], [1.0, 1.0, 0.5]])
    assert_close(best_match(scores), [-0.5, -1.0])
    # d = sqrt(2 - 2 s): row 0 -> d1 = 1, d2 = sqrt(2); row 1 -> d1 = d2 = 0
    assert_close(l2_distance(scores), [1.0, 0.0])
    assert_close(perceptual_aliasing(scores), [1 / math.sqrt(2), 1.0])
    assert_close(margin(scores), [-0.5, 0.0])


def test_baselines_use_given_distances():
    scores = np.array([[0.9, 0.8, 0.1]])
    distances = np.array([[4.0, 16.0, 25.0]])  # squared, deliberately not 2 - 2s
    assert_close(l2_distance(scores, distances=distances)[0], 2.0)
    assert_close(perceptual_aliasing(scores, distances=distances)[0], 0.5)


def test_baselines_match_reference_on_random_data():
    rng = np.random.default_rng(2)
    scores = sorted_rows(rng, 200, 10, low=-1, high=1)
    d = np.sqrt(np.maximum(2 - 2 * scores, 0))
    assert_close(best_match(scores), [-row[0] for row in scores])
    assert_close(l2_distance(scores), d[:, 0])
    assert_close(perceptual_aliasing(scores), [r[0] / r[1] for r in d])
    assert_close(margin(scores), [r[1] - r[0] for r in scores])


# --- hard input --------------------------------------------------------------------------------------------------

ALL_METRICS = (ratio_spread, similarity_distribution, statistical_uncertainty)
ALL_METHODS = (*ALL_METRICS, best_match, l2_distance, perceptual_aliasing, margin)


@pytest.mark.parametrize("metric", ALL_METRICS)
def test_nonpositive_best_is_ranked_most_uncertain(metric):
    scores = np.array(
        [
            [0.9, 0.9, 0.9, 0.9],  # as uncertain as a positive row gets: 1.0
            [0.0, -0.1, -0.2, -0.3],
            [-0.2, -0.3, -0.4, -0.5],
            [0.5, 0.1, 0.0, -0.9],
        ]
    )
    result = metric(scores, k=4)
    assert np.isfinite(result).all()
    assert_close(result[1:3], [1.0, 1.2])
    assert result[2] > result[1] >= result[0] >= result[3]
    with pytest.raises(ValueError, match=r"best similarity is <= 0.*row 1"):
        metric(scores, k=4, on_nonpositive="raise")
    with pytest.raises(ValueError, match="on_nonpositive"):
        metric(scores, k=4, on_nonpositive="ignore")


@pytest.mark.parametrize("metric", ALL_METRICS)
def test_missing_candidates_use_the_ones_present(metric):
    scores = np.array([[0.9, 0.5, 0.4, 0.3], [0.8, 0.6, -np.inf, -np.inf], [0.7, 0.65, 0.6, -np.inf]])
    expected = metric(scores[:1], k=4).tolist()
    expected.append(metric(scores[1:2, :2], k=4)[0])
    expected.append(metric(scores[2:3, :3], k=4)[0])
    assert_close(metric(scores, k=4), expected)
    # fewer columns than k: the same as k = number of columns
    assert_close(metric(scores[:1], k=10), metric(scores[:1], k=4))


@pytest.mark.parametrize("metric", ALL_METHODS)
def test_row_without_runner_up_is_rejected(metric):
    scores = np.array([[0.9, 0.5], [0.8, -np.inf]])
    if metric in (best_match, l2_distance):
        assert np.isfinite(metric(scores)).all()
        with pytest.raises(ValueError, match=r"fewer than 1 candidates.*rows 0"):
            metric(np.array([[-np.inf, -np.inf]]))
    else:
        with pytest.raises(ValueError, match=r"fewer than 2 candidates.*rows 1"):
            metric(scores)


@pytest.mark.parametrize("metric", ALL_METHODS)
@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ([[0.9, np.nan, 0.1]], "NaN.*row 0"),
        ([[0.9, 0.5, 0.1], [np.nan, 0.5, 0.1]], "NaN.*row 1"),
        ([[np.inf, 0.5, 0.1]], r"\+inf"),
        ([[0.9, -np.inf, 0.1]], "sorted in descending order"),
        ([[0.1, 0.5, 0.9]], "row 0 has 0.1 before 0.5.*sort=True"),
    ],
)
def test_bad_values_give_clear_errors(metric, bad, message):
    with pytest.raises(ValueError, match=message):
        metric(np.array(bad))


@pytest.mark.parametrize("metric", ALL_METHODS)
def test_sort_option_sorts_for_the_caller(metric):
    rng = np.random.default_rng(3)
    unsorted = rng.uniform(0.1, 1, size=(20, 10))
    assert_close(metric(unsorted, sort=True), metric(-np.sort(-unsorted, axis=1)))
    before = unsorted.copy()
    metric(unsorted, sort=True)
    np.testing.assert_array_equal(unsorted, before)  # the caller's array is untouched
    with pytest.raises(ValueError, match="NaN"):
        metric(np.array([[0.1, np.nan, 0.9]]), sort=True)


@pytest.mark.parametrize("metric", ALL_METHODS)
@pytest.mark.parametrize(
    ("k", "error", "message"),
    [(1, ValueError, "k must be >= 2"), (2.5, TypeError, "integer"), (True, TypeError, "integer")],
)
def test_bad_k(metric, k, error, message):
    with pytest.raises(error, match=message):
        metric(np.array([[0.9, 0.5, 0.1]]), k=k)


@pytest.mark.parametrize("alpha", [-0.1, 1.5, float("nan")])
def test_alpha_outside_unit_interval(alpha):
    with pytest.raises(ValueError, match="alpha must lie in"):
        statistical_uncertainty(np.array([[0.9, 0.5]]), alpha=alpha)
    with pytest.raises(ValueError, match="alpha must lie in"):
        StatisticalUncertainty(alpha=alpha)


@pytest.mark.parametrize("metric", ALL_METHODS)
def test_shapes(metric):
    empty = metric(np.empty((0, 10)))
    assert empty.shape == (0,)
    with pytest.raises(ValueError, match="2-D"):
        metric(np.array([0.9, 0.5, 0.1]))
    with pytest.raises(ValueError, match="2-D"):
        metric(np.ones((2, 3, 4)))
    with pytest.raises(ValueError, match="at least 2 columns"):
        metric(np.empty((3, 0)))
    with pytest.raises(TypeError, match="numeric"):
        metric(np.array([["a", "b"]]))


def test_overflow_is_reported_not_returned():
    scores = np.array([[1e-38, -3e38]], dtype=np.float32)
    with pytest.raises(ValueError, match="overflow"):
        ratio_spread(scores)
    assert np.isfinite(ratio_spread(scores.astype(np.float64)))[0]


def test_distances_are_validated():
    scores = np.array([[0.9, 0.5, 0.1]])
    with pytest.raises(ValueError, match="shape"):
        perceptual_aliasing(scores, distances=np.ones((2, 3)))
    with pytest.raises(ValueError, match="finite squared"):
        perceptual_aliasing(scores, distances=np.array([[-1.0, 0.5, 1.0]]))
    with pytest.raises(ValueError, match="ascending"):
        perceptual_aliasing(scores, distances=np.array([[1.0, 0.5, 2.0]]))


# --- the single-query scorer -------------------------------------------------------------------------------------


def test_single_query_scorer_matches_vectorised():
    rng = np.random.default_rng(4)
    scores = sorted_rows(rng, 100, 12, low=-0.5, high=1)
    for k, alpha in [(10, 0.5), (5, 0.3), (2, 1.0)]:
        scorer = StatisticalUncertainty(k=k, alpha=alpha)
        single = [scorer(row) for row in scores]
        assert_close(single, statistical_uncertainty(scores, k, alpha))
        assert_close(scorer.batch(scores), single)
    scorer = StatisticalUncertainty(k=4)
    assert_close(scorer([0.8, 0.6, -math.inf]), statistical_uncertainty(np.array([[0.8, 0.6]]), 4)[0])
    assert scorer((0.9, 0.5, 0.1)) == scorer(np.array([0.9, 0.5, 0.1]))


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ([0.9], "at least 2"),
        ([0.5, 0.9], "sorted"),
        ([0.9, float("nan")], "sorted"),
        ([math.inf, 0.5], "finite"),
        ([[0.9, 0.5], [0.8, 0.7]], r"\(k,\) or \(1, k\)"),
    ],
)
def test_single_query_scorer_rejects_bad_input(row, message):
    scorer = StatisticalUncertainty()
    with pytest.raises(ValueError, match=message):
        scorer(np.array(row) if isinstance(row[0], list) else row)


def test_single_query_scorer_nonpositive_policy():
    assert_close(StatisticalUncertainty()([-0.2, -0.3]), 1.2)
    with pytest.raises(ValueError, match="> 0"):
        StatisticalUncertainty(on_nonpositive="raise")([-0.2, -0.3])
