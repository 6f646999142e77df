"""How good is an uncertainty? Correctness, AUC-PR, rejection curves, recall@N, AURC and time per query.

Conventions
-----------
* A query's answer is **correct** when its top-1 database image is among its positives.
* An uncertainty is higher for answers to trust less. The evaluation negates it exactly once, to rank queries by
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
* **Uninformative**: a method that gives every query the same uncertainty ranks nothing; its AUC-PR is chance
  level. It is flagged (``informative: false``, ``distinct_values: 1``) and never reported as best.
* **k**: ``Evaluation.k`` is the k the methods used, ``min(k asked, candidates per query)``; a shortfall gives a
  :class:`FewerCandidatesWarning` and a note. Queries with s_1 <= 0 (ranked most uncertain by RS, SD, SU) are
  counted in the notes.
"""

from __future__ import annotations

import statistics
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import sparse
from sklearn.metrics import auc, average_precision_score, precision_recall_curve

from vpr_uncertainty._evaluation_notes import FewerCandidatesWarning, candidates_note, nonpositive_note, tied_note
from vpr_uncertainty.methods import OwnRetrievalUncertainty, available_methods, check_options, get_method
from vpr_uncertainty.retrieval import Retrieval

__all__ = [
    "DEFAULT_METHODS",
    "RECALL_NS",
    "Evaluation",
    "FewerCandidatesWarning",
    "MethodEvaluation",
    "RejectionCurve",
    "auc_pr",
    "aurc",
    "average_precision",
    "correct_at_n",
    "evaluate",
    "precision_at_recall",
    "recall_at_full_precision",
    "recall_at_n",
    "rejection_curve",
    "time_per_query",
]

#: The methods evaluated when none are named: the registered entries declared ``default=True``.
DEFAULT_METHODS: tuple[str, ...] = tuple(available_methods(default=True))
RECALL_LEVELS: tuple[float, ...] = (0.25, 0.5, 0.75)
#: The N of recall@N reported by :func:`evaluate`; the largest one sets how many candidates a retrieval needs.
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


def _check_labels(correct: object, uncertainty: object) -> tuple[np.ndarray, np.ndarray]:
    correct = np.asarray(correct)
    uncertainty = np.asarray(uncertainty, dtype=np.float64)
    if correct.ndim != 1 or uncertainty.shape != correct.shape:
        raise ValueError(
            f"correct and uncertainty must both have shape (n_queries,), got {correct.shape} and {uncertainty.shape}"
        )
    if correct.size == 0:
        raise ValueError("no queries to evaluate (correct and uncertainty are empty)")
    if correct.dtype != bool:
        if not np.isin(correct, (0, 1)).all():
            raise ValueError(f"correct must be boolean, got values {np.unique(correct)[:5]}")
        correct = correct.astype(bool)
    if not np.isfinite(uncertainty).all():
        raise ValueError(f"uncertainty contains {int((~np.isfinite(uncertainty)).sum())} NaN or inf values")
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
    correct, uncertainty = _check_labels(correct, uncertainty)
    _check_both_classes(correct)
    precision, recall, _ = precision_recall_curve(correct, -uncertainty)
    return float(auc(recall, precision))


def average_precision(correct: object, uncertainty: object) -> float:
    """Average precision (step-wise area under the PR curve) of an uncertainty; higher is better.

    Examples
    --------
    >>> average_precision([True, False, True, False], [0.1, 0.2, 0.3, 0.4])
    0.8333333333333333
    """
    correct, uncertainty = _check_labels(correct, uncertainty)
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
    correct, uncertainty = _check_labels(correct, uncertainty)
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
    """Precision at the strictest threshold whose recall reaches ``recall`` (None if it is never reached)."""
    if not 0.0 < recall <= 1.0:
        raise ValueError(f"recall must lie in (0, 1], got {recall}")
    reached = np.flatnonzero(curve.recall >= recall)
    return float(curve.precision[reached[0]]) if reached.size else None


def aurc(correct: object, uncertainty: object) -> float:
    """Area under the risk-coverage curve (lower is better); risk = share of wrong answers among the accepted.

    Examples
    --------
    >>> aurc([True, False], [0.1, 0.9])  # coverage 1/2: risk 0; coverage 1: risk 1/2
    0.25
    """
    curve = rejection_curve(correct, uncertainty)
    risk = 1.0 - curve.precision
    coverage_gained = np.diff(curve.coverage, prepend=0.0)
    return float(np.sum(coverage_gained * risk))


def time_per_query(
    compute: Callable[[], Any], n_queries: int, *, repeats: int = 5, budget_s: float = 0.5
) -> tuple[Any, float]:
    """Run ``compute`` once, then repeat it while within ``budget_s`` (at most ``repeats`` times in all).

    Returns
    -------
    result : the first call's return value
    seconds_per_query : float
        Median wall-clock time of one call divided by ``n_queries``.
    """
    durations = []
    start = time.perf_counter()
    result = compute()
    durations.append(time.perf_counter() - start)
    while len(durations) < repeats and sum(durations) < budget_s:
        start = time.perf_counter()
        compute()
        durations.append(time.perf_counter() - start)
    return result, statistics.median(durations) / max(n_queries, 1)


@dataclass
class MethodEvaluation:
    """Everything measured for one uncertainty method."""

    name: str
    uncertainty: np.ndarray
    auc_pr: float | None
    average_precision: float | None
    aurc: float
    time_per_query_ms: float
    curve: RejectionCurve
    recall_at_full_precision: float
    precision_at_recall: dict[float, float | None]
    own_recall_at_1: float | None = None

    @property
    def n_distinct(self) -> int:
        """Number of distinct uncertainty values (1: every query tied)."""
        return int(np.unique(self.uncertainty).size)

    @property
    def informative(self) -> bool:
        """False when every query has the same uncertainty: the ranking is arbitrary, AUC-PR and AP at chance."""
        return self.n_distinct > 1

    def to_dict(self) -> dict[str, Any]:
        return {
            "informative": self.informative,
            "distinct_values": self.n_distinct,
            "auc_pr": self.auc_pr,
            "average_precision": self.average_precision,
            "aurc": self.aurc,
            "time_per_query_ms": self.time_per_query_ms,
            "recall_at_100_precision": self.recall_at_full_precision,
            "precision_at_recall": {f"{level:g}": value for level, value in self.precision_at_recall.items()},
            **(
                {"correctness_from": "own retrieval", "own_recall@1": self.own_recall_at_1}
                if self.own_recall_at_1 is not None
                else {}
            ),
        }


@dataclass
class Evaluation:
    """Result of :func:`evaluate`: retrieval quality and one :class:`MethodEvaluation` per method."""

    n_queries: int
    n_answerable: int
    correct: np.ndarray
    recall_at_n: dict[int, float]
    methods: dict[str, MethodEvaluation] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    k: int | None = None
    k_requested: int | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON schema of ``evaluate --json``."""
        result: dict[str, Any] = {"n_queries": self.n_queries}
        if self.k is not None:
            result["k"] = self.k
        if self.k_requested is not None and self.k_requested != self.k:
            result["k_requested"] = self.k_requested
        result["recall@1"] = self.recall_at_n.get(1)
        result.update({f"recall@{n}": value for n, value in self.recall_at_n.items() if n != 1})
        result["n_queries_without_positives"] = self.n_queries - self.n_answerable
        result["methods"] = {name: method.to_dict() for name, method in self.methods.items()}
        if self.notes:
            result["notes"] = list(self.notes)
        return result


def evaluate(
    retrieval: Retrieval,
    methods: Sequence[str] = DEFAULT_METHODS,
    *,
    k: int = 10,
    alpha: float = 0.5,
    recall_levels: Sequence[float] = RECALL_LEVELS,
    timing_repeats: int = 5,
    **options: Any,
) -> Evaluation:
    """Compute every requested uncertainty on a retrieval and measure how well it predicts correct answers.

    Parameters
    ----------
    retrieval : Retrieval
        Top-k retrieval with its ground truth (``retrieval.positives``).
    methods : sequence of str
        Registered method names (see :func:`vpr_uncertainty.available_methods`).
    k, alpha : int, float
        Options of the score-based methods (k candidates, weight α of SU). When the retrieval holds fewer than
        k candidates per query, the methods use those it has: a :class:`FewerCandidatesWarning` and a note say
        so, and ``Evaluation.k`` records the k used.
    recall_levels : sequence of float
        Recall levels at which the end-to-end precision is reported.
    timing_repeats : int
        Calls per method for the time per query (median; fewer when a call is slow).
    **options
        Further options passed to the methods that accept them; an option that no selected method takes
        (besides the inputs of :data:`~vpr_uncertainty.methods.STAGE_INPUTS`) is a ValueError. Files the
        options name (e.g. BTL's head) are read once, before the timing.

    Returns
    -------
    Evaluation
    """
    if retrieval.positives is None:
        raise ValueError(
            "the retrieval has no ground truth (positives); read it with one (argument ground_truth) or from a file "
            "that holds it"
        )
    if retrieval.n_queries == 0:
        raise ValueError("the retrieval has no queries")
    if not methods:
        raise ValueError("no uncertainty method requested")
    entries = [get_method(name) for name in methods]  # unknown names fail before any work
    check_options(entries, options)  # and so do options that no selected method takes
    positives = retrieval.positives
    answerable = np.asarray(positives.sum(axis=1)).ravel() > 0
    correct = correct_at_n(retrieval.indices, positives, 1)
    evaluation = Evaluation(
        n_queries=retrieval.n_queries,
        n_answerable=int(answerable.sum()),
        correct=correct,
        recall_at_n=recall_at_n(retrieval.indices, positives),
        k=min(int(k), retrieval.k),
        k_requested=int(k),
    )
    if (~answerable).any():
        evaluation.notes.append(
            f"{int((~answerable).sum())} queries have no positive in the database; they count as wrong answers "
            "and are left out of the recall denominators"
        )
    both_classes = correct.any() and not correct.all()
    if not both_classes:
        evaluation.notes.append("AUC-PR and AP are undefined: every top-1 answer is correct, or none is")
        warnings.warn(evaluation.notes[-1], RuntimeWarning, stacklevel=2)
    names = [entry.name for entry in entries]
    shortfall = candidates_note(k, retrieval.k, names, retrieval.config.get("source"))
    if shortfall:
        evaluation.notes.append(shortfall)
        warnings.warn(shortfall, FewerCandidatesWarning, stacklevel=2)
    nonpositive = nonpositive_note(retrieval.scores, names)
    if nonpositive:
        evaluation.notes.append(nonpositive)
    for entry in entries:
        inputs = entry.resolve_inputs(retrieval, {"k": k, "alpha": alpha, **options})  # files read once
        result, seconds = time_per_query(
            lambda entry=entry, inputs=inputs: entry(retrieval, **inputs),
            retrieval.n_queries,
            repeats=timing_repeats,
        )
        method_correct, method_both, own_recall = correct, both_classes, None
        if isinstance(result, OwnRetrievalUncertainty):
            uncertainty = result.uncertainty
            own = result.retrieval
            method_correct = correct_at_n(own.indices, own.positives if own.positives is not None else positives, 1)
            method_both = bool(method_correct.any() and not method_correct.all())
            own_recall = float(method_correct[answerable].mean())
            evaluation.notes.append(
                f"{entry.name} retrieves with its own embeddings: its correctness labels come from its own top-1 "
                f"(recall@1 {own_recall:.3f})"
            )
        else:
            uncertainty = result
        curve = rejection_curve(method_correct, uncertainty, n_answerable=evaluation.n_answerable)
        evaluation.methods[entry.name] = MethodEvaluation(
            name=entry.name,
            uncertainty=uncertainty,
            auc_pr=auc_pr(method_correct, uncertainty) if method_both else None,
            average_precision=average_precision(method_correct, uncertainty) if method_both else None,
            aurc=aurc(method_correct, uncertainty),
            time_per_query_ms=seconds * 1e3,
            curve=curve,
            recall_at_full_precision=recall_at_full_precision(curve),
            precision_at_recall={level: precision_at_recall(curve, level) for level in recall_levels},
            own_recall_at_1=own_recall,
        )
    tied = tied_note(evaluation.methods.values(), evaluation.n_queries)
    if tied:
        evaluation.notes.append(tied)
    return evaluation
