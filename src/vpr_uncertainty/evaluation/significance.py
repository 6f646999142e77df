"""Which differences are real: bootstrap intervals, paired tests against a reference and the leaders of a column.

:func:`add_bootstrap` attaches to an :class:`~vpr_uncertainty.evaluation.Evaluation` what
:mod:`~vpr_uncertainty.evaluation.bootstrap` measures: each method's 95 % intervals of AUC-PR, AP and AURC, a paired
test of its AUC-PR against a reference method (Holm-corrected over the methods), and, per metric, the leaders
(:func:`leaders`): the best method alone when it is significantly better than every other one, otherwise every
method not significantly worse than the best, marked together.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from vpr_uncertainty.evaluation.bootstrap import (
    BOOTSTRAP_METRICS,
    bootstrap_metrics,
    holm,
    paired_p_value,
    percentile_interval,
)

if TYPE_CHECKING:
    from vpr_uncertainty.evaluation.results import Evaluation

__all__ = [
    "DEFAULT_REFERENCE",
    "TEST_DESCRIPTION",
    "add_bootstrap",
    "check_bootstrap",
    "evaluation_distributions",
    "leaders",
    "resolve_reference",
]

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
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if not 0.0 < confidence < 1.0 or not 0.0 < level < 1.0:
        raise ValueError(f"confidence and level must lie in (0, 1), got {confidence} and {level}")


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
    others = [name for name in names if name != top]
    p_values = [paired_p_value(sign * distributions[top], sign * distributions[name]) for name in others]
    tested = [(name, p) for name, p in zip(others, p_values, strict=True) if p is not None]
    adjusted = dict(zip([name for name, _ in tested], holm([p for _, p in tested]), strict=True)) if tested else {}
    # A comparison that could not be made (no common resample) is not significant.
    worse = {name for name in others if name in adjusted and adjusted[name] <= level}
    marked = [name for name in names if name not in worse]
    return marked, len(marked) == 1


def evaluation_distributions(evaluation: Evaluation, n_resamples: int, seed: int) -> dict[str, dict[str, np.ndarray]]:
    """The paired bootstrap distributions (``metric -> method -> (B,)``) of an evaluation's methods, each judged by
    its own correctness labels where it has them (a method that retrieves with its own embeddings)."""
    labels: dict[Any, np.ndarray] = {None: evaluation.correct}
    labels.update({name: m.correct for name, m in evaluation.methods.items() if m.correct is not None})
    uncertainties = {name: m.uncertainty for name, m in evaluation.methods.items()}
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
        Bootstrap resamples (>= 1).
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
        method.auc_pr_ci = percentile_interval(distributions["auc_pr"][name], confidence)
        method.average_precision_ci = percentile_interval(distributions["average_precision"][name], confidence)
        method.aurc_ci = percentile_interval(distributions["aurc"][name], confidence)
        method.vs_reference = None
    base = evaluation.methods[reference]
    compared = [name for name in names if name != reference and evaluation.methods[name].auc_pr is not None]
    p_values = {
        name: paired_p_value(distributions["auc_pr"][name], distributions["auc_pr"][reference]) for name in compared
    }
    tested = [name for name in compared if p_values[name] is not None and base.auc_pr is not None]
    adjusted = dict(zip(tested, holm([p_values[name] for name in tested]), strict=True)) if tested else {}
    for name in tested:
        evaluation.methods[name].vs_reference = {
            "reference": reference,
            "delta_auc_pr": float(evaluation.methods[name].auc_pr - base.auc_pr),
            "p_value": p_values[name],
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
    skipped = {name: int(np.isnan(distributions["auc_pr"][name]).sum()) for name in names}
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
