"""Input checks of the metric functions; each message names the argument, what was found and what was expected."""

from __future__ import annotations

import difflib
import math
import numbers
from collections.abc import Iterable

import numpy as np


def did_you_mean(name: object, valid: Iterable[str]) -> str:
    """``"did you mean 'X'? "`` for the valid name nearest to ``name``, case aside, or ``""`` when none is near."""
    lower = {known.lower(): known for known in valid}
    close = difflib.get_close_matches(str(name).lower(), list(lower), n=1, cutoff=0.6)
    return f"did you mean {lower[close[0]]!r}? " if close else ""


def check_k(k: object, *, name: str = "k") -> int:
    """Return ``k`` as an int after checking that it is an integer >= 2."""
    if isinstance(k, bool) or not isinstance(k, numbers.Integral):
        raise TypeError(f"{name} must be an integer >= 2, got {k!r} of type {type(k).__name__}")
    if k < 2:
        raise ValueError(f"{name} must be >= 2 (the metrics compare the best match with its runners-up), got {k}")
    return int(k)


def check_count(value: object, name: str, minimum: int) -> int:
    """Return ``value`` as an int after checking that it is an integer (not a bool) >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_resamples(n_resamples: object, name: str = "n_resamples", confidence: float = 0.95) -> int:
    """``n_resamples`` as an int, refused (naming ``name``) below 2 / (1 - confidence) resamples, 40 at 95 %: fewer
    leave a tail of the percentile interval without a resample, and the paired p-value (>= 2 / (B + 1)) could
    never fall below 1 - confidence."""
    n_resamples = check_count(n_resamples, name, 1)
    if n_resamples < (smallest := math.ceil(round(2 / (1 - confidence), 9))):
        raise ValueError(
            f"{n_resamples} bootstrap resamples (argument {name}) are too few: the {confidence:.0%} interval needs a "
            f"resample in each tail, and the p-value, at least 2/(resamples + 1), must be able to fall below "
            f"{1 - confidence:.2g}; use at least {smallest} (1000 is usual)"
        )
    return n_resamples


def check_fraction(value: object, name: str) -> float:
    """Return ``value`` as a float after checking that it is a real number (not a bool) in [0, 1]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number in [0, 1], got {value!r} of type {type(value).__name__}")
    if not 0.0 <= float(value) <= 1.0:  # also rejects NaN
        raise ValueError(f"{name} must lie in [0, 1], got {value}")
    return float(value)


#: Rows validated (and, in the metrics, computed) at once: small enough for the block to stay in cache.
BLOCK_ROWS = 65536


def as_score_array(scores: object, *, name: str = "scores", sort: bool = False) -> np.ndarray:
    """Check type and shape of top-k scores and return a C-contiguous float array (values not yet checked).

    See :func:`check_top_k_scores` for the parameters; ``sort=True`` sorts each row in descending order.
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
        _raise_for_nan(array, name, 0)
        array = -np.sort(-array.astype(dtype, copy=False), axis=1)
    return np.ascontiguousarray(array, dtype=dtype)


def _raise_for_nan(block: np.ndarray, name: str, offset: int) -> None:
    nan = np.isnan(block)
    if nan.any():
        row = offset + int(np.argwhere(nan)[0, 0])
        raise ValueError(f"{name} contains NaN (first in row {row}); expected finite similarities")


def check_block(
    block: np.ndarray,
    *,
    name: str = "scores",
    offset: int = 0,
    check_first_column: bool = True,
    buffer: np.ndarray | None = None,
) -> None:
    """Check the values of rows ``offset ...`` of top-k scores: descending order, no NaN, no +inf.

    ``block`` must come from :func:`as_score_array`. ``-inf`` (a missing candidate) is allowed after the finite
    values of a row. With ``check_first_column=False`` the caller checks the first column for +inf itself
    (with :func:`check_best_scores`), which is faster on a contiguous copy of it. ``buffer``, a boolean array of
    at least ``block.size`` elements, is reused for the comparison instead of allocating one per block.
    """
    n_rows, n_columns = block.shape
    if n_rows == 0:
        return
    if n_columns > 1:
        # One contiguous comparison over the flattened block checks the order of every row (NaN fails it); the
        # comparisons across row boundaries are set to True instead of being counted apart (a strided count is slow).
        flat = block.ravel()
        in_order = np.less_equal(flat[1:], flat[:-1], out=None if buffer is None else buffer[: flat.size - 1])
        in_order[n_columns - 1 :: n_columns] = True
        if np.count_nonzero(in_order) != in_order.size:
            _raise_for_nan(block, name, offset)
            bad = ~(block[:, 1:] <= block[:, :-1])
            row, col = np.argwhere(bad)[0]
            raise ValueError(
                f"{name} must be sorted in descending order in each row, but row {offset + row} has "
                f"{float(block[row, col]):g} before {float(block[row, col + 1]):g}; sort each row best first (in "
                "Python, the score functions' sort=True does it)"
            )
    else:
        _raise_for_nan(block, name, offset)
    if check_first_column:
        check_best_scores(block[:, 0], name=name, offset=offset)


def check_best_scores(best: np.ndarray, *, name: str = "scores", offset: int = 0) -> None:
    """Reject +inf in the first column of sorted, NaN-free scores (the only place +inf can then sit)."""
    if best.size and best.max() == np.inf:
        row = offset + int(np.flatnonzero(best == np.inf)[0])
        raise ValueError(f"{name} contains +inf (first in row {row}); expected finite similarities")


def check_top_k_scores(scores: object, *, name: str = "scores", sort: bool = False) -> np.ndarray:
    """Top-k similarity scores (Q, K), sorted descending per row (``-inf``, a missing candidate, after every finite
    value), as a C-contiguous array: float32 for float32 input (and small integers), float64 otherwise.

    ``sort`` sorts a copy's rows instead of rejecting unsorted ones. A TypeError for non-numeric input, a ValueError
    naming ``name`` for a wrong number of dimensions, no columns, NaN or +inf, or unsorted rows.
    """
    array = as_score_array(scores, name=name, sort=sort)
    check_rows(array, name=name)
    return array


def check_rows(array: np.ndarray, *, name: str = "scores", check_first_column: bool = True) -> None:
    """:func:`check_block` over every block of rows of ``array`` (from :func:`as_score_array`), one buffer reused."""
    rows = min(BLOCK_ROWS, array.shape[0])
    buffer = np.empty(rows * array.shape[1], dtype=bool) if rows else None
    for start in range(0, array.shape[0], BLOCK_ROWS):
        block = array[start : start + BLOCK_ROWS]
        check_block(block, name=name, offset=start, check_first_column=check_first_column, buffer=buffer)


def raise_for_short_rows(n_candidates: np.ndarray, needed: int = 2) -> None:
    """Raise for rows with fewer than ``needed`` finite candidates, naming the first of them."""
    short = np.flatnonzero(n_candidates < needed)
    if short.size:
        shown = ", ".join(str(r) for r in short[:5]) + (", ..." if short.size > 5 else "")
        what = "its best match" if needed == 1 else "its best match and at least one runner-up"
        raise ValueError(
            f"scores has {short.size} row(s) with fewer than {needed} candidates (rows {shown}); each query "
            f"needs {what} (-inf marks a missing candidate)"
        )


#: Scores per block of the fused passes (:func:`scan`): small enough for a block (and its comparison) to stay in cache.
_SCAN_ELEMENTS = 262_144


def scan(scores: np.ndarray, compute, dtype: np.dtype | None = None) -> tuple[np.ndarray, float, float]:
    """One pass over ``scores`` (from ``as_score_array``, >= 1 row, >= 2 columns), block by block in cache: check
    the order of every row, then ``compute(block, out_block)`` while the block is in cache. Returns ``out`` (of
    ``dtype``, by default that of ``scores``) and the smallest and largest of the values that ``compute`` returns
    (None: no values) for its range check.

    The score baselines and the numpy path of RS, SD and SU (:mod:`vpr_uncertainty.scores`) read every score once
    this way, instead of one pass to validate and another to compute. The order check is the only value check made
    here; NaN and unsorted rows raise ``check_block``'s message. The callers then check the few values their formula
    reads (±inf, range) on the result or on those extremes, and redo the whole input on the reference path when
    anything is unusual, so that its messages are raised unchanged.
    """
    n_rows, n_columns = scores.shape
    rows = max(1, _SCAN_ELEMENTS // n_columns)
    buffer = np.empty(min(rows, n_rows) * n_columns, dtype=bool)
    out = np.empty(n_rows, dtype=scores.dtype if dtype is None else dtype)
    low, high = math.inf, -math.inf
    with np.errstate(all="ignore"):  # ±inf and overflow send the caller to the reference path
        for start in range(0, n_rows, rows):
            block = scores[start : start + rows]
            check_block(block, offset=start, check_first_column=False, buffer=buffer)
            values = compute(block, out[start : start + rows])
            if values is not None:  # contiguous, so these reductions are cheap
                low, high = min(low, float(values.min())), max(high, float(values.max()))
    return out, low, high
