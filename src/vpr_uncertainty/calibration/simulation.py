"""Check the precision guarantee by simulation: many calibration draws from one labelled population.

Each draw takes ``n_calibration`` queries of the population at random **with replacement** (so they are i.i.d.
from the population, exactly the assumption of the guarantee), calibrates a gate on them, and applies it to the
whole population, whose precision among the accepted answers is then known exactly. The guarantee says that the
share of draws whose population precision falls below p* is at most δ.

The hindsight reference is the best SU threshold chosen on the whole population: the largest end-to-end recall of
any SU cut whose precision is ≥ p*.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vpr_uncertainty.calibration.features import feature_matrix
from vpr_uncertainty.calibration.fit import calibrate_arrays

__all__ = ["GuaranteeSimulation", "hindsight_recall", "simulate_guarantee"]


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
    order = np.argsort(uncertainty, kind="stable")
    ranked = uncertainty[order]
    hits = np.cumsum(correct[order])
    ends = np.append(np.flatnonzero(np.diff(ranked) != 0), ranked.size - 1)  # last index of each tied group
    precision = hits[ends] / (ends + 1)
    ok = precision >= target_precision
    return float(hits[ends][ok].max() / max(n_answerable, 1)) if ok.any() else 0.0


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

    With ``unlabelled=True`` every draw also passes the whole population's scores as unlabelled queries (the
    robot's own traversal). Draws that hold only one outcome cannot be calibrated; they are redrawn.
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
        accepted = gate.accept(scores)
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
