"""The numba kernels behind :mod:`vpr_uncertainty._fast`; importing this module imports numba (ImportError without).
Why they are fast (unrolled loops per row length, no data-dependent branch): see docs/explanation/uncertainty-scores.md.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_OPTIONS = {"cache": True, "nogil": True, "boundscheck": False, "error_model": "numpy"}


@numba.njit(**_OPTIONS)
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
        for j in range(1, n_columns):  # the columns after the first n must be sorted too
            value = scores[q, j]
            ok &= value <= previous  # False for NaN
            previous = value
        count = n
        while count > 0 and scores[q, count - 1] == -math.inf:  # missing candidates: score the finite ones
            count -= 1
        if not ok or count < 2 or (best <= 0 and not most_uncertain):
            return q + 1
        if best <= 0:
            out[q] = 1.0 - best
        else:  # the order of operations of scores._ratio_values: the same bits on both paths
            total = np.float64(scores[q, 1])
            for j in range(2, count):
                total += scores[q, j]
            middle = np.float64(scores[q, (count - 1) // 2]) + scores[q, count // 2]
            out[q] = (rs_weight / (count - 1) * total + sd_weight * 0.5 * middle) / best
        if not abs(out[q]) < math.inf:  # overflow of out's dtype
            return q + 1
    return 0


def make_ratio(n: int):
    """A kernel of (rs_weight·RS + sd_weight·SD) for rows of exactly ``n`` scores (``n`` a compile-time constant).

    ``kernel(scores, rs_weight, sd_weight, limit, out)`` writes every row's value into ``out`` and returns how many
    rows are bad: unsorted, NaN, +inf, a missing candidate, s_1 <= 0, or a result beyond ``limit`` (the largest
    finite value of ``out``'s dtype). Bad rows are left to :func:`ratio_kernel`; their values here are garbage.
    The order of operations is that of ``scores._ratio_values`` (the same bits on both paths).
    """
    low, high = (n - 1) // 2, n // 2

    @numba.njit(**_OPTIONS)
    def kernel(scores, rs_weight, sd_weight, limit, out):  # pragma: no cover - compiled
        flat = scores.ravel()
        rs_weight = rs_weight / (n - 1)
        sd_weight = sd_weight * 0.5
        bad = 0
        for q in range(scores.shape[0]):
            row = q * n
            ok = True
            for j in range(1, n):
                ok &= flat[row + j] <= flat[row + j - 1]  # False for NaN
            best = flat[row]
            total = np.float64(flat[row + 1])
            for j in range(2, n):
                total += flat[row + j]
            ok &= (best < math.inf) & (flat[row + n - 1] > -math.inf) & (best > 0)
            value = (rs_weight * total + sd_weight * (np.float64(flat[row + low]) + flat[row + high])) / best
            out[q] = value
            ok &= abs(value) <= limit
            bad += not ok
        return bad

    return kernel


def make_two_column(n_columns: int, distance_ratio: bool):
    """A kernel of the margin s_2 − s_1 or, with ``distance_ratio``, of PA = d_1 / d_2 (d² = 2 − 2s).

    ``n_columns`` is the row length as a compile-time constant, or 0 to read it from the input (slower).
    ``kernel(scores, tolerance, limit, out)`` writes every row's value into ``out`` and returns how many rows are
    bad: unsorted (over the whole row), NaN, +inf, fewer than 2 candidates, a result beyond ``limit`` (the largest
    finite value of ``out``'s dtype), or for PA a squared
    distance outside [−tolerance, 4 + tolerance]. The caller then redoes the input on the numpy path.
    """

    @numba.njit(**_OPTIONS)
    def kernel(scores, tolerance, limit, out):  # pragma: no cover - compiled
        m = n_columns if n_columns else scores.shape[1]
        flat = scores.ravel()
        bad = 0
        for q in range(scores.shape[0]):
            row = q * m
            # one boolean and-ed with every comparison, counted once per row: no branch, and LLVM vectorises it
            # (an integer flag or'ed with `not` comparisons took 1.3-1.8x the time)
            ok = True
            for j in range(1, m):
                ok &= flat[row + j] <= flat[row + j - 1]  # False for NaN
            first, second = flat[row], flat[row + 1]
            ok &= (first < math.inf) & (second > -math.inf)
            if distance_ratio:
                squared_first = 2.0 - 2.0 * np.float64(first)
                squared_second = 2.0 - 2.0 * np.float64(second)
                ok &= (squared_first >= -tolerance) & (squared_second <= 4.0 + tolerance)  # the extremes
                d_first = math.sqrt(max(squared_first, 0.0))
                d_second = math.sqrt(max(squared_second, 0.0))
                result = d_first / d_second if d_second != 0 else 1.0
            else:
                result = second - first
            out[q] = result
            ok &= abs(result) <= limit
            bad += not ok
        return bad

    return kernel
