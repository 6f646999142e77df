"""Exact descriptor search over a database read one block of rows at a time (databases larger than memory).

The database (a :class:`~vpr_uncertainty.retrieval.descriptor_rows.DescriptorRows`: a memory-mapped ``.npy``, the
HDF5 descriptor cache, or an array) is read twice, block by block, and never whole:

1. **Norms.** The squared norm of every row (Faiss's ``fvec_norms_L2sqr``, as the in-memory search computes
   them), checked for NaN, infinite and all-zero rows with the same errors, naming the row. As in memory, the
   rows are normalised only when some row's squared norm is farther than 1e-5 from 1 (then all rows are).
2. **Search.** Each block is read, normalised (Faiss's ``normalize_L2``: row by row, so a block gives the very
   same values as the whole array) and searched exhaustively by inner product against every batch of queries
   (``faiss.knn_inner_product``, the kernel of the in-memory exact search). Each block's top-k is made exact
   under the project's order (score descending, then database index ascending: a tie straddling the k-th place
   of the block is settled by searching that block deeper) and merged into the running top-k of each query by
   the same order. Since every block's list is exact under a total order, the merge is exact: the result equals
   the in-memory search in indices, and in scores up to float32 rounding of the inner products.

Peak memory: the queries, the (Q × k) result, one block of the database, and Faiss's work buffers of one
(batch × block) search; never the database.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vpr_uncertainty.retrieval._faiss import Searcher
from vpr_uncertainty.retrieval.descriptor_rows import DescriptorRows
from vpr_uncertainty.retrieval.search import (
    UNIT_NORM_TOLERANCE,
    _check_nonzero,
    _check_norms,
    _ordered,
    _settle_ties,
)

__all__ = ["as_rows", "search_blocks"]


def as_rows(database: object) -> DescriptorRows:
    """A DescriptorRows of the database: itself, or a checked numeric 2-D array (a memmap read block by block)."""
    if isinstance(database, DescriptorRows):
        rows = database
    else:
        from vpr_uncertainty.retrieval.search import _checked_array

        rows = DescriptorRows.from_array(_checked_array(database, "database"), source="database")
    if rows.shape[1] == 0:
        raise ValueError("database has dimension 0; descriptors need at least one component")
    return rows


def database_norms(rows: DescriptorRows, block: int, faiss: Any) -> np.ndarray:
    """Squared norms (float32) of every row, read block by block; bad rows raise as in the in-memory search."""
    squared = np.empty(len(rows), dtype=np.float32)
    for start in range(0, len(rows), block):
        data = rows.read(start, start + block)
        part = squared[start : start + len(data)]
        faiss.fvec_norms_L2sqr(faiss.swig_ptr(part), faiss.swig_ptr(data), data.shape[1], len(data))
        _check_norms(part, data, "database", first_row=start)
        del data  # before the next block is read: one block in memory at a time
    _check_nonzero(squared, "database")
    return squared


def _merge(
    scores: np.ndarray, indices: np.ndarray, new_scores: np.ndarray, new_indices: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The first ``scores.shape[1]`` of two candidate lists by score descending, then database index ascending."""
    kept = scores.shape[1]
    both_scores = np.concatenate([scores, new_scores], axis=1)
    both_indices = np.concatenate([indices, new_indices], axis=1)
    missing = both_indices < 0
    order = np.lexsort((np.where(missing, np.iinfo(np.int64).max, both_indices), -both_scores), axis=1)[:, :kept]
    return np.take_along_axis(both_scores, order, axis=1), np.take_along_axis(both_indices, order, axis=1)


def _block_top_k(searcher: Searcher, batch: np.ndarray, kept: int, n_block: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact top-``min(kept, n_block)`` of one block for a batch of queries, ties to the lower index."""
    depth = min(kept + 1, n_block)  # one more than kept reveals a tie across the kept-th place
    scores, indices = _ordered(*searcher.search(batch, depth))
    if depth > kept:
        tied = np.flatnonzero((indices[:, kept] >= 0) & (scores[:, kept - 1] == scores[:, kept]))
        if tied.size:
            settled_scores, settled_indices = _settle_ties(searcher, batch[tied], kept, n_block)
            scores[tied, :kept] = settled_scores
            indices[tied, :kept] = settled_indices
    width = min(kept, n_block)
    return scores[:, :width], indices[:, :width]


def search_blocks(
    rows: DescriptorRows,
    queries: np.ndarray,
    k: int,
    *,
    block: int,
    batch_size: int,
    faiss: Any,
    progress: bool | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact top-k (cosine) of each query among the database rows, reading ``block`` rows at a time.

    Parameters
    ----------
    rows : DescriptorRows of shape (D, dim), D ≥ 1
    queries : ndarray of shape (Q, dim), float32, L2-normalised
    k : int
    block : int
        Database rows read, normalised and searched at once.
    batch_size : int
        Queries searched at once against each block.
    faiss : module
    progress : bool, optional

    Returns
    -------
    scores : ndarray of shape (Q, min(k, D)), float32
        Sorted descending, ties ordered by lower database index.
    indices : ndarray of shape (Q, min(k, D)), int64
    """
    from vpr_uncertainty.progress import progress_bar

    n_database = len(rows)
    squared = database_norms(rows, block, faiss)
    normalise = bool(np.abs(squared - 1).max() > UNIT_NORM_TOLERANCE)
    del squared
    kept = min(k, n_database)
    scores = np.full((len(queries), kept), -np.inf, dtype=np.float32)
    indices = np.full((len(queries), kept), -1, dtype=np.int64)
    with progress_bar(total=n_database, desc="retrieval", unit="descriptor", enabled=progress) as bar:
        for start in range(0, n_database, block):
            data = rows.read(start, start + block)
            if normalise:
                faiss.normalize_L2(data)
            searcher = Searcher(data, "Flat", "cpu", None, faiss)
            for first in range(0, len(queries), batch_size):
                batch = queries[first : first + batch_size]
                block_scores, block_indices = _block_top_k(searcher, batch, kept, len(data))
                block_indices = np.where(block_indices >= 0, block_indices + start, -1)  # database numbering
                stop = first + len(batch)
                scores[first:stop], indices[first:stop] = _merge(
                    scores[first:stop], indices[first:stop], block_scores, block_indices
                )
            bar.update(len(data))
            del data, searcher
    return scores, indices
