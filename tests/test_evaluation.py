"""Evaluation metrics against direct scikit-learn calls and slow loop references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse
from sklearn.metrics import auc, average_precision_score, precision_recall_curve

from conftest import assert_close
from vpr_uncertainty import Retrieval, evaluate
from vpr_uncertainty.evaluation import (
    auc_pr,
    aurc,
    average_precision,
    correct_at_n,
    precision_at_recall,
    recall_at_full_precision,
    recall_at_n,
    rejection_curve,
    time_per_query,
)


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


def test_auc_pr_is_the_trapezoid_over_sklearn_curve(labels):
    correct, uncertainty = labels
    precision, recall, _ = precision_recall_curve(correct, -uncertainty)
    assert_close(auc_pr(correct, uncertainty), auc(recall, precision), atol=0)
    assert_close(average_precision(correct, uncertainty), average_precision_score(correct, -uncertainty))
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
    recalls = recall_at_n(indices, mask, ns=(1, 5, 25))
    assert set(recalls) == {1, 5}  # 25 > k is left out
    assert_close(recalls[5], correct_at_n(indices, mask, 5)[answerable].mean())
    with pytest.raises(ValueError, match="between 1 and"):
        correct_at_n(indices, mask, 21)


def test_evaluate_on_synthetic_retrieval_matches_direct_computation():
    rng = np.random.default_rng(2)
    scores = -np.sort(-rng.uniform(0.2, 0.9, size=(80, 10)), axis=1)
    indices = np.tile(np.arange(10), (80, 1))
    mask = np.zeros((80, 30), bool)
    mask[np.arange(80), rng.integers(0, 3, size=80)] = True  # top-1 correct for about a third
    retrieval = Retrieval(scores=scores, indices=indices, positives=sparse.csr_array(mask))
    result = evaluate(retrieval, ["SU", "BM"], k=10, alpha=0.5)
    correct = mask[:, 0]
    np.testing.assert_array_equal(result.correct, correct)
    from vpr_uncertainty import statistical_uncertainty

    assert_close(result.methods["SU"].auc_pr, auc_pr(correct, statistical_uncertainty(scores)))
    assert_close(result.methods["BM"].auc_pr, auc_pr(correct, -scores[:, 0]))
    as_json = result.to_dict()
    assert set(as_json) >= {"n_queries", "recall@1", "methods"}
    assert set(as_json["methods"]["SU"]) >= {"auc_pr", "average_precision", "aurc", "time_per_query_ms"}


def test_evaluate_reports_undefined_auc_instead_of_nan():
    scores = np.array([[0.9, 0.5], [0.8, 0.1]])
    retrieval = Retrieval(scores=scores, indices=np.array([[0, 1], [1, 0]]), positives=np.eye(2, dtype=bool))
    with pytest.warns(RuntimeWarning, match="undefined"):
        result = evaluate(retrieval, ["SU"])
    assert result.methods["SU"].auc_pr is None
    assert "undefined" in result.to_dict()["notes"][0]


def test_evaluate_rejects_bad_requests():
    retrieval = Retrieval(scores=np.array([[0.9, 0.5]]), indices=np.array([[0, 1]]))
    with pytest.raises(ValueError, match="no ground truth"):
        evaluate(retrieval)
    retrieval.positives = sparse.csr_array(np.array([[True, False]]))
    with pytest.raises(KeyError, match="unknown uncertainty method 'su'; did you mean 'SU'"):
        evaluate(retrieval, ["su"])


def test_queries_without_positives_are_wrong_and_left_out_of_recall():
    scores = np.array([[0.9, 0.5], [0.8, 0.1], [0.7, 0.6]])
    positives = np.array([[True, False], [False, False], [False, True]])
    retrieval = Retrieval(scores=scores, indices=np.array([[0, 1], [0, 1], [0, 1]]), positives=positives)
    result = evaluate(retrieval, ["BM"])
    assert result.recall_at_n[1] == 0.5  # 1 of the 2 answerable queries
    assert result.n_answerable == 2
    assert result.methods["BM"].curve.recall[-1] == 0.5
    assert result.to_dict()["n_queries_without_positives"] == 1


def test_time_per_query_uses_the_median_of_repeats():
    calls = []
    result, seconds = time_per_query(lambda: calls.append(1) or "done", 10, repeats=3)
    assert result == "done" and len(calls) == 3 and seconds >= 0


def test_method_with_its_own_retrieval_is_judged_by_its_own_top1():
    from vpr_uncertainty.methods import METHODS, OwnRetrievalUncertainty, register_method

    shared = Retrieval(
        scores=np.array([[0.9, 0.5], [0.8, 0.7], [0.6, 0.1]]),
        indices=np.array([[0, 1], [0, 1], [0, 1]]),
        positives=np.array([[True, False], [False, True], [True, False]]),
    )
    own = Retrieval(scores=shared.scores, indices=np.array([[1, 0], [1, 0], [0, 1]]), positives=shared.positives)

    def own_method(retrieval):
        return OwnRetrievalUncertainty(uncertainty=np.array([0.3, 0.1, 0.2]), retrieval=own)

    register_method("OWN-TEST", own_method, description="test")
    try:
        result = evaluate(shared, ["OWN-TEST", "BM"])
    finally:
        METHODS.unregister("OWN-TEST")
    own_correct = np.array([False, True, True])
    assert_close(result.methods["OWN-TEST"].auc_pr, auc_pr(own_correct, [0.3, 0.1, 0.2]))
    assert_close(result.methods["BM"].auc_pr, auc_pr([True, False, True], -shared.scores[:, 0]))
    as_json = result.to_dict()["methods"]
    assert as_json["OWN-TEST"]["correctness_from"] == "own retrieval"
    assert_close(as_json["OWN-TEST"]["own_recall@1"], 2 / 3)
    assert "correctness_from" not in as_json["BM"]
    assert any("OWN-TEST retrieves with its own embeddings" in note for note in result.notes)


def test_method_returning_nan_is_an_error():
    from vpr_uncertainty.methods import METHODS, register_method

    register_method("NAN-TEST", lambda retrieval: np.full(retrieval.n_queries, np.nan), description="test")
    retrieval = Retrieval(scores=np.array([[0.9, 0.5]]), indices=np.array([[0, 1]]), positives=np.eye(1, 2, dtype=bool))
    try:
        with pytest.raises(RuntimeError, match="NaN"):
            evaluate(retrieval, ["NAN-TEST"])
    finally:
        METHODS.unregister("NAN-TEST")
