"""``retrieve(database, queries, database_positions=, query_positions=, radius=)``: the search and its ground truth in
one call, the same file as the ``retrieve`` command with --database-positions/--query-positions/--radius."""

from __future__ import annotations

import numpy as np
import pytest

from vpr_uncertainty import cli, evaluate
from vpr_uncertainty.retrieval import load_retrieval, retrieve

pytest.importorskip("faiss")


def _problem(seed: int = 0):
    rng = np.random.default_rng(seed)
    n_database, n_queries, dim = 120, 30, 16
    database_positions = np.column_stack([np.arange(n_database) * 8.0, rng.normal(scale=2, size=n_database)])
    source = rng.integers(0, n_database, size=n_queries)
    query_positions = database_positions[source] + rng.normal(scale=6.0, size=(n_queries, 2))
    database = rng.standard_normal((n_database, dim)).astype(np.float32)
    queries = (database[source] + rng.uniform(0.3, 3, (n_queries, 1)) * rng.standard_normal((n_queries, dim))).astype(
        np.float32
    )
    return database, queries, database_positions, query_positions


def _reference_positives(query_positions, database_positions, radius):
    """Slow and obvious: every pair's Euclidean distance."""
    return np.array([[np.hypot(*(q - d)) <= radius for d in database_positions] for q in query_positions], dtype=bool)


@pytest.mark.parametrize("radius", [0.0, 10.0, 25.0])
def test_positions_give_the_positives_within_the_radius(radius):
    database, queries, database_positions, query_positions = _problem()
    result = retrieve(
        database, queries, 5, database_positions=database_positions, query_positions=query_positions, radius=radius
    )
    np.testing.assert_array_equal(
        result.positives.toarray(), _reference_positives(query_positions, database_positions, radius)
    )
    np.testing.assert_array_equal(result.database_positions, database_positions)
    np.testing.assert_array_equal(result.query_positions, query_positions)
    assert result.config["radius"] == radius and result.config["position_kind"] == "metres"
    plain = retrieve(database, queries, 5)
    np.testing.assert_array_equal(result.indices, plain.indices)  # the search is the same
    assert plain.positives is None and plain.database_positions is None


def test_one_call_equals_the_command(tmp_path):
    database, queries, database_positions, query_positions = _problem(1)
    paths = {}
    for name, array in {"db": database, "q": queries, "dbp": database_positions, "qp": query_positions}.items():
        paths[name] = tmp_path / f"{name}.npy"
        np.save(paths[name], array)
    out = tmp_path / "r.npz"
    argv = ["retrieve", "--database", str(paths["db"]), "--queries", str(paths["q"]), "--out", str(out)]
    argv += ["--database-positions", str(paths["dbp"]), "--query-positions", str(paths["qp"]), "--radius", "20"]
    assert cli.main([*argv, "--top-k", "7"]) == 0
    from_file = load_retrieval(out)
    in_memory = retrieve(
        database, queries, 7, database_positions=database_positions, query_positions=query_positions, radius=20
    )
    np.testing.assert_array_equal(in_memory.indices, from_file.indices)
    assert (in_memory.positives != from_file.positives).nnz == 0
    np.testing.assert_array_equal(in_memory.database_positions, from_file.database_positions)
    assert in_memory.config["radius"] == from_file.config["radius"] == 20.0
    evaluation = evaluate(in_memory, ["SU", "SUE"], k=5, timing_repeats=1)  # SUE reads the positions
    assert set(evaluation.methods) == {"SU", "SUE"}


def test_explicit_positives_and_bad_positions():
    database, queries, database_positions, query_positions = _problem()
    mask = np.zeros((len(queries), len(database)), dtype=bool)
    mask[:, 0] = True
    result = retrieve(database, queries, 3, positives=mask)
    assert result.positives[:, [0]].sum() == len(queries) and "radius" not in result.config
    with pytest.raises(ValueError, match="query_positions has 29 entries, expected 30"):
        retrieve(database, queries, 3, database_positions=database_positions, query_positions=query_positions[1:])
    located = {"database_positions": database_positions, "query_positions": query_positions}
    with pytest.raises(ValueError, match="radius"):
        retrieve(database, queries, 3, radius=-1.0, **located)
