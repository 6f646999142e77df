"""The uncertainty threshold that reached a target precision on labelled queries: empirical, with no guarantee.

:func:`threshold_at_precision` reads the end-to-end precision-recall curve of labelled queries (accept a query
when its uncertainty is <= the threshold; see :func:`~vpr_uncertainty.evaluation.metrics.rejection_curve`) and
returns the most lenient threshold whose precision **on these queries** is at least the target. On new queries
the precision can be lower: the threshold is fitted to the very queries it is measured on, and the fewer they are,
the more optimistic it is. For a threshold with a guarantee (precision >= p* on new queries with probability
1 − δ), use :func:`vpr_uncertainty.calibrate`, which fits and certifies on separate halves.
"""

from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass

import numpy as np

from vpr_uncertainty.evaluation.metrics import rejection_curve

__all__ = ["ThresholdChoice", "threshold_at_precision"]


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

    Empirical, **with no guarantee** on new queries (see the module docstring); for a certified threshold use
    :func:`vpr_uncertainty.calibrate`.

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
