"""``Retrieval(positives=...)`` accepts lists of positive indices, boolean masks and sparse matrices
(vpr_uncertainty.retrieval.result), and rejects anything else with one short message."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty import Retrieval, evaluate, positives_from_lists

SCORES = np.array([[0.9, 0.5, 0.4], [0.8, 0.7, 0.6], [0.95, 0.3, 0.2]])
INDICES = np.array([[3, 0, 1], [1, 2, 0], [2, 0, 1]])
LISTS = [[3], [0, 2], [2]]
MASK = np.array([[0, 0, 0, 1], [1, 0, 1, 0], [0, 0, 1, 0]], dtype=bool)


def _retrieval(positives, **fields) -> Retrieval:
    return Retrieval(scores=SCORES, indices=INDICES, positives=positives, **fields)


@pytest.mark.parametrize(
    "positives",
    [
        LISTS,
        tuple(tuple(row) for row in LISTS),
        [np.array(row) for row in LISTS],
        MASK,
        MASK.astype(np.uint8),
        MASK.tolist(),
        sparse.csr_matrix(MASK),
        sparse.coo_array(MASK.astype(float)),
    ],
    ids=["lists", "tuples", "arrays", "mask", "0/1 mask", "list mask", "csr_matrix", "coo float 0/1"],
)
def test_every_form_gives_the_same_sparse_ground_truth(positives):
    retrieval = _retrieval(positives)
    assert isinstance(retrieval.positives, sparse.csr_array) and retrieval.positives.dtype == bool
    assert retrieval.positives.toarray().tolist() == MASK.tolist()


def test_a_list_of_lists_is_accepted_and_evaluated():
    """Regression: a list of lists failed in scipy with 'inhomogeneous shape' and the whole ground truth."""
    retrieval = _retrieval(LISTS)
    assert retrieval.n_database == 4
    assert evaluate(retrieval, ["SU", "BM"], k=3).n_answerable == 3


def test_database_size_from_lists_covers_the_retrieved_indices_or_the_names():
    retrieval = Retrieval(scores=SCORES, indices=INDICES, positives=[[0], [1], []])  # index 3 retrieved
    assert retrieval.positives.shape == (3, 4)
    named = _retrieval([[0], [1], []], database_names=np.array([f"db{i}.jpg" for i in range(6)]))
    assert named.positives.shape == (3, 6)


@pytest.mark.parametrize(
    ("positives", "message"),
    [
        ([[3], [0.5], [2]], r"positives of query 1: 0\.5 is not a database index"),
        ([[3], [True], [2]], r"positives of query 1: True is not a database index"),
        ([[3], [-1], [2]], r"positives of query 1 must be database indices"),
        ([[3], [0]], r"positives has 2 rows but there are 3 queries"),
        ("abc", r"positives must be a list of positive database indices per query .*got str"),
        (np.array([1, 0, 1]), r"positives must be .*got an array of shape \(3,\)"),
        (np.full((3, 4), 0.5), r"a ground-truth mask must be boolean \(or 0/1\).*0\.5 at query 0"),
        (sparse.csr_array(np.full((3, 4), 2.0)), r"expected booleans \(or 0/1\), got values \[2\.0\]"),
        ([[True, False, False, True], [True], [False] * 4], r"rows of one length, got lengths \[1, 4\]"),
    ],
    ids=["float", "bool in lists", "negative", "rows", "string", "1-D", "0.5 mask", "sparse 2", "ragged mask"],
)
def test_bad_ground_truth_is_one_short_message(positives, message):
    with pytest.raises(ValueError, match=message) as error:
        _retrieval(positives)
    assert len(str(error.value)) < 300  # never the whole ground truth


def test_an_index_beyond_the_known_database_is_named():
    with pytest.raises(ValueError, match=r"positives of query 0 must be database indices \(an integer in \[0, 4\)\)"):
        _retrieval([[9], [], []], database_names=np.array(["a", "b", "c", "d"]))


def test_positives_from_lists_is_public_and_sizes_by_default():
    assert positives_from_lists([[1], [0, 1]]).shape == (2, 2)
    assert positives_from_lists([[1], []], n_database=5).shape == (2, 5)
    with pytest.raises(ValueError, match="n_database must be a non-negative integer"):
        positives_from_lists([[1]], n_database=-1)
