"""The VPR-Bench image-dataset reader on the real corridor dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vpr_uncertainty.data import load_dataset, load_vprbench_dataset


def test_corridor_images_and_ground_truth(corridor_dir: Path) -> None:
    dataset = load_vprbench_dataset(corridor_dir)
    assert (dataset.n_queries, dataset.n_database) == (111, 111)
    assert dataset.name == "corridor" and dataset.source_format == "vprbench" and dataset.root == corridor_dir
    assert dataset.query_names[0] == "query/0000000.jpg" and dataset.query_names[-1] == "query/0000110.jpg"
    assert dataset.database_names == [f"ref/{i:07d}.jpg" for i in range(111)]
    assert all(path.is_file() for path in dataset.query_paths + dataset.database_paths)
    assert dataset.database_positions is None and dataset.position_kind is None
    assert dataset.positive_radius is None

    # The positives are exactly the lists of ground_truth_new.npy (read here independently).
    rows = np.load(corridor_dir / "ground_truth_new.npy", allow_pickle=True, encoding="latin1")
    expected = np.zeros((111, 111), dtype=bool)
    for query, positives in rows:
        expected[int(query), np.atleast_1d(positives).astype(int)] = True
    np.testing.assert_array_equal(dataset.positives.toarray(), expected)
    assert dataset.queries_without_positives.size == int((~expected.any(axis=1)).sum())

    with pytest.raises(ValueError, match="needs database and query positions"):
        dataset.metric_positions(purpose="SUE")


def test_load_dataset_detects_vprbench(corridor_dir: Path) -> None:
    dataset = load_dataset(corridor_dir)
    assert dataset.source_format == "vprbench" and dataset.n_queries == 111
    with pytest.raises(ValueError, match="radius does not apply"):
        load_dataset(corridor_dir, radius=25)


def test_incomplete_vprbench_folders(tmp_path: Path) -> None:
    (tmp_path / "query").mkdir()
    (tmp_path / "query" / "0000000.jpg").write_bytes(b"")
    with pytest.raises(FileNotFoundError, match="no ref/ folder"):
        load_vprbench_dataset(tmp_path)
    (tmp_path / "ref").mkdir()
    (tmp_path / "ref" / "0000000.jpg").write_bytes(b"")
    with pytest.raises(FileNotFoundError, match=r"no ground_truth_new\.npy"):
        load_vprbench_dataset(tmp_path)
    # Ground truth for two queries, but one query image.
    rows = np.empty((2, 2), dtype=object)
    rows[0], rows[1] = [0, [0]], [1, [0]]
    np.save(tmp_path / "ground_truth_new.npy", rows, allow_pickle=True)
    with pytest.raises(ValueError, match=r"ground truth for 2 queries but .* holds 1"):
        load_vprbench_dataset(tmp_path)
