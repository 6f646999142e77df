"""Top-k of a similarity matrix, one block of query rows at a time.

The matrix may be a :class:`numpy.memmap` larger than memory: each block of rows is read (and converted to float)
on its own, checked by the caller's ``check_block``, and cut to its top-k, so peak memory is the (Q × k) result
plus one block, never a multiple of the matrix. The block is partitioned in place of a negated copy
(``argpartition`` at ``D − k``), and rows where ``argpartition`` cut through values tied at the k-th place are
re-sorted whole, so ties always go to the lower database index.
"""

from __future__ import annotations

import errno
from collections.abc import Callable

import numpy as np

__all__ = ["BLOCK_VALUES", "MappedRows", "top_k_blocks"]

#: Matrix values per block (rows × columns) when the caller gives no block size: 4 M values, ~50 MB of work memory.
BLOCK_VALUES = 1 << 22


class MappedRows:
    """Row blocks of a C-ordered :class:`numpy.memmap`, each mapped on its own and unmapped when dropped.

    Pages of one long-lived mapping stay resident once read, so a pass over a whole memmap ends with the file in
    the process's resident memory; mapping each block separately keeps it at one block.

    Parameters
    ----------
    matrix : numpy.memmap
        A 2-D, C-ordered memmap (as :func:`vpr_uncertainty.data.npy.read_npy` returns with ``mmap=True``).
    """

    def __init__(self, matrix: np.memmap) -> None:
        if matrix.ndim != 2 or not matrix.flags.c_contiguous or matrix.filename is None:
            raise ValueError("MappedRows needs a 2-D C-ordered memmap of a file")
        self.filename, self.offset = matrix.filename, int(matrix.offset)
        self.shape, self.dtype = tuple(matrix.shape), matrix.dtype

    def __getitem__(self, rows: slice) -> np.ndarray:
        start, stop, step = rows.indices(self.shape[0])
        if step != 1:
            raise ValueError("MappedRows reads contiguous row blocks only")
        row_bytes = self.shape[1] * self.dtype.itemsize
        try:
            return np.memmap(
                self.filename,
                dtype=self.dtype,
                mode="r",
                offset=self.offset + start * row_bytes,
                shape=(max(stop - start, 0), self.shape[1]),
            )
        except OSError as error:
            if error.errno != errno.ENOMEM:
                raise
            raise MemoryError(
                f"{self.filename}: cannot map rows {start}–{stop - 1} ({(stop - start) * row_bytes / 2**20:.0f} MiB) "
                f"([Errno {error.errno}] {error.strerror}); read it in smaller blocks (block_rows) or raise this "
                "process's address-space limit (ulimit -v)"
            ) from error


def _top_k_block(block: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    n_database = block.shape[1]
    if k < n_database:
        candidates = np.argpartition(block, n_database - k, axis=1)[:, n_database - k :]
    else:
        candidates = np.broadcast_to(np.arange(n_database), block.shape).copy()
    values = np.take_along_axis(block, candidates, axis=1)
    # Order by value descending, then index ascending (lexsort: last key is primary).
    order = np.lexsort((candidates, -values), axis=1)
    candidates = np.take_along_axis(candidates, order, axis=1)
    values = np.take_along_axis(values, order, axis=1)
    if k < n_database:
        # argpartition picks an arbitrary subset of the values tied at the k-th place: redo those rows.
        kth = values[:, -1:]
        tied_rows = np.flatnonzero((block == kth).sum(axis=1) > (values == kth).sum(axis=1))
        for row in tied_rows:
            full_order = np.lexsort((np.arange(n_database), -block[row]))[:k]
            candidates[row] = full_order
            values[row] = block[row, full_order]
    return values, candidates


def top_k_blocks(
    matrix: np.ndarray | MappedRows,
    k: int,
    *,
    block_rows: int | None = None,
    check_block: Callable[[np.ndarray, int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The k largest values of each row of a 2-D numeric matrix, with their column indices, block by block.

    Parameters
    ----------
    matrix : ndarray, memmap or MappedRows of shape (Q, D), D ≥ 1
        Integers or floats, already checked for shape and dtype by the caller.
    k : int
        Positive; ``min(k, D)`` are returned.
    block_rows : int, optional
        Rows read at once; by default as many as hold about :data:`BLOCK_VALUES` values.
    check_block : callable, optional
        Called as ``check_block(block, first_row)`` on every block (converted to float) before it is used; it
        raises for values the caller rejects (NaN, +inf), naming the row ``first_row + i``.

    Returns
    -------
    scores : ndarray of shape (Q, min(k, D)), float32 (float64 for float64 or wide integer input)
    indices : ndarray of shape (Q, min(k, D)), int64; -1 where the score is -inf (no candidate)
    """
    if block_rows is not None and (isinstance(block_rows, bool) or int(block_rows) < 1):
        raise ValueError(f"block_rows must be a positive integer, got {block_rows!r}")
    n_queries, n_database = matrix.shape
    dtype = np.result_type(matrix.dtype, np.float32)
    k = min(int(k), n_database)
    rows = max(1, BLOCK_VALUES // n_database) if block_rows is None else int(block_rows)
    scores = np.empty((n_queries, k), dtype=dtype)
    indices = np.empty((n_queries, k), dtype=np.int64)
    for start in range(0, n_queries, rows):
        block = np.asarray(matrix[start : start + rows], dtype=dtype)  # reads only these rows of a memmap
        if check_block is not None:
            check_block(block, start)
        values, candidates = _top_k_block(block, k)
        scores[start : start + len(block)] = values
        indices[start : start + len(block)] = candidates
    indices[scores == -np.inf] = -1  # -inf = no candidate: the retrieval convention pairs it with index -1
    return scores, indices
