"""Faiss descriptor search against a numpy reference (vpr_uncertainty.retrieval.search)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty.retrieval import search_descriptors, top_k_from_similarity

faiss = pytest.importorskip("faiss")


def unit(rows: np.ndarray) -> np.ndarray:
    rows = np.asarray(rows, dtype=np.float64)
    return (rows / np.linalg.norm(rows, axis=1, keepdims=True)).astype(np.float32)


def reference(database: np.ndarray, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Matmul of the normalised descriptors, then a stable sort (ties by lower index), padded to k columns."""
    similarity = unit(queries) @ unit(database).T
    scores, indices = top_k_from_similarity(similarity, k)
    pad = k - scores.shape[1]
    if pad:
        scores = np.pad(scores, ((0, 0), (0, pad)), constant_values=-np.inf)
        indices = np.pad(indices, ((0, 0), (0, pad)), constant_values=-1)
    return scores, indices


def tie_descriptors(rng: np.random.Generator, n: int, dim: int = 16) -> np.ndarray:
    """Entries ±1/4 with dim = 16: unit norm and inner products multiples of 1/8, all exact in float32."""
    return (rng.choice([-0.25, 0.25], size=(n, dim))).astype(np.float32)


@pytest.mark.parametrize("n_queries", [7, 60])  # Faiss's direct loop below 20 queries, BLAS above
def test_random_descriptors_match_numpy_reference(n_queries):
    rng = np.random.default_rng(0)
    database = rng.standard_normal((500, 32)).astype(np.float32)
    queries = rng.standard_normal((n_queries, 32)).astype(np.float32)
    scores, indices, distances = search_descriptors(database, queries, top_k=10)
    expected_scores, expected_indices = reference(database, queries, 10)
    np.testing.assert_array_equal(indices, expected_indices)
    assert_close(scores, expected_scores, atol=1e-6)
    assert_close(distances, np.maximum(2 - 2 * scores, 0), atol=1e-6)
    assert scores.dtype == distances.dtype == np.float32 and indices.dtype == np.int64
    assert (np.diff(scores, axis=1) <= 0).all() and (np.diff(distances, axis=1) >= 0).all()


@pytest.mark.parametrize("n_queries", [5, 64])
@pytest.mark.parametrize("k", [1, 3, 10, 40])
def test_ties_are_ordered_and_cut_by_lower_database_index(n_queries, k):
    rng = np.random.default_rng(k)
    base = tie_descriptors(rng, 120)
    database = np.concatenate([base, base[:30], base[:5]])  # exact duplicates, later indices
    rng.shuffle(database)
    queries = np.concatenate([tie_descriptors(rng, n_queries - 2), database[[3, 40]]])
    scores, indices, _ = search_descriptors(database, queries, top_k=k)
    expected_scores, expected_indices = reference(database, queries, k)
    np.testing.assert_array_equal(indices, expected_indices)
    np.testing.assert_array_equal(scores, expected_scores)  # exact by construction (multiples of 1/8)
    # Sanity: the data really has ties across the k-th place.
    similarity = unit(queries) @ unit(database).T
    kth = np.sort(similarity, axis=1)[:, ::-1][:, k - 1 : k]
    assert ((similarity == kth).sum(axis=1) > 1).any()


def test_ties_with_small_batches_and_scaled_duplicates():
    rng = np.random.default_rng(3)
    base = tie_descriptors(rng, 40)
    scale = 2.0 ** rng.integers(-3, 4, size=(80, 1))  # powers of two: normalisation stays exact
    database = (np.concatenate([base, base]) * scale).astype(np.float32)
    queries = tie_descriptors(rng, 25) * 4
    scores, indices, _ = search_descriptors(database, queries, top_k=6, batch_size=4)
    expected_scores, expected_indices = reference(database, queries, 6)
    np.testing.assert_array_equal(indices, expected_indices)
    np.testing.assert_array_equal(scores, expected_scores)  # exact by construction (multiples of 1/8)


def test_all_database_descriptors_identical():
    database = np.ones((50, 8), dtype=np.float32)
    scores, indices, _ = search_descriptors(database, np.ones((3, 8), np.float32), top_k=5)
    np.testing.assert_array_equal(indices, np.tile(np.arange(5), (3, 1)))
    assert_close(scores, 1.0)


@pytest.mark.parametrize("n_queries", [3, 30])
def test_k_larger_than_database_pads_with_missing_candidates(n_queries):
    rng = np.random.default_rng(1)
    database = rng.standard_normal((4, 6)).astype(np.float32)
    queries = rng.standard_normal((n_queries, 6)).astype(np.float32)
    scores, indices, distances = search_descriptors(database, queries, top_k=7)
    expected_scores, expected_indices = reference(database, queries, 7)
    assert scores.shape == indices.shape == distances.shape == (n_queries, 7)
    np.testing.assert_array_equal(indices, expected_indices)
    assert_close(scores[:, :4], expected_scores[:, :4], atol=1e-6)
    assert (indices[:, 4:] == -1).all()
    assert np.isneginf(scores[:, 4:]).all() and np.isposinf(distances[:, 4:]).all()
    assert np.isfinite(distances[:, :4]).all()


def test_missing_candidates_are_scored_on_what_is_there():
    from vpr_uncertainty import statistical_uncertainty

    rng = np.random.default_rng(2)
    database = rng.standard_normal((4, 6)).astype(np.float32)
    scores, _, _ = search_descriptors(database, rng.standard_normal((5, 6)).astype(np.float32), top_k=10)
    # Two code paths (padded columns skipped vs. absent): float32, so rtol 1e-5, not the default 1e-7.
    assert_close(statistical_uncertainty(scores, k=10), statistical_uncertainty(scores[:, :4], k=4))


def test_batches_and_unnormalised_input_give_the_same_result():
    rng = np.random.default_rng(4)
    database = rng.standard_normal((300, 24)).astype(np.float32) * 7
    queries = rng.standard_normal((45, 24)).astype(np.float64) * 0.1
    whole = search_descriptors(database, queries, top_k=8)
    batched = search_descriptors(database, queries, top_k=8, batch_size=7)
    # 45 queries go through Faiss's BLAS kernel, batches of 7 through its direct loop: another summation order.
    np.testing.assert_array_equal(whole[1], batched[1])
    assert_close(whole[0], batched[0], atol=1e-6)
    assert_close(whole[2], batched[2], atol=1e-6)
    np.testing.assert_array_equal(whole[1], reference(database, queries, 8)[1])


def test_callers_arrays_are_not_modified_unless_copy_is_false():
    rng = np.random.default_rng(5)
    database = rng.standard_normal((50, 8)).astype(np.float32)
    queries = rng.standard_normal((5, 8)).astype(np.float32)
    saved = database.copy(), queries.copy()
    first = search_descriptors(database, queries, top_k=3)
    np.testing.assert_array_equal(database, saved[0])
    np.testing.assert_array_equal(queries, saved[1])
    second = search_descriptors(database, queries, top_k=3, copy=False)
    assert_close(np.linalg.norm(database, axis=1), 1.0)  # normalised in place
    np.testing.assert_array_equal(first[1], second[1])


def test_unit_norm_input_is_used_without_a_copy(monkeypatch):
    rng = np.random.default_rng(6)
    database = unit(rng.standard_normal((40, 8)))
    calls = []
    monkeypatch.setattr(faiss, "normalize_L2", lambda x: calls.append(x.shape))
    search_descriptors(database, database[:3], top_k=2)
    assert calls == []


@pytest.mark.parametrize(
    ("index", "params"), [("IVF4,Flat", "nprobe=4"), ("HNSW16", "efSearch=256"), ("IVF1,Flat", None)]
)
def test_index_factory_matches_exact_search_when_it_visits_everything(index, params):
    rng = np.random.default_rng(7)
    database = rng.standard_normal((400, 16)).astype(np.float32)
    queries = rng.standard_normal((30, 16)).astype(np.float32)
    scores, indices, _ = search_descriptors(database, queries, top_k=5, index=index, search_params=params)
    expected_scores, expected_indices = reference(database, queries, 5)
    np.testing.assert_array_equal(indices, expected_indices)
    assert_close(scores, expected_scores, atol=1e-6)


def test_product_quantisation_is_approximate_but_well_formed():
    rng = np.random.default_rng(8)
    database = rng.standard_normal((600, 16)).astype(np.float32)
    scores, indices, distances = search_descriptors(database, database[:20], top_k=5, index="PQ4x4")
    assert indices.shape == (20, 5) and (indices >= 0).all()
    assert (np.diff(scores, axis=1) <= 0).all() and (distances >= 0).all()


def test_approximate_index_missing_candidates_follow_the_convention():
    rng = np.random.default_rng(9)
    database = rng.standard_normal((200, 8)).astype(np.float32)
    # One of 50 lists probed: some queries find fewer than k candidates.
    scores, indices, distances = search_descriptors(database, database[:20], top_k=20, index="IVF50,Flat")
    missing = indices == -1
    assert missing.any()
    assert np.isneginf(scores[missing]).all() and np.isposinf(distances[missing]).all()
    assert not np.isneginf(scores[~missing]).any()
    first_missing = np.where(missing.any(axis=1), missing.argmax(axis=1), 20)
    assert all(missing[row, first_missing[row] :].all() for row in range(20))


def test_cuda_without_gpu_faiss_is_a_clear_error():
    if hasattr(faiss, "StandardGpuResources") and faiss.get_num_gpus() > 0:
        pytest.skip("a GPU is available")
    database = np.eye(4, dtype=np.float32)
    with pytest.raises(ValueError, match="GPU Faiss"):
        search_descriptors(database, database, top_k=2, device="cuda")


@pytest.mark.parametrize(
    ("database", "queries", "options", "message"),
    [
        (np.ones((5, 4)), np.ones((2, 3)), {}, "same descriptor dimension"),
        (np.ones(5), np.ones((2, 5)), {}, "2-D"),
        (np.ones((0, 4)), np.ones((2, 4)), {}, "empty"),
        (np.ones((5, 0)), np.ones((2, 0)), {}, "dimension 0"),
        (np.ones((5, 4)), np.ones((2, 4)), {"top_k": 0}, "top_k must be a positive integer"),
        (np.ones((5, 4)), np.ones((2, 4)), {"batch_size": 0}, "batch_size"),
        (np.ones((5, 4)), np.ones((2, 4)), {"device": "tpu"}, "device"),
        (np.ones((5, 4)), np.ones((2, 4)), {"index": "NotAnIndex"}, "index-factory string"),
        (np.ones((5, 4)), np.ones((2, 4)), {"index": "IDMap,Flat"}, "cannot build the Faiss index"),
        (np.ones((5, 4)), np.ones((2, 4)), {"index": "IVF2,Flat", "search_params": "bogus=1"}, "search_params"),
        (np.ones((5, 4)), np.ones((2, 4)), {"search_params": "nprobe=2"}, "approximate index"),
    ],
)
def test_invalid_input_is_rejected_with_a_clear_message(database, queries, options, message):
    with pytest.raises(ValueError, match=message):
        search_descriptors(database, queries, **options)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (np.nan, "row 3 contains NaN"),
        (np.inf, "row 3 contains an infinite"),
        (0.0, r"has 1 all-zero row\(s\) \(rows 3\)"),
    ],
)
@pytest.mark.parametrize("which", ["database", "queries"])
def test_bad_rows_are_named(value, message, which):
    arrays = {"database": np.ones((6, 4), np.float32), "queries": np.ones((5, 4), np.float32)}
    arrays[which][3] = value
    with pytest.raises(ValueError, match=f"{which} {message}"):
        search_descriptors(arrays["database"], arrays["queries"], top_k=2)


def test_non_numeric_descriptors_are_rejected():
    with pytest.raises(TypeError, match="numeric"):
        search_descriptors(np.array([["a", "b"]]), np.ones((1, 2)))


def test_no_queries_gives_empty_results():
    scores, indices, distances = search_descriptors(np.eye(3, dtype=np.float32), np.empty((0, 3), np.float32), top_k=2)
    assert scores.shape == indices.shape == distances.shape == (0, 2)
