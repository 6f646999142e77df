"""Simulating :func:`~vpr_uncertainty.calibration.fit.calibrate` on draws of n labelled queries.

:func:`simulate_guarantee` draws from a population whose labels are all known (how often the guarantee holds, how
much a gate accepts); :func:`plan_labels` draws from the few labelled queries a user has (how many labels to ask
for). Recall, everywhere here: accepted correct answers / answerable queries.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from vpr_uncertainty._validation import as_score_array, check_count
from vpr_uncertainty.calibration.calibrator import feature_columns, feature_matrix
from vpr_uncertainty.calibration.fit import calibrate_arrays
from vpr_uncertainty.calibration.guarantee import min_accepted
from vpr_uncertainty.evaluation.metrics import rank_queries
from vpr_uncertainty.progress import progress_bar

__all__ = ["DEFAULT_SIZES", "GuaranteeSimulation", "LabelPlan", "hindsight_recall", "plan_labels", "simulate_guarantee"]

#: The calibration sizes :func:`plan_labels` simulates by default (those above the pool are replaced by the pool).
DEFAULT_SIZES: tuple[int, ...] = (25, 50, 100, 200, 400, 800, 1600)
_Z = 1.959963984540054  # the normal quantile of a two-sided 95 % interval


@dataclass
class LabelPlan:
    """The outcome of :func:`plan_labels`; per size, a point estimate and its 95 % interval ``(low, high)``.

    Attributes
    ----------
    sizes : list of int
        Numbers of labelled queries simulated, none above ``pool_size``.
    certified, certified_interval : list of float, list of (float, float)
        Share of simulations in which ``calibrate`` certifies p* (Wilson interval over ``draws`` simulations).
    mean_recall, recall_interval : list of float, list of (float, float)
        Mean recall (accepted correct / answerable; 0 when nothing is certified) and its normal interval.
    needed : int or None
        The smallest size whose ``certified`` share reaches 1 − δ (None: no size up to the pool does).
    n_labelled, pool_size : int
        Labels the estimate rests on; queries that could be labelled (labelled + unlabelled).
    draws : int
        Simulations per size (the same draws at every size).
    """

    sizes: list[int]
    certified: list[float]
    certified_interval: list[tuple[float, float]]
    mean_recall: list[float]
    recall_interval: list[tuple[float, float]]
    needed: int | None
    n_labelled: int
    pool_size: int
    target_precision: float
    delta: float
    draws: int
    message: str = ""
    notes: list[str] = field(default_factory=list)

    def table(self) -> str:
        """A Markdown table of the simulated sizes."""
        lines = [
            f"| labelled queries ({self.draws} simulations each) | P(certified) [95 % interval] | "
            "mean recall = accepted correct / answerable [95 % interval] |",
            "|---|---|---|",
        ]
        for size, c, (c_low, c_high), r, (r_low, r_high) in zip(
            self.sizes, self.certified, self.certified_interval, self.mean_recall, self.recall_interval, strict=True
        ):
            lines.append(f"| {size} | {c:.2f} [{c_low:.2f}, {c_high:.2f}] | {r:.3f} [{r_low:.3f}, {r_high:.3f}] |")
        return "\n".join(lines)


def _monotone(values: np.ndarray) -> list[np.ndarray]:
    """Per column of (draws, sizes) ``values``, the per-draw mean over its block of pool-adjacent-violators."""
    blocks: list[list[int]] = []
    for column in range(values.shape[1]):
        blocks.append([column])
        while len(blocks) > 1 and values[:, blocks[-2]].mean() > values[:, blocks[-1]].mean():
            blocks[-2:] = [blocks[-2] + blocks[-1]]
    return [values[:, block].mean(axis=1) for block in blocks for _ in block]


def _neighbours(pool_scores: np.ndarray, n_labelled: int, k: int) -> np.ndarray:
    """The 3 nearest labelled queries (the first ``n_labelled`` rows of ``pool_scores``) of each unlabelled one, by
    the pool ranks of the features the candidates read (s1, margin, RS, SD, SU, PA); 3, so that a ranking's
    clean top stays clean (wider ones blurred errors into every top: docs/evidence/calibration.md)."""
    found = feature_columns(pool_scores, k)
    features = np.column_stack(list(found.values()))
    ranks = np.argsort(np.argsort(features, axis=0, kind="stable"), axis=0) / max(len(features) - 1, 1)
    labelled, unlabelled = ranks[:n_labelled], ranks[n_labelled:]
    distance = (labelled**2).sum(axis=1) - 2 * unlabelled @ labelled.T  # squared distance, less ‖unlabelled‖²
    return np.argsort(distance, axis=1, kind="stable")[:, :3]


#: Pseudo-labels at the base rate in the neighbourhood rates' Beta priors, in all (plan_labels): 0.15 per label at 30
#: labels, chosen by Brier score; a total, since a prior that grew with the labels made the plan pessimistic.
PRIOR_LABELS = 4.5


def _wilson(share: float, n: int) -> tuple[float, float]:
    centre, spread = share + _Z**2 / (2 * n), _Z * np.sqrt(share * (1 - share) / n + _Z**2 / (4 * n * n))
    return float((centre - spread) / (1 + _Z**2 / n)), float((centre + spread) / (1 + _Z**2 / n))


def plan_labels(
    labelled_scores: np.ndarray,
    correct: np.ndarray,
    *,
    target_precision: float,
    unlabelled: np.ndarray | None = None,
    answerable: np.ndarray | None = None,
    delta: float = 0.1,
    k: int = 10,
    sizes: Sequence[int] = DEFAULT_SIZES,
    draws: int = 100,
    seed: int = 0,
    progress: bool | None = None,
) -> LabelPlan:
    """Estimate, before labelling more, how often n labelled queries certify ``target_precision`` and at what recall.

    The population is the pool, labelled and ``unlabelled`` queries: each simulation draws, for every labelled
    query, the correct rate of its neighbourhood from its posterior (its label plus 4.5 / L pseudo-labels at the base
    rate, L the labelled queries: 4.5 in all, a prior that does not grow with the labels; 0.15 per label made the
    plan pessimistic by 0.17 at 200 labels), gives every unlabelled query a label drawn with the mean rate of its 3
    nearest labelled queries in the ranks of the candidates' features (so each ranking's clean or dirty top is as
    the labels show it, errors the few labels missed included), draws queries from the pool with replacement, and runs
    :func:`calibrate_arrays` with ``calibrate``'s defaults on the first n, for each size n (common draws: the sizes
    differ by the labels added, not by luck). A draw holding one outcome certifies nothing (``calibrate`` refuses
    it). Recall is measured on the simulated pool. Where noise would make a figure fall with more labels,
    adjacent sizes are pooled (pool-adjacent-violators), so the table is monotone. The figures average over the
    posterior, so they carry the few labels' uncertainty; the intervals count the simulations' noise
    (docs/evidence/calibration.md measures the error).

    Parameters
    ----------
    labelled_scores : ndarray of shape (L, K)
        Top-K similarities of the queries labelled so far, sorted descending.
    correct : ndarray of shape (L,), bool
        Their top-1 correctness; at least 2 correct and 2 wrong.
    target_precision, delta : float in (0, 1)
        p* and δ, as in :func:`~vpr_uncertainty.calibrate`.
    unlabelled : ndarray of shape (U, K), optional
        Top-K similarities of the queries not labelled yet; no size above the pool, L + U, is simulated.
    answerable : ndarray of shape (L,), bool, optional
        Which labelled queries have a correct answer in the database (default: all; unlabelled ones count as
        answerable).
    k : int, default=10
    sizes : sequence of int
        Numbers of labelled queries to simulate.
    draws : int, default=100
        Simulations (each one draw per size).
    seed : int, default=0
    progress : bool, optional
        A progress bar over the simulations (default: on a terminal).

    Returns
    -------
    LabelPlan
        ``plan.table()`` prints one row per size; ``plan.message`` answers in a sentence.
    """
    correct = np.asarray(correct, dtype=bool)
    labelled_scores = np.asarray(labelled_scores, dtype=np.float64)
    if labelled_scores.ndim != 2 or correct.shape != (labelled_scores.shape[0],):
        raise ValueError(
            f"labelled_scores (L, K) and correct (L,) must match, got {labelled_scores.shape} and {correct.shape}"
        )
    if min(int(correct.sum()), int((~correct).sum())) < 2:
        raise ValueError(
            f"a label plan needs at least 2 correct and 2 wrong labelled answers, got {int(correct.sum())} correct "
            f"of {correct.size}: label a few more queries (a random handful is enough to start)"
        )
    answerable = np.ones(correct.size, bool) if answerable is None else np.asarray(answerable, dtype=bool)
    check_count(draws, "draws", 1)
    min_accepted(target_precision, delta)  # checks p* and δ
    pool_scores, pool_answerable = labelled_scores, answerable
    if unlabelled is not None and len(unlabelled):
        unlabelled = as_score_array(unlabelled, name="unlabelled")
        width = min(labelled_scores.shape[1], unlabelled.shape[1])
        pool_scores = np.concatenate([labelled_scores[:, :width], unlabelled[:, :width]])
        pool_answerable = np.concatenate([answerable, np.ones(len(pool_scores) - correct.size, bool)])
    pool = len(pool_scores)
    asked = sorted({int(size) for size in sizes})
    if not asked or asked[0] < 2:
        raise ValueError(f"sizes must be integers >= 2, got {asked}")
    sizes = [size for size in asked if size <= pool] + ([pool] if asked[-1] > pool else [])
    neighbours = _neighbours(pool_scores, correct.size, k) if pool > correct.size else np.zeros((0, 3), int)
    pseudo, prior = PRIOR_LABELS / correct.size, PRIOR_LABELS * correct.mean() / correct.size  # per labelled query
    rng = np.random.default_rng(seed)
    certified, recall = np.zeros((draws, len(sizes))), np.zeros((draws, len(sizes)))
    for draw in progress_bar(range(draws), desc="simulating calibrations", unit="draw", enabled=progress):
        rates = rng.beta(correct + prior, ~correct + pseudo - prior)  # one posterior draw per simulation
        labels = np.concatenate([correct, rng.random(len(neighbours)) < rates[neighbours].mean(axis=1)])
        rows = rng.choice(pool, sizes[-1], replace=True)
        for column, size in enumerate(sizes):
            pick = rows[:size]
            if labels[pick].all() or not labels[pick].any():
                continue
            gate = calibrate_arrays(
                pool_scores[pick],
                labels[pick],
                answerable=pool_answerable[pick],
                target_precision=target_precision,
                delta=delta,
                k=k,
            )
            if gate.precision_lower_bound is not None:
                certified[draw, column] = 1.0
                accepted = gate.accept(pool_scores[:, : gate.k])
                recall[draw, column] = (accepted & labels).sum() / max(int(pool_answerable.sum()), 1)
    shares, recalls = _monotone(certified), _monotone(recall)
    point = [float(share.mean()) for share in shares]
    mean_recall = [float(values.mean()) for values in recalls]
    spread = [_Z * float(values.std(ddof=1)) / np.sqrt(draws) if draws > 1 else np.inf for values in recalls]
    needed = next((size for size, share in zip(sizes, point, strict=True) if share >= 1 - delta), None)
    goal = f"precision {target_precision:g} in"
    if needed is not None:
        message = f"about {needed} labelled queries certify {goal} ≥ {1 - delta:.0%} of the simulations"
        message += f" (mean recall {mean_recall[sizes.index(needed)]:.2f})"
    elif sizes[-1] == pool:
        message = f"the pool holds only {pool} queries: labelling all of them certifies {goal} {point[-1]:.0%} of the "
        message += f"simulations, fewer than {1 - delta:.0%}"
    else:
        message = f"none of the simulated sizes (up to {sizes[-1]} labelled queries) certifies {goal} {1 - delta:.0%}"
        message += " of the simulations"
    notes = [
        f"simulated on the pool, the unlabelled queries' labels drawn from a posterior on the {correct.size} labelled "
        f"ones ({draws} simulations, the same draws at every size), calibrate run with its defaults"
    ]
    if asked[-1] > pool and not message.startswith("the pool holds only"):
        notes.append(f"the pool holds only {pool} queries: sizes above it are not simulated")
    return LabelPlan(
        sizes=sizes,
        certified=point,
        certified_interval=[_wilson(share, draws) for share in point],
        mean_recall=mean_recall,
        recall_interval=[(max(r - s, 0.0), r + s) for r, s in zip(mean_recall, spread, strict=True)],
        needed=needed,
        n_labelled=int(correct.size),
        pool_size=pool,
        target_precision=target_precision,
        delta=delta,
        draws=draws,
        message=message,
        notes=notes,
    )


@dataclass
class GuaranteeSimulation:
    """Per draw: population precision (NaN when nothing is accepted), recall and coverage; and the summary."""

    precision: np.ndarray
    recall: np.ndarray
    coverage: np.ndarray
    certified: np.ndarray
    target_precision: float
    delta: float
    hindsight_recall: float

    @property
    def violation_rate(self) -> float:
        """Share of draws whose accepted answers have population precision < p* (draws accepting none never do)."""
        return float(np.mean(np.nan_to_num(self.precision, nan=1.0) < self.target_precision))

    @property
    def mean_recall(self) -> float:
        return float(self.recall.mean())


def hindsight_recall(uncertainty: np.ndarray, correct: np.ndarray, target_precision: float, n_answerable: int) -> float:
    """Largest end-to-end recall of a cut on ``uncertainty`` (accept ≤ cut) with precision ≥ p*, ties kept together."""
    ranking = rank_queries(correct, uncertainty)
    ok = ranking.correct_accepted / ranking.accepted >= target_precision
    return float(ranking.correct_accepted[ok].max() / max(n_answerable, 1)) if ok.any() else 0.0


def simulate_guarantee(
    scores: np.ndarray,
    correct: np.ndarray,
    *,
    n_calibration: int,
    target_precision: float = 0.9,
    delta: float = 0.1,
    n_draws: int = 200,
    seed: int = 0,
    k: int = 10,
    model: str = "logistic",
    rankings: Sequence[str] | None = None,
    unlabelled: bool = False,
    answerable: np.ndarray | None = None,
) -> GuaranteeSimulation:
    """Calibrate on ``n_draws`` i.i.d. draws of ``n_calibration`` queries and measure each gate on the population.

    Draws are **with replacement**, so i.i.d. from the population (the assumption of the guarantee), and the
    population precision among each gate's accepted answers is known exactly: the guarantee says the share of
    draws below p* is at most δ. The hindsight reference is the largest recall of any SU cut with precision ≥ p* on
    the whole population. With ``unlabelled=True`` every draw also passes the whole population's scores as
    unlabelled queries (the robot's own traversal). Draws that hold only one outcome cannot be calibrated; they
    are redrawn.
    """
    correct = np.asarray(correct, dtype=bool)
    answerable = np.ones(correct.size, bool) if answerable is None else np.asarray(answerable, dtype=bool)
    rng = np.random.default_rng(seed)
    precision, recall, coverage, certified = (np.zeros(n_draws) for _ in range(4))
    n_answerable = int(answerable.sum())
    for draw in range(n_draws):
        rows = rng.choice(correct.size, n_calibration, replace=True)
        while correct[rows].all() or not correct[rows].any():
            rows = rng.choice(correct.size, n_calibration, replace=True)
        gate = calibrate_arrays(
            scores[rows],
            correct[rows],
            answerable=answerable[rows],
            target_precision=target_precision,
            delta=delta,
            k=k,
            seed=draw,
            model=model,
            rankings=rankings,
            unlabelled=scores if unlabelled else None,
        )
        accepted = gate.accept(scores[:, : gate.k])
        n_accepted = int(accepted.sum())
        good = int((accepted & correct).sum())
        precision[draw] = good / n_accepted if n_accepted else np.nan
        recall[draw] = good / max(n_answerable, 1)
        coverage[draw] = n_accepted / correct.size
        certified[draw] = gate.precision_lower_bound is not None
    su = feature_matrix(scores, k=k, features=("SU",))[:, 0]
    return GuaranteeSimulation(
        precision=precision,
        recall=recall,
        coverage=coverage,
        certified=certified.astype(bool),
        target_precision=target_precision,
        delta=delta,
        hindsight_recall=hindsight_recall(su, correct, target_precision, n_answerable),
    )
