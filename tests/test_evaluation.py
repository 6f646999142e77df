"""evaluate(): every method run on a retrieval and measured; its notes, errors and own-retrieval methods."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from conftest import assert_close
from vpr_uncertainty import Retrieval, evaluate
from vpr_uncertainty.evaluation import auc_pr, time_per_query


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


def test_a_score_entry_binds_its_scores_function_directly_with_its_own_options():
    from vpr_uncertainty import scores as score_functions
    from vpr_uncertainty.methods import get_method

    retrieval = Retrieval(scores=np.array([[0.9, 0.5, 0.4]]), indices=np.array([[0, 1, 2]]))
    call = get_method("SU").bind(retrieval, {"k": 3, "alpha": 0.2, "sort": True, "device": "cpu"})
    assert call.func is score_functions.statistical_uncertainty  # the timed call is the formula, no wrapper
    assert call.keywords == {"k": 3, "alpha": 0.2}
    assert np.shares_memory(call.args[0], retrieval.scores) and not call.args[0].flags.writeable  # read-only view
    call = get_method("L2").bind(retrieval, {"k": 3, "alpha": 0.2})
    assert call.func is score_functions.l2_distance and call.keywords == {"k": 3, "distances": None}


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


def test_evaluate_sorts_each_method_once_and_tables_count_no_ties_again(monkeypatch):
    """One argsort per method serves AUC-PR, AP, the rejection curve and AURC; format_table reads stored counts."""
    from vpr_uncertainty.reports.tables import format_table

    rng = np.random.default_rng(6)
    scores = -np.sort(-rng.uniform(0.2, 0.9, size=(200, 10)), axis=1)
    indices = np.tile(np.arange(10), (200, 1))
    mask = np.zeros((200, 30), bool)
    mask[np.arange(200), rng.integers(0, 3, size=200)] = True
    retrieval = Retrieval(scores=scores, indices=indices, positives=sparse.csr_array(mask))
    calls = {"argsort": 0, "unique": 0}
    for name in calls:
        original = getattr(np, name)

        def counting(*args, _original=original, _name=name, **kwargs):
            calls[_name] += 1
            return _original(*args, **kwargs)

        monkeypatch.setattr(np, name, counting)
    evaluation = evaluate(retrieval, ["SU", "BM", "RS"], timing_repeats=1)
    assert calls["argsort"] == 3
    calls.update(argsort=0, unique=0)
    text = format_table(evaluation)
    assert calls == {"argsort": 0, "unique": 0}
    monkeypatch.undo()
    for method in evaluation.methods.values():
        _, counts = np.unique(method.uncertainty, return_counts=True)
        assert method.n_distinct == counts.size
        assert method.tied_share == counts[counts > 1].sum() / counts.sum()
    assert "SU" in text
