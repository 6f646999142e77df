"""Evaluation and MethodEvaluation: from_dict is the inverse of to_dict, given the arrays it leaves out."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty import Retrieval, evaluate
from vpr_uncertainty.evaluation import Evaluation


@pytest.fixture
def evaluation() -> Evaluation:
    rng = np.random.default_rng(3)
    scores = -np.sort(-rng.uniform(0.2, 0.9, size=(60, 5)), axis=1)
    indices = np.tile(np.arange(5), (60, 1))
    positives = np.zeros((60, 20), bool)
    positives[np.arange(60), rng.integers(0, 3, size=60)] = True
    positives[7] = False  # a query without positives
    retrieval = Retrieval(scores=scores, indices=indices, positives=sparse.csr_array(positives))
    with pytest.warns(UserWarning):
        return evaluate(retrieval, ["RS", "SU", "BM", "PA"], k=10, timing_repeats=1)  # k > 5: a note


def test_from_dict_inverts_to_dict(evaluation):
    data = json.loads(json.dumps(evaluation.to_dict()))
    uncertainties = {name: method.uncertainty for name, method in evaluation.methods.items()}
    again = Evaluation.from_dict(data, correct=evaluation.correct, uncertainties=uncertainties)
    assert again.to_dict() == evaluation.to_dict()
    assert (again.n_queries, again.n_answerable, again.k, again.k_requested) == (60, 59, 5, 10)
    assert again.recall_at_n == evaluation.recall_at_n and again.notes == evaluation.notes
    for name, method in evaluation.methods.items():
        other = again.methods[name]
        np.testing.assert_array_equal(other.curve.thresholds, method.curve.thresholds)
        np.testing.assert_array_equal(other.curve.precision, method.curve.precision)
        np.testing.assert_array_equal(other.curve.coverage, method.curve.coverage)
        assert other.precision_at_recall == method.precision_at_recall


def test_from_dict_checks_the_arrays(evaluation):
    data = evaluation.to_dict()
    uncertainties = {name: method.uncertainty for name, method in evaluation.methods.items()}
    with pytest.raises(ValueError, match=r"correct must have shape \(60,\)"):
        Evaluation.from_dict(data, correct=evaluation.correct[:10], uncertainties=uncertainties)
    del uncertainties["PA"]
    with pytest.raises(ValueError, match="uncertainties of PA are missing"):
        Evaluation.from_dict(data, correct=evaluation.correct, uncertainties=uncertainties)
