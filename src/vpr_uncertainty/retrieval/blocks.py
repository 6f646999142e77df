"""Arrays read one block of rows at a time: descriptors on disk, and the top-k of a similarity matrix."""

from __future__ import annotations

import errno
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from vpr_uncertainty.retrieval.result import check_positive_int

#: Bytes of float32 descriptors per block when no block size is given (64 MiB: 65,536 rows of dimension 256).
DEFAULT_BLOCK_BYTES = 1 << 26


def default_block_rows(dimension: int) -> int:
    """Rows of float32 descriptors of ``dimension`` that fill :data:`DEFAULT_BLOCK_BYTES` (at least one).

    Examples
    --------
    >>> default_block_rows(256)
    65536
    """
    return max(1, DEFAULT_BLOCK_BYTES // (4 * max(int(dimension), 1)))


class DescriptorRows:
    """A (N, dim) descriptor array on disk (or in memory), read as float32 one range of rows at a time.

    Parameters
    ----------
    read : callable
        ``read(start, stop)`` returns rows ``start:stop`` (0 ≤ start ≤ stop ≤ N) as an array of any numeric dtype.
    shape : tuple of int
        (N, dim).
    source : str
        What the rows are, for messages (usually the file).
    """

    ndim = 2
    dtype = np.dtype(np.float32)

    def __init__(self, read: Callable[[int, int], np.ndarray], shape: tuple[int, int], *, source: str) -> None:
        if len(shape) != 2:
            raise ValueError(f"{source}: descriptors must be 2-D (n_images, dimension), got shape {tuple(shape)}")
        self._read = read
        self.shape = (int(shape[0]), int(shape[1]))
        self.source = source

    @classmethod
    def from_array(cls, array: np.ndarray, *, source: str = "array") -> DescriptorRows:
        """Rows of an array (a :class:`numpy.memmap` is sliced: the pages read stay mapped while it lives)."""
        array = np.asarray(array) if not isinstance(array, np.ndarray) else array
        return cls(lambda start, stop: array[start:stop], array.shape, source=source)

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return f"DescriptorRows({self.source}, shape={self.shape})"

    def read(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start:stop`` (clipped to the array) as a new float32 C-ordered array that the caller owns."""
        start, stop = max(int(start), 0), min(int(stop), self.shape[0])
        if stop <= start:
            return np.empty((0, self.shape[1]), dtype=np.float32)
        block = self._read(start, stop)
        if isinstance(block, np.memmap) or not block.flags.owndata:
            return np.array(block, dtype=np.float32, order="C")  # a view of the caller's array or of a mapping
        return np.require(block, np.float32, ["C_CONTIGUOUS", "WRITEABLE"])  # a new block: no second copy

    def row_blocks(self, rows: int | None = None) -> Iterator[np.ndarray]:
        """Consecutive blocks of ``rows`` rows (by default :func:`default_block_rows`), each a new float32 array."""
        rows = default_block_rows(self.shape[1]) if rows is None else int(rows)
        if rows < 1:
            raise ValueError(f"rows must be a positive integer, got {rows!r}")
        for start in range(0, self.shape[0], rows):
            yield self.read(start, start + rows)

    def to_array(self) -> np.ndarray:
        """All rows in memory, as a new float32 array."""
        return self.read(0, self.shape[0])

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        array = self.to_array()
        return array if dtype is None else array.astype(dtype, copy=False)


#: Matrix values per block (rows × columns) when the caller gives no block size: 4 M values, ~50 MB of work memory.
BLOCK_VALUES = 1 << 22


class MappedRows:
    """Row blocks of a C-ordered 2-D :class:`numpy.memmap`, each mapped on its own: read pages do not stay resident."""

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
    higher_is_better: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """The k largest values of each row of a (Q, D) numeric matrix and their columns, ``block_rows`` rows at a time.

    ``check_block(block, first_row)`` is called on every block (as float, as stored) and raises for values the caller
    rejects. Returns scores (Q, min(k, D)), float32 (float64 for float64 or wide integer input), and indices, int64,
    ``-1`` where the score is ``-inf``; ties go to the lower column. With ``higher_is_better=False`` (a distance
    matrix) the k smallest values are taken and returned negated, as similarities (``+inf``: no candidate).
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
        values, candidates = _top_k_block(block if higher_is_better else -block, k)
        scores[start : start + len(block)], indices[start : start + len(block)] = values, candidates
    indices[scores == -np.inf] = -1  # -inf = no candidate: the retrieval convention pairs it with index -1
    return scores, indices


def top_k_from_similarity(
    similarity: object, top_k: int, *, chunk_size: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The k most similar database images of each query from a full similarity matrix.

    Ties are broken by the lower database index, so the result does not depend on the sort algorithm. The matrix
    is processed in blocks of query rows (a :class:`numpy.memmap` is read block by block), so the work memory is
    one block plus the (Q × k) result.

    Parameters
    ----------
    similarity : array-like of shape (Q, D)
        Higher = more similar. NaN is rejected; ``-inf`` marks a database image that is no candidate for that
        query, and comes back with index -1.
    top_k : int
        Candidates per query; ``min(top_k, D)`` are returned.
    chunk_size : int, optional
        Queries processed at once, to bound memory; by default as many as hold about 4 M values.

    Returns
    -------
    scores : ndarray of shape (Q, min(top_k, D)), float32 (float64 for float64 input)
    indices : ndarray of shape (Q, min(top_k, D)), int64

    Examples
    --------
    >>> scores, indices = top_k_from_similarity(np.array([[0.1, 0.9, 0.9, 0.5]]), top_k=3)
    >>> scores, indices
    (array([[0.9, 0.9, 0.5]]), array([[1, 2, 3]]))
    """
    matrix = similarity if isinstance(similarity, np.ndarray) else np.asarray(similarity)
    if matrix.ndim != 2:
        raise ValueError(f"similarity must be 2-D (n_queries, n_database), got shape {matrix.shape}")
    if not (np.issubdtype(matrix.dtype, np.floating) or np.issubdtype(matrix.dtype, np.integer)):
        raise TypeError(f"similarity must be numeric, got dtype {matrix.dtype}")
    check_positive_int(top_k, "top_k")
    if chunk_size is not None and (isinstance(chunk_size, bool) or chunk_size < 1):
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    if matrix.shape[1] == 0:
        raise ValueError("similarity has no database columns")

    def check_block(block: np.ndarray, first_row: int) -> None:
        if np.isnan(block.max()):  # one pass, no temporary the size of the block unless there is a NaN
            row, col = np.argwhere(np.isnan(block))[0]
            raise ValueError(f"similarity contains NaN (first at query {first_row + row}, database image {col})")

    return top_k_blocks(matrix, top_k, block_rows=chunk_size, check_block=check_block)
