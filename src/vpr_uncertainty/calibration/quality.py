"""Calibration quality of P(correct): expected calibration error, Brier score, reliability diagram.

``probability`` is P(correct top-1), shape (Q,), in [0, 1]; ``correct`` the outcomes, shape (Q,), bool. Bins are
equal-width over [0, 1]; the last bin includes 1.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["Reliability", "brier_score", "expected_calibration_error", "reliability_diagram"]


def _check(probability: object, correct: object) -> tuple[np.ndarray, np.ndarray]:
    probability = np.asarray(probability, dtype=np.float64)
    correct = np.asarray(correct)
    if probability.ndim != 1 or correct.shape != probability.shape:
        raise ValueError(
            f"probability and correct must be 1-D of one length, got shapes {probability.shape} and {correct.shape}"
        )
    if probability.size == 0:
        raise ValueError("probability is empty")
    if not (np.isfinite(probability).all() and (probability >= 0).all() and (probability <= 1).all()):
        raise ValueError("probability must lie in [0, 1]")
    return probability, correct.astype(bool)


@dataclass
class Reliability:
    """A reliability diagram: per bin, its edges, the number of queries, mean P and the observed accuracy.

    Empty bins have count 0 and ``None`` for the mean and the accuracy.
    """

    edges: list[float]
    counts: list[int]
    mean_probability: list[float | None]
    accuracy: list[float | None]

    def to_dict(self) -> dict:
        return asdict(self)


def reliability_diagram(probability: object, correct: object, *, n_bins: int = 10) -> Reliability:
    """Bin the predictions and compare the mean P of each bin with its share of correct answers.

    Examples
    --------
    >>> r = reliability_diagram([0.1, 0.15, 0.9], [False, True, True], n_bins=2)
    >>> r.counts, r.accuracy
    ([2, 1], [0.5, 1.0])
    """
    probability, correct = _check(probability, correct)
    if not isinstance(n_bins, int) or n_bins < 1:
        raise ValueError(f"n_bins must be an integer >= 1, got {n_bins!r}")
    edges = np.linspace(0.0, 1.0, n_bins + 1)
    which = np.clip(np.searchsorted(edges, probability, side="right") - 1, 0, n_bins - 1)
    counts = np.bincount(which, minlength=n_bins)
    sums = np.bincount(which, weights=probability, minlength=n_bins)
    hits = np.bincount(which, weights=correct.astype(np.float64), minlength=n_bins)
    return Reliability(
        edges=edges.tolist(),
        counts=counts.tolist(),
        mean_probability=[float(s / c) if c else None for s, c in zip(sums, counts, strict=True)],
        accuracy=[float(h / c) if c else None for h, c in zip(hits, counts, strict=True)],
    )


def expected_calibration_error(probability: object, correct: object, *, n_bins: int = 10) -> float:
    """ECE = Σ_bins (n_b / n) · |accuracy_b − mean P_b| over equal-width bins.

    Examples
    --------
    >>> round(expected_calibration_error([0.1, 0.15, 0.9], [False, True, True], n_bins=2), 4)
    0.2833
    """
    diagram = reliability_diagram(probability, correct, n_bins=n_bins)
    total = sum(diagram.counts)
    return float(
        sum(
            count / total * abs(accuracy - mean)
            for count, mean, accuracy in zip(diagram.counts, diagram.mean_probability, diagram.accuracy, strict=True)
            if count
        )
    )


def brier_score(probability: object, correct: object) -> float:
    """Mean squared difference between P and the outcome (0 best).

    Examples
    --------
    >>> brier_score([1.0, 0.5], [True, False])
    0.125
    """
    probability, correct = _check(probability, correct)
    return float(np.mean((probability - correct) ** 2))
