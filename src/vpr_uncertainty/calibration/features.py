"""Training-free features of a VPR answer, from its top-k similarities: the inputs of the calibrator.

Direction
---------
Features are plain descriptive numbers, not uncertainties: the calibrator learns their signs. Every row of the
matrix is one query; every column one feature of :data:`FEATURES`.

Features (k candidates, similarities s_1 ≥ s_2 ≥ … ≥ s_k of one query)
    * ``s1``: the best similarity s_1
    * ``gap``: s_1 − s_2 (the margin, positive)
    * ``ratio``: s_2 / s_1
    * ``RS``, ``SD``, ``SU``: the paper's metrics (:mod:`vpr_uncertainty.scores`), α = 0.5 for SU
    * ``zscore``: (s_1 − mean(s_2..s_k)) / (s_1 − s_k), how far the best match stands out of the runners-up,
      scaled by the spread of the top-k (0 when the whole top-k ties)
    * ``PA``: d_1 / d_2 with d² = 2 − 2s (the perceptual-aliasing ratio of :func:`~vpr_uncertainty.baselines.
      perceptual_aliasing`); it needs cosine similarities in [−1, 1] and raises a ValueError otherwise

The ratio features (``ratio``, ``RS``, ``SD``, ``SU``) follow the convention of :mod:`vpr_uncertainty.scores` for a
row whose best similarity is ≤ 0: they take the value 1 − s_1 (≥ 1, beyond every row with s_1 > 0). Missing
candidates (``-inf`` at the end of a row) are handled as there: the row is described by the candidates it has.

The same numbers for one query at a time, in pure Python, are :func:`row_features` (the gate's fast path).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from vpr_uncertainty import baselines as _baselines
from vpr_uncertainty import scores as _scores
from vpr_uncertainty._validation import check_k, check_top_k_scores

__all__ = [
    "DEFAULT_FEATURES",
    "FEATURES",
    "aliasing_ratio",
    "check_features",
    "feature_matrix",
    "row_features",
    "row_statistics",
]

#: Every feature :func:`feature_matrix` can build, in a fixed order.
FEATURES: tuple[str, ...] = ("s1", "gap", "ratio", "RS", "SD", "SU", "zscore", "PA")
#: The features of the fitted calibrator: the best match, the margin, the perceptual-aliasing ratio and SU (the
#: signals that win on some VPR method; see README "Calibration"). Without cosine similarities PA is left out.
DEFAULT_FEATURES: tuple[str, ...] = ("s1", "gap", "PA", "SU")


def check_features(features: Sequence[str]) -> tuple[str, ...]:
    """``features`` as a tuple, checked: a non-empty sequence of distinct names from :data:`FEATURES`."""
    if isinstance(features, str) or not features:
        raise ValueError(f"features must be a non-empty list of names from {FEATURES}, got {features!r}")
    unknown = [name for name in features if name not in FEATURES]
    if unknown:
        raise ValueError(f"unknown feature(s) {unknown}; valid: {', '.join(FEATURES)}")
    if len(set(features)) != len(features):
        raise ValueError(f"features lists a name twice: {list(features)}")
    return tuple(features)


def feature_matrix(scores: object, *, k: int = 10, features: Sequence[str] = DEFAULT_FEATURES) -> np.ndarray:
    """The feature matrix of many queries, vectorised.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, higher = more similar, sorted descending along axis 1; ``-inf`` marks a
        missing candidate at the end of a row. At least two finite candidates per row.
    k : int, default=10
        Candidates used (the first ``min(k, K)`` columns); >= 2.
    features : sequence of str, default=DEFAULT_FEATURES
        Names from :data:`FEATURES`, in the order of the columns returned.

    Returns
    -------
    ndarray of shape (Q, F), float64

    Examples
    --------
    >>> feature_matrix(np.array([[0.8, 0.4, 0.2]]), k=3, features=("s1", "gap", "RS", "SD", "zscore")).round(4)
    array([[0.8   , 0.4   , 0.375 , 0.5   , 0.8333]])
    """
    names = check_features(features)
    k = check_k(k)
    array = check_top_k_scores(scores)
    if array.shape[1] < 2:
        raise ValueError(f"scores must have at least 2 columns, got shape {array.shape}")
    array = array.astype(np.float64, copy=False)
    n = min(k, array.shape[1])
    top = array[:, :n]
    finite = np.isfinite(top)
    counts = finite.sum(axis=1)
    if (counts < 2).any():
        row = int(np.flatnonzero(counts < 2)[0])
        raise ValueError(f"scores row {row} has {int(counts[row])} finite candidate(s); a row needs at least 2")
    with np.errstate(over="ignore", invalid="ignore"):  # huge finite scores: overflow is refused below
        columns = {name: _column(name, top, finite, counts, n) for name in names}
    if not len(top):
        return np.empty((0, len(names)))
    matrix = np.column_stack([columns[name] for name in names])
    if not np.isfinite(matrix).all():  # finite scores so large that a sum or ratio overflows
        row = int(np.flatnonzero(~np.isfinite(matrix).all(axis=1))[0])
        raise ValueError(f"scores row {row} is too large: its features overflow float64 ({top[row].tolist()})")
    return matrix


def _column(name: str, top: np.ndarray, finite: np.ndarray, counts: np.ndarray, n: int) -> np.ndarray:
    """One feature column of :func:`feature_matrix`, shape (Q,)."""
    best = top[:, 0]
    nonpositive = best <= 0
    if name == "s1":
        return best
    elif name == "gap":
        return best - top[:, 1]
    elif name == "ratio":
        return np.where(nonpositive, 1 - best, top[:, 1] / np.where(nonpositive, 1, best))
    elif name == "RS":
        return _scores.ratio_spread(top, n)
    elif name == "SD":
        return _scores.similarity_distribution(top, n)
    elif name == "SU":
        return _scores.statistical_uncertainty(top, n)
    elif name == "PA":
        return _baselines.perceptual_aliasing(top[:, :2], 2).astype(np.float64, copy=False)
    else:  # zscore
        safe = np.where(finite, top, 0.0)
        last = safe[np.arange(len(top)), counts - 1]
        runners_up = (safe.sum(axis=1) - best) / (counts - 1)
        spread = best - last
        return np.divide(best - runners_up, spread, out=np.zeros_like(best), where=spread > 0)


def row_statistics(values: list[float], k: int) -> tuple[float, float, float, float, float, int]:
    """(s_1, s_2, mean of s_2..s_n, median, s_n, n) of one query's sorted similarities, pure Python.

    ``values`` is truncated to ``k`` candidates and stripped of trailing ``-inf`` in place. A ValueError names
    what is wrong: fewer than 2 finite candidates, NaN, +inf, or a row not sorted in descending order.
    """
    if len(values) > k:
        del values[k:]
    while values and values[-1] == -math.inf:
        values.pop()
    n = len(values)
    if n < 2:
        raise ValueError(f"scores needs at least 2 finite candidates, got {n}")
    try:
        previous = values[0]
        if not -math.inf < previous < math.inf:
            raise ValueError(f"scores must be finite, got {values}")
        for value in values:
            if not value <= previous:  # also catches NaN
                raise ValueError(f"scores must be finite and sorted in descending order, got {values}")
            previous = value
        total = sum(values)
    except TypeError:
        raise TypeError(f"scores must be numbers, got {values}") from None
    best = values[0]
    if not -math.inf < total < math.inf:  # finite values whose sum overflows: the mean from scaled values
        scale = max(abs(best), abs(values[-1]))
        runners_up = scale * ((sum(value / scale for value in values) - best / scale) / (n - 1))
        return best, values[1], runners_up, 0.5 * values[(n - 1) // 2] + 0.5 * values[n // 2], values[-1], n
    median = 0.5 * (values[(n - 1) // 2] + values[n // 2])
    return best, values[1], (total - best) / (n - 1), median, values[-1], n


def row_features(values: Sequence[float], *, k: int = 10, features: Sequence[str] = DEFAULT_FEATURES) -> list[float]:
    """The features of one query (the same numbers as one row of :func:`feature_matrix`), in pure Python.

    Examples
    --------
    >>> [round(value, 4) for value in row_features([0.8, 0.4, 0.2], k=3, features=("RS", "SD", "zscore"))]
    [0.375, 0.5, 0.8333]
    """
    best, second, runners_up, median, last, _ = row_statistics(list(values), check_k(k))
    positive = best > 0
    spread = best - last
    table = {
        "s1": best,
        "gap": best - second,
        "ratio": second / best if positive else 1 - best,
        "RS": runners_up / best if positive else 1 - best,
        "SD": median / best if positive else 1 - best,
        "SU": 0.5 * (runners_up / best) + 0.5 * (median / best) if positive else 1 - best,
        "zscore": (best - runners_up) / spread if spread > 0 else 0.0,
    }
    names = check_features(features)
    if "PA" in names:
        table["PA"] = aliasing_ratio(best, second)
    return [table[name] for name in names]


def aliasing_ratio(best: float, second: float) -> float:
    """PA of one query, d_1 / d_2 with d² = 2 − 2s, in pure Python (1 when both distances are 0).

    A ValueError names the range when a similarity lies outside [−1, 1] (beyond rounding): the scores are then not
    cosine similarities and the distances would be meaningless.
    """
    tolerance = _baselines.COSINE_TOLERANCE
    if not (-1.0 - tolerance <= second and best <= 1.0 + tolerance):
        raise ValueError(f"feature PA needs cosine similarities in [-1, 1], got s_1 = {best:g}, s_2 = {second:g}")
    first_squared, second_squared = max(2.0 - 2.0 * best, 0.0), max(2.0 - 2.0 * second, 0.0)
    return math.sqrt(first_squared / second_squared) if second_squared > 0 else 1.0
