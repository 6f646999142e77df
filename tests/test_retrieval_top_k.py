"""Block-wise top-k of similarity matrices (retrieval/blocks.py) and the memory-mapped matrix reader."""

from __future__ import annotations

import numpy as np
import pytest

from vpr_uncertainty.data import read_results, read_similarity_top_k
from vpr_uncertainty.formats.ground_truth import read_npy
from vpr_uncertainty.retrieval import blocks as _top_k
from vpr_uncertainty.retrieval import top_k_from_similarity
from vpr_uncertainty.retrieval.blocks import top_k_blocks


def reference_top_k(matrix: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Full stable sort per row: value descending, then index ascending; -inf → index -1."""
    matrix = matrix.astype(np.result_type(matrix.dtype, np.float32))
    k = min(k, matrix.shape[1])
    order = np.stack([np.lexsort((np.arange(matrix.shape[1]), -row))[:k] for row in matrix])
    scores = np.take_along_axis(matrix, order, axis=1)
    order[scores == -np.inf] = -1
    return scores, order


def matrices() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    tied = rng.integers(0, 4, size=(37, 29)).astype(np.float32)  # many ties at the k-th place
    with_inf = rng.random((23, 31)).astype(np.float32)
    with_inf[with_inf < 0.7] = -np.inf  # some rows with fewer than k candidates
    return {
        "random float32": rng.random((41, 53)).astype(np.float32),
        "random float64": rng.standard_normal((19, 60)),
        "tied": tied,
        "integers": rng.integers(-5, 5, size=(17, 40)).astype(np.int16),
        "with -inf": with_inf,
    }


@pytest.mark.parametrize("name", list(matrices()))
@pytest.mark.parametrize("k", [1, 5, 29, 100])
@pytest.mark.parametrize("block_rows", [None, 1, 4, 1000])
def test_blocks_match_a_full_sort(name, k, block_rows):
    matrix = matrices()[name]
    scores, indices = top_k_blocks(matrix, k, block_rows=block_rows)
    expected_scores, expected_indices = reference_top_k(matrix, k)
    np.testing.assert_array_equal(indices, expected_indices)
    np.testing.assert_array_equal(scores, expected_scores)  # the very values of the matrix: exact
    assert scores.dtype == expected_scores.dtype


@pytest.mark.parametrize("name", list(matrices()))
def test_memory_mapped_read_equals_the_in_memory_path(tmp_path, name):
    matrix = matrices()[name]
    path = tmp_path / "similarity.npy"
    np.save(path, matrix)
    for block_rows in (None, 3):
        scores, indices, shape = read_similarity_top_k(path, 7, block_rows=block_rows)
        expected_scores, expected_indices = top_k_from_similarity(matrix, 7)
        assert shape == matrix.shape
        np.testing.assert_array_equal(indices, expected_indices)
        np.testing.assert_array_equal(scores, expected_scores)


def test_read_results_streams_the_matrix_in_blocks(tmp_path, monkeypatch):
    """read_results memory-maps the .npy and never converts more than one block of rows."""
    rng = np.random.default_rng(1)
    matrix = rng.random((50, 40)).astype(np.float32)
    path = tmp_path / "similarity.npy"
    np.save(path, matrix)
    np.save(tmp_path / "gt.npy", np.eye(50, 40, dtype=bool))
    monkeypatch.setattr(_top_k, "BLOCK_VALUES", 40 * 8)  # 8 rows per block
    seen = []
    original = np.asarray

    def spy(array, *args, **kwargs):
        if isinstance(array, np.memmap) and array.shape[1] == 40:
            seen.append(array.shape)
        return original(array, *args, **kwargs)

    monkeypatch.setattr(_top_k.np, "asarray", spy)
    retrieval = read_results(path, ground_truth=tmp_path / "gt.npy", top_k=5)
    monkeypatch.undo()
    assert seen and all(shape[0] <= 8 for shape in seen), seen
    expected_scores, expected_indices = reference_top_k(matrix, 5)
    np.testing.assert_array_equal(retrieval.indices, expected_indices)
    np.testing.assert_array_equal(retrieval.scores, expected_scores)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_bad_values_are_found_in_a_later_block_naming_query_and_column(tmp_path, bad):
    matrix = np.random.default_rng(2).random((30, 12)).astype(np.float32)
    matrix[22, 9] = bad
    path = tmp_path / "similarity.npy"
    np.save(path, matrix)
    with pytest.raises(ValueError, match=r"similarity.npy: .* at query 22, database image 9 .*expected finite"):
        read_similarity_top_k(path, 3, block_rows=4)
    with pytest.raises(ValueError, match="query 22, database image 9"):
        read_similarity_top_k(path, 3)  # default block size


def test_nan_in_a_later_block_of_an_in_memory_matrix():
    matrix = np.zeros((10, 3))
    matrix[7, 2] = np.nan
    with pytest.raises(ValueError, match=r"NaN \(first at query 7, database image 2\)"):
        top_k_from_similarity(matrix, 2, chunk_size=3)


def test_read_npy_mmap_keeps_the_checks(tmp_path):
    path = tmp_path / "a.npy"
    np.save(path, np.arange(12, dtype=np.float32).reshape(3, 4))
    mapped = read_npy(path, what="a matrix", mmap=True)
    assert isinstance(mapped, np.memmap) and not mapped.flags.writeable
    np.testing.assert_array_equal(mapped, np.arange(12, dtype=np.float32).reshape(3, 4))
    del mapped
    truncated = tmp_path / "t.npy"
    truncated.write_bytes(path.read_bytes()[:-8])
    with pytest.raises(ValueError, match="is truncated"):
        read_npy(truncated, what="a matrix", mmap=True)
    empty = tmp_path / "e.npy"
    np.save(empty, np.zeros((0, 4), np.float32))
    assert read_npy(empty, what="a matrix", mmap=True).shape == (0, 4)


def test_bad_block_rows_and_top_k(tmp_path):
    path = tmp_path / "s.npy"
    np.save(path, np.ones((2, 3), np.float32))
    with pytest.raises(ValueError, match="top_k must be a positive integer"):
        read_similarity_top_k(path, 0)
    with pytest.raises(ValueError, match="block_rows must be a positive integer"):
        read_similarity_top_k(path, 1, block_rows=0)
    with pytest.raises(ValueError, match="chunk_size must be a positive integer"):
        top_k_from_similarity(np.ones((2, 3)), 1, chunk_size=0)


def test_fortran_ordered_and_format_3_files_read_the_same(tmp_path):
    matrix = matrices()["tied"]
    fortran = tmp_path / "fortran.npy"
    np.save(fortran, np.asfortranarray(matrix))
    scores, indices, _ = read_similarity_top_k(fortran, 6, block_rows=5)
    expected_scores, expected_indices = reference_top_k(matrix, 6)
    np.testing.assert_array_equal(indices, expected_indices)
    np.testing.assert_array_equal(scores, expected_scores)
    version_3 = tmp_path / "v3.npy"
    with version_3.open("wb") as handle:
        np.lib.format.write_array(handle, matrix, version=(3, 0))
    scores, indices, _ = read_similarity_top_k(version_3, 6, block_rows=5)
    np.testing.assert_array_equal(indices, expected_indices)
