"""Ground truth: which database images are correct answers (positives) for each query.

Inside the toolkit the positives are one sparse boolean matrix of shape (n_queries, n_database), a
``scipy.sparse.csr_array``: row q holds True at the database indices that show the place of query q. It is
built from any of the formats users have:

* a boolean (Q × D) ``.npy`` mask;
* per-query lists of database indices (Python lists, a ``.json`` list of lists, or a text file with one line of
  whitespace- or comma-separated indices per query, an empty line for a query with no positive);
* a ``.npz`` with ``positives_indptr`` and ``positives_indices`` (the layout of retrieval files);
* VPR-Bench's ``ground_truth_new.npy`` (legacy object array, read with pickle: see
  :func:`vpr_uncertainty.data.vprbench.load_vprbench_ground_truth`).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
from scipy import sparse

__all__ = [
    "load_ground_truth",
    "positives_from_lists",
    "positives_from_mask",
    "positives_to_lists",
]


def positives_from_lists(lists: Sequence[Iterable[int]], n_database: int) -> sparse.csr_array:
    """Build the positives matrix from one list of database indices per query.

    Parameters
    ----------
    lists : sequence of iterables of int, length Q
        Positive database indices of each query (may be empty; duplicates are merged).
    n_database : int
        Number of database images D.

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool

    Examples
    --------
    >>> positives_from_lists([[0, 2], []], n_database=3).toarray()
    array([[ True, False,  True],
           [False, False, False]])
    """
    if isinstance(n_database, bool) or not isinstance(n_database, (int, np.integer)) or n_database < 0:
        raise ValueError(f"n_database must be a non-negative integer, got {n_database!r}")
    rows = [np.unique(np.asarray(list(item), dtype=np.int64)) for item in lists]
    for query, row in enumerate(rows):
        if row.size and (row[0] < 0 or row[-1] >= n_database):
            raise ValueError(
                f"positives of query {query} must be database indices in [0, {n_database}), "
                f"got {row[0] if row[0] < 0 else row[-1]}"
            )
    indptr = np.zeros(len(rows) + 1, dtype=np.int64)
    np.cumsum([row.size for row in rows], out=indptr[1:])
    indices = np.concatenate(rows) if rows else np.empty(0, np.int64)
    data = np.ones(indices.size, dtype=bool)
    return sparse.csr_array((data, indices, indptr), shape=(len(rows), n_database))


def positives_from_mask(mask: object) -> sparse.csr_array:
    """Build the positives matrix from a boolean (Q × D) mask.

    Examples
    --------
    >>> positives_from_mask(np.array([[True, False], [False, False]])).nnz
    1
    """
    array = np.asarray(mask)
    if array.ndim != 2:
        raise ValueError(f"a ground-truth mask must be 2-D (n_queries, n_database), got shape {array.shape}")
    if array.dtype != bool:
        if not np.isin(array, (0, 1)).all():
            raise ValueError(f"a ground-truth mask must be boolean (or 0/1), got dtype {array.dtype}")
        array = array.astype(bool)
    return sparse.csr_array(array)


def positives_to_lists(positives: sparse.csr_array) -> list[np.ndarray]:
    """One sorted int64 array of positive database indices per query."""
    positives = sparse.csr_array(positives)
    positives.sort_indices()
    return [
        positives.indices[positives.indptr[q] : positives.indptr[q + 1]].astype(np.int64)
        for q in range(positives.shape[0])
    ]


def _from_text(path: Path, n_database: int | None) -> sparse.csr_array:
    lists = []
    for line_number, line in enumerate(path.read_text().splitlines(), start=1):
        fields = line.replace(",", " ").split()
        try:
            lists.append([int(field) for field in fields])
        except ValueError as error:
            raise ValueError(f"{path}:{line_number}: expected integer database indices, got {line!r}") from error
    return positives_from_lists(lists, _database_size(lists, n_database, path))


def _database_size(lists: Sequence[Sequence[int]], n_database: int | None, path: Path) -> int:
    if n_database is not None:
        return n_database
    largest = max((max(item) for item in lists if len(item)), default=-1)
    return int(largest) + 1


def load_ground_truth(
    path: str | Path, *, n_queries: int | None = None, n_database: int | None = None
) -> sparse.csr_array:
    """Read ground truth from a file in any supported format (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The file.
    n_queries, n_database : int, optional
        Expected shape. Required to size the matrix exactly for list formats; checked against the file.

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ground truth file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            array = np.load(path, allow_pickle=False)
        except ValueError as error:
            if "allow_pickle" not in str(error):
                raise
            from vpr_uncertainty.data.vprbench import load_vprbench_ground_truth

            positives = load_vprbench_ground_truth(path, n_database=n_database)
        else:
            positives = positives_from_mask(array)
    elif suffix == ".npz":
        with np.load(path, allow_pickle=False) as archive:
            if "positives_indptr" not in archive or "positives_indices" not in archive:
                raise ValueError(
                    f"{path} has no ground truth: expected arrays 'positives_indptr' and 'positives_indices', "
                    f"found {sorted(archive.files)}"
                )
            indptr = archive["positives_indptr"]
            indices = archive["positives_indices"]
            size = int(archive["n_database"]) if "n_database" in archive else n_database
        if size is None:
            size = int(indices.max()) + 1 if indices.size else 0
        data = np.ones(indices.size, dtype=bool)
        positives = sparse.csr_array((data, indices, indptr), shape=(len(indptr) - 1, size))
    elif suffix == ".json":
        content = json.loads(path.read_text())
        lists = content["positives"] if isinstance(content, dict) else content
        if not isinstance(lists, list) or not all(isinstance(item, list) for item in lists):
            raise ValueError(f"{path}: expected a JSON list of lists of database indices (one list per query)")
        positives = positives_from_lists(lists, _database_size(lists, n_database, path))
    elif suffix in {".txt", ".csv", ".tsv"}:
        positives = _from_text(path, n_database)
    else:
        raise ValueError(
            f"unknown ground truth format {suffix!r} for {path}; expected .npy (boolean mask or VPR-Bench), "
            ".npz, .json or .txt/.csv"
        )
    if n_queries is not None and positives.shape[0] != n_queries:
        raise ValueError(f"ground truth {path} has {positives.shape[0]} queries, expected {n_queries}")
    if n_database is not None and positives.shape[1] != n_database:
        raise ValueError(f"ground truth {path} covers {positives.shape[1]} database images, expected {n_database}")
    return positives
