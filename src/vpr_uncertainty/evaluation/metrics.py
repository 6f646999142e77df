"""Metrics of an uncertainty as a predictor of correct answers: AUC-PR, AP, rejection curves, AURC and recall@N, as
plain functions on arrays in the style of :mod:`sklearn.metrics`; the threshold metrics read one
:class:`UncertaintyRanking` (:func:`rank_queries`). Definitions: see docs/explanation/evaluation.md.
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from vpr_uncertainty._repr import compact_repr

#: The N of recall@N reported by :func:`vpr_uncertainty.evaluate` by default (its ``recall_at`` takes any N); the
#: largest one sets how many candidates a retrieval needs.
RECALL_NS: tuple[int, ...] = (1, 5, 10, 20)


def _check_positives(indices: np.ndarray, positives: object) -> sparse.csr_array:
    positives = sparse.csr_array(positives, dtype=bool)
    if positives.shape[0] != indices.shape[0]:
        raise ValueError(f"positives has {positives.shape[0]} rows but indices has {indices.shape[0]} queries")
    return positives


def first_positive_rank(indices: object, positives: object, n: int | None = None) -> np.ndarray:
    """Rank (0-based) of each query's first positive among its first ``n`` candidates; ``n`` when there is none.

    One look-up of the ground truth answers every N <= n: a query has a positive among its first N candidates
    exactly when its rank is < N.

    Parameters
    ----------
    indices : array-like of shape (Q, K), int
        Database index of each candidate, best first; ``-1`` marks a missing candidate.
    positives : sparse or dense bool matrix of shape (Q, D)
        Ground truth.
    n : int, optional
        How many candidates count; must be <= K (default: K).

    Returns
    -------
    ndarray of shape (Q,), int64

    Examples
    --------
    >>> first_positive_rank(np.array([[2, 0], [1, 0], [1, 2]]), np.array([[1, 0, 0], [1, 0, 0], [1, 0, 0]], bool))
    array([1, 1, 2])
    """
    indices = np.asarray(indices)
    if indices.ndim != 2:
        raise ValueError(f"indices must be 2-D (n_queries, k), got shape {indices.shape}")
    n = indices.shape[1] if n is None else n
    if not 1 <= n <= indices.shape[1]:
        raise ValueError(f"n must be between 1 and the {indices.shape[1]} candidates per query, got {n}")
    positives = _check_positives(indices, positives)
    top = indices[:, :n]
    if top.size and top.max() >= positives.shape[1]:
        raise ValueError(
            f"indices refer to database image {int(top.max())} but the ground truth covers "
            f"{positives.shape[1]} database images"
        )
    hits = candidate_hits(top, positives)
    first = hits.argmax(axis=1)  # the first True, or 0 when none
    first[~hits[np.arange(len(hits)), first]] = n
    return first


def candidate_hits(indices: np.ndarray, positives: sparse.csr_array) -> np.ndarray:
    """Whether each candidate (``indices`` (Q, K), ``-1``: missing) is among its query's ``positives``, (Q, K) bool."""
    rows = np.repeat(np.arange(len(indices)), indices.shape[1])
    hits = np.asarray(positives[rows, np.maximum(indices.ravel(), 0)]).reshape(indices.shape)
    return hits & (indices >= 0)


def positives_against_mean(scores: np.ndarray, rows: np.ndarray, columns: np.ndarray) -> tuple[int, int]:
    """How many rows of ``scores`` (R, C) give their positives (at ``rows``, ``columns``) a mean score above the row's
    mean, and how many below it (rows without positives count in neither)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        count = np.bincount(rows, minlength=len(scores))
        positive = np.bincount(rows, scores[rows, columns], minlength=len(scores)) / count
        mean = scores.mean(axis=1, dtype=np.float64)
    return int((positive > mean).sum()), int((positive < mean).sum())


def correct_at_n(indices: object, positives: object, n: int = 1) -> np.ndarray:
    """Whether each query has a positive among its first ``n`` candidates.

    Parameters
    ----------
    indices : array-like of shape (Q, K), int
        Database index of each candidate, best first; ``-1`` marks a missing candidate.
    positives : sparse or dense bool matrix of shape (Q, D)
        Ground truth.
    n : int, default=1
        How many candidates count; must be <= K.

    Returns
    -------
    ndarray of shape (Q,), bool

    Examples
    --------
    >>> correct_at_n(np.array([[2, 0], [1, 0]]), np.array([[True, False, False], [True, False, False]]), n=1)
    array([False, False])
    >>> correct_at_n(np.array([[2, 0], [1, 0]]), np.array([[True, False, False], [True, False, False]]), n=2)
    array([ True,  True])
    """
    return first_positive_rank(indices, positives, n) < n


def answerable_queries(positives: object) -> np.ndarray:
    """Whether each query has at least one positive in the database, shape (Q,), bool."""
    return np.asarray(sparse.csr_array(positives, dtype=bool).sum(axis=1)).ravel() > 0


class FewerCandidatesWarning(UserWarning):
    """The retrieval holds fewer candidates per query than asked for: a method's k, or the N of a recall@N."""


def check_recall_ns(ns: object) -> tuple[int, ...]:
    """The N of recall@N as a sorted tuple of distinct ints >= 1; else TypeError or ValueError naming what was wrong.

    Examples
    --------
    >>> check_recall_ns([10, 1, 100, 5, 10])
    (1, 5, 10, 100)
    """
    if isinstance(ns, (str, bytes)) or not isinstance(ns, Sequence):
        raise TypeError(f"the N of recall@N must be a sequence of ints such as (1, 5, 10, 100), got {ns!r}")
    if not ns:
        raise ValueError("the N of recall@N must not be empty; give e.g. (1, 5, 10)")
    for n in ns:
        if isinstance(n, bool) or not isinstance(n, numbers.Integral):
            raise TypeError(f"each N of recall@N must be an int, got {n!r}")
        if n < 1:
            raise ValueError(f"each N of recall@N must be >= 1, got {n}")
    return tuple(sorted({int(n) for n in ns}))


def recall_candidates_note(ns: Sequence[int], k: int, n_database: int | None = None) -> str | None:
    """Why some recall@N are not reported: N exceeds the ``k`` candidates per query of a retrieval that does not
    hold the whole database (``n_database``; None: unknown). None when every N can be answered.

    recall@N with N > k is unknown (a positive may rank between k + 1 and N), so it is reported as None rather than
    as recall@k under the name recall@N; when the retrieval holds every database image (``k >= n_database``) it is
    exact and no note is needed.

    Examples
    --------
    >>> recall_candidates_note((1, 5, 100), 20)
    'recall@100 needs 100 candidates per query, the retrieval holds 20: reported as None; retrieve at least 100'
    >>> recall_candidates_note((1, 5, 100), 20, n_database=20) is None
    True
    """
    if n_database is not None and k >= n_database:
        return None
    missing = [int(n) for n in ns if n > k]
    if not missing:
        return None
    names = ", ".join(f"recall@{n}" for n in missing)
    return (
        f"{names} need{'s' if len(missing) == 1 else ''} {max(missing)} candidates per query, the retrieval holds "
        f"{k}: reported as None; retrieve at least {max(missing)}"
    )


def recall_at_n(
    indices: object,
    positives: object,
    ns: Sequence[int] = RECALL_NS,
    *,
    first_rank: np.ndarray | None = None,
    answerable: np.ndarray | None = None,
) -> dict[int, float | None]:
    """recall@N over the queries that have at least one positive, for any N.

    An N larger than the K candidates per query is reported as None, with a :class:`FewerCandidatesWarning`
    (:func:`recall_candidates_note`), unless the K candidates cover the whole database (K >= D, the columns of
    ``positives``): then recall@N = recall@K exactly.

    Parameters
    ----------
    indices : array-like of shape (Q, K), int
        Database index of each candidate, best first; ``-1`` marks a missing candidate.
    positives : sparse or dense bool matrix of shape (Q, D)
        Ground truth.
    ns : sequence of int, default=RECALL_NS
        The N to report, each >= 1 (sorted and deduplicated).
    first_rank, answerable : ndarray of shape (Q,), optional
        :func:`first_positive_rank` over all K candidates and :func:`answerable_queries` of these inputs, when the
        caller has them already (otherwise computed here; every N is answered from one look-up either way).

    Returns
    -------
    dict of int to float or None
        N -> share of the answerable queries with a positive among their first N candidates (None: unknown, N > K).

    Examples
    --------
    >>> recall_at_n(np.array([[2, 0], [1, 0]]), np.array([[1, 0, 0], [1, 0, 0]], bool), ns=(1, 2))
    {1: 0.0, 2: 1.0}
    >>> recall_at_n(np.array([[2, 0], [1, 0]]), np.array([[1, 0, 0, 0], [1, 0, 0, 0]], bool), ns=(1, 100))
    ... # doctest: +SKIP
    FewerCandidatesWarning: recall@100 needs 100 candidates per query, the retrieval holds 2: reported as None; ...
    {1: 0.0, 100: None}
    """
    indices = np.asarray(indices)
    if indices.ndim != 2:
        raise ValueError(f"indices must be 2-D (n_queries, k), got shape {indices.shape}")
    ns = check_recall_ns(ns)
    positives = _check_positives(indices, positives)
    if answerable is None:
        answerable = answerable_queries(positives)
    if not answerable.any():
        raise ValueError("no query has a positive in the database; recall@N is undefined")
    k, n_database = indices.shape[1], positives.shape[1]
    note = recall_candidates_note(ns, k, n_database)
    if note:
        warnings.warn(note, FewerCandidatesWarning, stacklevel=2)
    known = [n for n in ns if n <= k or k >= n_database]
    if known and first_rank is None:
        first_rank = first_positive_rank(indices, positives, min(max(known), k))
    ranks = first_rank[answerable] if known else None
    # N > K is known only when the K candidates cover the database: then it is recall@K, whatever the ranks hold.
    return {n: float((ranks < min(n, k)).mean()) if n in known else None for n in ns}


def check_labels(correct: object, uncertainty: object, *, name: str = "uncertainty") -> tuple[np.ndarray, np.ndarray]:
    """``correct`` as bool and ``uncertainty`` (called ``name`` in the errors) as float64, both of shape (Q,) with
    Q >= 1, finite; else ValueError."""
    correct = np.asarray(correct)
    uncertainty = np.asarray(uncertainty, dtype=np.float64)
    if correct.ndim != 1 or uncertainty.shape != correct.shape:
        raise ValueError(
            f"correct and {name} must both have shape (n_queries,) (1-D, of one length), got {correct.shape} and "
            f"{uncertainty.shape}"
        )
    if correct.size == 0:
        raise ValueError(f"no queries to evaluate (correct and {name} are empty)")
    if correct.dtype != bool:
        if not np.isin(correct, (0, 1)).all():
            raise ValueError(f"correct must be boolean, got values {np.unique(correct)[:5]}")
        correct = correct.astype(bool)
    if not np.isfinite(uncertainty).all():
        raise ValueError(f"{name} contains {int((~np.isfinite(uncertainty)).sum())} NaN or inf values")
    return correct, uncertainty


@dataclass(frozen=True)
class RejectionCurve:
    """Precision and recall of the VPR system at every uncertainty threshold, from strictest to most lenient.

    Attributes
    ----------
    thresholds : ndarray of shape (T,)
        Distinct uncertainty values, ascending; the system accepts queries with uncertainty <= threshold.
    precision, recall, coverage : ndarray of shape (T,)
        At each threshold: correct accepted / accepted, correct accepted / answerable queries, and accepted /
        all queries.
    """

    __repr__ = compact_repr

    thresholds: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    coverage: np.ndarray


@dataclass(frozen=True)
class UncertaintyRanking:
    """Queries grouped by distinct uncertainty, ascending: what every threshold metric reads, from one sort.

    Build it with :func:`rank_queries`. Tied queries form one group (one threshold, accepted together), so every
    number here is a count over whole groups and does not depend on how a sort orders the queries within a tie.

    Attributes
    ----------
    thresholds : ndarray of shape (T,), float64
        The distinct uncertainty values, ascending.
    accepted : ndarray of shape (T,), int64
        Queries with uncertainty <= each threshold.
    correct_accepted : ndarray of shape (T,), int64
        Correct answers among them.
    """

    __repr__ = compact_repr

    thresholds: np.ndarray
    accepted: np.ndarray
    correct_accepted: np.ndarray

    @property
    def n_queries(self) -> int:
        return int(self.accepted[-1])

    @property
    def n_correct(self) -> int:
        return int(self.correct_accepted[-1])

    @property
    def n_distinct(self) -> int:
        """Number of distinct uncertainty values (1: every query tied)."""
        return int(self.thresholds.size)

    @property
    def tied_share(self) -> float:
        """Share of the queries whose uncertainty equals that of at least one other query (0: no ties)."""
        sizes = np.diff(self.accepted, prepend=0)
        return float(sizes[sizes > 1].sum() / self.n_queries)

    def precision_recall(self) -> tuple[np.ndarray, np.ndarray]:
        """Precision and recall of ``sklearn.metrics.precision_recall_curve(correct, -uncertainty)``, in its layout
        (most lenient threshold first, then the point (recall 0, precision 1)) and its arithmetic.

        Needs both correct and wrong answers (else ValueError).
        """
        if self.n_correct in (0, self.n_queries):
            raise ValueError(
                f"all {self.n_queries} top-1 answers are {'correct' if self.n_correct else 'wrong'}: precision-recall "
                "needs both correct and wrong answers"
            )
        tps = self.correct_accepted.astype(np.float64)
        precision = tps / self.accepted  # sklearn: tps / (tps + fps), and tps + fps = accepted, exactly
        recall = tps / tps[-1]
        return np.concatenate((precision[::-1], [1.0])), np.concatenate((recall[::-1], [0.0]))

    def auc_pr(self) -> float:
        """Trapezoid AUC-PR, ``sklearn.metrics.auc(recall, precision)``; see :func:`auc_pr`."""
        precision, recall = self.precision_recall()
        # sklearn.metrics.auc's arithmetic for a decreasing x (direction -1), without importing scikit-learn (1-2 s
        # of a command's start-up, pandas and pyarrow included); tests compare it with sklearn's, bit for bit.
        return float(-1 * np.trapezoid(precision, recall))

    def average_precision(self) -> float:
        """Step-wise area, ``sklearn.metrics.average_precision_score``'s sum; see :func:`average_precision`."""
        precision, recall = self.precision_recall()
        return float(max(0.0, -np.sum(np.diff(recall) * precision[:-1])))

    def rejection_curve(self, *, n_answerable: int | None = None) -> RejectionCurve:
        """See :func:`rejection_curve`."""
        n_correct = self.n_correct
        n_answerable = self.n_queries if n_answerable is None else int(n_answerable)
        if n_answerable <= 0 or n_answerable < n_correct:
            raise ValueError(f"n_answerable must be >= the {n_correct} correct answers and > 0, got {n_answerable}")
        return RejectionCurve(
            thresholds=self.thresholds,
            precision=self.correct_accepted / self.accepted,
            recall=self.correct_accepted / n_answerable,
            coverage=self.accepted / self.n_queries,
        )

    def aurc(self) -> float:
        """See :func:`aurc`."""
        risk = 1.0 - self.correct_accepted / self.accepted
        coverage_gained = np.diff(self.accepted / self.n_queries, prepend=0.0)
        return float(np.sum(coverage_gained * risk))


def rank_queries(correct: object, uncertainty: object) -> UncertaintyRanking:
    """Sort the queries by uncertainty once and count, at each distinct value, the queries accepted and the correct.

    Parameters
    ----------
    correct : array-like of shape (Q,), bool
        Whether each query's top-1 answer is correct.
    uncertainty : array-like of shape (Q,)
        Higher = less trustworthy; finite.

    Returns
    -------
    UncertaintyRanking
        Its methods give AUC-PR, AP, the rejection curve and AURC without sorting again.

    Examples
    --------
    >>> ranking = rank_queries([True, False, True, False], [0.1, 0.3, 0.3, 0.4])
    >>> ranking.thresholds, ranking.accepted, ranking.correct_accepted
    (array([0.1, 0.3, 0.4]), array([1, 3, 4]), array([1, 2, 2]))
    >>> ranking.auc_pr() == auc_pr([True, False, True, False], [0.1, 0.3, 0.3, 0.4])
    True
    """
    correct, uncertainty = check_labels(correct, uncertainty)
    # Any order sorts the values; the counts at the ends of tie groups do not depend on the order within a group,
    # so the faster unstable sort gives the same numbers as a stable one.
    order = np.argsort(uncertainty)
    sorted_uncertainty = uncertainty[order]
    correct_accepted = np.cumsum(correct[order], dtype=np.int64)
    # The last query of each group of tied uncertainties marks one threshold.
    group_ends = np.flatnonzero(np.diff(sorted_uncertainty, append=np.inf) > 0)
    return UncertaintyRanking(
        thresholds=sorted_uncertainty[group_ends],
        accepted=group_ends + 1,
        correct_accepted=correct_accepted[group_ends],
    )


def auc_pr(correct: object, uncertainty: object) -> float:
    """AUC-PR of an uncertainty as a predictor of a correct top-1 answer (trapezoid rule; higher is better).

    The same number as ``sklearn.metrics.auc(recall, precision)`` over
    ``sklearn.metrics.precision_recall_curve(correct, -uncertainty)`` (one threshold per distinct uncertainty).

    Parameters
    ----------
    correct : array-like of shape (Q,), bool
        Whether each query's top-1 answer is correct.
    uncertainty : array-like of shape (Q,)
        Higher = less trustworthy.

    Examples
    --------
    >>> auc_pr([True, True, False, False], [0.1, 0.2, 0.3, 0.4])
    1.0
    """
    return rank_queries(correct, uncertainty).auc_pr()


def average_precision(correct: object, uncertainty: object) -> float:
    """Average precision (step-wise area under the PR curve) of an uncertainty; higher is better.

    The same number as ``sklearn.metrics.average_precision_score(correct, -uncertainty)``.

    Parameters
    ----------
    correct : array-like of shape (Q,), bool
        Whether each query's top-1 answer is correct.
    uncertainty : array-like of shape (Q,)
        Higher = less trustworthy.

    Examples
    --------
    >>> average_precision([True, False, True, False], [0.1, 0.2, 0.3, 0.4])
    0.8333333333333333
    """
    return rank_queries(correct, uncertainty).average_precision()


def rejection_curve(correct: object, uncertainty: object, *, n_answerable: int | None = None) -> RejectionCurve:
    """End-to-end precision-recall of the VPR system when queries above an uncertainty threshold are rejected.

    Parameters
    ----------
    correct : array-like of shape (Q,), bool
        Whether each query's top-1 answer is correct.
    uncertainty : array-like of shape (Q,)
        Higher = less trustworthy.
    n_answerable : int, optional
        Number of queries with at least one positive in the database (the recall denominator); by default all
        queries.

    Examples
    --------
    >>> curve = rejection_curve([True, False, True], [0.1, 0.5, 0.2], n_answerable=2)
    >>> curve.precision, curve.recall
    (array([1.        , 1.        , 0.66666667]), array([0.5, 1. , 1. ]))
    """
    return rank_queries(correct, uncertainty).rejection_curve(n_answerable=n_answerable)


def recall_at_full_precision(curve: RejectionCurve) -> float:
    """Largest recall reached with no wrong answer accepted (0 when the most confident answer is wrong)."""
    perfect = curve.precision >= 1.0
    return float(curve.recall[perfect].max()) if perfect.any() else 0.0


def precision_at_recall(curve: RejectionCurve, recall: float) -> float | None:
    """Precision at the strictest threshold whose recall reaches ``recall`` (None if it is never reached).

    Parameters
    ----------
    curve : RejectionCurve
    recall : float
        In (0, 1].
    """
    if not 0.0 < recall <= 1.0:
        raise ValueError(f"recall must lie in (0, 1], got {recall}")
    reached = np.flatnonzero(curve.recall >= recall)
    return float(curve.precision[reached[0]]) if reached.size else None


def aurc(correct: object, uncertainty: object) -> float:
    """Area under the risk-coverage curve (lower is better); risk = share of wrong answers among the accepted.

    Parameters
    ----------
    correct : array-like of shape (Q,), bool
        Whether each query's top-1 answer is correct.
    uncertainty : array-like of shape (Q,)
        Higher = less trustworthy; tied queries are accepted together.

    Examples
    --------
    >>> aurc([True, False], [0.1, 0.9])  # coverage 1/2: risk 0; coverage 1: risk 1/2
    0.25
    """
    return rank_queries(correct, uncertainty).aurc()


@dataclass(frozen=True)
class ThresholdChoice:
    """What :func:`threshold_at_precision` found: accept a query when its uncertainty is <= ``threshold``.

    Attributes
    ----------
    threshold : float
        The largest uncertainty value accepted; ``-inf`` when no threshold reaches the target (accept nothing).
    target_precision : float
        The precision asked for.
    precision : float or None
        Precision of the accepted queries (correct accepted / accepted); None when nothing is accepted.
    recall : float
        Correct accepted / answerable queries.
    coverage : float
        Accepted / all queries.
    n_accepted : int
        Number of queries accepted.
    """

    threshold: float
    target_precision: float
    precision: float | None
    recall: float
    coverage: float
    n_accepted: int

    def __str__(self) -> str:
        if not self.reached:
            return f"no threshold reaches precision {self.target_precision:g}: accept nothing"
        return (
            f"accept uncertainty <= {self.threshold:.4g}: precision {self.precision:.3f}, recall {self.recall:.3f}, "
            f"coverage {self.coverage:.3f} ({self.n_accepted} queries)"
        )

    @property
    def reached(self) -> bool:
        """Whether some threshold reached the target precision on these queries."""
        return self.n_accepted > 0

    def accept(self, uncertainty: object) -> np.ndarray:
        """Which of these uncertainties are accepted (``uncertainty <= threshold``), shape (Q,), bool."""
        return np.asarray(uncertainty, dtype=np.float64) <= self.threshold


def threshold_at_precision(
    uncertainty: object, correct: object, precision: float, *, n_answerable: int | None = None
) -> ThresholdChoice:
    """The most lenient uncertainty threshold whose empirical precision is at least ``precision``.

    Empirical, **with no guarantee**: the threshold is fitted to the very queries it is measured on, so on new
    queries the precision can be lower, the more so the fewer they are. For a threshold with a guarantee (precision
    >= p* on new queries with probability 1 − δ) use :func:`vpr_uncertainty.calibrate`.

    Parameters
    ----------
    uncertainty : array-like of shape (Q,)
        Uncertainty of each labelled query, higher = less trustworthy (e.g. SU); finite.
    correct : array-like of shape (Q,), bool
        Whether each query's top-1 answer is correct (0/1 accepted).
    precision : float in (0, 1]
        The target: correct accepted / accepted.
    n_answerable : int, optional
        Queries with at least one positive in the database (the recall denominator); by default all queries.

    Returns
    -------
    ThresholdChoice
        ``threshold`` (accept ``uncertainty <= threshold``; tied queries are accepted together), the precision,
        recall and coverage it gives on these queries and how many it accepts. When no threshold reaches the
        target (the most confident answer is already wrong), ``threshold`` is ``-inf`` (accept nothing),
        ``precision`` is None and a ``RuntimeWarning`` says so.

    Raises
    ------
    ValueError
        When the shapes differ, the arrays are empty, ``correct`` is not boolean (or 0/1), ``uncertainty`` holds
        NaN or inf or is boolean (arguments swapped?), or ``precision`` is outside (0, 1].

    Examples
    --------
    >>> choice = threshold_at_precision([0.1, 0.2, 0.3, 0.4, 0.5], [True, True, False, True, False], 0.75)
    >>> choice.threshold, choice.precision, choice.recall, choice.n_accepted
    (0.4, 0.75, 0.6, 4)
    >>> print(threshold_at_precision([0.1, 0.2, 0.3, 0.4, 0.5], [True, True, False, True, False], 1.0))
    accept uncertainty <= 0.2: precision 1.000, recall 0.400, coverage 0.400 (2 queries)
    """
    if isinstance(precision, bool) or not isinstance(precision, numbers.Real):
        raise TypeError(f"precision must be a number in (0, 1], got {precision!r}")
    target = float(precision)
    if not 0.0 < target <= 1.0:  # also rejects NaN
        raise ValueError(f"precision must lie in (0, 1], got {precision!r}")
    if np.asarray(uncertainty).dtype == bool:
        raise ValueError(
            "uncertainty is boolean; expected one real number per query (higher = less trustworthy): were "
            "uncertainty and correct swapped? The order is threshold_at_precision(uncertainty, correct, precision)"
        )
    ranking = rank_queries(correct, uncertainty)
    curve = ranking.rejection_curve(n_answerable=n_answerable)
    reached = np.flatnonzero(curve.precision >= target)
    if not reached.size:
        warnings.warn(
            f"no uncertainty threshold reaches precision {target:g} on these {ranking.n_queries} queries (the most "
            f"confident answers already give {curve.precision[0]:.3g}): the threshold accepts nothing",
            RuntimeWarning,
            stacklevel=2,
        )
        return ThresholdChoice(-math.inf, target, None, 0.0, 0.0, 0)
    last = int(reached[-1])
    return ThresholdChoice(
        threshold=float(curve.thresholds[last]),
        target_precision=target,
        precision=float(curve.precision[last]),
        recall=float(curve.recall[last]),
        coverage=float(curve.coverage[last]),
        n_accepted=int(ranking.accepted[last]),
    )
