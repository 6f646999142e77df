"""The retrieval file round trip (vpr_uncertainty.retrieval.result) and the Retrieval checks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from test_data_attach import toy_problem
from vpr_uncertainty.data.dataset import attach_ground_truth
from vpr_uncertainty.retrieval import Retrieval, load_retrieval, retrieve, save_retrieval

pytest.importorskip("faiss")


def test_retrieval_file_round_trip(tmp_path):
    database, queries, database_positions, query_positions = toy_problem(1)
    names = np.array([f"db/{i:04d}.jpg" for i in range(len(database))])
    result = attach_ground_truth(
        retrieve(database, queries, top_k=12),
        database_positions=database_positions,
        query_positions=query_positions,
        database_names=names,
        query_names=[f"q/{i}.jpg" for i in range(len(queries))],
    )
    path = save_retrieval(result, tmp_path / "sub" / "retrieval.npz")
    loaded = load_retrieval(path)
    for name in ("scores", "indices", "distances", "database_positions", "query_positions"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(result, name))  # written and read back
    np.testing.assert_array_equal(loaded.database_names, names)
    assert loaded.query_names[3] == "q/3.jpg"
    assert (loaded.positives != result.positives).nnz == 0 and loaded.positives.shape == (40, 200)
    assert loaded.config == result.config
    with np.load(path, allow_pickle=False) as archive:  # no pickles anywhere
        assert int(archive["format_version"]) == 1


def test_retrieval_file_round_trip_with_missing_candidates(tmp_path):
    database = np.eye(3, dtype=np.float32)
    result = retrieve(database, database, top_k=5)
    loaded = load_retrieval(save_retrieval(result, tmp_path / "r.npz"))
    assert (loaded.indices[:, 3:] == -1).all() and np.isneginf(loaded.scores[:, 3:]).all()
    assert np.isposinf(loaded.distances[:, 3:]).all()


def test_retrieval_checks_database_sizes():
    with pytest.raises(ValueError, match="database sizes disagree"):
        Retrieval(
            scores=np.zeros((1, 1)),
            indices=np.zeros((1, 1), dtype=np.int64),
            positives=sparse.csr_array(np.ones((1, 3), bool)),
            database_positions=np.zeros((4, 2)),
        )
    with pytest.raises(ValueError, match="database_positions covers only 2"):
        Retrieval(scores=np.zeros((1, 1)), indices=np.array([[5]]), database_positions=np.zeros((2, 2)))


def test_a_retrieval_has_a_short_repr():
    retrieval = Retrieval(np.zeros((1000, 50)), np.tile(np.arange(50), (1000, 1)), positives=[[0]] * 1000)
    text = repr(retrieval)
    assert text == ("Retrieval(n_queries=1000, k=50, n_database=50, scores=float64, fields=['positives'], config=[])")
