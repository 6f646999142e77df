"""Random labels only (issue 43): the default gate is never below the textbook where its old shape was.

The textbook: the Clopper–Pearson fixed sequence on one ranking fixed before labelling, every count from
⌈log δ / log p*⌉ = 22 at the full δ. benchmarks/random_labels.py measures both on the corridor and on populations
built to fail; these are the mechanisms, one population each.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from vpr_uncertainty.calibration.fit import calibrate_arrays
from vpr_uncertainty.calibration.guarantee import (
    DENSE_FROM,
    certify_rankings,
    cut_chain,
    default_rankings,
    min_accepted,
)


def _ranked_by_margin(n: int) -> np.ndarray:
    """Rows [0.9, 0.9 − gap, 0.1, …] with the gap (the margin) falling with the row: row i is the (i+1)-th most
    confident by the margin, SU and the model alike."""
    scores = np.full((n, 10), 0.1)
    scores[:, 0], scores[:, 1] = 0.9, 0.9 - (0.7 - 0.6 * np.arange(n) / n)
    return scores


def _textbook(correct: np.ndarray, p_star: float = 0.9, delta: float = 0.1) -> int:
    """Accepted count of the textbook fixed sequence on the ranking order (0: nothing certified)."""
    certified = 0
    for m in range(math.ceil(math.log(delta) / math.log(p_star)), correct.size + 1):
        if stats.binom.sf(correct[:m].sum() - 1, m, p_star) > delta:
            break
        certified = m
    return certified


def test_the_chain_tests_every_count_from_its_first_so_a_short_clean_top_is_found():
    """182 labels, the 36 most confident correct, then 4 wrong. The old chain (dense from n/4 = 46) tested 26, then
    the tolerant step 38 (36 of 38: p = 0.27, fails) and certified 26; the textbook certifies 36 (22 … 36 pass,
    36 of 37 gives p = 0.10). Testing every count from the first, the gate certifies 36 too."""
    rng = np.random.default_rng(0)
    correct = np.concatenate([np.ones(36, bool), np.zeros(4, bool), rng.random(142) < 0.5])
    scores = _ranked_by_margin(correct.size)
    gate = calibrate_arrays(scores, correct, target_precision=0.9, delta=0.1, rankings={"margin": 1.0})
    assert _textbook(correct) == 36 and gate.info["certificate"]["accepted"] == 36
    assert gate.accept(scores).tolist() == [True] * 36 + [False] * 146
    old = certify_rankings(
        *({"gap": scores[:, 0] - scores[:, 1]},) * 2,
        correct,
        np.ones(correct.size, bool),
        shares={"margin": 1.0},
        model_features=("gap",),
        target_precision=0.9,
        delta=0.1,
        folds=5,
        seed=0,
        dense_from=DENSE_FROM,
    )[0]
    assert old.accepted == 26


def test_delta_no_count_can_use_goes_to_the_ranking_that_can():
    """30 % of the corridor: 33 labels, the 24 most confident correct. Under CAL 0.9 + margin 0.1 the margin's chain
    (0.1 δ: 48 all correct) starts beyond 33 and CAL's fallback count beyond 33 too; before, CAL held 0.7 × 0.09 on
    its first count (27 accepted, all correct, needed: 24 of 27 fails) and nothing was certified. Now CAL holds the
    whole δ from 22 and certifies what the textbook does."""
    correct = np.concatenate([np.ones(24, bool), [False], np.arange(8) % 2 == 0])
    scores = _ranked_by_margin(correct.size)
    assert cut_chain(33, 0.9, 0.09, fallback=0.3)[0][0] == 27 and cut_chain(33, 0.9, 0.01)[0].size == 0
    gate = calibrate_arrays(scores, correct, target_precision=0.9, delta=0.1, rankings={"CAL": 0.9, "margin": 0.1})
    certificate = gate.info["certificate"]
    assert gate.info["rankings"] == pytest.approx({"CAL": 0.1, "margin": 0.0})
    assert certificate["ranking"] == "CAL" and certificate["accepted"] == _textbook(correct) == 24
    assert gate.accept(scores).sum() == 24 and certificate["min_accepted"] == 23


@pytest.mark.parametrize("rankings", [None, {"SU": 0.9, "margin": 0.1}])
def test_the_recycled_delta_keeps_the_guarantee_at_33_labels(rankings):
    """Every cut's precision 0.89 < p*: whatever is certified is a violation, so P(certified) ≤ δ (binomial noise
    of 300 draws allowed). With the whole δ on a first count of 22: 0.89^22 = 0.077 for a fixed ranking."""
    rng = np.random.default_rng(1)
    scores = -np.sort(-rng.uniform(0.2, 0.9, size=(2000, 10)), axis=1)
    correct = rng.random(2000) < 0.89
    draws, certified = 300, 0
    for draw in range(draws):
        rows = rng.choice(2000, 33, replace=True)
        if correct[rows].all():  # 0.89^33 = 2 %: calibrate refuses the draw, which certifies nothing
            continue
        gate = calibrate_arrays(
            scores[rows], correct[rows], target_precision=0.9, delta=0.1, seed=draw, rankings=rankings
        )
        certified += gate.precision_lower_bound is not None
    assert certified / draws <= 0.1 + 3 * math.sqrt(0.1 * 0.9 / draws)


def test_the_default_rankings_depend_on_the_number_of_labels_alone():
    """In multiples of ⌈log δ / log p*⌉ (22 for 0.9 / 0.1, 11 for 0.8 / 0.1): SU alone below 6×, SU and CAL below
    8×, then CAL 0.9 + margin 0.1 with the fallback count."""
    assert default_rankings(131, 0.9, 0.1) == ({"SU": 1.0}, 0.0)
    assert default_rankings(132, 0.9, 0.1) == default_rankings(175, 0.9, 0.1) == ({"SU": 0.5, "CAL": 0.5}, 0.0)
    assert default_rankings(176, 0.9, 0.1) == ({"CAL": 0.9, "margin": 0.1}, 0.3)
    assert default_rankings(65, 0.8, 0.1)[0] == {"SU": 1.0} and default_rankings(66, 0.8, 0.1)[0] == {
        "SU": 0.5,
        "CAL": 0.5,
    }
    assert min_accepted(0.95, 0.05) == 59 and default_rankings(353, 0.95, 0.05)[0] == {"SU": 1.0}


def _su(scores: np.ndarray) -> np.ndarray:
    """SU of each row, a slow and obvious float64 SU: the paper's formula, row by row (α = 0.5, k = 10)."""
    return np.array([0.5 * np.mean(row[1:] / row[0]) + 0.5 * np.median(row) / row[0] for row in scores[:, :10]])


def _su_order(scores: np.ndarray) -> np.ndarray:
    """Rows most confident first by SU."""
    return np.argsort(_su(scores), kind="stable")


def test_a_short_clean_top_among_100_random_labels_is_certified_as_the_textbook_does():
    """100 labels, SU's 24 most confident correct, then a wrong answer and a mixed rest, the margin's order another:
    the textbook on SU certifies 24 (24 of 24 at 0.1: p = 0.08). Under CAL 0.9 + margin 0.1 (the default before, at
    every n) CAL's first count held 0.063 (27 all correct needed) and nothing was certified."""
    rng = np.random.default_rng(3)
    n = 100
    scores = -np.sort(-rng.uniform(0.3, 0.6, size=(n, 10)), axis=1)
    scores[:, 0] = np.linspace(0.95, 0.62, n) + rng.uniform(0, 0.01, n)  # s1 falls: SU rises with the row
    order = _su_order(scores)
    correct = np.zeros(n, bool)
    correct[order[:24]] = True
    correct[order[25:]] = rng.random(n - 25) < 0.7
    assert _textbook(correct[order]) == 24
    gate = calibrate_arrays(scores, correct, target_precision=0.9, delta=0.1)
    assert gate.info["rankings"] == {"SU": 0.1} and gate.info["certificate"]["accepted"] == 24
    assert gate.accept(scores).sum() == 24 and gate.accept(scores)[order[:24]].all()
    old = calibrate_arrays(scores, correct, target_precision=0.9, delta=0.1, rankings={"CAL": 0.9, "margin": 0.1})
    assert old.precision_lower_bound is None or old.info["certificate"]["accepted"] < 24


@pytest.mark.parametrize("n", [40, 100])
def test_below_132_labels_the_default_is_the_textbook_on_su_on_the_corridor(corridor_dir, corridor_matches_dir, n):
    """Random draws of n labels (with replacement) of the ten corridor methods: the default gate accepts exactly the
    labelled queries that the textbook fixed sequence on SU (written out above) accepts."""
    from vpr_uncertainty import correct_at_n, read_results

    compared = 0
    for path in sorted(corridor_matches_dir.glob("*/precomputed_data_corrected.npy")):
        retrieval = read_results(path, ground_truth=corridor_dir / "ground_truth_new.npy")
        correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
        rng = np.random.default_rng([n, len(path.parent.name)])
        for draw in range(3):
            rows = rng.choice(correct.size, n, replace=True)
            if correct[rows].all() or not correct[rows].any():
                continue
            scores, labels = retrieval.scores[rows, :10], correct[rows]
            gate = calibrate_arrays(scores, labels, target_precision=0.9, delta=0.1, seed=draw)
            order = _su_order(scores)
            expected, ranked = _textbook(labels[order]), np.sort(_su(scores))
            if 0 < expected < n and math.isclose(ranked[expected - 1], ranked[expected], rel_tol=1e-6):
                continue  # a tie at the cut: the quantile cut accepts the tied group, the count above cannot
            assert int(gate.accept(scores).sum()) == expected, (path.parent.name, draw)
            compared += 1
    assert compared >= 20
