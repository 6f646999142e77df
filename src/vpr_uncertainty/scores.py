"""Uncertainty from the top-k similarity scores of a VPR system: arrays of shape (Q,), **higher = less trustworthy**.

* :func:`ratio_spread` (RS), :func:`similarity_distribution` (SD), :func:`statistical_uncertainty` (SU) and
  :func:`adaptive_statistical_uncertainty`; baselines :func:`best_match`, :func:`l2_distance`,
  :func:`perceptual_aliasing`, :func:`margin`. Inputs: similarities sorted descending, one row per query.

Formulas and hard input (missing candidates, s_1 <= 0, NaN, ...): see docs/explanation/uncertainty-scores.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from vpr_uncertainty import _fast
from vpr_uncertainty._validation import (
    as_score_array,
    check_best_scores,
    check_fraction,
    check_k,
    check_rows,
    raise_for_short_rows,
    scan,
)

_NONPOSITIVE_POLICIES = ("most_uncertain", "raise")
_NEG_INF, _INF = -math.inf, math.inf  # bound once: row_statistics runs in every gate(row)


def check_alpha(alpha: object, *, name: str = "alpha") -> float:
    """``alpha``, SU's weight of RS, as a float; a TypeError or ValueError (naming ``name``) unless it is in [0, 1].

    The one check of the range, for the library, the method specs and the command line (``name="--alpha"``).
    """
    return check_fraction(alpha, name)


def _ratio_values(top: np.ndarray, rs_weight: float, sd_weight: float, out: np.ndarray, columns=None) -> np.ndarray:
    """Write (rs_weight·mean(s_2..s_n) + sd_weight·median(s_1..s_n)) / s_1 of each sorted row of ``top`` (R, n) into
    ``out`` (R,) and return it: computed in float64 (or wider), rounded once to ``out``'s dtype.

    In the numba kernels' order of operations (:mod:`vpr_uncertainty._fast_kernel`), so that both paths give the same
    bits, and so the same ties: s_2 + s_3 + ... left to right, then (rs_weight / (n − 1))·sum + (sd_weight / 2)·(the
    middle two), divided by s_1. ``columns`` (n + 1, >= R), a buffer reused between calls, receives the columns
    transposed (contiguous: numpy is slow on strides) and a row of scratch.
    """
    n, m = top.shape[1], top.shape[0]
    columns = np.empty((n + 1, m), np.result_type(top.dtype, np.float64)) if columns is None else columns[:, :m]
    np.copyto(columns[:n], top.T)
    middle = np.add(columns[(n - 1) // 2], columns[n // 2], out=columns[n])
    middle *= sd_weight * 0.5
    total = columns[1]  # summed in place: the middle columns are read already
    for j in range(2, n):
        total += columns[j]
    total *= rs_weight / (n - 1)
    return np.divide(np.add(total, middle, out=total), columns[0], out=out)


def _check_policy(on_nonpositive: str) -> None:
    if on_nonpositive not in _NONPOSITIVE_POLICIES:
        raise ValueError(f"on_nonpositive must be one of {_NONPOSITIVE_POLICIES}, got {on_nonpositive!r}")


def _ratio_metric(
    scores: object, k: object, rs_weight: float, sd_weight: float, sort: bool, on_nonpositive: str
) -> np.ndarray:
    """(rs_weight·RS + sd_weight·SD) for every row, computed as one weighted sum divided by s_1.

    Large inputs go to the optional numba kernel (:mod:`vpr_uncertainty._fast`: one pass per row) when numba is
    installed; this numpy path is the reference, and the kernel hands every row it does not score the ordinary way
    back to it, and both compute in the same order (:func:`_ratio_values`): the same bits, so the same ties. With
    sorted rows the mean of the runners-up and the median are fixed combinations of the columns, so no per-row sort
    or median is needed. One pass, block by block in cache, checks the order of every row and computes its value;
    a value that is not finite, or an s_1 that is not positive, flags the rows with missing candidates (-inf), +inf,
    s_1 <= 0 or overflow, which are redone apart.
    """
    k = check_k(k)
    _check_policy(on_nonpositive)
    scores = as_score_array(scores, sort=sort)
    n_queries, n_columns = scores.shape
    if n_queries == 0:
        return np.empty(0, dtype=scores.dtype)
    n = min(k, n_columns)
    if n < 2:
        check_rows(scores, check_first_column=False)
        raise_for_short_rows(np.full(n_queries, n))
    fast = _fast.ratio_metric(scores, n, rs_weight, sd_weight, on_nonpositive == "most_uncertain")
    if fast is not None:
        return fast
    dtype = np.result_type(scores.dtype, np.float64)
    buffer: list[np.ndarray] = []  # the columns of the first (largest) block, reused for the others

    def compute(block: np.ndarray, out: np.ndarray) -> np.ndarray:
        if not buffer:
            buffer.append(np.empty((n + 1, len(block)), dtype))
        _ratio_values(block[:, :n], rs_weight, sd_weight, out, buffer[0])
        return buffer[0][0, : len(block)]  # s_1: its extremes flag +inf and s_1 <= 0

    values, low, high = scan(scores, compute)
    best = scores[:, 0]
    if high == _INF:
        check_best_scores(best)
    if low > 0 and np.isfinite(values).all():  # the common case: no row to redo
        return values
    unusual = np.flatnonzero(~np.isfinite(values) | (best <= 0))  # missing candidates, s_1 <= 0 or overflow
    top = scores[unusual, :n]
    n_candidates = np.isfinite(top).sum(axis=1)  # rows with missing candidates (-inf): scored on those they have
    if (n_candidates < 2).any():
        every_row = np.full(n_queries, n)
        every_row[unusual] = n_candidates
        raise_for_short_rows(every_row)
    first = top[:, 0].astype(dtype)
    nonpositive = first <= 0
    if nonpositive.any() and on_nonpositive == "raise":
        row = int(unusual[nonpositive][0])
        raise ValueError(
            f"scores has {int(nonpositive.sum())} row(s) whose best similarity is <= 0 (first: row {row}, "
            f"s_1 = {float(best[row]):g}); the ratios s_i / s_1 need s_1 > 0. Use on_nonpositive='most_uncertain' "
            "to rank such queries as the most uncertain"
        )
    with np.errstate(all="ignore"):  # overflow is reported below
        for count in np.unique(n_candidates):
            rows = unusual[n_candidates == count]
            # the ratios are those of the row scaled by a power of two, exactly: s_1 in [0.5, 1) sums no overflow
            group = np.ldexp(top[n_candidates == count, :count], -np.frexp(top[n_candidates == count, :1])[1])
            values[rows] = _ratio_values(group, rs_weight, sd_weight, np.empty(len(rows), dtype))  # rounded once
        values[unusual[nonpositive]] = 1.0 - first[nonpositive]
    if not np.isfinite(values).all():
        row = int(np.flatnonzero(~np.isfinite(values))[0])
        raise ValueError(
            f"scores overflow {values.dtype} in row {row} (s_1 = {float(best[row]):g}); cast the scores to float64"
        )
    return values


def ratio_spread(
    scores: object, k: int = 10, *, sort: bool = False, on_nonpositive: str = "most_uncertain"
) -> np.ndarray:
    """Ratio Spread: how closely the runners-up compete with the best match.

    RS = 1/(k−1) Σ_{i=2..k} s_i / s_1. Close to 1 when the runners-up are as similar as the best match.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, higher = more similar, sorted descending along axis 1.
    k : int, default=10
        Number of candidates used (the first ``min(k, K)`` columns). Must be >= 2.
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.
    on_nonpositive : {"most_uncertain", "raise"}, default="most_uncertain"
        What to do with rows whose best similarity is <= 0 (docs/explanation/uncertainty-scores.md).

    Returns
    -------
    ndarray of shape (Q,)
        Uncertainty, higher = less trustworthy.

    Examples
    --------
    >>> import numpy as np
    >>> ratio_spread(np.array([[0.8, 0.4, 0.2], [0.5, 0.5, 0.5]]), k=3)
    array([0.375, 1.   ])
    """
    return _ratio_metric(scores, k, 1.0, 0.0, sort, on_nonpositive)


def similarity_distribution(
    scores: object, k: int = 10, *, sort: bool = False, on_nonpositive: str = "most_uncertain"
) -> np.ndarray:
    """Similarity Distribution: how far the best match stands from the bulk of the top-k.

    SD = median(s_1 … s_k) / s_1 (for even k the median is the mean of the two middle values).

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, higher = more similar, sorted descending along axis 1.
    k : int, default=10
        Number of candidates used (the first ``min(k, K)`` columns). Must be >= 2.
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.
    on_nonpositive : {"most_uncertain", "raise"}, default="most_uncertain"
        What to do with rows whose best similarity is <= 0 (docs/explanation/uncertainty-scores.md).

    Returns
    -------
    ndarray of shape (Q,)
        Uncertainty, higher = less trustworthy.

    Examples
    --------
    >>> import numpy as np
    >>> similarity_distribution(np.array([[0.8, 0.4, 0.2, -np.inf], [0.8, 0.6, 0.4, 0.2]]), k=4)
    array([0.5  , 0.625])

    The first query has only three candidates (``-inf`` marks the missing one), so its median is 0.4.
    """
    return _ratio_metric(scores, k, 0.0, 1.0, sort, on_nonpositive)


def statistical_uncertainty(
    scores: object, k: int = 10, alpha: float = 0.5, *, sort: bool = False, on_nonpositive: str = "most_uncertain"
) -> np.ndarray:
    """Statistical Uncertainty: SU = α·RS + (1−α)·SD, the paper's training-free default.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, higher = more similar, sorted descending along axis 1.
    k : int, default=10
        Number of candidates used (the first ``min(k, K)`` columns). Must be >= 2.
    alpha : float in [0, 1], default=0.5
        Weight of RS; ``alpha=1`` gives RS and ``alpha=0`` gives SD.
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.
    on_nonpositive : {"most_uncertain", "raise"}, default="most_uncertain"
        What to do with rows whose best similarity is <= 0 (docs/explanation/uncertainty-scores.md).

    Returns
    -------
    ndarray of shape (Q,)
        Uncertainty, higher = less trustworthy.

    Examples
    --------
    >>> import numpy as np
    >>> statistical_uncertainty(np.array([[0.8, 0.4, 0.2]]), k=3, alpha=0.5)
    array([0.4375])
    """
    alpha = check_alpha(alpha)
    return _ratio_metric(scores, k, alpha, 1.0 - alpha, sort, on_nonpositive)


def one_row(scores: object, *, shapes: str = "(k,) or (1, k)", advice: str = "") -> list[float]:
    """One query's scores as a new list: from a sequence, or an ndarray or torch tensor (duck-typed) of shape (K,) or
    (1, K), of numbers; ``shapes`` and ``advice`` word the error for another shape."""
    if type(scores) is list:  # the common cases, first
        return scores[:]
    if type(scores) is np.ndarray and scores.ndim == 1 and scores.dtype.kind in "fiu":
        return scores.tolist()
    if not isinstance(scores, np.ndarray) and hasattr(scores, "detach") and hasattr(scores, "tolist"):
        scores = scores.detach()  # a torch tensor: .cpu().tolist() below, also for bfloat16 and CUDA tensors
        if hasattr(scores, "cpu"):
            scores = scores.cpu()
    if isinstance(scores, np.ndarray) and scores.dtype.kind not in "fiu":
        raise TypeError(f"scores must be numbers, got an array of dtype {scores.dtype}")
    shape = getattr(scores, "shape", None)
    if shape is not None:
        shape = tuple(shape)
        if len(shape) == 2 and shape[0] == 1:
            return scores.tolist()[0]
        if len(shape) != 1:
            raise ValueError(f"scores must be one query's top-k, of shape {shapes}, got shape {shape}{advice}")
        return scores.tolist()
    if isinstance(scores, (str, bytes)):
        raise TypeError(f"scores must be a sequence of similarities, got {type(scores).__name__} {scores!r}")
    return list(scores)


def row_statistics(values: list[float], k: int) -> tuple[float, float, float, float, float, int]:
    """(s_1, s_2, mean of s_2..s_n, median, s_n, n) of one query's sorted similarities, pure Python.

    ``values`` is truncated to ``k`` candidates and stripped of trailing ``-inf`` in place. A ValueError names
    what is wrong: fewer than 2 finite candidates, NaN, +inf, or a row not sorted in descending order.
    """
    if len(values) > k:
        del values[k:]
    while values and values[-1] == _NEG_INF:
        values.pop()
    n = len(values)
    if n < 2:
        raise ValueError(f"scores needs at least 2 finite candidates, got {n}")
    try:
        previous = values[0]
        if not _NEG_INF < previous < _INF:
            raise ValueError(f"scores must be finite, got {values}")
        for value in values:
            if not value <= previous:  # also catches NaN
                raise ValueError(f"scores must be finite and sorted in descending order, got {values}")
            previous = value
        total = sum(values)
    except TypeError:
        raise TypeError(f"scores must be numbers, got {values}") from None
    best = values[0]
    if not _NEG_INF < total < _INF:  # finite values whose sum overflows: the mean from scaled values
        scale = max(abs(best), abs(values[-1]))
        runners_up = scale * ((sum(value / scale for value in values) - best / scale) / (n - 1))
        return best, values[1], runners_up, 0.5 * values[(n - 1) // 2] + 0.5 * values[n // 2], values[-1], n
    median = 0.5 * (values[(n - 1) // 2] + values[n // 2])
    return best, values[1], (total - best) / (n - 1), median, values[-1], n


class StatisticalUncertainty:
    """SU for one query at a time, with the options checked once: the low-latency path for a running robot.

    Parameters
    ----------
    k : int, default=10
        Number of candidates used.
    alpha : float in [0, 1], default=0.5
        Weight of RS against SD.
    on_nonpositive : {"most_uncertain", "raise"}, default="most_uncertain"
        What to do when the best similarity is <= 0 (docs/explanation/uncertainty-scores.md).

    Examples
    --------
    >>> su = StatisticalUncertainty(k=3)
    >>> su
    StatisticalUncertainty(k=3, alpha=0.5)
    >>> su([0.8, 0.4, 0.2])
    0.4375
    >>> su(np.array([[0.8, 0.4, 0.2]], dtype=np.float32))  # Faiss's (1, k) for one query; a Python float
    0.4375
    """

    __slots__ = ("_alpha", "_k", "_raise_nonpositive")

    def __init__(self, k: int = 10, alpha: float = 0.5, *, on_nonpositive: str = "most_uncertain") -> None:
        self._k = check_k(k)
        self._alpha = check_alpha(alpha)
        _check_policy(on_nonpositive)
        self._raise_nonpositive = on_nonpositive == "raise"

    def __repr__(self) -> str:
        policy = ", on_nonpositive='raise'" if self._raise_nonpositive else ""
        return f"{type(self).__name__}(k={self._k}, alpha={self._alpha:g}{policy})"

    @property
    def k(self) -> int:
        return self._k

    @property
    def alpha(self) -> float:
        return self._alpha

    def __call__(self, scores: Sequence[float] | np.ndarray) -> float:
        """Return SU of one query, as a Python float.

        Parameters
        ----------
        scores : sequence of float, ndarray of shape (K,) or (1, K), or a torch tensor of those shapes
            That query's top-K similarities, sorted descending; ``-inf`` marks missing candidates at the end. A
            (1, K) array is what Faiss's ``index.search`` returns for one query. A tensor (any device, with or
            without grad) is read through ``.detach().cpu().tolist()``; torch itself is never imported.
        """
        if type(scores) is not list:  # a list is the fast path of a running robot
            scores = one_row(scores, advice="; use batch() or statistical_uncertainty() for many queries")
        if scores and isinstance(scores[0], (list, tuple)):
            if len(scores) == 1:
                return self(list(scores[0]))  # [[s_1, ..., s_k]]: one query written as a (1, K) nested list
            raise ValueError(
                f"scores must be one query's top-k, of shape (k,) or (1, k), got {len(scores)} rows; use "
                "batch() or statistical_uncertainty() for many queries"
            )
        best, _, runners_up, median, _, _ = row_statistics(scores[: self._k], self._k)  # a copy: never the caller's
        if best <= 0:
            if self._raise_nonpositive:
                raise ValueError(f"the best similarity must be > 0, got {best}")
            return float(1.0 - best)
        return float((self._alpha * runners_up + (1.0 - self._alpha) * median) / best)

    def batch(self, scores: object) -> np.ndarray:
        """SU of many queries at once (see :func:`statistical_uncertainty`)."""
        policy = "raise" if self._raise_nonpositive else "most_uncertain"
        return statistical_uncertainty(scores, self._k, self._alpha, on_nonpositive=policy)


#: How far outside [-1, 1] cosine similarities may lie through rounding (of normalised descriptors, of float32).
COSINE_TOLERANCE = 1e-3


def squared_distances_from_similarities(
    scores: np.ndarray, *, method: str | None = None, check: bool = True
) -> np.ndarray:
    """Squared L2 distances of L2-normalised descriptors from their cosine similarities: d² = 2 − 2s.

    The only place in the toolkit where this conversion is made. It holds only for cosine similarities, which
    lie in [−1, 1]; values outside that range (by more than :data:`COSINE_TOLERANCE`, which allows for rounding)
    mean the scores are some other similarity, and the converted distances would be meaningless (all clipped to
    0 above 1, so constant). Values are clipped at 0 so that rounding (s slightly above 1) never gives a
    negative square; ``-inf`` (a missing candidate) gives ``+inf``.

    Parameters
    ----------
    scores : ndarray
        Cosine similarities (any shape).
    method : str, optional
        The uncertainty method that needs the distances, named in the error.
    check : bool, default=True
        Check the range. Only a caller whose scores come from L2-normalised descriptors by construction (the
        descriptor search, where an approximate index may exceed 1 slightly) passes False.

    Raises
    ------
    ValueError
        When a finite score lies outside [−1, 1] (beyond the tolerance), naming the method and the range found.

    Examples
    --------
    >>> squared_distances_from_similarities(np.array([[1.0, 0.5, -1.0]]))
    array([[0., 1., 4.]])
    """
    scores = np.asarray(scores)
    if check and scores.size:
        finite = scores[np.isfinite(scores)] if np.issubdtype(scores.dtype, np.floating) else scores
        if finite.size:
            low, high = float(finite.min()), float(finite.max())
            if low < -1 - COSINE_TOLERANCE or high > 1 + COSINE_TOLERANCE:
                who = f"{method} needs" if method else "converting similarities to distances needs"
                raise ValueError(
                    f"{who} descriptor distances: the similarities lie in [{low:g}, {high:g}], outside [-1, 1], so "
                    "they are not cosine similarities of L2-normalised descriptors and d² = 2 − 2s does not hold; "
                    "give the squared L2 distances (the retrieval's distances), or use a method that reads the "
                    "similarities only (BM, RS, SD, SU)"
                )
    with np.errstate(over="ignore", invalid="ignore"):
        return np.maximum(2 - 2 * scores, 0)


def _top_distances(scores: np.ndarray, distances: object, n: int, method: str, sort: bool) -> np.ndarray:
    """First ``n`` columns of the L2 distances (not squared), from ``distances`` (sorted first with ``sort``) or from
    the similarities."""
    if distances is None:
        return np.sqrt(squared_distances_from_similarities(scores[:, :n], method=method))
    squared = np.sort(np.asarray(distances), axis=1) if sort else np.asarray(distances)
    if squared.ndim != 2 or squared.shape[0] != scores.shape[0] or squared.shape[1] < n:
        raise ValueError(f"distances must have shape ({scores.shape[0]}, >= {n}) to match scores, got {squared.shape}")
    squared = squared[:, :n].astype(scores.dtype, copy=False)
    if not (np.isfinite(squared).all() and (squared >= 0).all()):
        raise ValueError("distances must be finite squared L2 distances >= 0 in the columns used")
    if n > 1 and (squared[:, 1:] < squared[:, :-1]).any():
        raise ValueError("distances must be sorted in ascending order along axis 1 (nearest first)")
    return np.sqrt(squared)


def _baseline(scores: object, k: object, sort: bool, columns: int, formula, **options) -> np.ndarray:
    """``formula(top, out)`` of every row into ``out`` (Q,): ``top`` the first ``columns`` similarities or, for L2 and
    PA (``method`` in ``options``), their distances d (not squared), from ``distances`` or from d² = 2 − 2s.

    Fast first, without ``distances``: the numba kernel ``kernel`` (:func:`vpr_uncertainty._fast.two_column`), else
    one pass over the scores (:func:`~vpr_uncertainty._validation.scan`) that checks the order and computes each
    block in cache. That result is returned only if it is finite and the values 2 − 2s read are clearly those of
    cosine similarities (a margin of half :data:`COSINE_TOLERANCE` inside the accepted range, so that rounding never
    lets through what the reference rejects). Otherwise (±inf, a short row, a range error, values at the edge of
    the range, or nothing wrong but an overflow) the reference: every row validated, raising its message.
    """
    method, distances, kernel = options.get("method"), options.get("distances"), options.get("kernel")
    check_k(k)
    scores = as_score_array(scores, sort=sort)
    if distances is None and scores.shape[0] and scores.shape[1] >= max(columns, 2):
        fast = None if kernel is None else _fast.two_column(kernel, scores, COSINE_TOLERANCE)
        if fast is not None:
            return fast

        def compute(block: np.ndarray, out: np.ndarray) -> np.ndarray | None:
            if method is None:
                formula(block, out)
                return None
            squared = np.multiply(block[:, :columns].T, -2, out=np.empty((columns, len(block)), block.dtype))
            squared += 2  # 2 - 2s, each column contiguous (numpy is slow on rows of 2)
            formula(np.sqrt(np.maximum(squared, 0)).T, out)
            return squared

        out, low, high = scan(scores, compute)
        if (low > high or -COSINE_TOLERANCE <= low <= high <= 4 + COSINE_TOLERANCE) and np.isfinite(out).all():
            return out
    check_rows(scores)  # the reference
    if scores.shape[0] and scores.shape[1] < columns:
        raise ValueError(f"scores must have at least {columns} columns, got shape {scores.shape}")
    if scores.shape[0] and not np.isfinite(scores[:, :columns]).all():
        raise_for_short_rows(np.isfinite(scores[:, :columns]).sum(axis=1), needed=columns)
    top = scores if method is None else _top_distances(scores, distances, columns, method, sort)
    return formula(top, np.empty(len(scores), dtype=scores.dtype))


def _first_over_second(top2: np.ndarray, out: np.ndarray) -> np.ndarray:
    """d_1 / d_2 of each row of ``top2`` into ``out``; 1 where d_2 = 0 (two candidates at distance 0)."""
    out[:] = 1
    return np.divide(top2[:, 0], top2[:, 1], out=out, where=top2[:, 1] != 0)


def best_match(scores: object, k: int = 10, *, sort: bool = False) -> np.ndarray:
    """BM: the negated top-1 similarity, −s_1.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, sorted descending along axis 1.
    k : int, default=10
        Accepted so every method shares one signature; only the best match is read.
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.

    Returns
    -------
    ndarray of shape (Q,)
        Uncertainty, higher = less trustworthy.

    Examples
    --------
    >>> best_match(np.array([[0.8, 0.4], [0.3, 0.1]]))
    array([-0.8, -0.3])
    """
    return _baseline(scores, k, sort, 1, lambda top, out: np.negative(top[:, 0], out=out))


def l2_distance(scores: object, k: int = 10, *, distances: object = None, sort: bool = False) -> np.ndarray:
    """L2: the descriptor distance d_1 between the query and its best match.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, sorted descending along axis 1.
    k : int, default=10
        Accepted so every method shares one signature; only the best match is read.
    distances : array-like of shape (Q, K), optional
        Squared L2 distances of the same candidates, ascending. Without them the similarities are taken as
        cosine similarities of L2-normalised descriptors, d² = 2 − 2s; L2 then ranks queries exactly as BM.
        Similarities outside [−1, 1] then raise a ``ValueError`` (see :func:`squared_distances_from_similarities`).
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.

    Returns
    -------
    ndarray of shape (Q,)
        Uncertainty, higher = less trustworthy.

    Examples
    --------
    >>> l2_distance(np.array([[0.5, 0.0]]))
    array([1.])
    """
    return _baseline(
        scores, k, sort, 1, lambda top, out: np.positive(top[:, 0], out=out), method="L2", distances=distances
    )


def perceptual_aliasing(scores: object, k: int = 10, *, distances: object = None, sort: bool = False) -> np.ndarray:
    """PA: the ratio d_1 / d_2 of the two nearest-neighbour distances (Lowe's ratio for places).

    Close to 1 when a second place matches as well as the first. Two candidates at distance 0 give 1.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, sorted descending along axis 1.
    k : int, default=10
        Accepted so every method shares one signature; only the two best matches are read.
    distances : array-like of shape (Q, K), optional
        Squared L2 distances of the same candidates, ascending; by default d² = 2 − 2s, which needs cosine
        similarities in [−1, 1] (see :func:`squared_distances_from_similarities`).
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.

    Returns
    -------
    ndarray of shape (Q,)
        Uncertainty, higher = less trustworthy.

    Examples
    --------
    >>> perceptual_aliasing(np.array([[0.5, -1.0], [1.0, 1.0]]))
    array([0.5, 1. ])
    """
    return _baseline(scores, k, sort, 2, _first_over_second, method="PA", distances=distances, kernel="PA")


def margin(scores: object, k: int = 10, *, sort: bool = False) -> np.ndarray:
    """Margin baseline: s_2 − s_1, the negated gap between the best match and the runner-up.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, sorted descending along axis 1.
    k : int, default=10
        Accepted so every method shares one signature; only the two best matches are read.
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.

    Returns
    -------
    ndarray of shape (Q,)
        Uncertainty, higher = less trustworthy (0 when the two best matches tie).

    Examples
    --------
    >>> margin(np.array([[0.9, 0.5], [0.6, 0.6]]))
    array([-0.4,  0. ])
    """
    return _baseline(scores, k, sort, 2, lambda top, out: np.subtract(top[:, 1], top[:, 0], out=out), kernel="margin")


#: α of a row whose runners-up have no spread (or a single runner-up): the paper's default.
NO_EVIDENCE_ALPHA = 0.5


def _alpha_of_runners_up(runners_up: np.ndarray) -> np.ndarray:
    """α = 1 − |mean − median| / std of each row of sorted (descending), finite runners-up, shape (R, m)."""
    values = runners_up.astype(np.float64, copy=False)
    m = values.shape[1]
    mean = values.mean(axis=1)
    median = 0.5 * (values[:, (m - 1) // 2] + values[:, m // 2])  # rows are sorted
    spread = values.std(axis=1)
    # A spread at the rounding level of the values is no spread.
    flat = spread <= 8 * np.finfo(np.float64).eps * np.maximum(np.abs(mean), np.finfo(np.float64).tiny)
    with np.errstate(divide="ignore", invalid="ignore"):
        skew = np.abs(mean - median) / np.where(flat, 1.0, spread)
    return np.where(flat, NO_EVIDENCE_ALPHA, np.clip(1.0 - skew, 0.0, 1.0))


def adaptive_alpha(scores: object, k: int = 10, *, sort: bool = False) -> np.ndarray:
    """The weight α_q of RS of each query: 1 − the nonparametric skew of its runners-up.

    γ_q = |mean(s_2..s_k) − median(s_2..s_k)| / std(s_2..s_k) ∈ [0, 1] (population std) and α_q = 1 − γ_q: a
    homogeneous cohort of wrong candidates (mean = median) gives RS, one whose mean is pulled a standard deviation
    away from its median (a revisit, an aliasing candidate) gives SD, the robust estimate (Hogg 1974's adaptive
    estimators). Invariant to the location and scale of the scores. A cohort without spread gets
    :data:`NO_EVIDENCE_ALPHA` = 1/2. Evidence (docs/evidence/adaptive-alpha.md): mean AUC-PR 0.8145 against
    0.8116 for α = 0.5 on the corridor matrices, mostly from a shift towards RS; hence ``SU-adaptive`` is not a
    default method.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, higher = more similar, sorted descending along axis 1; ``-inf`` marks a
        missing candidate at the end of a row (the row is then used with the candidates it has).
    k : int, default=10
        Number of candidates used (the first ``min(k, K)`` columns). Must be >= 2.
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.

    Returns
    -------
    ndarray of shape (Q,), float64
        α_q in [0, 1].

    Examples
    --------
    >>> import numpy as np
    >>> adaptive_alpha(np.array([[0.9, 0.5, 0.4, 0.3], [0.9, 0.8, 0.3, 0.3], [0.9, 0.5, 0.5, 0.5]]), k=4).round(3)
    array([1.   , 0.293, 0.5  ])

    The first query's runners-up are symmetric (mean = median): RS. The second's mean is pulled up by one strong
    runner-up: mostly SD. The third's have no spread: the default 1/2.
    """
    k = check_k(k)
    scores = as_score_array(scores, sort=sort)
    check_rows(scores)
    n_queries = scores.shape[0]
    n = min(k, scores.shape[1])
    if n_queries == 0:
        return np.empty(0, dtype=np.float64)
    if n < 2:
        raise_for_short_rows(np.full(n_queries, n))
    top = scores[:, :n]
    n_candidates = np.isfinite(top).sum(axis=1)
    raise_for_short_rows(n_candidates)
    alpha = np.empty(n_queries, dtype=np.float64)
    for count in np.unique(n_candidates):  # usually one group: every row has n candidates
        rows = np.flatnonzero(n_candidates == count)
        alpha[rows] = _alpha_of_runners_up(top[rows, 1:count])
    return alpha


def adaptive_statistical_uncertainty(
    scores: object, k: int = 10, *, sort: bool = False, on_nonpositive: str = "most_uncertain"
) -> np.ndarray:
    """SU with a per-query α: α_q·RS_q + (1 − α_q)·SD_q, α_q from :func:`adaptive_alpha`. Training-free.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, higher = more similar, sorted descending along axis 1.
    k : int, default=10
        Number of candidates used. Must be >= 2.
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.
    on_nonpositive : {"most_uncertain", "raise"}, default="most_uncertain"
        What to do with rows whose best similarity is <= 0 (see :mod:`vpr_uncertainty.scores`).

    Returns
    -------
    ndarray of shape (Q,)
        Uncertainty, higher = less trustworthy.

    Examples
    --------
    >>> import numpy as np
    >>> adaptive_statistical_uncertainty(np.array([[0.8, 0.4, 0.3, 0.2]]), k=4)  # α = 1: RS
    array([0.375])
    """
    if sort:
        scores = as_score_array(scores, sort=True)
    rs = ratio_spread(scores, k, on_nonpositive=on_nonpositive)
    sd = similarity_distribution(scores, k, on_nonpositive=on_nonpositive)
    alpha = adaptive_alpha(scores, k).astype(rs.dtype)
    return alpha * rs + (1 - alpha) * sd
