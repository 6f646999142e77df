"""Certify a threshold over several candidate rankings, each at δ / R, on every labelled query.

For each ranking, the cuts are quantiles of its confidence over every query the caller passes (labelled and
unlabelled) at the label-free coverages of :func:`~vpr_uncertainty.calibration.guarantee.coverage_grid`; the
fixed-sequence test (:func:`~vpr_uncertainty.calibration.guarantee.fixed_sequence`) picks its loosest certified cut.
A training-free ranking is tested directly; the fitted model ``"CAL"`` is cross-fitted (each labelled query is
accepted or not by the fold model that did not see it, at that model's own quantile cut). Of the certified rules,
which all hold at once with probability ≥ 1 − δ (Bonferroni), the one accepting the most correct labelled queries
is kept.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from vpr_uncertainty.calibration.calibrator import Calibrator
from vpr_uncertainty.calibration.guarantee import (
    Certificate,
    clopper_pearson_lower,
    coverage_grid,
    cuts_at_coverage,
    fixed_sequence,
    min_accepted,
)
from vpr_uncertainty.calibration.rankings import RANKINGS, columns, cross_fitted, fit_model, platt

__all__ = ["CAL_MIN_LABELLED", "certify_rankings", "check_rankings", "default_rankings", "needed_message"]

#: From this many labelled queries on, the gate also tests the cross-fitted model (at δ/2 beside SU at δ/2);
#: below it, splitting δ costs more than the model gains (corridor simulations, README "Calibration").
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
        Feature columns (:func:`~vpr_uncertainty.calibration.rankings.feature_columns`) of the labelled queries
        and of every query passed (labelled first, then unlabelled); the cuts are quantiles over ``pool``.
    correct, answerable : ndarray of shape (L,), bool
        Top-1 correctness of the labelled queries, and which have a positive (the recall denominator).
    rankings : tuple of str
        Names from :data:`~vpr_uncertainty.calibration.rankings.RANKINGS` and ``"CAL"``.
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
    common = {
        "n_test": n,
        "min_accepted": n_needed,
        "delta_per_ranking": share,
        "rankings": outcomes,
    }
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
        certificate = Certificate(
            certified=False,
            cut=None,
            precision_lower_bound=None,
            accepted=0,
            correct_accepted=0,
            expected_coverage=0.0,
            expected_recall=0.0,
            cuts_tested=max((o["cuts_tested"] for o in outcomes.values()), default=0),
            message=f"nothing certified at precision {target_precision:g} with risk {delta:g}: {why}",
            **common,
        )
        return certificate, None, math.inf
    n_good, name, chosen, accepted, good = best
    coverage = float(grid[chosen])
    if name == "CAL":
        calibrator = fit_model(columns(labelled, model_features), correct, model_features)
        calibrator.ranking = "CAL"
        cut = float(
            cuts_at_coverage(calibrator.confidence(columns(pool, model_features)), grid[chosen : chosen + 1])[0]
        )
    else:
        feature, sign = RANKINGS[name]
        calibrator = platt(name, feature, sign, labelled[feature], correct)
        cut_on_score = float(cuts_at_coverage(sign * pool[feature], grid[chosen : chosen + 1])[0])
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
        coverage=coverage,
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
