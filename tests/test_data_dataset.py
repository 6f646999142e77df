"""The Dataset interface: validation, queries without positives, position kinds and placeholder warnings."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty.data import Dataset, PlaceholderPositionsWarning, detect_position_kind, positives_from_lists


def small_dataset(**overrides) -> Dataset:
    fields = {
        "name": "toy",
        "root": Path("/data/toy"),
        "positives": positives_from_lists([[0, 1], [], [2]], n_database=3),
        "database_paths": [Path("/data/toy/database/a.jpg"), Path("/data/toy/database/b.jpg"), Path("/other/c.jpg")],
        "query_paths": [Path(f"/data/toy/queries/{i}.jpg") for i in range(3)],
        "database_positions": np.array([[0.0, 0.0], [5.0, 3.0], [100.0, 40.0]]),
        "query_positions": np.array([[1.0, 1.0], [500.0, 500.0], [99.0, 41.0]]),
        "positive_radius": 25,
    }
    return Dataset(**{**fields, **overrides})


def test_names_sizes_and_queries_without_positives() -> None:
    dataset = small_dataset()
    assert (dataset.n_queries, dataset.n_database) == (3, 3)
    assert dataset.database_names == ["database/a.jpg", "database/b.jpg", "/other/c.jpg"]
    assert dataset.query_names == ["queries/0.jpg", "queries/1.jpg", "queries/2.jpg"]
    assert dataset.queries_without_positives.tolist() == [1]
    assert dataset.queries_without_positives.dtype == np.int64
    assert dataset.n_positives.tolist() == [2, 0, 1]
    assert dataset.position_kind == "metres" and dataset.has_metric_positions and dataset.has_images
    assert dataset.positive_radius == 25.0 and isinstance(dataset.positive_radius, float)
    assert "queries_without_positives=1" in repr(dataset)
    summary = json.loads(json.dumps(dataset.summary()))
    assert summary["n_queries_without_positives"] == 1 and summary["position_kind"] == "metres"


def test_positives_are_normalised_to_sorted_bool_csr() -> None:
    dense = np.array([[0, 1, 1], [0, 0, 0]])
    dataset = small_dataset(
        positives=sparse.coo_array(dense),
        database_paths=None,
        query_paths=None,
        database_positions=None,
        query_positions=None,
    )
    assert isinstance(dataset.positives, sparse.csr_array) and dataset.positives.dtype == bool
    assert dataset.positives.has_sorted_indices
    assert dataset.position_kind is None and not dataset.has_images and dataset.query_names is None


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"query_paths": [Path("q.jpg")]}, "query_paths has 1 entries but positives has 3"),
        ({"database_names": ["a", "b"]}, "database_names has 2 entries"),
        ({"database_positions": np.zeros((3, 3))}, r"database_positions must have shape \(n, 2\)"),
        ({"query_positions": np.zeros((2, 2))}, "query_positions has 2 rows, expected 3"),
        ({"query_positions": np.array([[0.0, 0.0], [np.inf, 0], [1, 1]])}, "finite; row 1"),
        ({"position_kind": "miles"}, "position_kind must be one of"),
    ],
)
def test_inconsistent_fields_are_rejected(overrides, message) -> None:
    with pytest.raises(ValueError, match=message):
        small_dataset(**overrides)


def test_detect_position_kind_on_synthetic_layouts() -> None:
    frames = np.arange(100.0)
    assert detect_position_kind(np.column_stack([frames, frames])) == "frames"  # Patch-NetVLAD Nordland
    assert detect_position_kind(np.column_stack([frames, np.zeros(100)])) == "frames"
    assert detect_position_kind(np.column_stack([np.zeros(100), frames * 25 / 10.5])) == "placeholder"
    assert detect_position_kind(np.column_stack([np.zeros(5), [0, 100, 300, 400, 500]])) == "placeholder"
    assert detect_position_kind(np.array([[0.0, 0.0], [1.0, 0.0]])) == "metres"  # too few to tell
    rng = np.random.default_rng(0)
    assert detect_position_kind(rng.uniform(0, 1000, size=(50, 2))) == "metres"
    assert detect_position_kind(None, None) is None
    # Judged together: queries alone on a line, database elsewhere, is still a 2-D layout.
    assert detect_position_kind(np.column_stack([frames, frames]), np.array([[3.0, 7.0]])) == "metres"


def test_metric_positions_warn_for_placeholders_and_not_for_metres() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        database, queries = small_dataset().metric_positions(purpose="SUE")
    assert database.shape == (3, 2) and queries.shape == (3, 2)
    frames = np.column_stack([np.arange(3.0), np.arange(3.0)])
    dataset = small_dataset(database_positions=frames, query_positions=frames, positive_radius=10)
    assert dataset.position_kind == "frames" and not dataset.has_metric_positions
    with pytest.warns(PlaceholderPositionsWarning, match="'toy' has frames positions, not metres: SUE"):
        dataset.metric_positions(purpose="SUE")
    explicit = small_dataset(database_positions=frames, query_positions=frames, position_kind="metres")
    assert explicit.has_metric_positions  # the caller's word wins over detection


def test_retrieval_fields_build_a_retrieval() -> None:
    from vpr_uncertainty.retrieval import Retrieval

    dataset = small_dataset()
    fields = dataset.retrieval_fields()
    retrieval = Retrieval(scores=np.array([[0.9, 0.5]] * 3), indices=np.array([[0, 1]] * 3), **fields)
    assert retrieval.positives.shape == (3, 3)
    assert list(retrieval.database_names) == dataset.database_names
    assert fields["config"]["dataset"]["name"] == "toy"
    np.testing.assert_array_equal(retrieval.query_positions, dataset.query_positions)
