"""Input checks shared by the metric functions.

Every check raises with a message that names the argument, what was found and what was expected.
"""

from __future__ import annotations

import numbers

import numpy as np

__all__ = ["check_alpha", "check_k", "check_top_k_scores"]


def check_k(k: object, *, name: str = "k") -> int:
    """Return ``k`` as an int after checking that it is an integer >= 2."""
    if isinstance(k, bool) or not isinstance(k, numbers.Integral):
        raise TypeError(f"{name} must be an integer >= 2, got {k!r} of type {type(k).__name__}")
    if k < 2:
        raise ValueError(f"{name} must be >= 2 (the metrics compare the best match with its runners-up), got {k}")
    return int(k)


def check_alpha(alpha: object) -> float:
    """Return ``alpha`` as a float after checking that it lies in [0, 1]."""
    if isinstance(alpha, bool) or not isinstance(alpha, numbers.Real):
        raise TypeError(f"alpha must be a real number in [0, 1], got {alpha!r} of type {type(alpha).__name__}")
    alpha = float(alpha)
    if not 0.0 <= alpha <= 1.0:  # also rejects NaN
        raise ValueError(f"alpha must lie in [0, 1], got {alpha}")
    return alpha


def _first_bad_row(scores: np.ndarray) -> tuple[int, int]:
    """Locate the first (row, column) whose value breaks the descending order (slow; errors only)."""
    bad = ~(scores[:, 1:] <= scores[:, :-1])
    row, col = np.argwhere(bad)[0]
    return int(row), int(col) + 1


def check_top_k_scores(scores: object, *, name: str = "scores", sort: bool = False) -> np.ndarray:
    """Validate top-k similarity scores and return them as a C-contiguous float array.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Similarities, higher = more similar, one row per query, sorted in descending order along axis 1.
        ``-inf`` marks a missing candidate (a query with fewer than K retrieved images) and must come after
        every finite value of its row.
    name : str
        Name of the argument, used in error messages.
    sort : bool
        Sort each row in descending order instead of rejecting unsorted rows. The input is not modified.

    Returns
    -------
    ndarray of shape (Q, K)
        float32 for float32 input (and small integers), float64 otherwise.

    Raises
    ------
    ValueError
        For a wrong number of dimensions, no columns, NaN or +inf, or rows that are not sorted.
    """
    array = np.asarray(scores)
    if array.dtype == object or not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise TypeError(f"{name} must be a numeric array, got dtype {array.dtype}")
    if array.ndim != 2:
        raise ValueError(
            f"{name} must be 2-D with shape (n_queries, k) (one row of top-k similarities per query), "
            f"got {array.ndim}-D with shape {array.shape}"
        )
    if array.shape[1] == 0:
        raise ValueError(f"{name} must have at least 2 columns (candidates per query), got shape {array.shape}")
    dtype = np.result_type(array.dtype, np.float32)
    if sort:
        if np.isnan(array).any():
            row = int(np.argwhere(np.isnan(array))[0, 0])
            raise ValueError(f"{name} contains NaN (first in row {row}); expected finite similarities")
        array = -np.sort(-array.astype(dtype, copy=False), axis=1)
    array = np.ascontiguousarray(array, dtype=dtype)
    n_queries, n_columns = array.shape
    if n_queries == 0:
        return array
    if n_columns == 1 and np.isnan(array).any():
        row = int(np.argwhere(np.isnan(array))[0, 0])
        raise ValueError(f"{name} contains NaN (first in row {row}); expected finite similarities")
    # One contiguous comparison over the flattened array checks the order of every row at once;
    # comparisons across row boundaries are masked. NaN fails every comparison, so it is caught here too.
    flat = array.ravel()
    in_order = flat[1:] <= flat[:-1]
    in_order[n_columns - 1 :: n_columns] = True
    if not in_order.all():
        if np.isnan(array).any():
            row = int(np.argwhere(np.isnan(array))[0, 0])
            raise ValueError(f"{name} contains NaN (first in row {row}); expected finite similarities")
        row, col = _first_bad_row(array)
        raise ValueError(
            f"{name} must be sorted in descending order along axis 1, but row {row} has "
            f"{array[row, col - 1]!r} before {array[row, col]!r}; pass sort=True to sort it for you"
        )
    # Sorted and NaN-free: +inf can only sit in the first column and -inf in the last.
    if np.isposinf(array[:, 0]).any():
        row = int(np.flatnonzero(np.isposinf(array[:, 0]))[0])
        raise ValueError(f"{name} contains +inf (first in row {row}); expected finite similarities")
    return array
