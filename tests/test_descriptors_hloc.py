"""hloc's global-descriptor HDF5 files are read (load_descriptors, retrieve) and written (extract --hloc)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty.cli import main
from vpr_uncertainty.data import load_descriptors
from vpr_uncertainty.formats.hloc import read_hloc_descriptors, write_hloc_descriptors


def _hloc_file(path, names, descriptors):
    """As hloc.extract_features writes it: one group per image name, a global_descriptor and an image_size."""
    with h5py.File(path, "w") as handle:
        for name, row in zip(names, descriptors, strict=True):
            group = handle.create_group(name)
            group.create_dataset("global_descriptor", data=row)
            group.create_dataset("image_size", data=np.array([640, 480]))
    return path


def test_load_descriptors_reads_an_hloc_file_split_by_prefix(tmp_path):
    rng = np.random.default_rng(0)
    descriptors = rng.standard_normal((5, 8)).astype(np.float32)
    names = ["db/b.jpg", "query/q1.jpg", "db/a.jpg", "query/q0.jpg", "db/c.jpg"]
    path = _hloc_file(tmp_path / "global-feats-netvlad.h5", names, descriptors)
    database_names, database = load_descriptors(path, "database")
    query_names, queries = load_descriptors(path, "queries")
    assert database_names.tolist() == ["db/a.jpg", "db/b.jpg", "db/c.jpg"]
    assert query_names.tolist() == ["query/q0.jpg", "query/q1.jpg"]
    assert_close(database[0], descriptors[2])
    assert_close(queries[1], descriptors[1])


def test_an_hloc_file_without_prefixes_is_one_split(tmp_path):
    rng = np.random.default_rng(1)
    path = _hloc_file(tmp_path / "q.h5", ["0001.jpg", "0000.jpg"], rng.standard_normal((2, 4)).astype(np.float32))
    names, descriptors = load_descriptors(path, "queries")
    assert names.tolist() == ["0000.jpg", "0001.jpg"] and descriptors.shape == (2, 4)


def test_retrieve_accepts_hloc_files(tmp_path, capsys):
    pytest.importorskip("faiss")
    rng = np.random.default_rng(2)
    database = rng.standard_normal((6, 8)).astype(np.float32)
    _hloc_file(tmp_path / "db.h5", [f"{i}.jpg" for i in range(6)], database)
    _hloc_file(tmp_path / "q.h5", ["a.jpg", "b.jpg"], database[[4, 1]])
    out = tmp_path / "r.npz"
    argv = ["retrieve", "--database", str(tmp_path / "db.h5"), "--queries", str(tmp_path / "q.h5"), "--out", str(out)]
    assert main([*argv, "--top-k", "3"]) == 0
    from vpr_uncertainty.retrieval import load_retrieval

    retrieval = load_retrieval(out)
    assert retrieval.indices[:, 0].tolist() == [4, 1]
    assert retrieval.query_names.tolist() == ["a.jpg", "b.jpg"]


def test_write_then_read_round_trip_in_hlocs_layout(tmp_path):
    rng = np.random.default_rng(3)
    descriptors = rng.standard_normal((3, 5)).astype(np.float32)
    path = write_hloc_descriptors(tmp_path / "g.h5", ["ref/0.jpg", "ref/1.jpg", "query/0.jpg"], descriptors)
    with h5py.File(path, "r") as handle:  # what hloc.pairs_from_retrieval reads
        assert handle["ref"]["1.jpg"]["global_descriptor"].shape == (5,)
        assert_close(handle["query/0.jpg"]["global_descriptor"][()], descriptors[2])
    names, read = read_hloc_descriptors(path, "database")
    assert names.tolist() == ["ref/0.jpg", "ref/1.jpg"]
    assert_close(read, descriptors[:2])


def test_a_file_with_neither_layout_is_still_rejected_by_name(tmp_path):
    with h5py.File(tmp_path / "other.h5", "w") as handle:
        handle.create_dataset("x", data=np.zeros(3))
    with pytest.raises(ValueError, match="not a vpr-uncertainty descriptor file"):
        load_descriptors(tmp_path / "other.h5", "database")


def test_extract_writes_an_hloc_file(tmp_path, corridor_dir, capsys):
    pytest.importorskip("torch")
    hloc = tmp_path / "global-feats.h5"
    argv = ["extract", "--dataset", str(corridor_dir), "--out", str(tmp_path / "d.h5"), "--hloc", str(hloc)]
    assert main([*argv, "--threads", "1"]) == 0
    names, queries = read_hloc_descriptors(hloc, "queries")
    cache_names, cache_queries = load_descriptors(tmp_path / "d.h5", "queries")
    assert names.tolist() == cache_names.tolist() and len(names) == 111
    assert_close(queries, cache_queries)
