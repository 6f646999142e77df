"""A threshold with a precision guarantee: Learn-then-Test with Clopper–Pearson p-values and fixed-sequence testing.

The question: accept the answers whose confidence is at least a cut t. Which t makes the precision of the accepted
answers on new queries at least p*, with probability at least 1 − δ over the draw of the calibration queries?

Method (Angelopoulos et al., "Learn then Test", 2021)
    1. The candidate cuts t_1 > t_2 > … (strictest first) are fixed **before** the test queries are looked at: the
       caller takes them from data the test does not reuse (the part of the calibration set the probabilities were
       fitted on).
    2. For each cut, H_j: "precision(t_j) < p*". Given n_j accepted test queries of which c_j are correct, the
       number correct is Binomial(n_j, precision(t_j)), so p_j = P[Binomial(n_j, p*) ≥ c_j] is a valid p-value
       (the exact binomial, i.e. Clopper–Pearson, test).
    3. Fixed-sequence testing: reject H_1, H_2, … while p_j ≤ δ; stop at the first p_j > δ. The last rejected cut
       is chosen. This controls the family-wise error at δ, so with probability ≥ 1 − δ the chosen cut has
       precision ≥ p* (the data-independent order is what makes testing every cut free of a multiplicity cost).

Nothing can be certified with fewer than ⌈log δ / log p*⌉ accepted test queries (even all correct, the p-value
p*^n stays above δ): :func:`min_accepted` gives that number.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import stats

#: Where the sequence of cuts starts, in multiples of min_accepted (see :func:`candidate_cuts`).
START_FACTOR = 1.5

__all__ = ["Certificate", "candidate_cuts", "certify_threshold", "clopper_pearson_lower", "min_accepted"]


def _check_target(target_precision: float, delta: float) -> None:
    if not 0.0 < target_precision < 1.0:
        raise ValueError(f"target_precision must lie in (0, 1), got {target_precision}")
    if not 0.0 < delta < 1.0:
        raise ValueError(f"delta must lie in (0, 1), got {delta}")


def min_accepted(target_precision: float, delta: float) -> int:
    """⌈log δ / log p*⌉: the fewest accepted queries (all correct) that can certify precision p* at risk δ.

    Examples
    --------
    >>> min_accepted(0.9, 0.1)
    22
    """
    _check_target(target_precision, delta)
    return math.ceil(math.log(delta) / math.log(target_precision) - 1e-12)


def clopper_pearson_lower(correct: np.ndarray | int, accepted: np.ndarray | int, delta: float) -> np.ndarray:
    """One-sided Clopper–Pearson lower bound at confidence 1 − δ of a proportion (0 where nothing is accepted).

    Examples
    --------
    >>> round(float(clopper_pearson_lower(22, 22, 0.1)), 4)
    0.9006
    """
    correct, accepted = np.asarray(correct, dtype=np.float64), np.asarray(accepted, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bound = stats.beta.ppf(delta, correct, accepted - correct + 1)
    return np.where(correct > 0, np.nan_to_num(bound, nan=0.0), 0.0)


@dataclass
class Certificate:
    """The outcome of :func:`certify_threshold`.

    Attributes
    ----------
    certified : bool
        Whether a cut was certified.
    cut : float or None
        The chosen confidence cut (accept confidence ≥ cut); None when nothing is certified.
    precision_lower_bound : float or None
        Clopper–Pearson lower bound (confidence 1 − δ) of the precision at the cut, on the test queries.
    n_test : int
        Test queries.
    accepted, correct_accepted : int
        Test queries accepted at the cut, and the correct ones among them.
    expected_coverage : float
        accepted / n_test.
    expected_recall : float
        correct_accepted / test queries that have a positive (end-to-end recall).
    min_accepted : int
        ⌈log δ / log p*⌉.
    cuts_tested : int
        Hypotheses tested before the sequence stopped.
    message : str
        One sentence on what was (or could not be) certified.
    """

    certified: bool
    cut: float | None
    precision_lower_bound: float | None
    n_test: int
    accepted: int
    correct_accepted: int
    expected_coverage: float
    expected_recall: float
    min_accepted: int
    cuts_tested: int
    message: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def candidate_cuts(confidence_fit: np.ndarray, n_test: int, target_precision: float, delta: float) -> np.ndarray:
    """The candidate cuts, strictest first, from the confidences of the fit queries (never the test queries).

    Every distinct fit confidence gives a cut (halfway to the next lower one). The sequence starts at the
    strictest cut that accepts, on the fit queries, a share which on ``n_test`` queries would reach
    :data:`START_FACTOR` × :func:`min_accepted`: stricter cuts could hardly be certified and would stop the
    sequence at once. The factor 1.5 (rather than 1) leaves room for one or two wrong answers and for the
    difference between the fit and test parts; it gave the highest certified recall in the simulations on the
    corridor matrices (README "Calibration").
    """
    sorted_desc = np.sort(np.asarray(confidence_fit, dtype=np.float64))[::-1]
    values = np.unique(sorted_desc)[::-1]
    if values.size == 0 or n_test == 0:
        return values
    share = np.searchsorted(-sorted_desc, -values, side="right") / sorted_desc.size  # fit share accepted per cut
    start = int(np.searchsorted(share * n_test, START_FACTOR * min_accepted(target_precision, delta), side="left"))
    # Each cut lies halfway to the next fit value, so no query sits exactly on a cut (rounding cannot flip it).
    below = np.append(values[1:], values[-1] - max(1.0, abs(values[-1])))
    return (0.5 * (values + below))[min(start, values.size - 1) :]


def certify_threshold(
    confidence: np.ndarray,
    correct: np.ndarray,
    cuts: np.ndarray,
    *,
    target_precision: float,
    delta: float = 0.1,
    answerable: np.ndarray | None = None,
) -> Certificate:
    """Learn-then-Test over ``cuts`` (strictest first) on the test queries.

    Parameters
    ----------
    confidence : ndarray of shape (n,)
        Confidence of each test query (higher = more likely correct), from a model not fitted on them.
    correct : ndarray of shape (n,), bool
        Whether each test query's top-1 answer is correct.
    cuts : ndarray of shape (m,)
        Candidate cuts in strictly decreasing order, fixed without looking at the test queries.
    target_precision : float in (0, 1)
        p*.
    delta : float in (0, 1), default=0.1
        Risk δ.
    answerable : ndarray of shape (n,), bool, optional
        Test queries with a positive in the database (the recall denominator); default all.

    Returns
    -------
    Certificate
    """
    _check_target(target_precision, delta)
    confidence = np.asarray(confidence, dtype=np.float64)
    correct = np.asarray(correct, dtype=bool)
    cuts = np.asarray(cuts, dtype=np.float64)
    if confidence.ndim != 1 or correct.shape != confidence.shape:
        raise ValueError(f"confidence and correct must be 1-D of one length, got {confidence.shape}, {correct.shape}")
    if cuts.ndim != 1 or (cuts.size > 1 and not (np.diff(cuts) < 0).all()):
        raise ValueError("cuts must be 1-D and strictly decreasing (strictest first)")
    n_needed = min_accepted(target_precision, delta)
    n_answerable = int(correct.size if answerable is None else np.asarray(answerable, dtype=bool).sum())
    order = np.argsort(-confidence, kind="stable")
    ranked, hits = confidence[order], np.concatenate([[0], np.cumsum(correct[order])])
    accepted = np.searchsorted(-ranked, -cuts, side="right")  # count of confidence >= cut
    good = hits[accepted]
    p_values = np.where(accepted > 0, stats.binom.sf(good - 1, accepted, target_precision), 1.0)
    failed = np.flatnonzero(p_values > delta)
    n_rejected = int(failed[0]) if failed.size else cuts.size
    tested = min(n_rejected + 1, cuts.size)
    if n_rejected == 0:
        if correct.size * 1.0 < n_needed:
            why = f"the {correct.size} test queries are fewer than the {n_needed} accepted ones needed"
        else:
            first = int(accepted[0]) if cuts.size else 0
            why = (
                f"the strictest candidate cut accepts {first} test queries, "
                f"{int(good[0]) if cuts.size else 0} correct, and that does not reach the bound"
            )
        return Certificate(
            certified=False,
            cut=None,
            precision_lower_bound=None,
            n_test=int(correct.size),
            accepted=0,
            correct_accepted=0,
            expected_coverage=0.0,
            expected_recall=0.0,
            min_accepted=n_needed,
            cuts_tested=tested,
            message=f"nothing certified at precision {target_precision:g} with risk {delta:g}: {why} "
            f"(at least {n_needed} accepted test queries, all correct, are needed)",
        )
    chosen = n_rejected - 1
    n_acc, n_good = int(accepted[chosen]), int(good[chosen])
    bound = float(clopper_pearson_lower(n_good, n_acc, delta))
    return Certificate(
        certified=True,
        cut=float(cuts[chosen]),
        precision_lower_bound=bound,
        n_test=int(correct.size),
        accepted=n_acc,
        correct_accepted=n_good,
        expected_coverage=n_acc / correct.size,
        expected_recall=n_good / max(n_answerable, 1),
        min_accepted=n_needed,
        cuts_tested=tested,
        message=f"precision >= {target_precision:g} certified with probability >= {1 - delta:g}: "
        f"{n_good} of {n_acc} accepted test queries correct, lower bound {bound:.3f}",
    )
