"""One pass over top-k scores, block by block in cache: the order check (NaN included) fused with a formula.

The score baselines and the numpy path of RS, SD and SU (:mod:`vpr_uncertainty.scores`) read every score once: a
block of rows is checked and then used while it is in cache, instead of one pass to validate and another to compute.
"""

from __future__ import annotations

import math

import numpy as np

from vpr_uncertainty._validation import check_block

__all__ = ["scan"]

#: Scores per block of the fused passes: small enough for a block (and its comparison) to stay in cache.
_SCAN_ELEMENTS = 262_144


def scan(scores: np.ndarray, compute, dtype: np.dtype | None = None) -> tuple[np.ndarray, float, float]:
    """One pass over ``scores`` (from ``as_score_array``, >= 1 row, >= 2 columns), block by block in cache: check
    the order of every row, then ``compute(block, out_block)`` while the block is in cache. Returns ``out`` (of
    ``dtype``, by default that of ``scores``) and the smallest and largest of the values that ``compute`` returns
    (None: no values) for its range check.

    The order check is the only value check made here; NaN and unsorted rows raise ``check_block``'s message. The
    callers then check the few values their formula reads (±inf, range) on the result or on those extremes, and
    redo the whole input on the reference path when anything is unusual, so that its messages are raised unchanged.
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
