"""The numba kernel behind :mod:`vpr_uncertainty._fast`; importing this module imports numba (ImportError without)."""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["ratio_kernel"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def ratio_kernel(scores, n, rs_weight, sd_weight, most_uncertain, out):  # pragma: no cover - compiled
    """Write (rs_weight·RS + sd_weight·SD) of every row of ``scores`` (sorted descending) into ``out``.

    Returns 0, or 1 + the first row the kernel does not score (NaN, unsorted, +inf, fewer than 2 candidates among
    the first ``n``, s_1 <= 0 when not ``most_uncertain``, a result that overflows ``out``'s dtype).
    """
    n_rows, n_columns = scores.shape
    for q in range(n_rows):
        best = scores[q, 0]
        ok = best < math.inf  # also False for NaN
        previous = best
        total = 0.0
        for j in range(1, n):
            value = scores[q, j]
            ok &= value <= previous  # False for NaN
            total += value
            previous = value
        for j in range(n, n_columns):  # the columns after the first n must be sorted too
            value = scores[q, j]
            ok &= value <= previous
            previous = value
        if not ok:
            return q + 1
        count = n
        if scores[q, n - 1] == -math.inf:  # missing candidates: score the finite ones
            count = 0
            total = 0.0
            for j in range(n):
                if scores[q, j] == -math.inf:
                    break
                count += 1
                total += scores[q, j]
            if count < 2:
                return q + 1
            total -= best
        if best <= 0:
            if not most_uncertain:
                return q + 1
            out[q] = 1.0 - best
        else:
            median = 0.5 * (np.float64(scores[q, (count - 1) // 2]) + np.float64(scores[q, count // 2]))
            out[q] = (rs_weight * (total / (count - 1)) + sd_weight * median) / best
        if not abs(out[q]) < math.inf:  # overflow of out's dtype
            return q + 1
    return 0
