"""Score-only baselines: BM, L2, PA and margin, and the cosine-to-distance conversion they share.

Direction and input as in :mod:`vpr_uncertainty.scores` (which re-exports everything here): every function returns
an array of shape (Q,), higher = less trustworthy, from top-k similarities sorted descending along axis 1.

    * :func:`best_match` BM = −s_1
    * :func:`l2_distance` L2 = d_1, the top-1 descriptor distance
    * :func:`perceptual_aliasing` PA = d_1 / d_2
    * :func:`margin` = s_2 − s_1

L2 and PA read the squared distances when given; otherwise they convert cosine similarities with
:func:`squared_distances_from_similarities`, d² = 2 − 2s, which refuses similarities outside [−1, 1].
"""

from __future__ import annotations

import numpy as np

from vpr_uncertainty._validation import check_k, check_top_k_scores, raise_for_short_rows

__all__ = [
    "COSINE_TOLERANCE",
    "best_match",
    "l2_distance",
    "margin",
    "perceptual_aliasing",
    "squared_distances_from_similarities",
]

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


def _top_distances(scores: np.ndarray, distances: object, n: int, method: str) -> np.ndarray:
    """First ``n`` columns of the L2 distances (not squared), from ``distances`` or from the similarities."""
    if distances is None:
        return np.sqrt(squared_distances_from_similarities(scores[:, :n], method=method))
    squared = np.asarray(distances)
    if squared.ndim != 2 or squared.shape[0] != scores.shape[0] or squared.shape[1] < n:
        raise ValueError(f"distances must have shape ({scores.shape[0]}, >= {n}) to match scores, got {squared.shape}")
    squared = squared[:, :n].astype(scores.dtype, copy=False)
    if not (np.isfinite(squared).all() and (squared >= 0).all()):
        raise ValueError("distances must be finite squared L2 distances >= 0 in the columns used")
    if n > 1 and (squared[:, 1:] < squared[:, :-1]).any():
        raise ValueError("distances must be sorted in ascending order along axis 1 (nearest first)")
    return np.sqrt(squared)


def _prepare(scores: object, k: object, sort: bool, columns: int) -> np.ndarray:
    check_k(k)
    scores = check_top_k_scores(scores, sort=sort)
    if scores.shape[0] and scores.shape[1] < columns:
        raise ValueError(f"scores must have at least {columns} columns, got shape {scores.shape}")
    if scores.shape[0] and not np.isfinite(scores[:, :columns]).all():
        raise_for_short_rows(np.isfinite(scores[:, :columns]).sum(axis=1), needed=columns)
    return scores


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
    return -_prepare(scores, k, sort, 1)[:, 0]


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
    scores = _prepare(scores, k, sort, 1)
    if distances is not None and sort:
        distances = np.sort(np.asarray(distances), axis=1)
    return _top_distances(scores, distances, 1, "L2")[:, 0]


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
    scores = _prepare(scores, k, sort, 2)
    if distances is not None and sort:
        distances = np.sort(np.asarray(distances), axis=1)
    top2 = _top_distances(scores, distances, 2, "PA")
    first, second = top2[:, 0], top2[:, 1]
    both_zero = second == 0
    return np.divide(first, second, out=np.ones_like(first), where=~both_zero)


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
    scores = _prepare(scores, k, sort, 2)
    return scores[:, 1] - scores[:, 0]
