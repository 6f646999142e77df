"""A threshold with a precision guarantee: Learn-then-Test with exact binomial p-values and fixed-sequence testing.

The question: accept the answers whose confidence is at least a cut t. Which t makes the precision of the accepted
answers on new queries at least p*, with probability at least 1 − δ over the draw of the calibration queries?

Method (Angelopoulos et al., "Learn then Test", 2021)
    1. The candidate cuts t_1 > t_2 > … (strictest first) are fixed **before** any label is read: they are the
       quantiles of the ranking's confidence over the queries the caller passes, labelled or not, at the coverages
       of :func:`coverage_grid`, which depend on nothing but the number of labelled queries, p* and δ.
    2. For each cut, H_j: "precision(t_j) < p*". Given n_j accepted labelled queries of which c_j are correct, the
       number correct is Binomial(n_j, precision(t_j)), so p_j = P[Binomial(n_j, p*) ≥ c_j] is a valid p-value
       (the exact binomial test; its inversion is the Clopper–Pearson bound).
    3. Fixed-sequence testing: reject H_1, H_2, … while p_j ≤ δ; stop at the first p_j > δ. The last rejected cut
       is chosen. This controls the family-wise error at δ, so with probability ≥ 1 − δ the chosen cut has
       precision ≥ p* (the label-free order is what makes testing every cut free of a multiplicity cost).

Several rankings (SU, the margin, a cross-fitted model, …) are tested each at δ / R (Bonferroni), so that every
certified rule holds at once with probability ≥ 1 − δ and the loosest of them may be kept.

Nothing can be certified with fewer than ⌈log δ / log p*⌉ accepted queries (even all correct, the p-value p*^n
stays above δ): :func:`min_accepted` gives that number, and the grid starts there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from vpr_uncertainty._validation import check_count
from vpr_uncertainty.calibration.calibrator import RANKINGS, Calibrator, columns, cross_fitted, fit_model, platt

#: With many labelled queries, the coverage grid starts at the first step that accepts at least this share.
START_COVERAGE = 0.05

__all__ = [
    "CAL_MIN_LABELLED",
    "Certificate",
    "certify_rankings",
    "certify_threshold",
    "check_rankings",
    "clopper_pearson_lower",
    "coverage_grid",
    "cuts_at_coverage",
    "default_rankings",
    "fixed_sequence",
    "min_accepted",
    "needed_message",
]


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
    ranking : str or None
        The ranking whose rule was certified (``"SU"``, ``"margin"``, ``"CAL"``, …), None when none was.
    coverage : float or None
        The certified share of the queries accepted (the coverage of the grid at the chosen cut).
    delta_per_ranking : float or None
        δ / R, the risk each of the R candidate rankings was tested at.
    rankings : dict
        Per candidate ranking: ``certified``, ``accepted``, ``correct_accepted`` (labelled queries at its last
        certified cut) and ``cuts_tested``.
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
    ranking: str | None = None
    coverage: float | None = None
    delta_per_ranking: float | None = None
    rankings: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _uncertified(message: str, **fields: Any) -> Certificate:
    """A certificate of nothing: no cut, no bound, no query accepted."""
    zero = {"accepted": 0, "correct_accepted": 0, "expected_coverage": 0.0, "expected_recall": 0.0}
    return Certificate(certified=False, cut=None, precision_lower_bound=None, message=message, **zero, **fields)


def coverage_grid(n_labelled: int, target_precision: float, delta: float) -> np.ndarray:
    """The candidate coverages, strictest first: fixed by the number of labelled queries, p* and δ alone.

    The w-th coverage accepts m_w of the ``n_labelled`` queries: the fewest accepted queries among which w wrong
    answers can still be certified (P[Binomial(m_w, p*) ≥ m_w − w] ≤ δ). It starts at m_0 = :func:`min_accepted`
    (all correct needed; stricter cuts cannot be certified and would stop the sequence at once) and each step
    makes room for one more wrong answer, so that a single wrong answer between two cuts cannot stop the sequence
    by itself. For p* = 0.9, δ = 0.1: 22, 38, 52, 65, … accepted. With many labels the grid starts at the first
    step that accepts at least :data:`START_COVERAGE` of them, where a few wrong answers are allowed (among the
    22 most confident of 1,000 queries a single wrong answer would otherwise stop everything). Empty when n < m_0.

    Examples
    --------
    >>> (coverage_grid(100, 0.9, 0.1) * 100).round().astype(int).tolist()
    [22, 38, 52, 65, 78, 91]
    """
    _check_target(target_precision, delta)
    check_count(n_labelled, "n_labelled", 0)
    accepted = np.arange(1, n_labelled + 1)
    # the fewest correct answers that certify among m accepted: P[Binomial(m, p*) >= c] <= δ
    needed = stats.binom.isf(delta, accepted, target_precision) + 1
    room = accepted - needed  # wrong answers that can still be certified (negative: none can)
    first = np.flatnonzero((room >= 0) & (room > np.maximum.accumulate(np.concatenate([[-1], room[:-1]]))))
    counts = accepted[first]
    start = np.searchsorted(counts, START_COVERAGE * n_labelled)  # the first step of at least that coverage
    return counts[min(start, max(counts.size - 1, 0)) :] / max(n_labelled, 1)


def cuts_at_coverage(confidence: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    """Cuts on ``confidence`` (Q,) that accept the share ``coverage`` (m,) of it, strictest first.

    The cut for coverage q accepts the ⌈qQ⌉ highest confidences (more where values tie at the cut): it lies halfway
    between the lowest accepted value and the next lower one, so that rounding cannot flip a query.
    Non-increasing, of shape (m,).
    """
    ranked = np.sort(np.asarray(confidence, dtype=np.float64))[::-1]
    if ranked.size == 0:
        raise ValueError("cuts need at least one confidence value")
    count = np.clip(np.ceil(np.asarray(coverage) * ranked.size - 1e-9).astype(int), 1, ranked.size)
    below = np.append(ranked[1:], ranked[-1] - max(1.0, abs(ranked[-1])))
    return 0.5 * (ranked[count - 1] + below[count - 1])


def fixed_sequence(
    accepted: np.ndarray, correct: np.ndarray, *, target_precision: float, delta: float
) -> tuple[int, np.ndarray]:
    """Fixed-sequence test of "precision < p*" over a sequence of cuts, strictest first.

    Parameters
    ----------
    accepted, correct : ndarray of shape (m,), int
        Labelled queries accepted at each cut, and the correct ones among them.
    target_precision, delta : float in (0, 1)

    Returns
    -------
    rejected : int
        How many hypotheses were rejected before the first p-value above δ (0: nothing certified); the chosen cut
        is ``rejected - 1``.
    p_values : ndarray of shape (m,)
        P[Binomial(n_j, p*) ≥ c_j] (1 where nothing is accepted).

    Examples
    --------
    >>> fixed_sequence(np.array([22, 30, 40]), np.array([22, 29, 33]), target_precision=0.9, delta=0.1)[0]
    1
    """
    _check_target(target_precision, delta)
    accepted, correct = np.asarray(accepted), np.asarray(correct)
    p_values = np.where(accepted > 0, stats.binom.sf(correct - 1, np.maximum(accepted, 1), target_precision), 1.0)
    failed = np.flatnonzero(p_values > delta)
    return (int(failed[0]) if failed.size else int(accepted.size)), p_values


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
    """
    n_needed = min_accepted(target_precision, delta)  # checks p* and δ
    confidence = np.asarray(confidence, dtype=np.float64)
    correct = np.asarray(correct, dtype=bool)
    cuts = np.asarray(cuts, dtype=np.float64)
    if confidence.ndim != 1 or correct.shape != confidence.shape:
        raise ValueError(f"confidence and correct must be 1-D of one length, got {confidence.shape}, {correct.shape}")
    if cuts.ndim != 1 or (cuts.size > 1 and not (np.diff(cuts) < 0).all()):
        raise ValueError("cuts must be 1-D and strictly decreasing (strictest first)")
    n_answerable = int(correct.size if answerable is None else np.asarray(answerable, dtype=bool).sum())
    order = np.argsort(-confidence, kind="stable")
    ranked, hits = confidence[order], np.concatenate([[0], np.cumsum(correct[order])])
    accepted = np.searchsorted(-ranked, -cuts, side="right")  # count of confidence >= cut
    good = hits[accepted]
    n_rejected, _ = fixed_sequence(accepted, good, target_precision=target_precision, delta=delta)
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
        return _uncertified(
            f"nothing certified at precision {target_precision:g} with risk {delta:g}: {why} "
            f"(at least {n_needed} accepted test queries, all correct, are needed)",
            n_test=int(correct.size),
            min_accepted=n_needed,
            cuts_tested=tested,
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


#: From this many labelled queries on, the gate also tests the cross-fitted model (at δ/2 beside SU at δ/2);
#: below it, splitting δ costs more than the model gains (corridor simulations, docs/evidence/calibration.md).
CAL_MIN_LABELLED = 150


def default_rankings(n_labelled: int) -> tuple[str, ...]:
    """The rankings the gate tests by default: SU, and the cross-fitted model from :data:`CAL_MIN_LABELLED` on."""
    return ("SU", "CAL") if n_labelled >= CAL_MIN_LABELLED else ("SU",)


def check_rankings(rankings: Sequence[str], available: dict[str, np.ndarray]) -> tuple[str, ...]:
    """The names of ``rankings``, checked: known, distinct, and their feature among ``available``."""
    if isinstance(rankings, str) or not rankings:
        raise ValueError(f"rankings must be a non-empty list of names from {[*RANKINGS, 'CAL']}, got {rankings!r}")
    names = tuple(rankings)
    unknown = [name for name in names if name != "CAL" and name not in RANKINGS]
    if unknown:
        raise ValueError(f"unknown ranking(s) {unknown}; valid: {', '.join([*RANKINGS, 'CAL'])}")
    if len(set(names)) != len(names):
        raise ValueError(f"rankings lists a name twice: {list(names)}")
    missing = [name for name in names if name != "CAL" and RANKINGS[name][0] not in available]
    if missing:
        raise ValueError(f"ranking(s) {missing} need cosine similarities in [-1, 1] (d² = 2 − 2s)")
    return names


def certify_rankings(
    labelled: dict[str, np.ndarray],
    pool: dict[str, np.ndarray],
    correct: np.ndarray,
    answerable: np.ndarray,
    *,
    rankings: tuple[str, ...],
    model_features: tuple[str, ...],
    target_precision: float,
    delta: float,
    folds: int,
    seed: int,
) -> tuple[Certificate, Calibrator | None, float]:
    """Every ranking tested at δ / R on all labelled queries; the winner's calibrator and cut.

    Parameters
    ----------
    labelled, pool : dict of str to ndarray of shape (L,) and (N,)
        Feature columns (:func:`~vpr_uncertainty.calibration.calibrator.feature_columns`) of the labelled queries
        and of every query passed (labelled first, then unlabelled); the cuts are quantiles over ``pool``.
    correct, answerable : ndarray of shape (L,), bool
        Top-1 correctness of the labelled queries, and which have a positive (the recall denominator).
    rankings : tuple of str
        Names from :data:`~vpr_uncertainty.calibration.calibrator.RANKINGS` and ``"CAL"``.
    model_features : tuple of str
        Features of the cross-fitted model ``"CAL"``.
    target_precision, delta : float in (0, 1)
        p* and the total risk δ (each ranking gets δ / R).
    folds, seed : int
        Cross-fitting of ``"CAL"``.

    Returns
    -------
    certificate : Certificate
        With the winning ``ranking`` and every ranking's outcome.
    calibrator : Calibrator or None
        P in the winner's order (Platt scaling of a fixed score, or the model refitted on all labels); None when
        nothing is certified.
    cut : float
        The certified cut on ``calibrator.confidence`` (``inf`` when nothing is certified).
    """
    n = int(correct.size)
    share = delta / len(rankings)
    grid = coverage_grid(n, target_precision, share)
    outcomes: dict[str, dict[str, Any]] = {}
    best: tuple[int, str, int, np.ndarray, np.ndarray] | None = None
    for name in rankings:
        if grid.size == 0:
            outcomes[name] = {"certified": False, "accepted": 0, "correct_accepted": 0, "cuts_tested": 0}
            continue
        if name == "CAL":
            matrix = columns(labelled, model_features)
            crossed = cross_fitted(matrix, correct, model_features, folds, seed)
            if crossed is None:
                outcomes[name] = {"certified": False, "accepted": 0, "correct_accepted": 0, "cuts_tested": 0}
                continue
            assignment, models = crossed
            pool_matrix = columns(pool, model_features)
            acceptance = np.zeros((grid.size, n), dtype=bool)
            for fold, model in enumerate(models):
                rows = assignment == fold
                cuts = cuts_at_coverage(model.confidence(pool_matrix), grid)
                acceptance[:, rows] = model.confidence(matrix[rows])[None, :] >= cuts[:, None]
        else:
            feature, sign = RANKINGS[name]
            cuts = cuts_at_coverage(sign * pool[feature], grid)
            acceptance = (sign * labelled[feature])[None, :] >= cuts[:, None]
        accepted = acceptance.sum(axis=1)
        good = (acceptance & correct[None, :]).sum(axis=1)
        rejected, _ = fixed_sequence(accepted, good, target_precision=target_precision, delta=share)
        chosen = rejected - 1
        outcomes[name] = {
            "certified": rejected > 0,
            "accepted": int(accepted[chosen]) if rejected else 0,
            "correct_accepted": int(good[chosen]) if rejected else 0,
            "cuts_tested": min(rejected + 1, grid.size),
        }
        if rejected and (best is None or good[chosen] > best[0]):
            best = (int(good[chosen]), name, chosen, accepted, good)
    n_needed = min_accepted(target_precision, share)
    common = {"n_test": n, "min_accepted": n_needed, "delta_per_ranking": share, "rankings": outcomes}
    if best is None:
        if n < n_needed:
            why = f"the {n} labelled queries are fewer than the {n_needed} accepted ones needed at δ/{len(rankings)}"
        else:
            tried = "; ".join(
                f"{name}: {o['cuts_tested']} cut(s) tested" for name, o in outcomes.items() if o["cuts_tested"]
            )
            why = (
                f"the strictest cut ({n_needed} of {n} labelled queries) already holds a wrong answer for every "
                f"ranking ({tried})"
            )
        certificate = _uncertified(
            f"nothing certified at precision {target_precision:g} with risk {delta:g}: {why}",
            cuts_tested=max((o["cuts_tested"] for o in outcomes.values()), default=0),
            **common,
        )
        return certificate, None, math.inf
    n_good, name, chosen, accepted, good = best
    coverage = grid[chosen : chosen + 1]
    if name == "CAL":
        calibrator = replace(fit_model(columns(labelled, model_features), correct, model_features), ranking="CAL")
        cut = float(cuts_at_coverage(calibrator.confidence(columns(pool, model_features)), coverage)[0])
    else:
        feature, sign = RANKINGS[name]
        calibrator = platt(name, feature, sign, labelled[feature], correct)
        cut_on_score = float(cuts_at_coverage(sign * pool[feature], coverage)[0])
        slope = calibrator.coef[0] * sign  # > 0: the calibrator's confidence is slope · (sign · f) + intercept
        cut = slope * cut_on_score + calibrator.intercept
    n_acc = int(accepted[chosen])
    bound = float(clopper_pearson_lower(n_good, n_acc, share))
    certificate = Certificate(
        certified=True,
        cut=cut,
        precision_lower_bound=bound,
        accepted=n_acc,
        correct_accepted=n_good,
        expected_coverage=n_acc / n,
        expected_recall=n_good / max(int(answerable.sum()), 1),
        cuts_tested=outcomes[name]["cuts_tested"],
        message=(
            f"precision >= {target_precision:g} certified with probability >= {1 - delta:g} by the {name} ranking: "
            f"{n_good} of {n_acc} accepted labelled queries correct, lower bound {bound:.3f} "
            f"({len(rankings)} ranking(s) tested, each at risk {share:.3g})"
        ),
        ranking=name,
        coverage=float(coverage[0]),
        **common,
    )
    return certificate, calibrator, cut


def needed_message(confidence: np.ndarray, correct: np.ndarray, p_star: float, delta: float) -> str:
    """What more labels could do, from the in-sample precision of the confidence (a lower bound on the need)."""
    order = np.argsort(-confidence, kind="stable")
    precision = np.cumsum(correct[order]) / np.arange(1, correct.size + 1)
    reaching = np.flatnonzero(precision >= p_star)
    n_min = min_accepted(p_star, delta)
    if reaching.size == 0:
        return "no cut reaches that precision even on the labelled queries themselves"
    share = (reaching[-1] + 1) / correct.size
    needed = math.ceil(n_min / share)
    plan = "`vpr-uncertainty calibrate --plan` (plan_labels) estimates how many labelled queries would certify it"
    if needed > correct.size:
        return (
            f"at most {share:.0%} of the queries are accepted at precision {p_star:g} (in-sample), so at least "
            f"about {needed} labelled queries would be needed ({n_min} accepted ones); {plan}"
        )
    return plan
