"""Paired bootstrap over queries (vpr_uncertainty.evaluation.bootstrap): the vectorised metrics against a slow
loop over the very same resamples with the reference metrics, intervals, the paired test and Holm's correction."""

import numpy as np
import pytest

from vpr_uncertainty.evaluation import auc_pr, aurc, average_precision
from vpr_uncertainty.evaluation.bootstrap import (
    bootstrap_metrics,
    holm,
    paired_p_value,
    percentile_interval,
    resample_indices,
    weighted_metrics,
)

METRICS = {"auc_pr": auc_pr, "average_precision": average_precision, "aurc": aurc}


def _data(n=40, seed=3):
    rng = np.random.default_rng(seed)
    correct = rng.random(n) < 0.6
    return correct, {
        "continuous": rng.random(n) - 0.3 * correct,
        "tied": np.round(rng.random(n) - 0.5 * correct, 1),  # a few distinct values, like inlier counts
        "constant": np.zeros(n),
    }


def _slow(correct, uncertainty, n_resamples, seed):
    """The bootstrap as a plain loop over resampled arrays, with the metrics of evaluation.metrics."""
    values = {name: [] for name in METRICS}
    for block in resample_indices(correct.size, n_resamples, seed):
        for index in block:
            labels = correct[index]
            both = labels.any() and not labels.all()
            for name, metric in METRICS.items():
                values[name].append(metric(labels, uncertainty[index]) if both else np.nan)
    return {name: np.array(v) for name, v in values.items()}


def test_vectorised_bootstrap_equals_a_slow_loop_over_the_same_resamples():
    correct, uncertainties = _data()
    fast = bootstrap_metrics(correct, uncertainties, n_resamples=150, seed=7)
    for method, uncertainty in uncertainties.items():
        slow = _slow(correct, uncertainty, 150, 7)
        for metric in METRICS:
            np.testing.assert_allclose(fast[metric][method], slow[metric], rtol=1e-12, atol=1e-14)


def test_all_weights_one_give_the_metrics_themselves():
    correct, uncertainties = _data(111, seed=5)
    for uncertainty in uncertainties.values():
        values = weighted_metrics(correct, uncertainty, np.ones((1, correct.size)))
        for metric, reference in METRICS.items():
            np.testing.assert_allclose(values[metric][0], reference(correct, uncertainty), rtol=1e-12)


def test_same_seed_same_resamples_and_another_seed_others():
    first = np.concatenate(list(resample_indices(30, 250, seed=1)))
    again = np.concatenate(list(resample_indices(30, 250, seed=1)))
    other = np.concatenate(list(resample_indices(30, 250, seed=2)))
    assert first.shape == (250, 30) and np.array_equal(first, again) and not np.array_equal(first, other)


def test_resamples_with_one_class_are_skipped_for_every_metric():
    correct = np.array([True] * 5 + [False])  # one wrong answer: ~(5/6)^6 = 33 % of resamples miss it
    distributions = bootstrap_metrics(correct, {"A": np.arange(6.0)}, n_resamples=300, seed=0)
    skipped = [np.isnan(distributions[metric]["A"]) for metric in METRICS]
    assert 50 < skipped[0].sum() < 150
    assert all(np.array_equal(skipped[0], other) for other in skipped[1:])


def test_intervals_contain_the_point_estimate():
    correct, uncertainties = _data(111, seed=11)
    distributions = bootstrap_metrics(correct, uncertainties, n_resamples=1000, seed=0)
    for method, uncertainty in uncertainties.items():
        for metric, reference in METRICS.items():
            low, high = percentile_interval(distributions[metric][method])
            assert low <= reference(correct, uncertainty) <= high, (method, metric)


def test_percentile_interval_leaves_out_skipped_resamples_and_checks_confidence():
    assert percentile_interval([np.nan, 1.0, 3.0], 0.5) == (1.5, 2.5)
    assert percentile_interval([np.nan, np.nan]) is None
    with pytest.raises(ValueError, match="confidence must lie in"):
        percentile_interval([1.0], 1.0)


def test_holm_on_a_hand_computed_case():
    # sorted: 0.005 x 4 = 0.02; 0.01 x 3 = 0.03; 0.03 x 2 = 0.06; 0.04 x 1 = 0.04 -> monotone max: 0.06
    np.testing.assert_allclose(holm([0.04, 0.005, 0.03, 0.01]), [0.06, 0.02, 0.06, 0.03], rtol=1e-12)
    assert holm([0.5, 0.9]) == [1.0, 1.0]
    assert holm([]) == []
    with pytest.raises(ValueError, match=r"p_values must be a sequence of numbers in \[0, 1\]"):
        holm([0.1, 1.5])


def test_the_paired_test_finds_a_real_difference_and_none_against_itself():
    rng = np.random.default_rng(0)
    correct = rng.random(111) < 0.6
    perfect = np.where(correct, 0.0, 1.0) + 0.01 * rng.random(111)
    random = rng.random(111)
    distributions = bootstrap_metrics(correct, {"perfect": perfect, "random": random}, n_resamples=1000, seed=0)
    auc = distributions["auc_pr"]
    assert paired_p_value(auc["perfect"], auc["random"]) == pytest.approx(2 / 1001, rel=1e-12)
    assert paired_p_value(auc["random"], auc["random"]) == 1.0


def test_the_p_value_counts_the_other_sign_twice_with_the_plus_one_correction():
    difference = np.array([0.1] * 17 + [-0.1] * 3)  # 3 of 20 resamples on the other side
    assert paired_p_value(difference, np.zeros(20)) == pytest.approx(2 * 4 / 21, rel=1e-12)
    assert paired_p_value([np.nan, 0.2], [0.1, np.nan]) is None


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="n_resamples must be an integer >= 1"):
        next(resample_indices(10, 0, seed=0))
    with pytest.raises(ValueError, match=r"method 'B': correct and uncertainty must both have shape"):
        bootstrap_metrics({None: [True, False]}, {"A": [0.1, 0.2], "B": [0.1, 0.2, 0.3]}, n_resamples=5)
    with pytest.raises(ValueError, match="method 'A': uncertainty contains 1 NaN"):
        bootstrap_metrics([True, False], {"A": [0.1, np.nan]}, n_resamples=5)


def test_a_thousand_resamples_of_eight_methods_on_111_queries_take_well_under_a_second():
    import time

    rng = np.random.default_rng(0)
    correct = rng.random(111) < 0.6
    uncertainties = {f"m{i}": rng.random(111) for i in range(8)}
    start = time.perf_counter()
    bootstrap_metrics(correct, uncertainties, n_resamples=1000, seed=0)
    assert time.perf_counter() - start < 1.0
