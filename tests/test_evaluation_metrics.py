"""Evaluation metrics against slow loop references and hand-computed values."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import sparse

from conftest import assert_close
from vpr_uncertainty.evaluation.metrics import (
    FewerCandidatesWarning,
    auc_pr,
    aurc,
    average_precision,
    correct_at_n,
    first_positive_rank,
    precision_at_recall,
    rank_queries,
    recall_at_full_precision,
    recall_at_n,
    rejection_curve,
)


def reference_precision_recall(correct, uncertainty):
    """Loop over every distinct confidence, strictest first: (recall, precision) of the queries accepted."""
    confidence = -np.asarray(uncertainty, dtype=np.float64)
    points = [(0.0, 1.0)]  # the convention of the published tables: the curve starts at recall 0, precision 1
    for threshold in sorted(set(confidence.tolist()), reverse=True):
        accepted = confidence >= threshold
        true_positives = int((correct & accepted).sum())
        points.append((true_positives / correct.sum(), true_positives / accepted.sum()))
    return points


def reference_auc_pr(correct, uncertainty):
    """Trapezoid rule over the loop's points."""
    points = reference_precision_recall(correct, uncertainty)
    return sum((r1 - r0) * (p1 + p0) / 2 for (r0, p0), (r1, p1) in itertools.pairwise(points))


def reference_average_precision(correct, uncertainty):
    """Step-wise area: Σ (recall gained) × precision at each threshold."""
    points = reference_precision_recall(correct, uncertainty)
    return sum((r1 - r0) * p1 for (r0, _), (r1, p1) in itertools.pairwise(points))


def reference_rejection_curve(correct, uncertainty, n_answerable):
    """Loop over every distinct threshold: accept the queries whose uncertainty is <= it."""
    rows = []
    for threshold in sorted(set(uncertainty.tolist())):
        accepted = uncertainty <= threshold
        correct_accepted = int((correct & accepted).sum())
        rows.append((threshold, correct_accepted / accepted.sum(), correct_accepted / n_answerable))
    return np.array(rows)


def reference_aurc_without_ties(correct, uncertainty):
    """The textbook AURC: mean over i of the error rate among the i most confident queries."""
    order = np.argsort(uncertainty)
    errors = np.cumsum(~correct[order])
    return float(np.mean(errors / np.arange(1, len(order) + 1)))


@pytest.fixture
def labels():
    rng = np.random.default_rng(0)
    uncertainty = rng.normal(size=300)
    # correctness that depends on the uncertainty, with noise, so the curves are not trivial
    correct = rng.uniform(size=300) > 1 / (1 + np.exp(-2 * uncertainty))
    return correct, uncertainty


def test_auc_pr_and_average_precision_match_loop_references(labels):
    correct, uncertainty = labels
    assert_close(auc_pr(correct, uncertainty), reference_auc_pr(correct, uncertainty))
    assert_close(average_precision(correct, uncertainty), reference_average_precision(correct, uncertainty))
    tied = np.round(uncertainty, 1)  # tied queries enter together, at one threshold
    assert_close(auc_pr(correct, tied), reference_auc_pr(correct, tied))
    assert_close(average_precision(correct, tied), reference_average_precision(correct, tied))
    # the sign convention: a perfect uncertainty (wrong answers most uncertain) gives AUC-PR 1
    assert_close(auc_pr(correct, np.where(correct, 0.0, 1.0)), 1.0)
    assert auc_pr(correct, uncertainty) > auc_pr(correct, -uncertainty)


def test_precision_recall_needs_both_classes():
    with pytest.raises(ValueError, match="all 3 top-1 answers are correct"):
        auc_pr([True, True, True], [0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="are wrong"):
        average_precision([False, False], [0.1, 0.2])


@pytest.mark.parametrize("ties", [False, True])
def test_rejection_curve_matches_loop(labels, ties):
    correct, uncertainty = labels
    if ties:
        uncertainty = np.round(uncertainty, 1)
    curve = rejection_curve(correct, uncertainty, n_answerable=320)
    expected = reference_rejection_curve(correct, uncertainty, 320)
    assert_close(curve.thresholds, expected[:, 0])
    assert_close(curve.precision, expected[:, 1])
    assert_close(curve.recall, expected[:, 2])
    assert curve.coverage[-1] == 1.0


def test_rejection_summaries_hand_computed():
    #            accepted in order: T    T    F    T    F
    correct = np.array([True, True, False, True, False])
    uncertainty = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    curve = rejection_curve(correct, uncertainty, n_answerable=4)
    assert_close(curve.precision, [1, 1, 2 / 3, 3 / 4, 3 / 5])
    assert_close(curve.recall, [1 / 4, 2 / 4, 2 / 4, 3 / 4, 3 / 4])
    assert recall_at_full_precision(curve) == 0.5
    assert precision_at_recall(curve, 0.5) == 1.0
    assert precision_at_recall(curve, 0.75) == 0.75
    assert precision_at_recall(curve, 1.0) is None
    first_wrong = rejection_curve(~correct, uncertainty)
    assert recall_at_full_precision(first_wrong) == 0.0


def test_aurc_matches_textbook_formula_without_ties(labels):
    correct, uncertainty = labels
    assert_close(aurc(correct, uncertainty), reference_aurc_without_ties(correct, uncertainty))


def test_aurc_with_ties_accepts_tied_queries_together():
    correct = np.array([True, False, True, True])
    uncertainty = np.array([0.1, 0.1, 0.2, 0.2])
    # coverage 1/2 with risk 1/2, then coverage 1 with risk 1/4
    assert_close(aurc(correct, uncertainty), 0.5 * 0.5 + 0.5 * 0.25)
    # independent of the order of tied queries
    assert aurc(correct[[1, 0, 3, 2]], uncertainty) == aurc(correct, uncertainty)


def test_label_validation():
    with pytest.raises(ValueError, match="shape"):
        auc_pr([True, False], [0.1])
    with pytest.raises(ValueError, match="NaN or inf"):
        rejection_curve([True, False], [0.1, np.nan])
    with pytest.raises(ValueError, match="empty"):
        aurc([], [])
    with pytest.raises(ValueError, match="boolean"):
        auc_pr([2, 0], [0.1, 0.2])


def test_correct_and_recall_at_n_match_loop():
    rng = np.random.default_rng(1)
    n_queries, n_database, k = 60, 40, 20
    indices = np.array([rng.permutation(n_database)[:k] for _ in range(n_queries)])
    indices[5, 3:] = -1  # a query with only three candidates
    mask = rng.uniform(size=(n_queries, n_database)) < 0.05
    mask[7] = False  # a query with no positive at all
    answerable = mask.any(axis=1)
    for n in (1, 5, 10, 20):
        expected = np.array([any(i >= 0 and mask[q, i] for i in indices[q, :n]) for q in range(n_queries)])
        np.testing.assert_array_equal(correct_at_n(indices, mask, n), expected)
        np.testing.assert_array_equal(correct_at_n(indices, sparse.csr_array(mask), n), expected)
    with pytest.warns(FewerCandidatesWarning, match="recall@25 needs 25 candidates"):
        recalls = recall_at_n(indices, mask, ns=(1, 5, 25))
    assert recalls[25] is None  # 25 > k (< the database): unknown, said so, never left out silently
    assert_close(recalls[5], correct_at_n(indices, mask, 5)[answerable].mean())
    with pytest.raises(ValueError, match="between 1 and"):
        correct_at_n(indices, mask, 21)


def test_ranking_hand_computed_with_a_tie():
    # accepted in order: T (0.1), then F and T together (0.3, tied), then F (0.4)
    correct = np.array([True, False, True, False])
    uncertainty = np.array([0.1, 0.3, 0.3, 0.4])
    ranking = rank_queries(correct, uncertainty)
    np.testing.assert_array_equal(ranking.thresholds, [0.1, 0.3, 0.4])
    np.testing.assert_array_equal(ranking.accepted, [1, 3, 4])
    np.testing.assert_array_equal(ranking.correct_accepted, [1, 2, 2])
    assert ranking.n_distinct == 3 and ranking.tied_share == 0.5
    # PR points (recall, precision): (0, 1), (1/2, 1), (1, 2/3), (1, 1/2); the tie is one step, never split
    assert_close(ranking.auc_pr(), 0.5 * 1 + 0.5 * (1 + 2 / 3) / 2)
    assert_close(ranking.average_precision(), 0.5 * 1 + 0.5 * 2 / 3)
    # coverage 1/4 at risk 0, 3/4 at risk 1/3, 1 at risk 1/2
    assert_close(ranking.aurc(), 0.5 * (1 / 3) + 0.25 * 0.5)
    curve = ranking.rejection_curve(n_answerable=3)
    assert_close(curve.precision, [1, 2 / 3, 1 / 2])
    assert_close(curve.recall, [1 / 3, 2 / 3, 2 / 3])
    assert_close(curve.coverage, [1 / 4, 3 / 4, 1])
    with pytest.raises(ValueError, match="n_answerable must be >= the 2 correct"):
        ranking.rejection_curve(n_answerable=1)


@pytest.mark.parametrize("decimals", [None, 1, 0])
def test_one_ranking_gives_what_each_function_and_scikit_learn_give(labels, decimals):
    from sklearn.metrics import auc, average_precision_score, precision_recall_curve

    correct, uncertainty = labels
    if decimals is not None:
        uncertainty = np.round(uncertainty, decimals)  # ties: decimals 0 leaves about 7 distinct values
    ranking = rank_queries(correct, uncertainty)
    # the functions sort themselves; given one ranking the metrics are the very same code path: equal exactly
    assert ranking.auc_pr() == auc_pr(correct, uncertainty)
    assert ranking.average_precision() == average_precision(correct, uncertainty)
    assert ranking.aurc() == aurc(correct, uncertainty)
    curve, alone = ranking.rejection_curve(n_answerable=320), rejection_curve(correct, uncertainty, n_answerable=320)
    for field in ("thresholds", "precision", "recall", "coverage"):
        np.testing.assert_array_equal(getattr(curve, field), getattr(alone, field))
    # and scikit-learn's convention: one threshold per distinct value of -uncertainty
    precision, recall, _ = precision_recall_curve(correct, -uncertainty)
    got_precision, got_recall = ranking.precision_recall()
    assert_close(got_precision, precision)
    assert_close(got_recall, recall)
    assert_close(ranking.auc_pr(), auc(recall, precision))
    assert_close(ranking.average_precision(), average_precision_score(correct, -uncertainty))
    _, counts = np.unique(uncertainty, return_counts=True)
    assert ranking.n_distinct == counts.size
    assert ranking.tied_share == counts[counts > 1].sum() / counts.sum()


def test_ranking_does_not_depend_on_the_order_of_the_queries():
    rng = np.random.default_rng(5)
    correct = rng.uniform(size=500) < 0.6
    uncertainty = rng.integers(0, 12, size=500) / 4.0  # heavy ties
    ranking = rank_queries(correct, uncertainty)
    for _ in range(5):
        order = rng.permutation(500)  # ties now meet the sort in another order
        shuffled = rank_queries(correct[order], uncertainty[order])
        for field in ("thresholds", "accepted", "correct_accepted"):
            np.testing.assert_array_equal(getattr(shuffled, field), getattr(ranking, field))
        assert shuffled.auc_pr() == ranking.auc_pr() and shuffled.aurc() == ranking.aurc()


def test_ranking_validates_like_the_functions():
    with pytest.raises(ValueError, match="NaN or inf"):
        rank_queries([True, False], [0.1, np.inf])
    with pytest.raises(ValueError, match="all 2 top-1 answers are correct"):
        rank_queries([True, True], [0.1, 0.2]).auc_pr()
    with pytest.raises(ValueError, match="are wrong"):
        rank_queries([False, False], [0.1, 0.2]).average_precision()
    assert rank_queries([False, False], [0.1, 0.2]).aurc() == 1.0  # AURC is defined with one class


def test_first_positive_rank_answers_every_n_from_one_look_up():
    rng = np.random.default_rng(4)
    n_queries, n_database, k = 50, 30, 10
    indices = np.array([rng.permutation(n_database)[:k] for _ in range(n_queries)])
    indices[3, 2:] = -1
    mask = rng.uniform(size=(n_queries, n_database)) < 0.08
    mask[9] = False
    rank = first_positive_rank(indices, mask)
    for q in range(n_queries):
        hits = [i >= 0 and mask[q, i] for i in indices[q]]
        assert rank[q] == (hits.index(True) if any(hits) else k)
    for n in range(1, k + 1):
        np.testing.assert_array_equal(rank < n, correct_at_n(indices, mask, n))
        np.testing.assert_array_equal(first_positive_rank(indices, mask, n), np.minimum(rank, n))
    answerable = mask.any(axis=1)
    given = recall_at_n(indices, mask, ns=(1, 2, 5, 10), first_rank=rank, answerable=answerable)
    assert given == recall_at_n(indices, mask, ns=(1, 2, 5, 10))
    assert given == {n: float(correct_at_n(indices, mask, n)[answerable].mean()) for n in (1, 2, 5, 10)}
    with pytest.raises(ValueError, match="must be >= 1"):
        recall_at_n(indices, mask, ns=(0, 1))


def test_auc_pr_is_scikit_learns_trapezoid_bit_for_bit(labels):
    """AUC-PR is computed without importing scikit-learn, with sklearn.metrics.auc's arithmetic."""
    from sklearn.metrics import auc

    correct, uncertainty = labels
    for values in (uncertainty, np.round(uncertainty, 1)):
        ranking = rank_queries(correct, values)
        precision, recall = ranking.precision_recall()
        assert ranking.auc_pr() == auc(recall, precision)
