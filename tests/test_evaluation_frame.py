"""``Evaluation.to_frame()`` (pandas, the ``pandas`` extra) and the compact ``repr`` of Evaluation and
MethodEvaluation (vpr_uncertainty.evaluation.results)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from vpr_uncertainty import Retrieval, evaluate

pandas = pytest.importorskip("pandas")


@pytest.fixture(scope="module")
def retrieval() -> Retrieval:
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((300, 10)), axis=1)
    return Retrieval(scores=scores, indices=np.tile(np.arange(10), (300, 1)), positives=rng.random((300, 10)) < 0.3)


def test_one_row_per_method_with_the_numbers_of_to_dict(retrieval):
    evaluation = evaluate(retrieval, ["SU", "BM", "RS"], k=10)
    frame = evaluation.to_frame()
    assert list(frame.index) == ["SU", "BM", "RS"] and frame.index.name == "method"
    document = evaluation.to_dict()["methods"]
    for name in frame.index:
        for column in ("auc_pr", "average_precision", "aurc", "recall_at_100_precision", "time_per_query_ms"):
            assert frame.loc[name, column] == document[name][column]  # the same floats, not recomputed
        assert frame.loc[name, "precision_at_recall_0.25"] == document[name]["precision_at_recall"]["0.25"]
    assert frame["auc_pr"].dtype == np.float64 and frame["informative"].dtype == bool
    assert not any(column.endswith("_ci_low") for column in frame.columns)  # no bootstrap, no intervals
    assert frame.attrs["n_queries"] == 300 and frame.attrs["recall@1"] == evaluation.recall_at_n[1]


def test_bootstrap_intervals_and_paired_tests_become_columns(retrieval):
    evaluation = evaluate(retrieval, ["SU", "BM"], k=10, bootstrap=50, seed=0)
    frame = evaluation.to_frame()
    for metric in ("auc_pr", "average_precision", "aurc"):
        low, high = evaluation.methods["BM"].__getattribute__(f"{metric}_ci")
        assert (frame.loc["BM", f"{metric}_ci_low"], frame.loc["BM", f"{metric}_ci_high"]) == (low, high)
    assert frame.loc["BM", "delta_auc_pr"] == evaluation.methods["BM"].vs_reference["delta_auc_pr"]
    assert "p_value_holm" in frame.columns and "significant" in frame.columns


def test_an_undefined_auc_pr_is_nan_not_an_object_column():
    retrieval = Retrieval(
        scores=np.array([[0.9, 0.1], [0.8, 0.2]]), indices=np.array([[0, 1], [1, 0]]), positives=[[0], [1]]
    )  # every answer correct: AUC-PR undefined
    with pytest.warns(RuntimeWarning, match="undefined"):
        frame = evaluate(retrieval, ["SU"], k=2).to_frame()
    assert frame["auc_pr"].dtype == np.float64 and np.isnan(frame.loc["SU", "auc_pr"])


def test_without_pandas_the_error_names_the_extra(retrieval, monkeypatch):
    evaluation = evaluate(retrieval, ["SU"], k=10)
    monkeypatch.setitem(sys.modules, "pandas", None)
    with pytest.raises(ImportError, match=r"pip install 'vpr-uncertainty\[pandas\]'"):
        evaluation.to_frame()


def test_repr_is_a_compact_summary_not_the_arrays(retrieval):
    """Regression: repr(evaluation) printed every array (correctness, uncertainties, curves) of every method."""
    evaluation = evaluate(retrieval, ["SU", "BM"], k=10, bootstrap=40)
    text = repr(evaluation)
    assert len(text.splitlines()) == 4 and len(text) < 600, text
    assert text.startswith("Evaluation(n_queries=300, n_answerable=")
    assert f"SU  AUC-PR {evaluation.methods['SU'].auc_pr:.4f} [" in text
    assert "array(" not in text
    method = repr(evaluation.methods["SU"])
    assert method.startswith("MethodEvaluation('SU', auc_pr=") and "n_queries=300" in method
    assert "array(" not in method and len(method) < 300
