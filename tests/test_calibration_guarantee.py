"""The precision guarantee: Clopper–Pearson and fixed-sequence testing, and a simulation on the real corridor."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy import stats

from vpr_uncertainty.calibration.guarantee import (
    candidate_cuts,
    certify_threshold,
    clopper_pearson_lower,
    min_accepted,
)
from vpr_uncertainty.calibration.simulation import simulate_guarantee
from vpr_uncertainty.evaluation import correct_at_n
from vpr_uncertainty.retrieval import read_results

CORRIDOR = [
    "AMOSNet",
    "AlexNet_VPR",
    "CALC",
    "CoHOG",
    "HOG",
    "HybridNet",
    "NetVLAD",
    "RegionVLAD",
    "ap-gem-r101",
    "denseVLAD",
]


@pytest.mark.parametrize(("p", "delta"), [(0.9, 0.1), (0.95, 0.05), (0.8, 0.2)])
def test_min_accepted_is_the_smallest_certifiable_count(p, delta):
    n = min_accepted(p, delta)
    assert n == math.ceil(math.log(delta) / math.log(p))
    assert clopper_pearson_lower(n, n, delta) >= p > clopper_pearson_lower(n - 1, n - 1, delta)


def test_clopper_pearson_lower_matches_binomial_inversion():
    for correct, accepted in [(30, 30), (35, 37), (5, 10)]:
        bound = float(clopper_pearson_lower(correct, accepted, 0.1))
        # the bound is the p at which P[Binomial(n, p) >= c] = δ
        assert stats.binom.sf(correct - 1, accepted, bound) == pytest.approx(0.1, rel=1e-6)
    assert clopper_pearson_lower(0, 5, 0.1) == 0


def test_fixed_sequence_stops_at_first_failure():
    # ranked confidences: 30 correct, then one wrong, then 30 correct
    correct = np.array([True] * 30 + [False] + [True] * 30)
    confidence = -np.arange(61.0)
    cuts = -np.arange(21.0, 61.0) - 0.5  # cut j accepts the 22 + j best
    certificate = certify_threshold(confidence, correct, cuts, target_precision=0.9, delta=0.1)
    assert certificate.certified
    # 22..30 accepted, all correct, pass; at 31 the wrong answer makes the p-value exceed δ and the sequence stops,
    # although laxer cuts (e.g. 61 accepted, 60 correct) would pass on their own.
    assert certificate.accepted == 30 and certificate.correct_accepted == 30
    assert stats.binom.sf(59, 61, 0.9) <= 0.1
    # A sequence that starts too strict (1 accepted) stops at once: nothing is certified.
    strict = certify_threshold(confidence, correct, -np.arange(61.0) - 0.5, target_precision=0.9, delta=0.1)
    assert not strict.certified and strict.cuts_tested == 1
    assert certificate.precision_lower_bound == pytest.approx(float(clopper_pearson_lower(30, 30, 0.1)))


def test_nothing_certifiable_says_why():
    certificate = certify_threshold(np.arange(10.0), np.ones(10, bool), np.array([5.5, 0.5]), target_precision=0.9)
    assert not certificate.certified and "fewer than the 22" in certificate.message


def test_candidate_cuts_start_and_midpoints():
    cuts = candidate_cuts(np.arange(100.0), n_test=100, target_precision=0.9, delta=0.1)
    assert (np.diff(cuts) < 0).all()
    assert cuts[0] == pytest.approx(100 - 33 - 0.5)  # 1.5 × 22 = 33 accepted of 100 at the first cut


def test_cuts_must_be_decreasing():
    with pytest.raises(ValueError, match="strictly decreasing"):
        certify_threshold(np.zeros(3), np.ones(3, bool), np.array([0.0, 1.0]), target_precision=0.9)


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_guarantee_holds_over_200_draws_on_the_real_corridor(corridor_dir, corridor_matches_dir):
    """200 i.i.d. calibration draws of 333 queries from each matrix's 111: precision < p* in at most δ of them."""
    start = time.perf_counter()
    target, delta, draws = 0.9, 0.1, 200
    slack = 3 * math.sqrt(delta * (1 - delta) / draws)  # binomial noise of the observed violation rate
    recalls = {}
    for method in CORRIDOR:
        retrieval = read_results(
            corridor_matches_dir / method / "precomputed_data_corrected.npy",
            ground_truth=corridor_dir / "ground_truth_new.npy",
        )
        correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
        simulation = simulate_guarantee(
            retrieval.scores, correct, n_calibration=333, target_precision=target, delta=delta, n_draws=draws
        )
        assert simulation.violation_rate <= delta + slack, method
        recalls[method] = (simulation.mean_recall, simulation.hindsight_recall, simulation.certified.mean())
    # Where a precision of 0.9 is reachable on most answers, the gate accepts a useful share of the correct ones.
    for method in ("AMOSNet", "HybridNet"):
        mean_recall, hindsight, certified = recalls[method]
        assert hindsight > 0.5 and certified > 0.8 and mean_recall > 0.4 * hindsight, (method, recalls[method])
    assert time.perf_counter() - start < 60
