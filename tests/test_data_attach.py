"""Ground truth, names and positions attached to a search result (vpr_uncertainty.data.dataset)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty.data.dataset import attach_ground_truth, ground_truth_fields
from vpr_uncertainty.retrieval import retrieve

pytest.importorskip("faiss")


def toy_problem(seed: int = 0, n_database: int = 200, n_queries: int = 40, dim: int = 16):
    """Descriptors that follow positions on a line, so that most top-1 answers are right."""
    rng = np.random.default_rng(seed)
    database_positions = np.column_stack([np.arange(n_database) * 10.0, np.zeros(n_database)])
    database_positions += rng.normal(scale=1.0, size=database_positions.shape)
    source = rng.integers(0, n_database, size=n_queries)
    query_positions = database_positions[source] + rng.normal(scale=3.0, size=(n_queries, 2))
    database = rng.standard_normal((n_database, dim)).astype(np.float32)
    noise = rng.uniform(0.2, 3.0, size=(n_queries, 1))
    queries = (database[source] + noise * rng.standard_normal((n_queries, dim))).astype(np.float32)
    return database, queries, database_positions, query_positions


def test_attach_builds_positives_from_positions_and_a_config():
    database, queries, database_positions, query_positions = toy_problem()
    result = attach_ground_truth(
        retrieve(database, queries, top_k=5, config={"dataset": "toy"}),
        database_positions=database_positions,
        query_positions=query_positions,
        radius=25,
    )
    distance = np.linalg.norm(query_positions[:, None] - database_positions[None], axis=2)
    np.testing.assert_array_equal(result.positives.toarray(), distance <= 25)
    assert result.config["radius"] == 25.0 and result.config["position_kind"] == "metres"
    assert result.config["k"] == 5 and result.config["index"] == "Flat" and result.config["dataset"] == "toy"
    assert result.config["n_database"] == 200 and result.config["dimension"] == 16
    assert result.n_database == 200
    json.dumps(result.config)


def test_attach_detects_frame_positions():
    database = np.eye(30, dtype=np.float32)
    frames = np.repeat(np.arange(30.0)[:, None], 2, axis=1)
    result = attach_ground_truth(
        retrieve(database, database, top_k=3), database_positions=frames, query_positions=frames, radius=2
    )
    assert result.config["position_kind"] == "frames"


def test_attach_accepts_one_dimensional_positions():
    database = np.eye(10, dtype=np.float32)
    frames = np.arange(10.0)
    result = attach_ground_truth(
        retrieve(database, database[:4], top_k=3), database_positions=frames, query_positions=frames[:4], radius=1
    )
    assert result.database_positions.shape == (10, 1)
    assert result.positives[[0], :].toarray().ravel().nonzero()[0].tolist() == [0, 1]


def test_attach_takes_explicit_positives_and_checks_lengths():
    database = np.eye(4, dtype=np.float32)
    result = attach_ground_truth(retrieve(database, database[:2], top_k=2), positives=np.eye(2, 4, dtype=bool))
    assert result.positives.shape == (2, 4) and "radius" not in result.config
    with pytest.raises(ValueError, match="positives must have shape"):
        attach_ground_truth(retrieve(database, database[:2], top_k=2), positives=np.eye(3, 4, dtype=bool))
    with pytest.raises(ValueError, match="database_positions has 3 entries"):
        attach_ground_truth(retrieve(database, database, top_k=2), database_positions=np.zeros((3, 2)))
    with pytest.raises(ValueError, match="position_kind"):
        attach_ground_truth(retrieve(database, database, top_k=2), position_kind="miles")


def test_fields_checked_before_the_search_have_the_form_of_a_datasets():
    frames = np.arange(6.0)
    fields = ground_truth_fields(2, 6, database_positions=frames, query_positions=frames[:2], radius=1)
    assert set(fields) == {"positives", "query_names", "database_names", "query_positions", "database_positions"} | {
        "config"
    }
    assert fields["positives"].toarray().nonzero()[1].tolist() == [0, 1, 0, 1, 2]
    assert fields["config"] == {"radius": 1.0}  # 1-D positions: the kind is not guessed
    with pytest.raises(ValueError, match="query_names has 3 entries, expected 2"):
        ground_truth_fields(2, 6, query_names=["a", "b", "c"])
    result = attach_ground_truth(
        retrieve(np.eye(6, dtype=np.float32), np.eye(6, dtype=np.float32)[:2], top_k=2), fields
    )
    assert result.query_positions.shape == (2, 1) and result.config["radius"] == 1.0


def test_attaching_keeps_what_is_not_given_and_drops_stale_ground_truth_settings():
    database = np.eye(4, dtype=np.float32)
    frames = np.repeat(np.arange(4.0)[:, None], 2, axis=1)
    first = attach_ground_truth(
        retrieve(database, database[:2], top_k=2),
        database_positions=frames,
        query_positions=frames[:2],
        radius=1.5,  # frames (i, i) are sqrt(2) apart
        database_names=[f"db/{i}" for i in range(4)],
    )
    assert first.config["radius"] == 1.5 and first.config["position_kind"] == "frames"
    second = attach_ground_truth(first, positives=np.eye(2, 4, dtype=bool))
    assert "radius" not in second.config and second.config["position_kind"] == "frames"  # positions kept
    assert second.database_names.tolist() == ["db/0", "db/1", "db/2", "db/3"]
    assert (second.positives != sparse.csr_array(np.eye(2, 4, dtype=bool))).nnz == 0
    assert first.positives.sum() == 5  # the first retrieval is not changed
    with pytest.raises(TypeError, match="not both"):
        attach_ground_truth(first, {"positives": None}, radius=3)
    with pytest.raises(ValueError, match="unknown ground-truth fields"):
        attach_ground_truth(first, {"positive": np.eye(2, 4, dtype=bool)})
