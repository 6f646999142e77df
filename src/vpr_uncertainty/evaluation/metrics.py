"""Metrics of an uncertainty as a predictor of correct answers: AUC-PR, AP, rejection curves, AURC and recall@N.

Plain functions on arrays, in the style of :mod:`sklearn.metrics`: inputs are validated at the boundary and every
error names the argument, what was found and what was expected.

Conventions
-----------
* A query's answer is **correct** when its top-1 database image is among its positives.
* An uncertainty is higher for answers to trust less. These functions negate it exactly once, to rank queries by
  confidence; a correct answer is the positive class.
* **AUC-PR** is the trapezoid area ``sklearn.metrics.auc(recall, precision)`` under
  ``precision_recall_curve(correct, -uncertainty)``, the convention of the published VPR uncertainty tables;
  average precision (the step-wise area) is reported beside it.
* **End-to-end precision-recall**: the VPR system accepts the queries whose uncertainty is <= a threshold.
  Precision = correct accepted / accepted; recall = correct accepted / queries with at least one positive in
  the database. Each distinct uncertainty value is one threshold (tied queries are accepted together).
* **recall@N** is the share of queries with at least one positive that have one among their first N
  candidates.
* **AURC** is the area under the risk-coverage curve: Σ over thresholds of (coverage gained) × (error rate among
  the accepted queries), with coverage in steps of tied groups; lower is better.
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from sklearn.metrics import auc, average_precision_score, precision_recall_curve

__all__ = [
    "RECALL_NS",
    "RejectionCurve",
    "ThresholdChoice",
    "auc_pr",
    "aurc",
    "average_precision",
    "check_labels",
    "correct_at_n",
    "precision_at_recall",
    "recall_at_full_precision",
    "recall_at_n",
    "rejection_curve",
    "threshold_at_precision",
]

#: The N of recall@N reported by :func:`vpr_uncertainty.evaluate`; the largest one sets how many candidates a
#: retrieval needs.
RECALL_NS: tuple[int, ...] = (1, 5, 10, 20)


def _check_positives(indices: np.ndarray, positives: object) -> sparse.csr_array:
    positives = sparse.csr_array(positives, dtype=bool)
    if positives.shape[0] != indices.shape[0]:
        raise ValueError(f"positives has {positives.shape[0]} rows but indices has {indices.shape[0]} queries")
    return positives


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
    indices = np.asarray(indices)
    if indices.ndim != 2:
        raise ValueError(f"indices must be 2-D (n_queries, k), got shape {indices.shape}")
    if not 1 <= n <= indices.shape[1]:
        raise ValueError(f"n must be between 1 and the {indices.shape[1]} candidates per query, got {n}")
    positives = _check_positives(indices, positives)
    top = indices[:, :n]
    if top.size and top.max() >= positives.shape[1]:
        raise ValueError(
            f"indices refer to database image {int(top.max())} but the ground truth covers "
            f"{positives.shape[1]} database images"
        )
    rows = np.repeat(np.arange(len(top)), n)
    hits = np.asarray(positives[rows, np.maximum(top.ravel(), 0)]).reshape(top.shape)
    return (hits & (top >= 0)).any(axis=1)


def recall_at_n(indices: object, positives: object, ns: Sequence[int] = RECALL_NS) -> dict[int, float]:
    """recall@N over the queries that have at least one positive; N larger than K is left out.

    Parameters
    ----------
    indices : array-like of shape (Q, K), int
        Database index of each candidate, best first; ``-1`` marks a missing candidate.
    positives : sparse or dense bool matrix of shape (Q, D)
        Ground truth.
    ns : sequence of int, default=RECALL_NS
        The N to report.

    Returns
    -------
    dict of int to float
        N -> share of the answerable queries with a positive among their first N candidates.

    Examples
    --------
    >>> recall_at_n(np.array([[2, 0], [1, 0]]), np.array([[1, 0, 0], [1, 0, 0]], bool), ns=(1, 2, 5))
    {1: 0.0, 2: 1.0}
    """
    indices = np.asarray(indices)
    positives = _check_positives(indices, positives)
    answerable = np.asarray(positives.sum(axis=1)).ravel() > 0
    if not answerable.any():
        raise ValueError("no query has a positive in the database; recall@N is undefined")
    return {int(n): float(correct_at_n(indices, positives, n)[answerable].mean()) for n in ns if n <= indices.shape[1]}


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


def _check_both_classes(correct: np.ndarray) -> None:
    if correct.all() or not correct.any():
        state = "correct" if correct.all() else "wrong"
        raise ValueError(
            f"all {correct.size} top-1 answers are {state}: precision-recall needs both correct and wrong answers"
        )


def auc_pr(correct: object, uncertainty: object) -> float:
    """AUC-PR of an uncertainty as a predictor of a correct top-1 answer (trapezoid rule; higher is better).

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
    correct, uncertainty = check_labels(correct, uncertainty)
    _check_both_classes(correct)
    precision, recall, _ = precision_recall_curve(correct, -uncertainty)
    return float(auc(recall, precision))


def average_precision(correct: object, uncertainty: object) -> float:
    """Average precision (step-wise area under the PR curve) of an uncertainty; higher is better.

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
    correct, uncertainty = check_labels(correct, uncertainty)
    _check_both_classes(correct)
    return float(average_precision_score(correct, -uncertainty))


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

    thresholds: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    coverage: np.ndarray


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
    correct, uncertainty = check_labels(correct, uncertainty)
    n_answerable = correct.size if n_answerable is None else int(n_answerable)
    if n_answerable <= 0 or n_answerable < correct.sum():
        raise ValueError(
            f"n_answerable must be >= the {int(correct.sum())} correct answers and > 0, got {n_answerable}"
        )
    order = np.argsort(uncertainty, kind="stable")
    sorted_uncertainty = uncertainty[order]
    correct_accepted = np.cumsum(correct[order])
    # The last query of each group of tied uncertainties marks one threshold.
    group_ends = np.flatnonzero(np.diff(sorted_uncertainty, append=np.inf) > 0)
    accepted = group_ends + 1
    return RejectionCurve(
        thresholds=sorted_uncertainty[group_ends],
        precision=correct_accepted[group_ends] / accepted,
        recall=correct_accepted[group_ends] / n_answerable,
        coverage=accepted / correct.size,
    )


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
    curve = rejection_curve(correct, uncertainty)
    risk = 1.0 - curve.precision
    coverage_gained = np.diff(curve.coverage, prepend=0.0)
    return float(np.sum(coverage_gained * risk))


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


def _check_precision(precision: object) -> float:
    if isinstance(precision, bool) or not isinstance(precision, numbers.Real):
        raise TypeError(f"precision must be a number in (0, 1], got {precision!r}")
    value = float(precision)
    if not 0.0 < value <= 1.0:  # also rejects NaN
        raise ValueError(f"precision must lie in (0, 1], got {precision!r}")
    return value


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
    target = _check_precision(precision)
    if np.asarray(uncertainty).dtype == bool:
        raise ValueError(
            "uncertainty is boolean; expected one real number per query (higher = less trustworthy): were "
            "uncertainty and correct swapped? The order is threshold_at_precision(uncertainty, correct, precision)"
        )
    curve = rejection_curve(correct, uncertainty, n_answerable=n_answerable)
    reached = np.flatnonzero(curve.precision >= target)
    n_queries = np.asarray(correct).size
    if not reached.size:
        warnings.warn(
            f"no uncertainty threshold reaches precision {target:g} on these {n_queries} queries (the most "
            f"confident answers already give {curve.precision[0]:.3g}): the threshold accepts nothing",
            RuntimeWarning,
            stacklevel=2,
        )
        return ThresholdChoice(-math.inf, target, None, 0.0, 0.0, 0)
    last = int(reached[-1])
    threshold = float(curve.thresholds[last])
    return ThresholdChoice(
        threshold=threshold,
        target_precision=target,
        precision=float(curve.precision[last]),
        recall=float(curve.recall[last]),
        coverage=float(curve.coverage[last]),
        n_accepted=int(np.count_nonzero(np.asarray(uncertainty, dtype=np.float64) <= threshold)),
    )
