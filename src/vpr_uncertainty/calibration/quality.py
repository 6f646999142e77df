"""Calibration quality of P(correct): expected calibration error, Brier score, reliability diagram; the held-out
evaluation over repeated splits; and the uncertainty method ``CAL`` (1 − P(correct) of a gate).

``probability`` is P(correct top-1), shape (Q,), in [0, 1]; ``correct`` the outcomes, shape (Q,), bool. Bins are
equal-width over [0, 1]; the last bin includes 1.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from vpr_uncertainty._validation import check_count
from vpr_uncertainty.calibration.calibrator import stratified_split
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.evaluation import correct_at_n, evaluate
from vpr_uncertainty.evaluation.bootstrap import BOOTSTRAP_METRICS
from vpr_uncertainty.evaluation.metrics import check_labels
from vpr_uncertainty.methods import get_method, register_method
from vpr_uncertainty.retrieval import Retrieval


def _check(probability: object, correct: object) -> tuple[np.ndarray, np.ndarray]:
    correct, probability = check_labels(correct, probability, name="probability")
    if not ((probability >= 0).all() and (probability <= 1).all()):
        raise ValueError("probability must lie in [0, 1]")
    return probability, correct


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
    check_count(n_bins, "n_bins", 1)
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


#: The fewest held-out queries of a split, and of each outcome among them, that a held-out figure is reported on.
MIN_HELD_OUT, MIN_HELD_OUT_PER_OUTCOME = 10, 2


def _check_split_sizes(correct: np.ndarray, held_out: np.ndarray, fraction: float) -> None:
    """Refuse splits whose held-out part is too small to measure anything (AUC-PR 1.000 from 2 queries)."""
    good, wrong = int(correct[held_out].sum()), int((~correct[held_out]).sum())
    if held_out.size < MIN_HELD_OUT or min(good, wrong) < MIN_HELD_OUT_PER_OUTCOME:
        raise ValueError(
            f"calibration fraction {fraction:g} leaves {held_out.size} held-out queries ({good} correct, {wrong} "
            f"wrong) of {correct.size}: a held-out figure needs at least {MIN_HELD_OUT} queries and "
            f"{MIN_HELD_OUT_PER_OUTCOME} of each outcome; lower the fraction"
        )


@dataclass
class HeldOutEvaluation:
    """Per method and metric, one value per repeat; CAL's calibration quality per repeat and pooled.

    ``times`` holds each method's time per query (ms) of every repeat, on the held-out queries.
    """

    calibration_fraction: float
    repeats: int
    seed: int
    n_queries: int
    n_calibration: int
    n_held_out: int
    k: int
    values: dict[str, dict[str, list[float | None]]] = field(default_factory=dict)
    quality: dict[str, Any] = field(default_factory=dict)
    times: dict[str, list[float]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def mean(self, method: str, metric: str = "auc_pr") -> float | None:
        """Mean over the repeats (None when the metric was undefined in every repeat)."""
        finite = [v for v in self.values[method][metric] if v is not None]
        return float(np.mean(finite)) if finite else None

    def std(self, method: str, metric: str = "auc_pr") -> float | None:
        finite = [v for v in self.values[method][metric] if v is not None]
        return float(np.std(finite, ddof=1)) if len(finite) > 1 else None

    def to_dict(self) -> dict[str, Any]:
        """JSON types: ``auc_pr`` of a method is the mean over the repeats."""
        methods = {}
        for name, metrics in self.values.items():
            entry: dict[str, Any] = {}
            for metric in BOOTSTRAP_METRICS:
                entry[metric] = self.mean(name, metric)
                entry[f"{metric}_std"] = self.std(name, metric)
            entry["auc_pr_per_repeat"] = metrics["auc_pr"]
            if self.times.get(name):
                entry["time_per_query_ms"] = float(np.mean(self.times[name]))
            methods[name] = entry
        return {
            "n_queries": self.n_queries,
            "k": self.k,
            "calibration": {
                "fraction": self.calibration_fraction,
                "repeats": self.repeats,
                "seed": self.seed,
                "n_calibration": self.n_calibration,
                "n_held_out": self.n_held_out,
            },
            "methods": methods,
            **({"calibration_quality": self.quality} if self.quality else {}),
            **({"notes": list(self.notes)} if self.notes else {}),
        }


def evaluate_held_out(
    retrieval: Retrieval,
    methods: Sequence[str],
    *,
    calibration_fraction: float = 0.3,
    repeats: int = 20,
    seed: int = 0,
    k: int = 10,
    alpha: float = 0.5,
    model: str = "logistic",
    **options: Any,
) -> HeldOutEvaluation:
    """Evaluate ``methods`` on held-out queries over ``repeats`` random splits, without leakage.

    Each repeat splits the queries (stratified by correctness) into a calibration part and a held-out part; ``CAL``
    is fitted on the calibration part, and every method, CAL included, is evaluated on the held-out part only.
    Reported: mean and standard deviation over the repeats of AUC-PR, AP and AURC, and CAL's ECE, Brier score and
    reliability diagram of all held-out predictions pooled.

    Parameters
    ----------
    retrieval : Retrieval
        With its ground truth.
    methods : sequence of str
        Method names or specs; ``CAL`` gets a gate fitted on each split's calibration part.
    calibration_fraction : float in (0, 1)
        Share of the queries (of each outcome) used for calibration.
    repeats : int >= 1
        Random splits.
    seed : int
        Seed of the splits (repeat r uses ``numpy.random.default_rng([seed, r])``).
    k, alpha : int, float
        Options of the score-based methods; CAL's features read k candidates.
    model : {"logistic", "isotonic"}
        CAL's calibrator.
    **options
        Further method options (as :func:`vpr_uncertainty.evaluate`); ``query_paths`` (one per query) is cut to
        the held-out queries of each split.
    """
    from vpr_uncertainty.calibration.fit import calibrate_arrays  # scipy.stats: only when CAL is fitted

    if retrieval.positives is None:
        raise ValueError("the held-out evaluation needs the ground truth (argument ground_truth)")
    if not 0.0 < calibration_fraction < 1.0:
        raise ValueError(f"calibration_fraction must lie in (0, 1), got {calibration_fraction}")
    check_count(repeats, "repeats", 1)
    entries = [get_method(name) for name in methods]
    names = [entry.name for entry in entries]
    uses_cal = any((entry.base or entry.name) == "CAL" for entry in entries)
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    if min(int(correct.sum()), int((~correct).sum())) < 2:
        raise ValueError("a held-out evaluation needs at least 2 correct and 2 wrong top-1 answers")
    result = HeldOutEvaluation(
        calibration_fraction=float(calibration_fraction),
        repeats=repeats,
        seed=seed,
        n_queries=retrieval.n_queries,
        n_calibration=0,
        n_held_out=0,
        k=min(int(k), retrieval.k),
        values={name: {metric: [] for metric in BOOTSTRAP_METRICS} for name in names},
    )
    pooled_p, pooled_correct, eces, briers = [], [], [], []
    for repeat in range(repeats):
        calibration, held_out = stratified_split(correct, calibration_fraction, np.random.default_rng([seed, repeat]))
        result.n_calibration, result.n_held_out = int(calibration.size), int(held_out.size)
        if repeat == 0:  # every split has the same counts per outcome
            _check_split_sizes(correct, held_out, calibration_fraction)
        extra = dict(options)
        if options.get("query_paths") is not None:  # the images of the held-out queries only
            extra["query_paths"] = [options["query_paths"][int(row)] for row in held_out]
        if uses_cal:
            extra["gate"] = calibrate_arrays(
                retrieval.scores[calibration], correct[calibration], k=k, seed=repeat, model=model
            )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the notes of the first repeat are kept below
            evaluation = evaluate(
                retrieval.subset_queries(held_out), names, k=k, alpha=alpha, timing_repeats=1, **extra
            )
        if repeat == 0:
            result.notes.extend(evaluation.notes)
        for name, measured in evaluation.methods.items():
            for metric in BOOTSTRAP_METRICS:
                result.values[name][metric].append(getattr(measured, metric))
            result.times.setdefault(name, []).append(measured.time_per_query_ms)
            if (get_method(name).base or name) == "CAL":
                probability = 1.0 - measured.uncertainty
                pooled_p.append(probability)
                pooled_correct.append(correct[held_out])
                eces.append(expected_calibration_error(probability, correct[held_out]))
                briers.append(brier_score(probability, correct[held_out]))
    if pooled_p:
        result.quality["CAL"] = {
            "ece": float(np.mean(eces)),
            "ece_std": float(np.std(eces, ddof=1)) if len(eces) > 1 else None,
            "brier": float(np.mean(briers)),
            "brier_std": float(np.std(briers, ddof=1)) if len(briers) > 1 else None,
            "reliability": reliability_diagram(np.concatenate(pooled_p), np.concatenate(pooled_correct)).to_dict(),
        }
    return result


def resolve_gate(retrieval: Retrieval, options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` with ``gate`` read from its file (the method's ``resolve`` hook)."""
    resolved = dict(options)
    value = resolved.get("gate")
    if value in (None, ""):
        resolved["gate"] = None
    elif isinstance(value, (str, os.PathLike)):
        resolved["gate"] = Gate.load(value)
    elif not isinstance(value, Gate):
        raise TypeError(f"option gate must be the path of a gate file or a Gate, got {type(value).__name__}")
    return resolved


def cal_uncertainty(retrieval: Retrieval, *, gate: Gate | None = None) -> np.ndarray:
    """1 − P(correct top-1) for every query, shape (Q,): higher = less trustworthy."""
    if gate is None:
        raise ValueError(
            "uncertainty method 'CAL' needs a fitted gate (option gate=GATE.json, written by "
            "`vpr-uncertainty calibrate`), or a held-out evaluation that fits one per split"
        )
    return 1.0 - gate.probability_correct(retrieval.scores[:, : gate.k])


register_method(
    "CAL",
    cal_uncertainty,
    description="1 − calibrated P(correct) of a fitted gate (calibrate; fitted per split in held-out evaluate)",
    requires=("gate",),
    options={"gate": ""},
    kind="calibrated",
    resolve=resolve_gate,
)
