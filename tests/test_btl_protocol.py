"""BTL evaluation protocols (btl/protocol.py): training and test queries never overlap.

Synthetic data only; benchmarks/btl_protocol.py runs the protocols on the real corridor.
"""

from __future__ import annotations

import numpy as np
import pytest

from vpr_uncertainty.btl.method import (
    PROTOCOLS,
    BTLProtocol,
    btl_protocol,
    database_frame_positives,
    train_for_protocol,
)
from vpr_uncertainty.data import positives_within_frames


@pytest.mark.parametrize("name", PROTOCOLS)
@pytest.mark.parametrize("n_queries", [2, 3, 111])
def test_train_and_test_queries_are_disjoint(name, n_queries):
    protocol = btl_protocol(name, n_queries)
    assert np.intersect1d(protocol.train_queries, protocol.test_queries).size == 0
    covered = np.concatenate([protocol.train_queries, protocol.test_queries])
    assert sorted(covered.tolist()) == list(range(n_queries))  # every query is used, once
    assert protocol.train_queries.dtype == protocol.test_queries.dtype == np.int64


def test_corridor_protocols_as_the_readme_states_them():
    split = btl_protocol("query-split", 111, split_at=56)
    assert split.anchors == "queries"
    assert split.train_queries.tolist() == list(range(56))
    assert split.test_queries.tolist() == list(range(56, 111))
    assert split.description == "trained on queries 0..55 as anchors, tested on queries 56..110"
    database = btl_protocol("database", 111)
    assert database.anchors == "database" and database.train_queries.size == 0
    assert database.test_queries.tolist() == list(range(111))


@pytest.mark.parametrize(
    ("name", "n_queries", "split_at", "message"),
    [
        ("queries", 10, None, "unknown BTL protocol 'queries'; expected one of database, query-split"),
        ("query-split", 10, 10, r"at least one test query: got 10 with 10 queries \(expected 2 <= split_at <= 9\)"),
        ("query-split", 10, 1, "split_at must be an integer >= 2, got 1"),
        ("query-split", 1, None, "n_queries must be an integer >= 2, got 1"),
        ("database", 10, 5, "split_at applies to the 'query-split' protocol only"),
    ],
)
def test_bad_protocol_arguments(name, n_queries, split_at, message):
    with pytest.raises(ValueError, match=message):
        btl_protocol(name, n_queries, split_at=split_at)


def test_database_frame_positives_match_the_frame_tolerance_ground_truth():
    positives = database_frame_positives(7, 2)
    frames = np.arange(7)
    np.testing.assert_array_equal(positives.toarray(), np.abs(frames[:, None] - frames[None, :]) <= 2)


def _sequence(n: int, dim: int = 16, seed: int = 0) -> np.ndarray:
    """Descriptors of a traversal: a smooth random walk, so that neighbouring frames look alike."""
    steps = np.random.default_rng(seed).normal(size=(n, dim)).astype(np.float32)
    return np.cumsum(steps, axis=0) + 5.0 * np.eye(1, dim, dtype=np.float32)


QUICK = {"embedding_dim": 8, "hidden_dim": 4, "epochs": 2, "n_negatives": 3, "progress": False}


@pytest.mark.parametrize("name", PROTOCOLS)
def test_training_never_reads_a_test_query(name):
    pytest.importorskip("torch")
    database = _sequence(40)
    queries = database + np.random.default_rng(1).normal(scale=0.1, size=database.shape).astype(np.float32)
    positives = positives_within_frames(np.arange(40), np.arange(40), tolerance=2)
    protocol = btl_protocol(name, 40, split_at=20 if name == "query-split" else None)
    poisoned = queries.copy()
    poisoned[protocol.test_queries] = np.nan  # training fails on NaN descriptors: it must not see these rows
    head, history = train_for_protocol(protocol, poisoned, database, positives, seed=0, **QUICK)
    expected = 20 if name == "query-split" else 40
    assert history.n_train_anchors + history.n_val_anchors == expected
    assert head.input_dim == 16


def test_a_protocol_that_trains_on_its_test_queries_is_refused():
    pytest.importorskip("torch")
    leaky = BTLProtocol("query-split", "queries", np.arange(5), np.arange(4, 10), "overlapping")
    database = _sequence(10)
    positives = positives_within_frames(np.arange(10), np.arange(10), tolerance=1)
    with pytest.raises(ValueError, match="trains on 1 of its test queries \\(first: 4\\)"):
        train_for_protocol(leaky, database, database, positives, **QUICK)
