"""Optional numba kernels of RS, SD and SU, margin and PA: one pass over each row (order, finiteness, formula). The
numpy path of :mod:`vpr_uncertainty.scores` is the reference: a kernel only speeds up large inputs and never decides an
error. When a kernel is loaded, when it gives up, ``VPR_UNCERTAINTY_NUMBA``: see docs/explanation/uncertainty-scores.md.
"""

from __future__ import annotations

import os
import sys

import numpy as np

ENVIRONMENT_VARIABLE = "VPR_UNCERTAINTY_NUMBA"

#: Scores (rows x columns) from which a loaded kernel beats the numpy path (measured: benchmarks/bench_scores.py).
MIN_ELEMENTS = 100_000
#: Scores from which one call repays importing numba and loading the kernel (about 0.3-0.5 s once per process)
#: unless numba is already imported.
LOAD_ELEMENTS = 20_000_000

#: Row lengths (k = number of columns) with kernels compiled for that length (several times faster).
SPECIALISED = (5, 10, 20, 25)

_kernel = None  # the compiled kernel once loaded; False when numba is missing or failed
_made: dict = {}  # (kind, row length) -> kernel made by _fast_kernel.make_*, compiled (or loaded) on first call


def _load():
    global _kernel
    if _kernel is None:
        try:
            from vpr_uncertainty._fast_kernel import ratio_kernel
        except ImportError:  # numba is not installed (or not importable here): the numpy path
            _kernel = False
        else:
            _kernel = ratio_kernel
    return _kernel


def _kernel_for(n_elements: int):
    """The kernel to use for an input of ``n_elements`` scores, or None for the numpy path."""
    mode = os.environ.get(ENVIRONMENT_VARIABLE, "")
    if mode == "0":
        return None
    if mode != "1":
        if n_elements < MIN_ELEMENTS:
            return None
        if _kernel is None and n_elements < LOAD_ELEMENTS and "numba" not in sys.modules:
            return None
    return _load() or None


def _made_kernel(kind: str, n_columns: int):
    key = (kind, n_columns)
    if key not in _made:
        from vpr_uncertainty import _fast_kernel as kernels

        _made[key] = (
            kernels.make_ratio(n_columns) if kind == "ratio" else kernels.make_two_column(n_columns, kind == "PA")
        )
    return _made[key]


def ratio_metric(
    scores: np.ndarray, n: int, rs_weight: float, sd_weight: float, most_uncertain: bool
) -> np.ndarray | None:
    """(rs_weight·RS + sd_weight·SD) of each row of ``scores`` on its first ``n`` columns, or None.

    ``scores`` comes from ``as_score_array`` (C-contiguous float32 or float64, at least one row, ``n >= 2``
    columns). None means: the numpy path decides (numba absent, disabled, input too small, or a row the kernel does
    not score: the numpy path then raises its message or scores it).
    """
    kernel = _kernel_for(scores.size)
    if kernel is None:
        return None
    out = np.empty(scores.shape[0], dtype=scores.dtype)
    limit = float(np.finfo(scores.dtype).max)
    if n == scores.shape[1] and n in SPECIALISED:
        if _made_kernel("ratio", n)(scores, float(rs_weight), float(sd_weight), limit, out) == 0:
            return out
    return out if kernel(scores, n, float(rs_weight), float(sd_weight), most_uncertain, out) == 0 else None


def two_column(kind: str, scores: np.ndarray, tolerance: float) -> np.ndarray | None:
    """The margin (``kind="margin"``) or PA (``kind="PA"``, from d² = 2 − 2s) of every row, or None.

    ``scores`` comes from ``as_score_array`` (>= 1 row, >= 2 columns). None: the numpy path decides (as for
    :func:`ratio_metric`, or a row that is unsorted, NaN, +inf, short, overflows or, for PA, has a squared distance
    outside [−``tolerance``, 4 + ``tolerance``]).
    """
    if _kernel_for(scores.size) is None:
        return None
    n_columns = scores.shape[1]
    kernel = _made_kernel(kind, n_columns if n_columns in SPECIALISED else 0)
    out = np.empty(scores.shape[0], dtype=scores.dtype)
    return out if kernel(scores, float(tolerance), float(np.finfo(scores.dtype).max), out) == 0 else None
