"""Retrieval results: the top-k database images of every query, and the retrieval file that stores them.

A :class:`Retrieval` is what every uncertainty method and the evaluation read. It is made from a full
similarity matrix (:func:`top_k_from_similarity`), from descriptors (Faiss search), or read back from a
retrieval file (:func:`load_retrieval`).

Retrieval file (``.npz``, no pickles), format version 1
    ``format_version``   int, 1
    ``scores``           (Q, K) float32, similarities sorted descending; ``-inf`` where a query has fewer than
                         K candidates
    ``indices``          (Q, K) int64, database index of each candidate; ``-1`` where missing
    ``distances``        (Q, K) float32, squared L2 distances of the candidates (optional)
    ``positives_indptr``, ``positives_indices``, ``n_database``
                         ground truth as a CSR matrix (optional)
    ``query_names``, ``database_names``          (Q,), (D,) unicode (optional)
    ``query_positions``, ``database_positions``  (Q, 2), (D, 2) float64 metres (optional)
    ``config``           JSON text describing what produced the file (optional)
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse

__all__ = ["FORMAT_VERSION", "Retrieval", "load_retrieval", "save_retrieval", "top_k_from_similarity"]

FORMAT_VERSION = 1


@dataclass
class Retrieval:
    """Top-k retrieval of Q queries against a database of D images.

    Attributes
    ----------
    scores : ndarray of shape (Q, K), float
        Similarities, higher = more similar, sorted descending; ``-inf`` marks a missing candidate.
    indices : ndarray of shape (Q, K), int64
        Database index of each candidate; ``-1`` marks a missing candidate.
    positives : scipy.sparse.csr_array of shape (Q, D), bool, optional
        Ground truth: the database images that are correct answers for each query.
    distances : ndarray of shape (Q, K), optional
        Squared L2 distances of the candidates, ascending.
    query_names, database_names : ndarray of str, optional
    query_positions, database_positions : ndarray of shape (Q, 2) and (D, 2), optional
        Positions in metres (e.g. UTM easting, northing).
    config : dict
        What produced this retrieval (method, dataset, k, ...), stored with the file.
    """

    scores: np.ndarray
    indices: np.ndarray
    positives: sparse.csr_array | None = None
    distances: np.ndarray | None = None
    query_names: np.ndarray | None = None
    database_names: np.ndarray | None = None
    query_positions: np.ndarray | None = None
    database_positions: np.ndarray | None = None
    config: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.scores = np.asarray(self.scores)
        self.indices = np.asarray(self.indices, dtype=np.int64)
        if self.scores.ndim != 2 or self.scores.shape != self.indices.shape:
            raise ValueError(
                f"scores and indices must both have shape (n_queries, k), got {self.scores.shape} and "
                f"{self.indices.shape}"
            )
        if self.distances is not None:
            self.distances = np.asarray(self.distances)
            if self.distances.shape != self.scores.shape:
                raise ValueError(f"distances must have shape {self.scores.shape}, got {self.distances.shape}")
        if self.positives is not None:
            self.positives = sparse.csr_array(self.positives, dtype=bool)
            if self.positives.shape[0] != self.n_queries:
                raise ValueError(f"positives has {self.positives.shape[0]} rows but there are {self.n_queries} queries")
            if self.indices.size and self.indices.max() >= self.positives.shape[1]:
                raise ValueError(
                    f"indices refer to database image {int(self.indices.max())} but the ground truth covers "
                    f"only {self.positives.shape[1]} database images"
                )
        for name, expected in (("query_names", self.n_queries), ("query_positions", self.n_queries)):
            value = getattr(self, name)
            if value is not None and len(value) != expected:
                raise ValueError(f"{name} has {len(value)} entries, expected {expected} (one per query)")

    @property
    def n_queries(self) -> int:
        return self.scores.shape[0]

    @property
    def k(self) -> int:
        """Number of candidates stored per query."""
        return self.scores.shape[1]


def top_k_from_similarity(similarity: object, k: int, *, chunk_size: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """The k most similar database images of each query from a full similarity matrix.

    Ties are broken by the lower database index, so the result does not depend on the sort algorithm.

    Parameters
    ----------
    similarity : array-like of shape (Q, D)
        Higher = more similar. NaN is rejected.
    k : int
        Candidates per query; ``min(k, D)`` are returned.
    chunk_size : int
        Queries processed at once, to bound memory.

    Returns
    -------
    scores : ndarray of shape (Q, min(k, D)), float32 (float64 for float64 input)
    indices : ndarray of shape (Q, min(k, D)), int64

    Examples
    --------
    >>> scores, indices = top_k_from_similarity(np.array([[0.1, 0.9, 0.9, 0.5]]), k=3)
    >>> scores, indices
    (array([[0.9, 0.9, 0.5]]), array([[1, 2, 3]]))
    """
    matrix = np.asarray(similarity)
    if matrix.ndim != 2:
        raise ValueError(f"similarity must be 2-D (n_queries, n_database), got shape {matrix.shape}")
    if not (np.issubdtype(matrix.dtype, np.floating) or np.issubdtype(matrix.dtype, np.integer)):
        raise TypeError(f"similarity must be numeric, got dtype {matrix.dtype}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"k must be a positive integer, got {k!r}")
    matrix = matrix.astype(np.result_type(matrix.dtype, np.float32), copy=False)
    n_queries, n_database = matrix.shape
    if n_database == 0:
        raise ValueError("similarity has no database columns")
    if np.isnan(matrix).any():
        row, col = np.argwhere(np.isnan(matrix))[0]
        raise ValueError(f"similarity contains NaN (first at query {row}, database image {col})")
    k = min(int(k), n_database)
    scores = np.empty((n_queries, k), dtype=matrix.dtype)
    indices = np.empty((n_queries, k), dtype=np.int64)
    for start in range(0, n_queries, chunk_size):
        block = matrix[start : start + chunk_size]
        if k < n_database:
            candidates = np.argpartition(-block, k - 1, axis=1)[:, :k]
        else:
            candidates = np.broadcast_to(np.arange(n_database), block.shape).copy()
        values = np.take_along_axis(block, candidates, axis=1)
        # Order by value descending, then index ascending (lexsort: last key is primary).
        order = np.lexsort((candidates, -values), axis=1)
        candidates = np.take_along_axis(candidates, order, axis=1)
        values = np.take_along_axis(values, order, axis=1)
        # argpartition picks an arbitrary subset of the values tied at the k-th place: redo those rows.
        kth = values[:, -1:]
        tied_rows = np.flatnonzero((block == kth).sum(axis=1) > (values == kth).sum(axis=1))
        for row in tied_rows:
            full_order = np.lexsort((np.arange(n_database), -block[row]))[:k]
            candidates[row] = full_order
            values[row] = block[row, full_order]
        scores[start : start + len(block)] = values
        indices[start : start + len(block)] = candidates
    return scores, indices


def _optional(archive: Any, key: str) -> np.ndarray | None:
    return archive[key] if key in archive.files else None


def save_retrieval(retrieval: Retrieval, path: str | Path) -> Path:
    """Write a retrieval file (see the module docstring for the layout) and return its path."""
    path = Path(path)
    arrays: dict[str, Any] = {
        "format_version": np.array(FORMAT_VERSION),
        "scores": retrieval.scores.astype(np.float32, copy=False),
        "indices": retrieval.indices,
        "config": np.array(json.dumps(retrieval.config, sort_keys=True)),
    }
    if retrieval.distances is not None:
        arrays["distances"] = retrieval.distances.astype(np.float32, copy=False)
    if retrieval.positives is not None:
        positives = retrieval.positives
        arrays["positives_indptr"] = positives.indptr.astype(np.int64)
        arrays["positives_indices"] = positives.indices.astype(np.int64)
        arrays["n_database"] = np.array(positives.shape[1])
    for name in ("query_names", "database_names"):
        value = getattr(retrieval, name)
        if value is not None:
            arrays[name] = np.asarray(value, dtype=str)
    for name in ("query_positions", "database_positions"):
        value = getattr(retrieval, name)
        if value is not None:
            arrays[name] = np.asarray(value, dtype=np.float64)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as handle:
        np.savez_compressed(handle, **arrays)
    return path


def load_retrieval(path: str | Path) -> Retrieval:
    """Read a retrieval file written by :func:`save_retrieval` (or any ``.npz`` with ``scores``, ``indices``)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"retrieval file not found: {path}")
    with np.load(path, allow_pickle=False) as archive:
        missing = {"scores", "indices"} - set(archive.files)
        if missing:
            raise ValueError(
                f"{path} is not a retrieval file: missing {sorted(missing)} (found {sorted(archive.files)})"
            )
        version = int(archive["format_version"]) if "format_version" in archive.files else FORMAT_VERSION
        if version > FORMAT_VERSION:
            raise ValueError(
                f"{path} has retrieval format version {version}; this toolkit reads up to {FORMAT_VERSION}. "
                "Upgrade vpr-uncertainty."
            )
        positives = None
        if "positives_indptr" in archive.files:
            indices = archive["positives_indices"]
            n_database = int(archive["n_database"]) if "n_database" in archive.files else int(indices.max()) + 1
            positives = sparse.csr_array(
                (np.ones(indices.size, dtype=bool), indices, archive["positives_indptr"]),
                shape=(len(archive["positives_indptr"]) - 1, n_database),
            )
        config = json.loads(str(archive["config"])) if "config" in archive.files else {}
        return Retrieval(
            scores=archive["scores"],
            indices=archive["indices"],
            positives=positives,
            distances=_optional(archive, "distances"),
            query_names=_optional(archive, "query_names"),
            database_names=_optional(archive, "database_names"),
            query_positions=_optional(archive, "query_positions"),
            database_positions=_optional(archive, "database_positions"),
            config=config,
        )
