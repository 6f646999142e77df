"""The ground truth a :class:`~vpr_uncertainty.retrieval.Retrieval` accepts, turned into one sparse matrix.

``Retrieval(positives=...)`` takes what users have at hand:

* a list (or tuple, or 1-D object array) of positive database indices per query, e.g. ``[[0, 4], [], [7]]``:
  the form of VPR-methods-evaluation's ``get_positives()`` and of most datasets' ground-truth files;
* a boolean (Q × D) mask, a NumPy array (0/1 numbers are accepted, nothing else) or a list of lists of booleans;
* a SciPy sparse matrix or array of shape (Q × D) (boolean or 0/1).

With lists, the number of database images D is taken from ``database_names`` or ``database_positions`` when the
retrieval has them; otherwise it is the smallest size that holds every positive and every retrieved index.
Each problem is one ``ValueError`` that names ``positives``, the query and the value, never the whole ground truth.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from scipy import sparse

from vpr_uncertainty.data.ground_truth import positives_from_lists, positives_from_mask

__all__ = ["coerce_positives"]

_EXPECTED = (
    "a list of positive database indices per query (e.g. [[0, 4], [], [7]]), a boolean (n_queries, n_database) "
    "mask or a scipy sparse matrix"
)


def _is_boolean_rows(rows: list[object]) -> bool:
    """A list of non-empty lists of booleans: a mask written as Python lists."""
    return bool(rows) and all(
        isinstance(row, (list, tuple)) and len(row) > 0 and all(isinstance(x, (bool, np.bool_)) for x in row)
        for row in rows
    )


def _from_sparse(value: object) -> sparse.csr_array:
    matrix = sparse.csr_array(value)
    if matrix.ndim != 2:
        raise ValueError(f"positives must be 2-D (n_queries, n_database), got shape {matrix.shape}")
    if matrix.dtype != bool:
        if matrix.dtype.kind not in "iuf" or not np.isin(matrix.data, (0, 1)).all():
            raise ValueError(
                f"positives is a sparse matrix of dtype {matrix.dtype}; expected booleans (or 0/1), got values "
                f"{np.unique(matrix.data)[:5].tolist()}"
            )
        matrix = matrix.astype(bool)
        matrix.eliminate_zeros()
    return matrix


def coerce_positives(value: object, *, n_database: int | None, indices: np.ndarray) -> sparse.csr_array:
    """``positives`` in any accepted form (see the module docstring) as a boolean ``csr_array``.

    Parameters
    ----------
    value : list of lists of int, array-like of bool of shape (Q, D), or scipy sparse matrix
        The ground truth.
    n_database : int, optional
        The database size when the retrieval knows it (its names or positions); sizes the matrix built from lists.
    indices : ndarray of shape (Q, K), int64
        The retrieved database indices (``-1`` for none): lists without a known database size cover them too.

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool

    Raises
    ------
    ValueError
        Naming ``positives``, the query and the value at fault.
    """
    if sparse.issparse(value):
        return _from_sparse(value)
    if isinstance(value, np.ndarray) and value.dtype != object:
        if value.ndim != 2:
            raise ValueError(f"positives must be {_EXPECTED}; got an array of shape {value.shape}")
        return positives_from_mask(value, source="positives")
    if isinstance(value, (str, bytes, dict)) or not isinstance(value, Iterable):
        raise ValueError(f"positives must be {_EXPECTED}; got {type(value).__name__}")
    rows = list(value)
    if _is_boolean_rows(rows):
        widths = {len(row) for row in rows}
        if len(widths) > 1:
            raise ValueError(f"positives as a boolean mask needs rows of one length, got lengths {sorted(widths)}")
        return positives_from_mask(np.array(rows, dtype=bool), source="positives")
    try:
        lists = positives_from_lists(rows, n_database=n_database)
    except ValueError as error:
        raise ValueError(f"{error} (positives must be {_EXPECTED})") from None
    if n_database is None:
        largest = int(lists.indices.max()) if lists.nnz else -1
        if indices.size:
            largest = max(largest, int(indices.max()))
        n_database = largest + 1
        lists = sparse.csr_array((lists.data, lists.indices, lists.indptr), shape=(lists.shape[0], n_database))
    return lists
