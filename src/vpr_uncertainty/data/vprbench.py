"""Readers for the legacy files of the VPR-Bench benchmark (Zaffar et al., IJCV 2021).

VPR-Bench stores its ground truth and its precomputed matches as NumPy *object* arrays, which can only be read
with pickle. Unpickling a file can run arbitrary code: these two readers are the only places in the toolkit
that do it, they say so with a warning, and they should only be given files from a source you trust.

:func:`load_vprbench_dataset` reads a whole VPR-Bench image dataset (``query/``, ``ref/``, ground truth) into a
:class:`~vpr_uncertainty.data.dataset.Dataset`.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from scipy import sparse

from vpr_uncertainty.data.dataset import Dataset
from vpr_uncertainty.data.ground_truth import positives_from_lists

__all__ = ["PickleWarning", "load_vprbench_dataset", "load_vprbench_ground_truth", "load_vprbench_similarity"]


class PickleWarning(UserWarning):
    """Issued when a legacy file is read with pickle."""


def _load_object_array(path: Path) -> np.ndarray:
    warnings.warn(
        f"reading the legacy VPR-Bench file {path} with pickle; only open files from a source you trust",
        PickleWarning,
        stacklevel=3,
    )
    return np.load(path, allow_pickle=True, encoding="latin1")


def load_vprbench_ground_truth(path: str | Path, *, n_database: int | None = None) -> sparse.csr_array:
    """Read VPR-Bench's ``ground_truth_new.npy``: rows of [query index, list of positive database indices].

    Parameters
    ----------
    path : str or Path
        The ``.npy`` file.
    n_database : int, optional
        Number of database images; by default the largest positive index + 1.

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool
    """
    path = Path(path)
    rows = _load_object_array(path)
    if rows.ndim != 2 or rows.shape[1] != 2:
        raise ValueError(
            f"{path}: expected VPR-Bench ground truth of shape (n_queries, 2) = [query index, positives], "
            f"got shape {rows.shape}"
        )
    query_ids = np.asarray(rows[:, 0], dtype=np.int64)
    if not np.array_equal(np.sort(query_ids), np.arange(len(rows))):
        raise ValueError(f"{path}: query indices must be a permutation of 0..{len(rows) - 1}")
    lists: list[list[int]] = [[] for _ in range(len(rows))]
    for query, positives in zip(query_ids, rows[:, 1], strict=True):
        lists[query] = [int(index) for index in np.atleast_1d(positives)]
    if n_database is None:
        n_database = max((max(item) for item in lists if item), default=-1) + 1
    return positives_from_lists(lists, n_database)


def load_vprbench_similarity(path: str | Path) -> np.ndarray:
    """Read the full similarity matrix from VPR-Bench's ``precomputed_data_corrected.npy``.

    The file holds [query indices, top-1 indices, top-1 scores, similarity matrix, encoding time, matching
    time]; the matrix has one row per query and one column per database image, higher = more similar.

    Returns
    -------
    ndarray of shape (Q, D), float32
    """
    path = Path(path)
    content = _load_object_array(path)
    if content.shape != (6,):
        raise ValueError(
            f"{path}: expected VPR-Bench precomputed matches (an object array of 6 items), got shape {content.shape}"
        )
    similarity = np.asarray(content[3], dtype=np.float32)
    if similarity.ndim != 2:
        raise ValueError(f"{path}: item 3 should be the (queries × database) similarity matrix")
    order = np.asarray(content[0]).astype(np.int64)
    if not np.array_equal(order, np.arange(len(order))) or len(order) != similarity.shape[0]:
        raise ValueError(f"{path}: expected query indices 0..{similarity.shape[0] - 1} in order")
    return similarity


def load_vprbench_dataset(root: str | Path, *, name: str | None = None) -> Dataset:
    """Read a VPR-Bench image dataset: ``query/``, ``ref/`` and ``ground_truth_new.npy``.

    The ground truth is an explicit list of positives per query (no positions), read with pickle: see
    :func:`load_vprbench_ground_truth`, which warns with :class:`PickleWarning`.

    Parameters
    ----------
    root : str or Path
        The dataset folder, e.g. ``VPR-Bench/datasets/corridor``.
    name : str, optional
        Dataset name; by default the folder name.

    Returns
    -------
    Dataset
        Database = ``ref/`` images, queries = ``query/`` images, each sorted by name; names relative to
        ``root`` (``ref/0000000.jpg``); no positions.

    Raises
    ------
    FileNotFoundError
        When a folder or the ground truth is missing.
    ValueError
        When the ground truth does not match the number of images.
    """
    from vpr_uncertainty.data.folder import list_images

    root = Path(root)
    paths = {}
    for folder in ("query", "ref"):
        if not (root / folder).is_dir():
            raise FileNotFoundError(f"{root} is not a VPR-Bench dataset: no {folder}/ folder (expected query/, ref/)")
        paths[folder] = list_images(root / folder)
        if not paths[folder]:
            raise FileNotFoundError(f"no image found under {root / folder}")
    ground_truth = root / "ground_truth_new.npy"
    if not ground_truth.is_file():
        raise FileNotFoundError(f"{root} is not a VPR-Bench dataset: no ground_truth_new.npy")
    positives = load_vprbench_ground_truth(ground_truth, n_database=len(paths["ref"]))
    if positives.shape[0] != len(paths["query"]):
        raise ValueError(
            f"{ground_truth} has ground truth for {positives.shape[0]} queries but {root / 'query'} holds "
            f"{len(paths['query'])} images"
        )
    return Dataset(
        name=name or root.name,
        root=root,
        positives=positives,
        database_paths=paths["ref"],
        query_paths=paths["query"],
        source_format="vprbench",
        info={"ground_truth": ground_truth.name},
    )
