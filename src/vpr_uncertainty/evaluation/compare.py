"""Is one VPR method, or one uncertainty method, better than another on the same queries? Paired tests:
:func:`compare` (paired-bootstrap differences of AUC-PR and AP) and :func:`mcnemar` (the exact test of recall@1).
Conventions: see docs/explanation/evaluation.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from vpr_uncertainty._validation import check_count, check_resamples
from vpr_uncertainty.evaluation.bootstrap import (
    evaluation_distributions,
    holm,
    paired_p_value,
    percentile_interval,
    significance_notice,
)
from vpr_uncertainty.evaluation.results import Evaluation, MethodEvaluation

#: The metrics compared, and how they are named in tables.
COMPARED_METRICS: dict[str, str] = {"auc_pr": "AUC-PR", "average_precision": "AP"}
#: Defaults shared with ``evaluate --bootstrap`` and :func:`~vpr_uncertainty.evaluation.bootstrap.bootstrap_metrics`.
DEFAULT_RESAMPLES, DEFAULT_SEED = 1000, 0


@dataclass(frozen=True)
class McNemar:
    """Exact McNemar test of two paired sets of top-1 correctness flags (recall@1 of A against B)."""

    #: Queries both answer correctly, only A, only B, neither.
    both_correct: int
    a_only: int
    b_only: int
    both_wrong: int
    p_value: float

    @property
    def n_queries(self) -> int:
        return self.both_correct + self.a_only + self.b_only + self.both_wrong

    @property
    def recall_a(self) -> float:
        return (self.both_correct + self.a_only) / self.n_queries

    @property
    def recall_b(self) -> float:
        return (self.both_correct + self.b_only) / self.n_queries

    def to_dict(self) -> dict[str, Any]:
        return {"recall@1_a": self.recall_a, "recall@1_b": self.recall_b, **asdict(self)}


def mcnemar(correct_a: object, correct_b: object) -> McNemar:
    """Exact (binomial) two-sided McNemar test of two methods' top-1 correctness on the same queries.

    Parameters
    ----------
    correct_a, correct_b : array-like of shape (Q,), bool
        Whether each query's top-1 answer is correct, for A and for B.

    Returns
    -------
    McNemar
        The four counts and the p-value of the discordant pairs ``a_only`` (b) and ``b_only`` (c).

    Examples
    --------
    >>> test = mcnemar([1, 0, 0, 0, 0, 0, 0, 1], [0, 1, 1, 1, 1, 1, 1, 1])
    >>> test.a_only, test.b_only, test.p_value
    (1, 6, 0.125)
    """
    from scipy.stats import binomtest

    a, b = _flags(correct_a, "correct_a"), _flags(correct_b, "correct_b")
    if a.shape != b.shape:
        raise ValueError(f"correct_a and correct_b must have the same shape (n_queries,), got {a.shape} and {b.shape}")
    both, a_only, b_only, neither = (int(flags.sum()) for flags in (a & b, a & ~b, ~a & b, ~a & ~b))
    p_value = 1.0 if a_only + b_only == 0 else float(binomtest(a_only, a_only + b_only, 0.5).pvalue)
    return McNemar(both_correct=both, a_only=a_only, b_only=b_only, both_wrong=neither, p_value=min(1.0, p_value))


def _flags(values: object, name: str) -> np.ndarray:
    array = np.asarray(values)
    if array.ndim != 1 or array.size == 0:
        raise ValueError(f"{name} must have shape (n_queries,) with n_queries >= 1, got {array.shape}")
    if array.dtype != bool:
        if not np.isin(array, (0, 1)).all():
            raise ValueError(f"{name} must be boolean, got values {np.unique(array)[:5]}")
        array = array.astype(bool)
    return array


@dataclass(frozen=True)
class Difference:
    """One metric of A against B: point values, their difference A - B, its interval and paired p-values."""

    metric: str
    method_a: str
    method_b: str
    value_a: float | None
    value_b: float | None
    difference: float | None
    interval: tuple[float, float] | None
    p_value: float | None
    p_value_holm: float | None
    #: Resamples left out (one side's labels held one class only).
    skipped: int = 0

    def to_dict(self) -> dict[str, Any]:
        """The fields in field order, four named for JSON: ``a``, ``b``, ``ci`` (a list) and ``skipped_resamples``."""
        json_names = {"value_a": "a", "value_b": "b", "interval": "ci", "skipped": "skipped_resamples"}
        data = {json_names.get(key, key): value for key, value in asdict(self).items()}
        return {**data, "ci": None if self.interval is None else list(self.interval)}


@dataclass(frozen=True)
class Comparison:
    """What :func:`compare` returns: the differences of each metric, and McNemar's test when two VPR methods are
    compared. ``str`` is a table; :meth:`to_dict` the JSON document of ``vpr-uncertainty compare --json``."""

    label_a: str
    label_b: str
    n_queries: int
    differences: list[Difference]
    mcnemar: McNemar | None
    n_resamples: int
    seed: int
    confidence: float
    notes: list[str] = field(default_factory=list)
    #: Candidates per query the uncertainties of both sides were computed from (``Evaluation.k``).
    k: int | None = None

    def difference(self, metric: str, method: str) -> Difference:
        """The row of ``metric`` (``auc_pr`` or ``average_precision``) for ``method`` (A's method name)."""
        for row in self.differences:
            if row.metric == metric and row.method_a == method:
                return row
        raise KeyError(f"no {metric} difference for {method!r}")

    def to_dict(self) -> dict[str, Any]:
        return {
            "a": self.label_a,
            "b": self.label_b,
            "n_queries": self.n_queries,
            "k": self.k,
            "bootstrap": {
                "resamples": self.n_resamples,
                "seed": self.seed,
                "confidence": self.confidence,
                "test": "paired bootstrap over queries (the same resamples for A and B); percentile interval of A - B; "
                "two-sided paired p-value; Holm over the uncertainty methods compared, per metric",
            },
            "differences": [row.to_dict() for row in self.differences],
            "mcnemar_recall@1": None if self.mcnemar is None else self.mcnemar.to_dict(),
            **({"notes": list(self.notes)} if self.notes else {}),
        }

    def __str__(self) -> str:
        percent = f"{self.confidence * 100:g}% CI"
        lines = [
            f"A = {self.label_a}, B = {self.label_b}: {self.n_queries} queries, k = {self.k}, paired bootstrap "
            f"({self.n_resamples} resamples, seed {self.seed})",
            "significant: Holm-adjusted p <= 0.05 (Holm over the methods compared, per metric)",
            f"{'metric':<7} {'method':<14} {'A':>7} {'B':>7} {'A - B':>8} {percent:>19} {'p':>7} {'Holm p':>7}",
        ]
        for row in self.differences:
            name = row.method_a if row.method_a == row.method_b else f"{row.method_a}-{row.method_b}"
            interval = "n/a" if row.interval is None else f"[{row.interval[0]:+.4f}, {row.interval[1]:+.4f}]"
            lines.append(
                f"{COMPARED_METRICS[row.metric]:<7} {name:<14} {_number(row.value_a):>7} {_number(row.value_b):>7} "
                f"{_number(row.difference, '+.4f'):>8} {interval:>19} {_number(row.p_value):>7} "
                f"{_number(row.p_value_holm):>7}"
            )
        if self.mcnemar is not None:
            test = self.mcnemar
            lines.append(
                f"recall@1: A {test.recall_a:.4f}, B {test.recall_b:.4f}; McNemar exact: A only {test.a_only}, "
                f"B only {test.b_only}, both {test.both_correct}, neither {test.both_wrong}, p = {test.p_value:.4g}"
            )
        lines.extend(f"note: {note}" for note in self.notes)
        return "\n".join(lines)

    __repr__ = __str__


def _number(value: float | None, spec: str = ".4f") -> str:
    return "n/a" if value is None else f"{value:{spec}}"


def _check_evaluation(value: object, name: str) -> None:
    if not (hasattr(value, "methods") and hasattr(value, "correct") and hasattr(value, "n_queries")):
        raise TypeError(f"{name} must be an Evaluation (from vpr_uncertainty.evaluate), got {type(value).__name__}")


def _check_same_queries(
    evaluation_a: Evaluation, evaluation_b: Evaluation, names_a: object, names_b: object, labels: Sequence[str]
) -> None:
    if evaluation_a.n_queries != evaluation_b.n_queries:
        raise ValueError(
            f"{labels[0]} and {labels[1]} must hold the same queries: they have {evaluation_a.n_queries} and "
            f"{evaluation_b.n_queries} queries"
        )
    if names_a is None or names_b is None:
        return
    names_a, names_b = np.asarray(names_a).astype(str), np.asarray(names_b).astype(str)
    if names_a.shape != (evaluation_a.n_queries,) or names_b.shape != (evaluation_b.n_queries,):
        raise ValueError(
            f"query names must have shape ({evaluation_a.n_queries},), got {names_a.shape} and {names_b.shape}"
        )
    differ = np.flatnonzero(names_a != names_b)
    if differ.size:
        first = int(differ[0])
        raise ValueError(
            f"{labels[0]} and {labels[1]} must hold the same queries in the same order: {differ.size} query names "
            f"differ, first at query {first} ({names_a[first]!r} vs {names_b[first]!r})"
        )


def _differences(
    pairs: Sequence[tuple[MethodEvaluation, MethodEvaluation]],
    distributions_a: dict[str, dict[str, np.ndarray]],
    distributions_b: dict[str, dict[str, np.ndarray]],
    confidence: float,
) -> list[Difference]:
    rows: list[Difference] = []
    for metric in COMPARED_METRICS:
        found = []
        for method_a, method_b in pairs:
            first, second = distributions_a[metric][method_a.name], distributions_b[metric][method_b.name]
            value_a, value_b = getattr(method_a, metric), getattr(method_b, metric)
            row = {
                "metric": metric,
                "method_a": method_a.name,
                "method_b": method_b.name,
                "value_a": value_a,
                "value_b": value_b,
                "difference": None if value_a is None or value_b is None else float(value_a - value_b),
                "interval": percentile_interval(first - second, confidence),
                "p_value": paired_p_value(first, second),
                "skipped": int((np.isnan(first) | np.isnan(second)).sum()),
            }
            found.append(row)
        tested = [row for row in found if row["p_value"] is not None]
        for row, p_holm in zip(tested, holm([row["p_value"] for row in tested]), strict=True):
            row["p_value_holm"] = p_holm
        rows.extend(Difference(**{"p_value_holm": None, **row}) for row in found)
    return rows


def compare(
    evaluation_a: Evaluation,
    evaluation_b: Evaluation | None = None,
    *,
    method_a: str | None = None,
    method_b: str | None = None,
    methods: Sequence[str] | None = None,
    labels: Sequence[str] = ("A", "B"),
    query_names_a: object = None,
    query_names_b: object = None,
    n_resamples: int = DEFAULT_RESAMPLES,
    seed: int = DEFAULT_SEED,
    confidence: float = 0.95,
) -> Comparison:
    """Paired comparison of two VPR methods on the same queries, or of two uncertainty methods in one evaluation.

    Parameters
    ----------
    evaluation_a : Evaluation
        A: what :func:`vpr_uncertainty.evaluate` returned.
    evaluation_b : Evaluation, optional
        B: the evaluation of another VPR method's retrieval of the **same queries, in the same order**. Given:
        every uncertainty method evaluated in both (or ``methods``) is compared, A - B, and recall@1 by McNemar's
        test. Not given: ``method_a`` and ``method_b`` of ``evaluation_a`` are compared.
    method_a, method_b : str, optional
        The two uncertainty methods of ``evaluation_a`` to compare (``method_a - method_b``), without
        ``evaluation_b``.
    methods : sequence of str, optional
        With ``evaluation_b``: the uncertainty methods to compare (each must be in both); default, every method in
        both, in A's order.
    labels : (str, str), default=("A", "B")
        Names of the two evaluations in the table and the errors (e.g. the VPR methods); with ``method_a`` and
        ``method_b`` the sides are named by the methods.
    query_names_a, query_names_b : array-like of shape (Q,), optional
        The queries' names (``Retrieval.query_names``); when both are given they must be equal.
    n_resamples : int, default=1000
        Bootstrap resamples, >= 40 at 95 % (:func:`~vpr_uncertainty._validation.check_resamples`).
    seed : int, default=0
        Seed of the resamples (:func:`~vpr_uncertainty.evaluation.bootstrap.resample_indices`).
    confidence : float, default=0.95
        Of the intervals, in (0, 1).

    Returns
    -------
    Comparison
        One :class:`Difference` per metric (AUC-PR, AP) and compared method, and :class:`McNemar` of recall@1 when
        ``evaluation_b`` is given.

    Raises
    ------
    ValueError
        When the two evaluations do not hold the same queries or were evaluated at different k (``Evaluation.k``), a
        method is missing, no method is in both, or ``n_resamples`` is too few for an interval and a p-value.

    Examples
    --------
    >>> import numpy as np
    >>> from vpr_uncertainty import Retrieval, evaluate
    >>> retrieval = Retrieval(scores=np.array([[0.6, 0.1], [0.5, 0.45], [0.8, 0.2], [0.95, 0.94]]),
    ...                       indices=np.array([[0, 1], [0, 1], [1, 0], [0, 1]]), positives=[[0], [1], [1], [1]])
    >>> evaluation = evaluate(retrieval, ["SU", "BM"], k=2)
    >>> result = compare(evaluation, method_a="SU", method_b="BM", n_resamples=200)
    >>> row = result.difference("auc_pr", "SU")
    >>> row.method_b, round(row.difference, 4)  # SU ranks both correct answers first, BM does not
    ('BM', 0.5833)
    """
    seed = check_count(seed, "seed", 0)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    n_resamples = check_resamples(n_resamples, confidence=confidence)
    labels = tuple(str(label) for label in labels)
    if len(labels) != 2:
        raise ValueError(f"labels must name the two sides, got {labels}")
    _check_evaluation(evaluation_a, "evaluation_a")
    notes: list[str] = []
    if evaluation_b is None:
        if methods is not None or query_names_a is not None or query_names_b is not None:
            raise ValueError("methods and query names apply to two evaluations; give evaluation_b")
        if method_a is None or method_b is None:
            raise ValueError(
                "give evaluation_b (two VPR methods), or method_a and method_b (two uncertainty methods of one "
                "evaluation)"
            )
        for name in (method_a, method_b):
            if name not in evaluation_a.methods:
                raise ValueError(f"{name!r} is not evaluated (methods: {', '.join(evaluation_a.methods)})")
        if method_a == method_b:
            raise ValueError(f"method_a and method_b are both {method_a!r}; name two different methods")
        labels, test = (method_a, method_b), None  # the sides are named by the methods
        pairs = [(evaluation_a.methods[method_a], evaluation_a.methods[method_b])]
        distributions_a = distributions_b = evaluation_distributions(evaluation_a, n_resamples, seed, labels)
    else:
        if method_a is not None or method_b is not None:
            raise ValueError("method_a and method_b compare two methods of one evaluation; leave out evaluation_b")
        _check_evaluation(evaluation_b, "evaluation_b")
        _check_same_queries(evaluation_a, evaluation_b, query_names_a, query_names_b, labels)
        if None not in (evaluation_a.k, evaluation_b.k) and evaluation_a.k != evaluation_b.k:
            raise ValueError(
                f"{labels[0]} was evaluated at k = {evaluation_a.k} and {labels[1]} at k = {evaluation_b.k} (k is "
                "capped by the candidates a retrieval holds): their uncertainties would differ by k alone; evaluate "
                f"both at k = {min(evaluation_a.k, evaluation_b.k)}"
            )
        if methods is None:
            names = [name for name in evaluation_a.methods if name in evaluation_b.methods]
            only = sorted(set(evaluation_a.methods).symmetric_difference(evaluation_b.methods))
            if only:
                notes.append(f"not in both, not compared: {', '.join(only)}")
            if not names:
                raise ValueError(
                    f"no uncertainty method is evaluated in both {labels[0]} ({', '.join(evaluation_a.methods)}) and "
                    f"{labels[1]} ({', '.join(evaluation_b.methods)})"
                )
        else:
            names = list(methods)
            if not names:
                raise ValueError("methods is empty; name at least one uncertainty method")
            for name in names:
                for label, evaluation in zip(labels, (evaluation_a, evaluation_b), strict=True):
                    if name not in evaluation.methods:
                        known = ", ".join(evaluation.methods)
                        raise ValueError(f"{name!r} is not evaluated in {label} (methods: {known})")
        pairs = [(evaluation_a.methods[name], evaluation_b.methods[name]) for name in names]
        distributions_a, distributions_b = (
            evaluation_distributions(evaluation, n_resamples, seed, names)
            for evaluation in (evaluation_a, evaluation_b)
        )
        test = mcnemar(evaluation_a.correct, evaluation_b.correct)
    return Comparison(
        label_a=labels[0],
        label_b=labels[1],
        n_queries=evaluation_a.n_queries,
        differences=_differences(pairs, distributions_a, distributions_b, confidence),
        mcnemar=test,
        n_resamples=n_resamples,
        seed=seed,
        confidence=confidence,
        notes=[*notes, *filter(None, [significance_notice(n_resamples, len(pairs))])],
        k=evaluation_a.k,
    )
