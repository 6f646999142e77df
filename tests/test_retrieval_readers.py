"""Top-k from a full similarity matrix, reading precomputed results (vpr_uncertainty.formats) and descriptor files."""

from __future__ import annotations

import numpy as np
import pytest

from vpr_uncertainty import read_results, top_k_from_similarity
from vpr_uncertainty.data import load_descriptors
from vpr_uncertainty.retrieval import Retrieval, save_retrieval


def reference_top_k(similarity, k):
    order = np.array([sorted(range(len(row)), key=lambda j: (-row[j], j))[:k] for row in similarity])
    return np.take_along_axis(similarity, order, axis=1), order


@pytest.mark.parametrize("k", [1, 5, 30, 60])
def test_top_k_matches_reference_with_ties(k):
    rng = np.random.default_rng(0)
    similarity = rng.integers(0, 6, size=(50, 30)).astype(np.float32) / 5  # many ties
    scores, indices = top_k_from_similarity(similarity, k, chunk_size=7)
    expected_scores, expected_indices = reference_top_k(similarity, k)
    np.testing.assert_array_equal(indices, expected_indices)
    np.testing.assert_array_equal(scores, expected_scores)
    assert scores.shape == (50, min(k, 30))


def test_top_k_rejects_bad_input():
    with pytest.raises(ValueError, match=r"NaN .* query 1, database image 2"):
        top_k_from_similarity(np.array([[0.1, 0.2, 0.3], [0.1, 0.2, np.nan]]), 2)
    with pytest.raises(ValueError, match="2-D"):
        top_k_from_similarity(np.ones(3), 2)
    with pytest.raises(ValueError, match="positive integer"):
        top_k_from_similarity(np.ones((2, 3)), 0)


def test_read_matrix_with_ground_truth(tmp_path):
    rng = np.random.default_rng(1)
    similarity = rng.uniform(size=(20, 40)).astype(np.float32)
    np.save(tmp_path / "sim.npy", similarity)
    (tmp_path / "gt.txt").write_text("\n".join(str(int(np.argmax(row))) for row in similarity) + "\n")
    retrieval = read_results(tmp_path / "sim.npy", ground_truth=tmp_path / "gt.txt")
    assert retrieval.positives.shape == (20, 40)  # sized by the matrix, not by the largest positive index
    np.testing.assert_array_equal(retrieval.indices[:, 0], similarity.argmax(axis=1))
    with pytest.raises(ValueError, match="without ground truth"):
        read_results(tmp_path / "sim.npy")
    np.save(tmp_path / "objects.npy", np.array([1, "a"], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match=r"objects\.npy holds Python objects"):
        read_results(tmp_path / "objects.npy", ground_truth=tmp_path / "gt.txt")


def test_read_retrieval_file_and_override_ground_truth(tmp_path):
    retrieval = Retrieval(
        scores=np.array([[0.9, 0.5], [0.8, 0.7]]), indices=np.array([[0, 1], [1, 0]]), positives=np.eye(2, dtype=bool)
    )
    path = save_retrieval(retrieval, tmp_path / "r.npz")
    loaded = read_results(path)
    assert (loaded.positives != retrieval.positives).nnz == 0
    np.save(tmp_path / "gt.npy", np.array([[False, True], [True, False]]))
    overridden = read_results(path, ground_truth=tmp_path / "gt.npy")
    assert overridden.positives.toarray().tolist() == [[False, True], [True, False]]


# --- descriptor files ---------------------------------------------------------------------------------------


def test_load_descriptors_from_npy(tmp_path):
    array = np.arange(12, dtype=np.float64).reshape(4, 3)
    np.save(tmp_path / "d.npy", array)
    names, loaded = load_descriptors(tmp_path / "d.npy")
    assert names is None and loaded.dtype == np.float32 and loaded.flags.c_contiguous
    np.testing.assert_array_equal(loaded, array)  # small integers: exact in float32
    np.save(tmp_path / "flat.npy", np.ones(3))
    with pytest.raises(ValueError, match="2-D"):
        load_descriptors(tmp_path / "flat.npy")
    with pytest.raises(FileNotFoundError):
        load_descriptors(tmp_path / "missing.npy")
    (tmp_path / "d.txt").write_text("1 2\n")
    with pytest.raises(ValueError, match="unsupported descriptor file"):
        load_descriptors(tmp_path / "d.txt")


def test_load_descriptors_from_the_cache_contract(tmp_path, monkeypatch):
    """The .h5 branch calls vpr_uncertainty.descriptors.cache.read_descriptors(path, split) -> (names, array)."""
    calls = []

    def read_descriptors(path, split):
        calls.append((path, split))
        return [f"{split}/{i}.jpg" for i in range(3)], np.ones((3, 4), np.float32) * (split == "database")

    import vpr_uncertainty.descriptors.cache as cache  # the real module (its package needs it), with a stand-in

    monkeypatch.setattr(cache, "read_descriptors", read_descriptors)
    path = tmp_path / "descriptors.h5"
    path.write_bytes(b"")
    names, descriptors = load_descriptors(path, "database")
    assert calls == [(path, "database")]
    assert names.tolist() == ["database/0.jpg", "database/1.jpg", "database/2.jpg"]
    assert descriptors.shape == (3, 4) and descriptors.dtype == np.float32
    with pytest.raises(ValueError, match="split"):
        load_descriptors(path)


def test_empty_or_truncated_descriptor_npy_is_one_clear_error(tmp_path):
    """Regression: an empty .npy gave a bare EOFError ("No data left in file") instead of naming the file."""
    (tmp_path / "empty.npy").write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty\.npy is empty \(0 bytes\)"):
        load_descriptors(tmp_path / "empty.npy")
    np.save(tmp_path / "whole.npy", np.ones((50, 8), np.float32))
    (tmp_path / "cut.npy").write_bytes((tmp_path / "whole.npy").read_bytes()[:300])
    with pytest.raises(ValueError, match=r"cut\.npy is truncated"):
        load_descriptors(tmp_path / "cut.npy")
    np.save(tmp_path / "text.npy", np.array([["a", "b"]]))
    with pytest.raises(ValueError, match="not a numeric descriptor array"):
        load_descriptors(tmp_path / "text.npy")


def test_results_formats_are_a_registry_a_plugin_can_extend(tmp_path):
    from vpr_uncertainty.data import RESULTS_FORMAT_REGISTRY, ResultsFormat, input_formats, register_results_format

    builtin = ("closures", "vpr-methods-evaluation", "retrieval", "per-query", "matrix", "vprbench")
    assert input_formats() == ("auto", *builtin)
    assert RESULTS_FORMAT_REGISTRY.get("matrix").provides == ("scores",)

    def read_pairs(path, *, ground_truth, top_k):  # one "query database score" line per candidate
        rows = np.loadtxt(path, ndmin=2)
        return Retrieval(rows[:, 2:3], rows[:, 1:2].astype(np.int64), positives=[[0]] * len(rows))

    register_results_format(
        ResultsFormat("pairs", "query database score", read_pairs, detect=lambda p: p.suffix == ".pairs")
    )
    try:
        (tmp_path / "run.pairs").write_text("0 0 0.9\n1 0 0.4\n")
        assert "pairs" in input_formats()
        for file_format in ("auto", "pairs"):
            retrieval = read_results(tmp_path / "run.pairs", file_format=file_format)
            np.testing.assert_array_equal(retrieval.scores, [[0.9], [0.4]])
    finally:
        RESULTS_FORMAT_REGISTRY.unregister("pairs")
    with pytest.raises(ValueError, match="file_format must be one of"):
        read_results(tmp_path / "run.pairs", file_format="pairs")
