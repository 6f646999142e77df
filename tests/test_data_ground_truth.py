"""Ground-truth readers: every format gives the same sparse positives matrix."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vpr_uncertainty.data import load_ground_truth, positives_from_lists, positives_from_mask, positives_to_lists
from vpr_uncertainty.formats.ground_truth import load_vprbench_ground_truth
from vpr_uncertainty.formats.matrix import load_vprbench_similarity

LISTS = [[0, 2], [], [1, 2, 3]]
MASK = np.array([[1, 0, 1, 0], [0, 0, 0, 0], [0, 1, 1, 1]], dtype=bool)


def test_lists_and_mask_agree():
    from_lists = positives_from_lists(LISTS, n_database=4)
    np.testing.assert_array_equal(from_lists.toarray(), MASK)
    np.testing.assert_array_equal(positives_from_mask(MASK).toarray(), MASK)
    assert [row.tolist() for row in positives_to_lists(from_lists)] == LISTS


def test_out_of_range_positive_is_named():
    with pytest.raises(ValueError, match=r"query 1 .* got 7"):
        positives_from_lists([[0], [7]], n_database=4)
    with pytest.raises(ValueError, match="boolean"):
        positives_from_mask(np.array([[0, 2]]))


@pytest.mark.parametrize("suffix", [".npy", ".json", ".txt", ".csv", ".npz"])
def test_file_formats_round_trip(tmp_path, suffix):
    path = tmp_path / f"gt{suffix}"
    if suffix == ".npy":
        np.save(path, MASK)
    elif suffix == ".json":
        path.write_text(json.dumps(LISTS))
    elif suffix == ".txt":
        path.write_text("0 2\n\n1 2 3\n")
    elif suffix == ".csv":
        path.write_text("0,2\n\n1,2,3\n")
    else:
        csr = positives_from_mask(MASK)
        np.savez(path, positives_indptr=csr.indptr, positives_indices=csr.indices, n_database=4)
    positives = load_ground_truth(path, n_queries=3, n_database=4)
    np.testing.assert_array_equal(positives.toarray(), MASK)


def test_file_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        load_ground_truth(tmp_path / "missing.npy")
    bad = tmp_path / "gt.txt"
    bad.write_text("0 2\nfoo\n")
    with pytest.raises(ValueError, match=r"gt.txt:2: expected integer"):
        load_ground_truth(bad)
    other = tmp_path / "gt.xml"
    other.write_text("<gt/>")
    with pytest.raises(ValueError, match="unknown ground truth format"):
        load_ground_truth(other)
    np.save(tmp_path / "mask.npy", MASK)
    with pytest.raises(ValueError, match="has 3 queries, expected 5"):
        load_ground_truth(tmp_path / "mask.npy", n_queries=5)


def test_real_vprbench_ground_truth(corridor_dir):
    path = corridor_dir / "ground_truth_new.npy"
    positives = load_vprbench_ground_truth(path, n_database=111)  # restricted unpickler: no warning to give
    raw = np.load(path, allow_pickle=True, encoding="latin1")
    assert positives.shape == (111, 111)
    for query, expected in raw:
        assert positives_to_lists(positives)[query].tolist() == sorted(expected)
    assert (load_ground_truth(path, n_database=111) != positives).nnz == 0


def test_real_vprbench_similarity(corridor_matches_dir):
    matrix = load_vprbench_similarity(corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy")
    assert matrix.shape == (111, 111) and matrix.dtype == np.float32 and np.isfinite(matrix).all()
