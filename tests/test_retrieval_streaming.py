"""Exact search of a database read block by block (retrieval.search, retrieval.blocks) equals the
in-memory search: indices exactly, scores within float32 tolerance, ties to the lower database index."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty import cache as cache_protocol
from vpr_uncertainty import cli
from vpr_uncertainty.data import load_descriptors, open_descriptors
from vpr_uncertainty.retrieval import (
    DescriptorRows,
    load_retrieval,
    retrieve,
    search_descriptors,
    top_k_from_similarity,
)
from vpr_uncertainty.retrieval import (
    blocks as descriptor_rows,
)
from vpr_uncertainty.retrieval import (
    search as _streaming,
)

faiss = pytest.importorskip("faiss")


def tie_descriptors(rng: np.random.Generator, n: int, dim: int = 16) -> np.ndarray:
    """Entries ±1/4 with dim = 16: unit norm and inner products multiples of 1/8, all exact in float32."""
    return rng.choice([-0.25, 0.25], size=(n, dim)).astype(np.float32)


def assert_same_search(streamed, in_memory, *, exact_scores: bool = False) -> None:
    (scores, indices, distances), (expected_scores, expected_indices, expected_distances) = streamed, in_memory
    np.testing.assert_array_equal(indices, expected_indices)
    finite = np.isfinite(expected_scores)
    np.testing.assert_array_equal(np.isfinite(scores), finite)
    if exact_scores:
        np.testing.assert_array_equal(scores, expected_scores)
    assert_close(scores[finite], expected_scores[finite], atol=1e-6)
    assert_close(distances[finite], expected_distances[finite], atol=1e-6)
    assert scores.dtype == distances.dtype == np.float32 and indices.dtype == np.int64


@pytest.fixture
def spy_blocks(monkeypatch):
    """Records the blocks (start, stop) read from every DescriptorRows, and each streamed search."""
    reads, searches = [], []
    original_read, original_search = DescriptorRows.read, _streaming.search_blocks

    def read(self, start, stop):
        block = original_read(self, start, stop)
        reads.append((int(start), int(start) + len(block)))
        return block

    def search_blocks(*args, **kwargs):
        searches.append(kwargs["block"])
        return original_search(*args, **kwargs)

    monkeypatch.setattr(DescriptorRows, "read", read)
    monkeypatch.setattr(_streaming, "search_blocks", search_blocks)
    return reads, searches


# --- equal to the in-memory search ------------------------------------------------------------------------------


@pytest.mark.parametrize("n_queries", [7, 60])  # Faiss's direct loop below 20 queries, BLAS above
@pytest.mark.parametrize(("block", "k"), [(1, 5), (7, 10), (64, 10), (333, 25), (500, 10), (10_000, 10), (7, 40)])
def test_random_descriptors_equal_the_in_memory_search(n_queries, block, k):
    """Blocks that do not divide D (7, 64, 333), one block (500, 10,000), and k larger than the block (7, 40)."""
    rng = np.random.default_rng(block + k)
    database = rng.standard_normal((500, 32)).astype(np.float32)
    queries = rng.standard_normal((n_queries, 32)).astype(np.float32)
    in_memory = search_descriptors(database, queries, top_k=k)
    assert_same_search(search_descriptors(database, queries, top_k=k, database_block=block), in_memory)


@pytest.mark.parametrize("n_queries", [5, 64])
@pytest.mark.parametrize(("block", "k"), [(1, 3), (13, 1), (13, 10), (50, 40), (29, 200)])
def test_ties_and_duplicate_rows_go_to_the_lower_index_across_blocks(n_queries, block, k):
    rng = np.random.default_rng(k)
    base = tie_descriptors(rng, 120)
    database = np.concatenate([base, base[:30], base[:5]])  # exact duplicates at later indices, in other blocks
    rng.shuffle(database)
    queries = np.concatenate([tie_descriptors(rng, n_queries - 2), database[[3, 40]]])
    in_memory = search_descriptors(database, queries, top_k=k)
    streamed = search_descriptors(database, queries, top_k=k, database_block=block, batch_size=17)
    assert_same_search(streamed, in_memory, exact_scores=True)  # multiples of 1/8: exact in float32
    similarity = queries @ database.T
    expected_scores, expected_indices = top_k_from_similarity(similarity, k)  # ties by lower index
    width = expected_scores.shape[1]
    np.testing.assert_array_equal(streamed[1][:, :width], expected_indices)
    # Sanity: the data really has ties across the k-th place.
    kth = np.sort(similarity, axis=1)[:, ::-1][:, min(k, len(database)) - 1 : min(k, len(database))]
    assert ((similarity == kth).sum(axis=1) > 1).any()


def test_all_rows_identical_keeps_the_first_k():
    database = np.ones((50, 8), dtype=np.float32)
    scores, indices, _ = search_descriptors(database, np.ones((3, 8), np.float32), top_k=6, database_block=7)
    np.testing.assert_array_equal(indices, np.tile(np.arange(6), (3, 1)))
    assert_close(scores, np.ones((3, 6), np.float32))


@pytest.mark.parametrize("block", [1, 3, 100])
def test_database_smaller_than_k_pads_with_missing_candidates(block):
    rng = np.random.default_rng(1)
    database = rng.standard_normal((5, 8)).astype(np.float32)
    queries = rng.standard_normal((4, 8)).astype(np.float32)
    streamed = search_descriptors(database, queries, top_k=9, database_block=block)
    assert_same_search(streamed, search_descriptors(database, queries, top_k=9))
    assert (streamed[1][:, 5:] == -1).all() and np.isneginf(streamed[0][:, 5:]).all()
    assert np.isposinf(streamed[2][:, 5:]).all()


def test_normalisation_is_decided_on_the_whole_database():
    """Unit-norm blocks of a database that has other rows are normalised too, as the in-memory search does."""
    rng = np.random.default_rng(2)
    database = rng.standard_normal((90, 24))
    database /= np.linalg.norm(database, axis=1, keepdims=True)
    database[80:] *= 3.0  # only the last block is far from unit norm
    database = database.astype(np.float32)
    queries = rng.standard_normal((30, 24)).astype(np.float32)
    assert_same_search(
        search_descriptors(database, queries, top_k=8, database_block=40),
        search_descriptors(database, queries, top_k=8),
    )
    unit = database[:80].copy()  # all unit-norm: used as they are, in memory and in blocks
    assert_same_search(
        search_descriptors(unit, queries, top_k=8, database_block=40), search_descriptors(unit, queries, top_k=8)
    )


def test_retrieve_streams_with_the_same_result_and_config():
    rng = np.random.default_rng(4)
    database = rng.standard_normal((120, 16)).astype(np.float32)
    queries = rng.standard_normal((10, 16)).astype(np.float32)
    streamed = retrieve(DescriptorRows.from_array(database), queries, top_k=5, database_block=11)
    in_memory = retrieve(database, queries, top_k=5)
    np.testing.assert_array_equal(streamed.indices, in_memory.indices)
    assert_close(streamed.scores, in_memory.scores, atol=1e-6)
    assert streamed.config == in_memory.config  # n_database and dimension read from the shape, not the data


# --- descriptor files on disk ----------------------------------------------------------------------------------


def test_a_memory_mapped_npy_database_is_streamed_block_by_block(tmp_path, spy_blocks, monkeypatch):
    reads, searches = spy_blocks
    rng = np.random.default_rng(5)
    database = rng.standard_normal((1000, 16)) * 3  # float64, not normalised: converted one block at a time
    queries = rng.standard_normal((40, 16)).astype(np.float32)
    np.save(tmp_path / "db.npy", database)
    names, rows = open_descriptors(tmp_path / "db.npy")
    assert names is None and rows.shape == (1000, 16) and rows.dtype == np.float32
    in_memory = search_descriptors(load_descriptors(tmp_path / "db.npy")[1], queries, top_k=10)
    assert_same_search(search_descriptors(rows, queries, top_k=10, database_block=300), in_memory)
    assert searches == [300] and max(stop - start for start, stop in reads) == 300
    assert sorted(set(reads)) == [(0, 300), (300, 600), (600, 900), (900, 1000)]  # norms pass, then search pass
    # By default a database on disk is streamed when it is larger than one default block (64 MiB; here 1 KiB).
    monkeypatch.setattr(descriptor_rows, "DEFAULT_BLOCK_BYTES", 16 * 4 * 128)
    reads.clear()
    assert_same_search(search_descriptors(rows, queries, top_k=10), in_memory)
    assert searches[-1] == 128 and max(stop - start for start, stop in reads) == 128
    mapped = np.load(tmp_path / "db.npy", mmap_mode="r")  # a memmap given directly is streamed as well
    assert_same_search(search_descriptors(mapped, queries, top_k=10), in_memory)
    assert searches[-1] == 128
    # A database in memory is searched whole unless database_block is given; one block on disk as well.
    search_descriptors(database, queries, top_k=10)
    search_descriptors(DescriptorRows.from_array(database[:100]), queries, top_k=10)
    assert len(searches) == 3


@pytest.mark.parametrize("dtype", ["<f4", ">f4", "<f8", "<f2", "|i1"])
def test_blocks_of_a_npy_file_are_read_into_new_float32_arrays(tmp_path, dtype):
    array = (np.arange(60).reshape(20, 3) % 7).astype(dtype)
    np.save(tmp_path / "d.npy", array)
    np.save(tmp_path / "f.npy", np.asfortranarray(array))  # Fortran order: sliced through the mapping
    _, rows = open_descriptors(tmp_path / "d.npy")
    block = rows.read(5, 9)
    assert type(block) is np.ndarray and block.dtype == np.float32 and block.flags.c_contiguous
    assert block.flags.writeable and block.flags.owndata
    np.testing.assert_array_equal(block, array[5:9])  # small integers: exact in every dtype
    np.testing.assert_array_equal(np.concatenate(list(rows.row_blocks(7))), array)
    np.testing.assert_array_equal(open_descriptors(tmp_path / "f.npy")[1].to_array(), array)
    assert rows.read(18, 40).shape == (2, 3) and rows.read(25, 30).shape == (0, 3)


def test_a_npy_file_cut_after_it_was_opened_is_one_clear_error(tmp_path):
    np.save(tmp_path / "d.npy", np.ones((20, 3), np.float32))
    _, rows = open_descriptors(tmp_path / "d.npy")
    content = (tmp_path / "d.npy").read_bytes()
    (tmp_path / "d.npy").write_bytes(content[: len(content) - 30])
    with pytest.raises(ValueError, match=r"d\.npy changed while it was read: rows 16–19"):
        rows.read(16, 20)


def write_cache(path, rng, counts=(("database", 700), ("queries", 30)), dtype=np.float32, complete=True):
    """The HDF5 descriptor cache in its documented layout (descriptors.cache), written by hand."""
    h5py = pytest.importorskip("h5py")
    from vpr_uncertainty.descriptors import cache

    with h5py.File(path, "w") as handle:
        handle.attrs["format"] = cache.FORMAT
        handle.attrs["format_version"] = cache.FORMAT_VERSION
        for split, count in counts:
            group = handle.create_group(split)
            group.attrs["complete"] = complete
            values = rng.standard_normal((count, 16))
            values /= np.linalg.norm(values, axis=1, keepdims=True)
            values[::50] = values[1::50][: len(values[::50])]  # duplicate rows: ties
            group.create_dataset("descriptors", data=values.astype(dtype), chunks=(min(64, count), 16))
            group.create_dataset(
                "names", data=[f"{split}/{i:04d}.jpg" for i in range(count)], dtype=h5py.string_dtype()
            )
            group.create_dataset("keys", data=["k"] * count, dtype=h5py.string_dtype())


@pytest.mark.parametrize("dtype", [np.float32, np.float16])
def test_the_hdf5_descriptor_cache_is_read_by_slices(tmp_path, spy_blocks, dtype):
    reads, searches = spy_blocks
    path = tmp_path / "descriptors.h5"
    write_cache(path, np.random.default_rng(6), dtype=dtype)
    names, rows = open_descriptors(path, "database")
    expected_names, database = load_descriptors(path, "database")
    np.testing.assert_array_equal(names, expected_names)
    assert rows.shape == database.shape == (700, 16)
    np.testing.assert_array_equal(rows.to_array(), database)
    _, queries = load_descriptors(path, "queries")
    reads.clear()
    streamed = search_descriptors(rows, queries, top_k=12, database_block=96)
    assert_same_search(streamed, search_descriptors(database, queries, top_k=12))
    assert searches == [96] and max(stop - start for start, stop in reads) == 96


def test_an_incomplete_cache_warns_as_the_whole_reader_does(tmp_path):
    path = tmp_path / "descriptors.h5"
    write_cache(path, np.random.default_rng(7), complete=False)
    with pytest.warns(UserWarning, match="incomplete"):
        _, rows = open_descriptors(path, "database")
    assert len(rows) == 700


def test_digest_of_rows_on_disk_equals_the_digest_of_the_array(tmp_path):
    """The retrieval stage fingerprints the database block by block: the same key as the array in memory."""
    array = np.random.default_rng(8).standard_normal((300, 8)).astype(np.float32)
    np.save(tmp_path / "db.npy", array)
    _, rows = open_descriptors(tmp_path / "db.npy")
    names = np.array([f"{i}.jpg" for i in range(300)])
    assert cache_protocol.array_digest(names, rows) == cache_protocol.array_digest(names, array)
    assert cache_protocol.array_digest(rows) != cache_protocol.array_digest(array[:-1])


def test_the_retrieve_command_streams_a_npy_database(tmp_path, spy_blocks):
    reads, searches = spy_blocks
    rng = np.random.default_rng(9)
    database = rng.standard_normal((400, 16)).astype(np.float32)
    queries = np.concatenate([rng.standard_normal((20, 16)), database[[5, 6]]]).astype(np.float32)
    np.save(tmp_path / "db.npy", database)
    np.save(tmp_path / "q.npy", queries)
    common = ["retrieve", "--database", str(tmp_path / "db.npy"), "--queries", str(tmp_path / "q.npy"), "--top-k", "7"]
    assert cli.main([*common, "--out", str(tmp_path / "streamed.npz"), "--database-block", "64"]) == 0
    # The fingerprint hashes the file in blocks of 64 MiB (here the whole file at once), then the search streams it.
    assert searches == [64] and reads[0] == (0, 400) and max(stop - start for start, stop in reads[1:]) == 64
    streamed, in_memory = load_retrieval(tmp_path / "streamed.npz"), retrieve(database, queries, top_k=7)
    np.testing.assert_array_equal(streamed.indices, in_memory.indices)
    assert_close(streamed.scores, in_memory.scores, atol=1e-6)
    with pytest.raises(SystemExit) as stopped:  # argparse: "must be an integer >= 1, got 0"
        cli.main([*common, "--out", str(tmp_path / "bad.npz"), "--database-block", "0"])
    assert stopped.value.code == 2
    assert cli.main([*common, "--out", str(tmp_path / "r.npz"), "--database-block", "8", "--index", "HNSW8"]) == 2


# --- bad input --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"database_block": 0}, "database_block must be a positive integer, got 0"),
        ({"database_block": -3}, "database_block must be a positive integer, got -3"),
        ({"database_block": True}, "database_block must be a positive integer, got True"),
        ({"database_block": 2.5}, "database_block must be a positive integer, got 2.5"),
        ({"database_block": 10, "index": "HNSW8"}, "exact search on the CPU .*'HNSW8'.*leave database_block unset"),
    ],
)
def test_bad_block_options_are_one_clear_error(options, message):
    database = np.eye(4, dtype=np.float32)
    with pytest.raises(ValueError, match=message):
        search_descriptors(database, database, top_k=2, **options)


def test_mismatched_dimensions_and_empty_databases_are_one_clear_error(tmp_path):
    np.save(tmp_path / "db.npy", np.ones((10, 8), np.float32))
    _, rows = open_descriptors(tmp_path / "db.npy")
    with pytest.raises(ValueError, match="same descriptor dimension, got 8 and 4"):
        search_descriptors(rows, np.ones((2, 4), np.float32), top_k=2, database_block=3)
    with pytest.raises(ValueError, match="database is empty"):
        search_descriptors(np.empty((0, 8), np.float32), np.ones((2, 8), np.float32), database_block=3)
    with pytest.raises(ValueError, match="2-D"):
        search_descriptors(np.ones(8, np.float32), np.ones((2, 8), np.float32), database_block=3)


@pytest.mark.parametrize(("value", "message"), [(np.nan, "row 57 contains NaN"), (np.inf, "row 57 contains an inf")])
def test_bad_rows_in_a_later_block_are_named_by_their_database_row(value, message):
    database = np.ones((80, 4), np.float32)
    database[57, 2] = value
    with pytest.raises(ValueError, match=message):
        search_descriptors(database, np.ones((2, 4), np.float32), database_block=10)


def test_all_zero_rows_are_counted_over_the_whole_database():
    database = np.ones((80, 4), np.float32)
    database[[3, 41, 79]] = 0
    with pytest.raises(ValueError, match=r"3 all-zero row\(s\) \(rows 3, 41, 79\)"):
        search_descriptors(database, np.ones((2, 4), np.float32), database_block=10)


def test_open_descriptors_errors_match_load_descriptors(tmp_path):
    np.save(tmp_path / "flat.npy", np.ones(3))
    np.save(tmp_path / "text.npy", np.array([["a", "b"]]))
    (tmp_path / "d.txt").write_text("1 2\n")
    (tmp_path / "d.h5").write_bytes(b"")
    cases = [
        ("flat.npy", None, ValueError, "2-D"),
        ("text.npy", None, ValueError, "not a numeric descriptor array"),
        ("missing.npy", None, FileNotFoundError, "not found"),
        ("d.txt", None, ValueError, "unsupported descriptor file"),
        ("d.h5", None, ValueError, "split"),
    ]
    for name, split, error, message in cases:
        with pytest.raises(error, match=message):
            open_descriptors(tmp_path / name, split)
        with pytest.raises(error, match=message):
            load_descriptors(tmp_path / name, split)


def test_a_vpr_methods_evaluation_log_folder_streams_its_database(tmp_path, spy_blocks, monkeypatch):
    from test_retrieval_vpr_methods_evaluation import _log_folder
    from vpr_uncertainty.formats.vpr_methods_evaluation import read_vpr_methods_evaluation

    reads, searches = spy_blocks
    folder = _log_folder(tmp_path)
    in_memory = read_vpr_methods_evaluation(folder).retrieval
    assert searches == [] and reads[-1] == (0, 12)  # 12 rows: less than one default block, read whole
    reads.clear()
    monkeypatch.setattr(descriptor_rows, "DEFAULT_BLOCK_BYTES", 16 * 4 * 5)  # 5 rows a block
    streamed = read_vpr_methods_evaluation(folder).retrieval
    assert searches == [5] and max(stop - start for start, stop in reads) == 5
    np.testing.assert_array_equal(streamed.indices, in_memory.indices)
    assert_close(streamed.scores, in_memory.scores, atol=1e-6)
