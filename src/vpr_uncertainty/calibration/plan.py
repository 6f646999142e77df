"""A label budget: how many labelled queries a certified gate needs, estimated before the user labels them.

From the scores of the queries (unlabelled) and a few labelled ones, :func:`plan_labels` estimates P(correct) of
every query by Platt scaling of SU on the few labels, then simulates the whole calibration
(:func:`~vpr_uncertainty.calibration.fit.calibrate_arrays`, with the queries as its unlabelled pool) on draws of
n queries whose labels are drawn from those probabilities, for a range of n. A draw is *useful* when it certifies
p* and the gate's expected recall on all queries reaches ``useful_fraction`` of the best recall any SU cut could
have at p* (the plug-in oracle). The answer is the smallest n at which a useful certificate comes with probability
≥ 1 − δ.

The estimate is a plug-in: it trusts the fitted P(correct), which a few labels pin down only roughly, and it
ranks by the candidates of :func:`~vpr_uncertainty.calibration.fit.default_rankings`. Treat it as an order of
magnitude (it is what tells 33 labels from 300), not as a guarantee.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from vpr_uncertainty.calibration.calibrator import fit_logistic
from vpr_uncertainty.calibration.features import feature_matrix
from vpr_uncertainty.calibration.fit import calibrate_arrays
from vpr_uncertainty.calibration.guarantee import min_accepted
from vpr_uncertainty.progress import progress_bar

__all__ = ["DEFAULT_SIZES", "LabelPlan", "plan_labels"]

#: The calibration sizes :func:`plan_labels` simulates by default.
DEFAULT_SIZES: tuple[int, ...] = (25, 50, 100, 200, 400, 800, 1600)


@dataclass
class LabelPlan:
    """The outcome of :func:`plan_labels`.

    Attributes
    ----------
    sizes : list of int
        Calibration sizes simulated.
    certified : list of float
        Per size, the share of draws that certify p*.
    useful : list of float
        Per size, the share of draws that certify with an expected recall ≥ ``useful_fraction`` × oracle.
    mean_recall : list of float
        Per size, the mean expected recall on all queries (0 for draws that certify nothing).
    oracle_recall : float
        The plug-in recall of the best SU cut at p*.
    needed : int or None
        The smallest size whose ``useful`` share reaches 1 − δ (None: none of the sizes simulated).
    n_labelled, n_queries : int
        Labels the estimate used, and queries in the pool.
    message : str
        The answer in one or two sentences.
    """

    sizes: list[int]
    certified: list[float]
    useful: list[float]
    mean_recall: list[float]
    oracle_recall: float
    needed: int | None
    n_labelled: int
    n_queries: int
    target_precision: float
    delta: float
    useful_fraction: float
    draws: int
    message: str = ""
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def table(self) -> str:
        """A Markdown table of the simulated sizes."""
        lines = [
            "| labelled queries | P(certified) | P(useful certificate) | mean recall |",
            "|---|---|---|---|",
        ]
        for size, certified, useful, recall in zip(
            self.sizes, self.certified, self.useful, self.mean_recall, strict=True
        ):
            lines.append(f"| {size} | {certified:.2f} | {useful:.2f} | {recall:.3f} |")
        return "\n".join(lines)


def _probability(su_labelled: np.ndarray, correct: np.ndarray, su_all: np.ndarray) -> np.ndarray:
    """P(correct) of every query by Platt scaling of −SU on the labels (decreasing in SU)."""
    confidence = -su_labelled
    mean, spread = float(confidence.mean()), float(confidence.std()) or 1.0
    intercept, (slope,) = fit_logistic(((confidence - mean) / spread)[:, None], correct, regularisation=1.0)
    slope = max(float(slope), 0.0)
    z = intercept + slope * (-su_all - mean) / spread
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def _oracle(probability: np.ndarray, su: np.ndarray, target_precision: float) -> float:
    order = np.argsort(su, kind="stable")
    expected = np.cumsum(probability[order])
    precision = expected / np.arange(1, su.size + 1)
    reaching = np.flatnonzero(precision >= target_precision)
    return float(expected[reaching[-1]] / su.size) if reaching.size else 0.0


def plan_labels(
    scores: np.ndarray,
    labelled_scores: np.ndarray,
    correct: np.ndarray,
    *,
    target_precision: float,
    delta: float = 0.1,
    k: int = 10,
    sizes: Sequence[int] = DEFAULT_SIZES,
    draws: int = 40,
    useful_fraction: float = 0.5,
    seed: int = 0,
    progress: bool | None = None,
) -> LabelPlan:
    """Estimate how many labelled queries certify ``target_precision`` at a useful recall.

    Parameters
    ----------
    scores : ndarray of shape (Q, K)
        Top-K similarities of the queries the gate will decide (unlabelled), sorted descending.
    labelled_scores : ndarray of shape (L, K)
        The few labelled queries' scores (may be rows of ``scores``).
    correct : ndarray of shape (L,), bool
        Their top-1 correctness; both outcomes must occur.
    target_precision, delta : float in (0, 1)
        p* and δ, as in :func:`~vpr_uncertainty.calibrate`.
    k : int, default=10
    sizes : sequence of int
        Calibration sizes to simulate.
    draws : int, default=40
        Simulated calibrations per size.
    useful_fraction : float in (0, 1], default=0.5
        A certificate is useful when its expected recall reaches this share of the plug-in SU oracle.
    seed : int, default=0
    progress : bool, optional
        A progress bar over the sizes (default: on a terminal).

    Returns
    -------
    LabelPlan
    """
    correct = np.asarray(correct, dtype=bool)
    scores = np.asarray(scores, dtype=np.float64)
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
    if not 0.0 < useful_fraction <= 1.0:
        raise ValueError(f"useful_fraction must lie in (0, 1], got {useful_fraction}")
    if not isinstance(draws, int) or draws < 1:
        raise ValueError(f"draws must be an integer >= 1, got {draws!r}")
    sizes = sorted({int(size) for size in sizes})
    if not sizes or sizes[0] < 2:
        raise ValueError(f"sizes must be integers >= 2, got {sizes}")
    min_accepted(target_precision, delta)  # checks p* and δ
    su_all = feature_matrix(scores, k=k, features=("SU",))[:, 0]
    su_labelled = feature_matrix(labelled_scores, k=k, features=("SU",))[:, 0]
    probability = _probability(su_labelled, correct, su_all)
    oracle = _oracle(probability, su_all, target_precision)
    rng = np.random.default_rng(seed)
    certified, useful, mean_recall = [], [], []
    for size in progress_bar(sizes, desc="simulating calibration sizes", unit="size", enabled=progress):
        hits = good = 0
        recall_sum = 0.0
        for _ in range(draws):
            rows = rng.choice(scores.shape[0], size, replace=True)
            labels = rng.random(size) < probability[rows]
            if labels.all() or not labels.any():
                continue  # nothing can be calibrated on one outcome: certifies nothing
            gate = calibrate_arrays(
                scores[rows],
                labels,
                target_precision=target_precision,
                delta=delta,
                k=k,
                seed=int(rng.integers(1 << 31)),
                unlabelled=scores,
            )
            if gate.precision_lower_bound is None:
                continue
            recall = float(probability[gate.accept(scores)].sum() / scores.shape[0])
            hits += 1
            recall_sum += recall
            good += recall >= useful_fraction * oracle
        certified.append(hits / draws)
        useful.append(good / draws)
        mean_recall.append(recall_sum / draws)
    reached = [size for size, share in zip(sizes, useful, strict=True) if share >= 1 - delta]
    needed = reached[0] if reached else None
    have = labelled_scores.shape[0]
    if needed is None:
        message = (
            f"none of the simulated sizes (up to {sizes[-1]} labelled queries) certifies precision "
            f"{target_precision:g} at a useful recall with probability {1 - delta:g}"
        )
    else:
        message = f"about {needed} labelled queries certify precision {target_precision:g} at a useful recall"
        message += f" (≥ {useful_fraction:g} × the best SU cut's {oracle:.2f}) with probability ≥ {1 - delta:g}"
    if needed is None or have < needed:
        message += f"; with the {have} labelled now, the expected certified recall is about "
        below = [recall for size, recall in zip(sizes, mean_recall, strict=True) if size <= have]
        message += f"{below[-1]:.2f}" if below else "0 (none)"
    notes = [
        f"P(correct) estimated from {have} labels by Platt scaling of SU (a plug-in estimate: an order of magnitude)"
    ]
    return LabelPlan(
        sizes=sizes,
        certified=certified,
        useful=useful,
        mean_recall=mean_recall,
        oracle_recall=oracle,
        needed=needed,
        n_labelled=have,
        n_queries=int(scores.shape[0]),
        target_precision=target_precision,
        delta=delta,
        useful_fraction=useful_fraction,
        draws=draws,
        message=message,
        notes=notes,
    )
