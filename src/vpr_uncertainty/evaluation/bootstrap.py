"""Paired bootstrap over queries: confidence intervals of AUC-PR, AP and AURC and paired tests between methods, every
method on the same resamples (:func:`resample_indices`); :func:`add_bootstrap` attaches them to an Evaluation.
Conventions (skipped resamples, intervals, p-values, Holm): see docs/explanation/evaluation.md.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from vpr_uncertainty._validation import check_count, check_resamples
from vpr_uncertainty.evaluation.metrics import check_labels
from vpr_uncertainty.evaluation.results import Evaluation

#: The metrics resampled, and whether higher is better.
BOOTSTRAP_METRICS: dict[str, bool] = {"auc_pr": True, "average_precision": True, "aurc": False}
#: Resamples drawn per block: bounds the memory (block × queries integers) and fixes the random stream.
_BLOCK = 100


def resample_indices(n_queries: int, n_resamples: int, seed: int) -> Iterator[np.ndarray]:
    """The bootstrap resamples of ``n_queries`` queries, in blocks of at most 100 resamples.

    Parameters
    ----------
    n_queries : int
        Queries to draw from (with replacement), >= 1.
    n_resamples : int
        Resamples in all, >= 1.
    seed : int
        Seed of :func:`numpy.random.default_rng`; the same three arguments give the same resamples.

    Yields
    ------
    ndarray of shape (b, n_queries), int64
        Query indices, one resample per row (b <= 100).

    Examples
    --------
    >>> [block.shape for block in resample_indices(5, 150, seed=0)]
    [(100, 5), (50, 5)]
    """
    n_queries = check_count(n_queries, "n_queries", 1)
    n_resamples = check_count(n_resamples, "n_resamples", 1)
    rng = np.random.default_rng(seed)
    for start in range(0, n_resamples, _BLOCK):
        yield rng.integers(0, n_queries, size=(min(_BLOCK, n_resamples - start), n_queries), dtype=np.int64)


def weighted_metrics(correct: object, uncertainty: object, weights: object) -> dict[str, np.ndarray]:
    """AUC-PR, AP and AURC of one method on many weighted copies of its queries at once.

    With integer weights (how many times a resample draws each query) this equals the metrics of
    :mod:`vpr_uncertainty.evaluation.metrics` on the resampled arrays; with all weights 1, the metrics themselves.
    Vectorised over resamples: the queries are sorted once and grouped by tied values, and the weights reduced per
    group and accumulated along that order give every threshold's true and false positives of every row at once.

    Parameters
    ----------
    correct : array-like of shape (Q,), bool
        Whether each query's top-1 answer is correct.
    uncertainty : array-like of shape (Q,)
        Higher = less trustworthy; equal values are one threshold.
    weights : array-like of shape (B, Q), non-negative
        One row per resample.

    Returns
    -------
    dict of str to ndarray of shape (B,)
        ``auc_pr``, ``average_precision`` and ``aurc``; NaN for a row whose weighted labels hold one class only.

    Examples
    --------
    >>> metrics = weighted_metrics([True, False, True], [0.1, 0.5, 0.2], [[1, 1, 1], [2, 1, 0]])
    >>> metrics["average_precision"], metrics["aurc"]
    (array([1., 1.]), array([0.11111111, 0.11111111]))
    """
    correct, uncertainty = check_labels(correct, uncertainty)
    weights = np.asarray(weights, dtype=np.float64)
    if weights.ndim != 2 or weights.shape[1] != correct.size:
        raise ValueError(f"weights must have shape (n_resamples, {correct.size}), got {weights.shape}")
    order = np.argsort(uncertainty, kind="stable")
    sorted_uncertainty = uncertainty[order]
    starts = np.flatnonzero(np.diff(sorted_uncertainty, prepend=-np.inf) > 0)  # first query of each tied group
    sorted_weights = weights[:, order]
    group_weight = np.add.reduceat(sorted_weights, starts, axis=1)
    group_true = np.add.reduceat(sorted_weights * correct[order], starts, axis=1)
    accepted = np.cumsum(group_weight, axis=1)  # the most confident groups first
    true_accepted = np.cumsum(group_true, axis=1)
    total, positives = accepted[:, -1:], true_accepted[:, -1:]
    defined = ((positives > 0) & (positives < total)).ravel()
    with np.errstate(invalid="ignore", divide="ignore"):
        # Before the first drawn group nothing is accepted: the curve's starting point (recall 0, precision 1).
        precision = np.where(accepted > 0, true_accepted / np.where(accepted > 0, accepted, 1), 1.0)
        recall = true_accepted / np.where(positives > 0, positives, 1)
    previous_recall = np.concatenate([np.zeros_like(recall[:, :1]), recall[:, :-1]], axis=1)
    previous_precision = np.concatenate([np.ones_like(precision[:, :1]), precision[:, :-1]], axis=1)
    gained = recall - previous_recall
    auc_pr = np.sum(gained * (precision + previous_precision) / 2, axis=1)
    average_precision = np.sum(gained * precision, axis=1)
    aurc = np.sum(group_weight / np.where(total > 0, total, 1) * (1.0 - precision), axis=1)
    return {
        name: np.where(defined, values, np.nan)
        for name, values in (("auc_pr", auc_pr), ("average_precision", average_precision), ("aurc", aurc))
    }


def bootstrap_metrics(
    correct: object | Mapping[str, object],
    uncertainties: Mapping[str, object],
    *,
    n_resamples: int = 1000,
    seed: int = 0,
) -> dict[str, dict[str, np.ndarray]]:
    """The paired bootstrap distributions of AUC-PR, AP and AURC of several methods on the same resamples.

    Parameters
    ----------
    correct : array-like of shape (Q,), bool, or mapping of str to such arrays
        Correctness of each query's top-1 answer; a mapping gives a method its own labels (a method that retrieves
        with its own embeddings), and the methods it leaves out use ``correct[None]`` if present.
    uncertainties : mapping of str to array-like of shape (Q,)
        Each method's uncertainties, higher = less trustworthy.
    n_resamples : int, default=1000
        Bootstrap resamples.
    seed : int, default=0
        Seed of the resamples (see :func:`resample_indices`).

    Returns
    -------
    dict of str to dict of str to ndarray of shape (n_resamples,)
        ``metric -> method -> values``; NaN on the resamples skipped for that method (one class only).

    Examples
    --------
    >>> dist = bootstrap_metrics([True, False, True, False], {"A": [0.1, 0.9, 0.2, 0.8]}, n_resamples=50)
    >>> float(np.nanmin(dist["auc_pr"]["A"]))
    1.0
    """
    if not uncertainties:
        raise ValueError("no uncertainties given to bootstrap")
    arrays = {}
    for name in uncertainties:
        if isinstance(correct, Mapping) and name not in correct and None not in correct:
            raise ValueError(f"no correctness labels for method {name!r}")
        labels = correct.get(name, correct.get(None)) if isinstance(correct, Mapping) else correct
        try:
            arrays[name] = check_labels(labels, uncertainties[name])
        except ValueError as error:
            raise ValueError(f"method {name!r}: {error}") from None
    sizes = {name: pair[0].size for name, pair in arrays.items()}
    n_queries = next(iter(sizes.values()))
    if any(size != n_queries for size in sizes.values()):
        raise ValueError(f"every method must have the same number of queries, got {sizes}")
    blocks: dict[str, dict[str, list[np.ndarray]]] = {
        metric: {name: [] for name in arrays} for metric in BOOTSTRAP_METRICS
    }
    for indices in resample_indices(n_queries, n_resamples, seed):
        offsets = np.arange(indices.shape[0])[:, None] * n_queries  # counts: (b, Q), draws of each query
        counts = np.bincount((indices + offsets).ravel(), minlength=indices.size).reshape(-1, n_queries)
        for name, (labels_of, uncertainty) in arrays.items():
            for metric, values in weighted_metrics(labels_of, uncertainty, counts).items():
                blocks[metric][name].append(values)
    return {
        metric: {name: np.concatenate(parts) for name, parts in by_method.items()}
        for metric, by_method in blocks.items()
    }


def percentile_interval(values: object, confidence: float = 0.95) -> tuple[float, float] | None:
    """The percentile bootstrap interval of ``values`` (NaN entries, the skipped resamples, are left out).

    Parameters
    ----------
    values : array-like of shape (B,)
        Resampled values of a metric.
    confidence : float, default=0.95
        In (0, 1).

    Returns
    -------
    (low, high) or None
        None when no resample is defined.

    Examples
    --------
    >>> [round(bound, 6) for bound in percentile_interval(np.arange(101.0), 0.9)]
    [5.0, 95.0]
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    values = np.asarray(values, dtype=np.float64)
    kept = values[~np.isnan(values)]
    if kept.size == 0:
        return None
    tail = (1.0 - confidence) / 2 * 100
    low, high = np.percentile(kept, [tail, 100 - tail])
    return float(low), float(high)


def paired_p_value(first: object, second: object) -> float | None:
    """Two-sided paired-bootstrap p-value of the difference ``first - second`` (docs/explanation/evaluation.md).

    Parameters
    ----------
    first, second : array-like of shape (B,)
        The two methods' values on the same resamples (NaN where skipped; such resamples are left out).

    Returns
    -------
    float or None
        In (0, 1]; None when no resample is defined for both.

    Examples
    --------
    >>> paired_p_value([0.9, 0.8, 0.85, 0.95], [0.5, 0.6, 0.55, 0.4])  # first better on every resample
    0.4
    >>> paired_p_value([0.5, 0.6], [0.5, 0.6])  # no difference at all
    1.0
    """
    first, second = np.asarray(first, dtype=np.float64), np.asarray(second, dtype=np.float64)
    if first.shape != second.shape or first.ndim != 1:
        raise ValueError(f"first and second must have the same shape (n_resamples,), got {first.shape}, {second.shape}")
    difference = (first - second)[~(np.isnan(first) | np.isnan(second))]
    if difference.size == 0:
        return None
    other_sign = min(int((difference <= 0).sum()), int((difference >= 0).sum()))
    return float(min(1.0, 2.0 * (1 + other_sign) / (difference.size + 1)))


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjustment of p-values for multiple comparisons (family-wise error control).

    The i-th smallest of m p-values becomes ``max_{j <= i} min(1, (m - j + 1) p_(j))``; a hypothesis is rejected
    at level α when its adjusted p-value is <= α.

    Parameters
    ----------
    p_values : sequence of float
        In [0, 1].

    Returns
    -------
    list of float
        Adjusted p-values, in the order given.

    Examples
    --------
    >>> holm([0.01, 0.04, 0.03])
    [0.03, 0.06, 0.06]
    """
    p = np.asarray(p_values, dtype=np.float64)
    if p.ndim != 1 or np.isnan(p).any() or (p < 0).any() or (p > 1).any():
        raise ValueError(f"p_values must be a sequence of numbers in [0, 1], got {list(p_values)}")
    order = np.argsort(p, kind="stable")
    m = p.size
    adjusted = np.maximum.accumulate(np.minimum(1.0, (m - np.arange(m)) * p[order]))
    result = np.empty(m)
    result[order] = adjusted
    return [float(value) for value in result]


def holm_against(distributions: Mapping[str, np.ndarray], one: str, others: Sequence[str]) -> dict[str, float]:
    """Table 1's and the heatmaps' one rule: the paired p-value of ``one`` against each of ``others`` (arrays of shape
    (B,), the same resamples), Holm-adjusted over that family (<= level: significant); no common resample: left out."""
    p_values = {name: paired_p_value(distributions[one], distributions[name]) for name in others}
    tested = [name for name, p in p_values.items() if p is not None]
    return dict(zip(tested, holm([p_values[name] for name in tested]), strict=True))


def significance_notice(n_resamples: int, comparisons: int, level: float = 0.05) -> str | None:
    """The notice when Holm over ``comparisons`` leaves no difference significant: the smallest paired p-value,
    2 / (B + 1) (:func:`paired_p_value`), times ``comparisons`` exceeds ``level``; None when one can be."""
    if comparisons * (2.0 / (n_resamples + 1)) <= level:
        return None
    return (  # B >= the smallest B with comparisons × 2 / (B + 1) <= level
        f"no difference can be significant with B = {n_resamples} resamples over {comparisons} comparisons; "
        f"use B >= {int(np.ceil(2 * comparisons / level - 1e-9)) - 1}"
    )


#: The reference of the paired tests when none is named (and it is evaluated).
DEFAULT_REFERENCE = "SU"
TEST_DESCRIPTION = (
    "paired bootstrap over queries (the same resamples for every method); percentile intervals; two-sided p-value "
    "= 2 x share of resamples where the difference has the other sign or is 0 (+1 correction); Holm over methods"
)


def check_bootstrap(n_resamples: object, seed: object, confidence: float = 0.95, level: float = 0.05) -> None:
    """Raise ValueError naming the argument when a bootstrap setting is not valid (0 resamples: no bootstrap)."""
    if isinstance(n_resamples, bool) or not isinstance(n_resamples, (int, np.integer)) or n_resamples < 0:
        raise ValueError(f"bootstrap must be an integer >= 0 (resamples; 0 = none), got {n_resamples!r}")
    check_count(seed, "seed", 0)
    if not 0.0 < confidence < 1.0 or not 0.0 < level < 1.0:
        raise ValueError(f"confidence and level must lie in (0, 1), got {confidence} and {level}")
    if n_resamples:
        check_resamples(n_resamples, "bootstrap", confidence)


def resolve_reference(reference: str | None, methods: list[str]) -> str:
    """The reference method: the one named (which must be evaluated), else SU when evaluated, else the first."""
    if reference is None:
        return DEFAULT_REFERENCE if DEFAULT_REFERENCE in methods else methods[0]
    if reference not in methods:
        raise ValueError(
            f"the reference method {reference!r} of the paired tests is not among the evaluated methods "
            f"({', '.join(methods)})"
        )
    return reference


def leaders(
    distributions: Mapping[str, np.ndarray],
    values: Mapping[str, float],
    *,
    higher_is_better: bool = True,
    level: float = 0.05,
) -> tuple[list[str], bool]:
    """The methods to mark as best in one column of a table.

    The best method by point value is tested against each other method (paired bootstrap, Holm-corrected over
    those comparisons). If it is significantly better than every one, it is the only leader; otherwise the
    leaders are the best and every method not significantly worse than it.

    Parameters
    ----------
    distributions : mapping of str to ndarray of shape (B,)
        Each candidate's bootstrap values on the same resamples (NaN where skipped).
    values : mapping of str to float
        Each candidate's point value (the candidates: only these are compared).
    higher_is_better : bool, default=True
        False for AURC.
    level : float, default=0.05
        Family-wise significance level.

    Returns
    -------
    leaders : list of str
        In the order of ``values``; empty when fewer than two candidates compete.
    significant : bool
        Whether a single leader is significantly better than every other candidate.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> dist = {"A": 0.9 + 0.01 * rng.standard_normal(200), "B": 0.5 + 0.01 * rng.standard_normal(200)}
    >>> leaders(dist, {"A": 0.9, "B": 0.5})
    (['A'], True)
    """
    names = list(values)
    if len(names) < 2:
        return [], False
    sign = 1.0 if higher_is_better else -1.0
    top = max(names, key=lambda name: sign * values[name])
    adjusted = holm_against(distributions, top, [name for name in names if name != top])  # two-sided: any sign
    # A comparison that could not be made (no common resample) is not significant.
    worse = {name for name, p in adjusted.items() if p <= level}
    marked = [name for name in names if name not in worse]
    return marked, len(marked) == 1


def evaluation_distributions(
    evaluation: Evaluation, n_resamples: int, seed: int, names: Sequence[str] | None = None
) -> dict[str, dict[str, np.ndarray]]:
    """The paired bootstrap distributions (``metric -> method -> (B,)``) of an evaluation's methods (or those
    ``names``), each judged by its own correctness labels where it has them (a method with its own retrieval)."""
    methods = {name: evaluation.methods[name] for name in (evaluation.methods if names is None else names)}
    labels: dict[Any, np.ndarray] = {None: evaluation.correct}
    labels.update({name: m.correct for name, m in methods.items() if m.correct is not None})
    uncertainties = {name: m.uncertainty for name, m in methods.items()}
    return bootstrap_metrics(labels, uncertainties, n_resamples=n_resamples, seed=seed)


def add_bootstrap(
    evaluation: Evaluation,
    *,
    n_resamples: int,
    seed: int = 0,
    reference: str | None = None,
    confidence: float = 0.95,
    level: float = 0.05,
) -> Evaluation:
    """Attach bootstrap intervals, paired tests against a reference and the leaders of each metric, in place.

    Sets each method's ``auc_pr_ci``, ``average_precision_ci``, ``aurc_ci`` and (except the reference's)
    ``vs_reference`` = ``{"reference", "delta_auc_pr", "p_value", "p_value_holm", "significant"}``, and
    ``evaluation.bootstrap`` (the settings, the resamples skipped per method and, per metric, the leaders).

    Parameters
    ----------
    evaluation : Evaluation
        With its methods' uncertainties and correctness labels.
    n_resamples : int
        Bootstrap resamples (>= 40 at 95 %, :func:`~vpr_uncertainty._validation.check_resamples`).
    seed : int, default=0
        Seed of the resamples.
    reference : str, optional
        The method every other one is tested against; default SU when evaluated, else the first method.
    confidence : float, default=0.95
        Of the intervals.
    level : float, default=0.05
        Family-wise level of the tests (``significant`` is Holm-adjusted p <= level).

    Returns
    -------
    Evaluation
        The same object.
    """
    check_bootstrap(n_resamples, seed, confidence, level)
    if n_resamples < 1:
        raise ValueError(f"n_resamples must be >= 1, got {n_resamples}")
    names = list(evaluation.methods)
    reference = resolve_reference(reference, names)
    distributions = evaluation_distributions(evaluation, n_resamples, seed)
    for name, method in evaluation.methods.items():
        for metric in BOOTSTRAP_METRICS:
            setattr(method, f"{metric}_ci", percentile_interval(distributions[metric][name], confidence))
        method.vs_reference = None
    base, auc_pr = evaluation.methods[reference], distributions["auc_pr"]
    compared = [name for name in names if name != reference and evaluation.methods[name].auc_pr is not None]
    adjusted = holm_against(auc_pr, reference, compared) if base.auc_pr is not None else {}
    for name in adjusted:
        evaluation.methods[name].vs_reference = {
            "reference": reference,
            "delta_auc_pr": float(evaluation.methods[name].auc_pr - base.auc_pr),
            "p_value": paired_p_value(auc_pr[name], auc_pr[reference]),
            "p_value_holm": adjusted[name],
            "significant": bool(adjusted[name] <= level),
        }
    best = {}
    for metric, higher in BOOTSTRAP_METRICS.items():
        values = {
            name: getattr(m, metric)
            for name, m in evaluation.methods.items()
            if m.informative and getattr(m, metric) is not None
        }
        marked, significant = leaders(distributions[metric], values, higher_is_better=higher, level=level)
        best[metric] = {"methods": marked, "significant": significant}
    skipped = {name: int(np.isnan(auc_pr[name]).sum()) for name in names}
    notice = significance_notice(n_resamples, len(names) - 1, level)
    evaluation.notes.extend([notice] if notice and notice not in evaluation.notes else [])
    evaluation.bootstrap = {
        "resamples": int(n_resamples),
        "seed": int(seed),
        "reference": reference,
        "confidence": confidence,
        "level": level,
        "test": TEST_DESCRIPTION,
        "skipped": {name: count for name, count in skipped.items() if count},
        "best": best,
    }
    return evaluation
