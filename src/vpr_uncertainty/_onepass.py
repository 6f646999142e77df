"""One pass over top-k scores, block by block in cache: the order check (NaN included) fused with a formula.

The score baselines and the numpy path of RS, SD and SU (:mod:`vpr_uncertainty.scores`) read every score once: a
block of rows is checked and then used while it is in cache, instead of one pass to validate and another to compute.
"""

from __future__ import annotations

import math

import numpy as np

from vpr_uncertainty._validation import check_block

__all__ = ["block_rows", "check_order", "rows_in_order", "scan"]

#: Scores per block of the fused passes: small enough for a block (and its comparison) to stay in cache.
_SCAN_ELEMENTS = 262_144


def block_rows(n_columns: int) -> int:
    return max(1, _SCAN_ELEMENTS // n_columns)


def rows_in_order(block: np.ndarray, buffer: np.ndarray) -> bool:
    """Whether every row of ``block`` (C-contiguous, >= 2 columns) is sorted descending and NaN-free.

    One comparison over the flattened block (NaN fails it) and one count; the comparisons across row boundaries are
    set to True instead of being counted apart (a strided count is slow). ``check_block`` words the error when this
    is False.
    """
    n_columns = block.shape[1]
    flat = block.ravel()
    in_order = np.less_equal(flat[1:], flat[:-1], out=buffer[: flat.size - 1])
    in_order[n_columns - 1 :: n_columns] = True
    return np.count_nonzero(in_order) == in_order.size


def check_order(block: np.ndarray, buffer: np.ndarray, offset: int) -> None:
    """Raise ``check_block``'s error for an unsorted or NaN row of ``block`` (first column: the caller checks +inf)."""
    if not rows_in_order(block, buffer):
        check_block(block, offset=offset, check_first_column=False)


def scan(scores: np.ndarray, compute) -> tuple[np.ndarray, float, float]:
    """One pass over ``scores`` (from ``as_score_array``, >= 1 row, >= 2 columns), block by block in cache: check
    the order of every row, then ``compute(block, out_block)`` while the block is in cache. Returns ``out`` and the
    smallest and largest of the values that ``compute`` returns (None: no values) for its range check.

    The order check is the only value check made here; NaN and unsorted rows raise ``check_block``'s message. The
    callers then check the few values their formula reads (±inf, range) on the result or on those extremes, and
    redo the whole input on the reference path when anything is unusual, so that its messages are raised unchanged.
    """
    n_rows, n_columns = scores.shape
    rows = block_rows(n_columns)
    buffer = np.empty(min(rows, n_rows) * n_columns, dtype=bool)
    out = np.empty(n_rows, dtype=scores.dtype)
    low, high = math.inf, -math.inf
    with np.errstate(all="ignore"):  # ±inf and overflow send the caller to the reference path
        for start in range(0, n_rows, rows):
            block = scores[start : start + rows]
            check_order(block, buffer, start)
            values = compute(block, out[start : start + rows])
            if values is not None:  # contiguous, so these reductions are cheap
                low, high = min(low, float(values.min())), max(high, float(values.max()))
    return out, low, high
