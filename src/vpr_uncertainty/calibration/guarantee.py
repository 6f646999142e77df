"""A threshold with a precision guarantee: Learn-then-Test with exact binomial p-values and fixed-sequence testing.

The question: accept the answers whose confidence is at least a cut t. Which t makes the precision of the accepted
answers on new queries at least p*, with probability at least 1 − δ over the draw of the calibration queries?

Method (Angelopoulos et al., "Learn then Test", 2021)
    1. The candidate cuts t_1 > t_2 > … (strictest first) are fixed **before** any label is read: quantiles of the
       ranking's confidence over the queries the caller passes, labelled or not, accepting the counts of
       :func:`cut_chain`, which depend on nothing but the number of labelled queries, p* and the ranking's level.
    2. For each cut, H_j: "precision(t_j) < p*". Given n_j accepted labelled queries of which c_j are correct, the
       number correct is Binomial(n_j, precision(t_j)), so p_j = P[Binomial(n_j, p*) ≥ c_j] is a valid p-value
       (the exact binomial test; its inversion is the Clopper–Pearson bound).
    3. The fallback procedure (:func:`fallback_test`) along the chain controls the family-wise error at the
       ranking's level, so with probability ≥ 1 − level every rejected cut has precision ≥ p*; the loosest one is
       chosen. Unlike the plain fixed sequence, a wrong answer among the most confident does not end the chain.

Several rankings (the margin, SU, a cross-fitted model, …) are tested each at its share of δ (a weighted union
bound), so that every certified rule holds at once with probability ≥ 1 − δ and the one accepting the most correct
labelled queries may be kept. Nothing can be certified with fewer than ⌈log δ / log p*⌉ accepted queries (even all
correct, the p-value p*^n stays above δ): :func:`min_accepted`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from vpr_uncertainty._validation import check_count, did_you_mean
from vpr_uncertainty.calibration.calibrator import RANKINGS, Calibrator, columns, cross_fitted, fit_model, ranking_rule

#: The candidate rankings of the default gate and the share of δ each is given, from 8 × :func:`min_accepted`
#: labelled queries on (:data:`DEFAULT_SCHEDULE`; docs/evidence/calibration.md).
DEFAULT_SHARES: dict[str, float] = {"CAL": 0.9, "margin": 0.1}
#: The share of a ranking's level its chain holds for the fallback count (:func:`cut_chain`).
FALLBACK = 0.3
#: The default rankings by the number of labelled queries: from ``multiple`` × :func:`min_accepted` labelled queries
#: on (22 for p* = 0.9, δ = 0.1), these shares of δ and this fallback share. With few labels the whole δ on SU (the
#: textbook fixed sequence): a cross-fitted model is noisy and a split δ misses short clean tops.
DEFAULT_SCHEDULE: tuple[tuple[int, dict[str, float], float], ...] = (
    (0, {"SU": 1.0}, 0.0),
    (6, {"SU": 0.5, "CAL": 0.5}, 0.0),
    (8, DEFAULT_SHARES, FALLBACK),
)
#: From this share of the labelled queries on, a chain tests every count (:func:`cut_chain`, the sequential mode's
#: chains; the batch gate's, :func:`certify_rankings`, test every count from the first).
DENSE_FROM = 0.25

__all__ = [
    "DEFAULT_SCHEDULE",
    "DEFAULT_SHARES",
    "Certificate",
    "certify_rankings",
    "certify_threshold",
    "check_rankings",
    "clopper_pearson_lower",
    "cut_chain",
    "cuts_at_coverage",
    "default_rankings",
    "fallback_test",
    "fixed_sequence",
    "min_accepted",
    "needed_message",
    "tolerant_steps",
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


def default_rankings(n_labelled: int, target_precision: float, delta: float) -> tuple[dict[str, float], float]:
    """The default rankings' shares of δ and their chains' fallback share for ``n_labelled`` labelled queries
    (:data:`DEFAULT_SCHEDULE`): fixed by n, p* and δ alone, never by a label, so the union bound holds.

    Examples
    --------
    >>> default_rankings(111, 0.9, 0.1), default_rankings(176, 0.9, 0.1)[0]
    (({'SU': 1.0}, 0.0), {'CAL': 0.9, 'margin': 0.1})
    """
    needed = min_accepted(target_precision, delta)
    _, shares, fallback = [step for step in DEFAULT_SCHEDULE if n_labelled >= step[0] * needed][-1]
    return dict(shares), fallback


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
    rankings : dict
        Per candidate ranking: ``delta`` (its share of δ), ``certified``, ``accepted``, ``correct_accepted``
        (labelled queries at its loosest certified cut) and ``cuts_tested`` (the counts of its chain).
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
    rankings: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _uncertified(message: str, **fields: Any) -> Certificate:
    """A certificate of nothing: no cut, no bound, no query accepted."""
    zero = {"accepted": 0, "correct_accepted": 0, "expected_coverage": 0.0, "expected_recall": 0.0}
    return Certificate(certified=False, cut=None, precision_lower_bound=None, message=message, **zero, **fields)


def tolerant_steps(n: int, target_precision: float, level: float) -> np.ndarray:
    """The tolerant steps up to ``n``: for w = 0, 1, 2, …, the fewest accepted queries among which w wrong answers
    still pass the exact binomial test at ``level`` (P[Binomial(m_w, p*) ≥ m_w − w] ≤ level), increasing.

    Examples
    --------
    >>> tolerant_steps(100, 0.9, 0.1).tolist()
    [22, 38, 52, 65, 78, 91]
    """
    accepted = np.arange(1, n + 1)
    room = accepted - (stats.binom.isf(level, accepted, target_precision) + 1)  # wrong answers allowed
    widened = room > np.maximum.accumulate(np.concatenate([[-1], room[:-1]]))
    return accepted[(room >= 0) & widened]


def cut_chain(
    n_labelled: int,
    target_precision: float,
    level: float,
    *,
    fallback: float = FALLBACK,
    dense_from: float = DENSE_FROM,
) -> tuple[np.ndarray, np.ndarray]:
    """The accepted counts one ranking tests, strictest first, and the level each holds before any is passed on.

    Fixed by n, p* and the ranking's level alone (never by a label). The first count, m_0 at (1 − f)·level, holds
    (1 − f)·level; the fallback count, the fewest among which one wrong answer passes at f·level, holds f·level;
    the counts between are the tolerant steps at ``level`` (each allows one more wrong answer, 22, 38, 52, 65, …
    for p* = 0.9 at 0.1), and from ``dense_from``·n on every count is tested, where the cut is found. Tested by
    :func:`fallback_test`, so a wrong answer among the most confident stops the chain's first level only.

    Returns
    -------
    counts : ndarray of shape (m,), int
        Labelled queries accepted at each tested cut, increasing (empty when n is too small).
    levels : ndarray of shape (m,)
        The level (share of δ) each count holds on its own; they sum to ``level``.

    Examples
    --------
    >>> counts, levels = cut_chain(60, 0.9, 0.1, fallback=0.3, dense_from=0.5)
    >>> counts[:4].tolist(), counts[-1].item(), levels[levels > 0].round(3).tolist()
    ([26, 30, 31, 32], 60, [0.07, 0.03])
    """
    _check_target(target_precision, level)
    check_count(n_labelled, "n_labelled", 0)
    first = min_accepted(target_precision, (1 - fallback) * level)
    spare = tolerant_steps(n_labelled, target_precision, fallback * level)[1:2] if fallback > 0 else []
    dense = np.arange(max(first, math.ceil(dense_from * n_labelled)), n_labelled + 1)
    steps = tolerant_steps(n_labelled, target_precision, level)
    counts = np.unique(np.concatenate([[first], spare, steps[steps > first], dense]).astype(int))
    counts = counts[counts <= n_labelled]
    levels = np.zeros(counts.size)
    if counts.size:
        levels[0] = (1 - fallback) * level
        levels[np.searchsorted(counts, spare)] += fallback * level
    return counts, levels


def fallback_test(p_values: np.ndarray, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which hypotheses of a chain the fallback procedure rejects (Wiens 2003), and the level each was tested at,
    both of shape (m,).

    Hypothesis j is tested at its own level plus the level of hypothesis j − 1 when that one was rejected: a
    graphical procedure on the chain H_1 → H_2 → …, which controls the family-wise error at Σ levels. With the
    whole level on H_1 it is the fixed sequence.

    Examples
    --------
    >>> fallback_test(np.array([0.2, 0.02, 0.03, 0.2, 0.01]), np.array([0.07, 0.03, 0.0, 0.0, 0.0]))[0].tolist()
    [False, True, True, False, False]
    """
    rejected, tested_at = np.zeros(len(p_values), bool), np.zeros(len(p_values))
    carried = 0.0
    for j, (p_value, level) in enumerate(zip(p_values, levels, strict=True)):
        carried = tested_at[j] = level + (carried if j and rejected[j - 1] else 0.0)
        rejected[j] = p_value <= carried
    return rejected, tested_at


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


def check_rankings(rankings: Sequence[str] | dict[str, float], available: dict[str, np.ndarray]) -> dict[str, float]:
    """Each ranking's share of δ: a list of names shares it evenly, a dict gives each its share (positive, summing
    to at most 1). Checked: names known, distinct, and their feature among ``available``."""
    if isinstance(rankings, str) or not rankings:
        raise ValueError(f"rankings must be a non-empty list of names from {[*RANKINGS, 'CAL']}, got {rankings!r}")
    names = tuple(rankings)
    unknown = [name for name in names if name != "CAL" and name not in RANKINGS]
    if unknown:
        valid = [*RANKINGS, "CAL"]
        raise ValueError(f"unknown ranking(s) {unknown}; {did_you_mean(unknown[0], valid)}valid: {', '.join(valid)}")
    if len(set(names)) != len(names):
        raise ValueError(f"rankings lists a name twice: {list(names)}")
    missing = [name for name in names if name != "CAL" and RANKINGS[name][0] not in available]
    if missing:
        raise ValueError(f"ranking(s) {missing} need cosine similarities in [-1, 1] (d² = 2 − 2s)")
    if not isinstance(rankings, dict):
        return dict.fromkeys(names, 1.0 / len(names))
    shares = {name: float(share) for name, share in rankings.items()}
    if not all(0 < share <= 1 for share in shares.values()) or sum(shares.values()) > 1 + 1e-9:
        raise ValueError(f"the shares of δ must be positive and sum to at most 1, got {shares}")
    return shares


def certify_rankings(
    labelled: dict[str, np.ndarray],
    pool: dict[str, np.ndarray],
    correct: np.ndarray,
    answerable: np.ndarray,
    *,
    shares: dict[str, float],
    model_features: tuple[str, ...],
    target_precision: float,
    delta: float,
    folds: int,
    seed: int,
    fallback: float = FALLBACK,
    dense_from: float = 0.0,
) -> tuple[Certificate, Calibrator | None, float]:
    """Each ranking's chain (:func:`cut_chain`) tested at its share of δ on all labelled queries; the winner's rule.

    ``labelled`` and ``pool`` hold feature columns of shape (L,) and (N,) (labelled first, then unlabelled: the
    cuts are quantiles over the pool); ``correct`` and ``answerable`` (L,) the labels and the recall denominator;
    ``shares`` each ranking's share of δ (a union bound: all certified rules hold at once with probability
    ≥ 1 − δ); ``model_features``, ``folds`` and ``seed`` the cross-fitted ``"CAL"``. No δ is left where no label
    can use it: a ranking whose chain starts beyond n gives its share to the others (pro rata), and a chain whose
    fallback count lies beyond n holds its whole level on its first count; both depend on n, p* and δ alone.

    Returns the :class:`Certificate` (the winner: the certified rule accepting the most correct labelled queries;
    every ranking's outcome and δ), the rule (a linear confidence in the winner's order: the fixed score itself, or
    the model refitted on all labels; None when nothing is certified) and its cut (``inf``: accept nothing).
    """
    n = int(correct.size)
    outcomes: dict[str, dict[str, Any]] = {}
    best: tuple[int, str, float, int, float] | None = None

    def chain(level: float) -> tuple[np.ndarray, np.ndarray]:
        spare = fallback > 0 and tolerant_steps(n, target_precision, fallback * level)[1:2].size
        return cut_chain(n, target_precision, level, fallback=fallback if spare else 0.0, dense_from=dense_from)

    usable = {name: share for name, share in shares.items() if chain(share * delta)[0].size}
    scale = sum(shares.values()) / sum(usable.values()) if usable else 1.0
    for name, share in shares.items():
        share = usable.get(name, 0.0) * scale if usable else share
        counts, levels = chain(share * delta) if share else (np.zeros(0, int), np.zeros(0))
        outcome = outcomes[name] = {"delta": share * delta, "certified": False, "accepted": 0, "correct_accepted": 0}
        outcome["cuts_tested"] = int(counts.size)
        matrix = columns(labelled, model_features) if name == "CAL" else None
        crossed = None if matrix is None else cross_fitted(matrix, correct, model_features, folds, seed)
        if counts.size == 0 or (name == "CAL" and crossed is None):
            continue
        coverage = counts / n
        if crossed is not None:
            assignment, models = crossed
            acceptance = np.zeros((counts.size, n), dtype=bool)
            for fold, model in enumerate(models):
                rows = assignment == fold
                cuts = cuts_at_coverage(model.confidence(columns(pool, model_features)), coverage)
                acceptance[:, rows] = model.confidence(matrix[rows])[None, :] >= cuts[:, None]
        else:
            feature, sign = RANKINGS[name]
            cuts = cuts_at_coverage(sign * pool[feature], coverage)
            acceptance = (sign * labelled[feature])[None, :] >= cuts[:, None]
        accepted = acceptance.sum(axis=1)
        good = (acceptance & correct[None, :]).sum(axis=1)
        _, p_values = fixed_sequence(accepted, good, target_precision=target_precision, delta=share * delta)
        rejected, tested_at = fallback_test(p_values, levels)
        if rejected.any():
            chosen = int(np.flatnonzero(rejected)[-1])  # the loosest certified cut
            outcome.update(certified=True, accepted=int(accepted[chosen]), correct_accepted=int(good[chosen]))
            if best is None or good[chosen] > best[0]:
                best = (int(good[chosen]), name, float(coverage[chosen]), int(accepted[chosen]), tested_at[chosen])
    n_needed = min(min_accepted(target_precision, share * delta) for share in shares.values())
    common = {"n_test": n, "min_accepted": n_needed, "rankings": outcomes}
    given = ", ".join(f"{ranking} {o['delta']:.3g}" for ranking, o in outcomes.items())
    if best is None:
        why = f"{n} labelled queries, fewer than the {n_needed} needed" if n < n_needed else "every chain failed"
        message = f"nothing certified at precision {target_precision:g} with risk {delta:g}: {why} (δ given: {given})"
        tested = sum(o["cuts_tested"] for o in outcomes.values())
        return _uncertified(message, cuts_tested=tested, **common), None, math.inf
    n_good, name, coverage, n_acc, level = best
    if name == "CAL":
        rule = replace(fit_model(columns(labelled, model_features), correct, model_features), ranking="CAL")
        confidence = rule.confidence(columns(pool, model_features))
    else:
        rule = ranking_rule(name)
        confidence = rule.confidence(pool[rule.features[0]][:, None])
    cut = float(cuts_at_coverage(confidence, np.array([coverage]))[0])
    bound = float(clopper_pearson_lower(n_good, n_acc, level))
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
            f"{n_good} of {n_acc} accepted labelled queries correct, lower bound {bound:.3f} (δ given: {given})"
        ),
        ranking=name,
        coverage=coverage,
        **common,
    )
    return certificate, rule, cut


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
