"""The precision guarantee: Clopper–Pearson and fixed-sequence testing, and a simulation on the real corridor."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from vpr_uncertainty.calibration.guarantee import (
    certify_threshold,
    clopper_pearson_lower,
    cut_chain,
    cuts_at_coverage,
    fallback_test,
    fixed_sequence,
    min_accepted,
    tolerant_steps,
)
from vpr_uncertainty.calibration.plan import simulate_guarantee
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation import correct_at_n

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


def test_tolerant_steps_make_room_for_one_more_wrong_answer_per_step():
    counts = tolerant_steps(200, 0.9, 0.1)
    assert counts[:4].tolist() == [22, 38, 52, 65] and counts[0] == min_accepted(0.9, 0.1)
    for wrong, count in enumerate(counts):  # the fewest accepted that certify with `wrong` wrong answers
        assert stats.binom.sf(count - wrong - 1, count, 0.9) <= 0.1 < stats.binom.sf(count - wrong - 2, count - 1, 0.9)
    assert tolerant_steps(21, 0.9, 0.1).size == 0
    assert tolerant_steps(200, 0.9, 0.05)[0] == 29  # at δ/2: 29 accepted, all correct, are needed


def test_the_chain_is_fixed_by_n_p_and_level_and_holds_the_whole_level():
    counts, levels = cut_chain(100, 0.9, 0.1, fallback=0.3, dense_from=0.25)
    # m_0 at 0.07 (26), the tolerant steps at 0.1 up to 25 (none past 26), every count from 26 on; the fallback count
    # (the fewest among which one wrong answer passes at 0.03) holds 0.03
    assert counts[0] == min_accepted(0.9, 0.07) == 26 and counts.tolist() == list(range(26, 101))
    spare = int(counts[np.isclose(levels, 0.03)][0])
    assert stats.binom.sf(spare - 2, spare, 0.9) <= 0.03 < stats.binom.sf(spare - 3, spare - 1, 0.9)
    assert levels.sum() == pytest.approx(0.1) and np.count_nonzero(levels) == 2
    sparse, _ = cut_chain(400, 0.9, 0.1, fallback=0.0, dense_from=0.5)
    assert sparse[:5].tolist() == [22, 38, 52, 65, 78] and sparse[-1] == 400 and 198 not in sparse and 200 in sparse
    assert cut_chain(21, 0.9, 0.1, fallback=0.0)[0].size == 0


def _fallback_by_hand(p_values, levels):
    """Wiens' fallback written out: a level passes on to the next hypothesis only from a rejected one."""
    rejected, inherited = [], 0.0
    for p_value, level in zip(p_values, levels, strict=True):
        level_now = level + inherited
        rejected.append(p_value <= level_now)
        inherited = level_now if rejected[-1] else 0.0
    return rejected


def test_fallback_test_matches_the_procedure_written_out():
    rng = np.random.default_rng(0)
    for _ in range(200):
        m = int(rng.integers(1, 12))
        p_values, levels = rng.uniform(0, 0.15, m), rng.dirichlet(np.ones(m)) * 0.1 * (rng.random(m) < 0.5)
        assert fallback_test(p_values, levels)[0].tolist() == _fallback_by_hand(p_values, levels)
    # all the level on the first hypothesis: the fixed sequence
    p_values = np.array([0.05, 0.08, 0.2, 0.01])
    assert fallback_test(p_values, np.array([0.1, 0, 0, 0]))[0].tolist() == [True, True, False, False]


def test_cuts_at_coverage_accept_the_share_and_lie_between_values():
    confidence = np.array([0.9, 0.1, 0.5, 0.7, 0.3])
    cuts = cuts_at_coverage(confidence, np.array([0.2, 0.4, 0.6, 1.0]))
    assert cuts.tolist() == pytest.approx([0.8, 0.6, 0.4, 0.1 - 0.5])
    assert [(confidence >= cut).sum() for cut in cuts] == [1, 2, 3, 5]


def test_fixed_sequence_uses_exact_binomial_p_values():
    # 44 of 45 correct at p* = 0.9: the exact p-value is 0.052 (a Bentkus bound gives about twice that)
    rejected, p_values = fixed_sequence(np.array([45]), np.array([44]), target_precision=0.9, delta=0.1)
    assert rejected == 1 and p_values[0] == pytest.approx(stats.binom.sf(43, 45, 0.9)) and 0.05 < p_values[0] < 0.053
    # one wrong answer in the first 22 accepted stops the sequence, even where later cuts would pass
    rejected, _ = fixed_sequence(np.array([22, 60]), np.array([21, 59]), target_precision=0.9, delta=0.1)
    assert rejected == 0


def test_cuts_must_be_decreasing():
    with pytest.raises(ValueError, match="strictly decreasing"):
        certify_threshold(np.zeros(3), np.ones(3, bool), np.array([0.0, 1.0]), target_precision=0.9)


@pytest.mark.filterwarnings("ignore:reading the legacy")
@pytest.mark.parametrize("n_calibration", [333, 182])
def test_guarantee_holds_over_200_draws_on_the_real_corridor(corridor_dir, corridor_matches_dir, n_calibration):
    """200 i.i.d. calibration draws of n queries from each matrix's 111: precision < p* in at most δ of them."""
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
            retrieval.scores, correct, n_calibration=n_calibration, target_precision=target, delta=delta, n_draws=draws
        )
        assert simulation.violation_rate <= delta + slack, method
        recalls[method] = (simulation.mean_recall, simulation.hindsight_recall, simulation.certified.mean())
    # Where a precision of 0.9 is reachable on most answers, the gate accepts a useful share of the correct ones.
    for method in ("AMOSNet", "HybridNet") if n_calibration == 333 else ():
        mean_recall, hindsight, certified = recalls[method]
        assert hindsight > 0.5 and certified > 0.8 and mean_recall > 0.4 * hindsight, (method, recalls[method])
