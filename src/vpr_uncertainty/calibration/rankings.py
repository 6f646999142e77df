"""What ranks the queries, and P(correct) from it: fixed scores, a cross-fitted model, and the choice between them.

:func:`select_calibrator` is the doubt ``CAL``: among the fixed training-free scores (:data:`RANKINGS`: SU, RS, SD,
BM, the margin, PA) and an L2-regularised logistic model on
:data:`~vpr_uncertainty.calibration.features.DEFAULT_FEATURES`, it keeps the one with the best average precision on
the labelled queries. A fixed score needs no fitting, so its average precision there is an honest estimate; the
model's is measured on cross-fitted confidences (:func:`cross_fitted`: K stratified folds, each query scored by a
model that did not see it). P is then a logistic map of the winner fitted on all labels: Platt scaling of a fixed
score (:func:`platt`, increasing in its confidence), or the model refitted on all.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from vpr_uncertainty.calibration.calibrator import Calibrator, fit_calibrator, fit_logistic
from vpr_uncertainty.calibration.features import feature_matrix

__all__ = [
    "FOLDS",
    "RANKINGS",
    "average_precision",
    "columns",
    "cross_fitted",
    "feature_columns",
    "fit_model",
    "platt",
    "select_calibrator",
    "stratified_folds",
    "stratified_split",
]

#: The training-free rankings: name → (feature, sign); confidence = sign × feature (higher = more likely correct).
RANKINGS: dict[str, tuple[str, float]] = {
    "SU": ("SU", -1.0),
    "RS": ("RS", -1.0),
    "SD": ("SD", -1.0),
    "BM": ("s1", 1.0),
    "margin": ("gap", 1.0),
    "PA": ("PA", -1.0),
}
#: Cross-fitting folds of the fitted model.
FOLDS = 5
#: Every feature a candidate reads.
_FEATURES_USED = ("s1", "gap", "RS", "SD", "SU", "PA")


def stratified_split(correct: np.ndarray, fraction: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Indices (first, second): ``fraction`` of each class (rounded, at least one of each when possible) first."""
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction must lie in (0, 1), got {fraction}")
    first, second = [], []
    for label in (True, False):
        members = rng.permutation(np.flatnonzero(correct == label))
        count = round(fraction * members.size)
        if members.size >= 2:
            count = min(max(count, 1), members.size - 1)
        first.append(members[:count])
        second.append(members[count:])
    return np.sort(np.concatenate(first)), np.sort(np.concatenate(second))


def stratified_folds(correct: np.ndarray, folds: int, rng: np.random.Generator) -> np.ndarray:
    """The fold (0 … folds − 1) of each query, shape (Q,): each outcome dealt round-robin in a random order."""
    assignment = np.empty(correct.size, dtype=np.int64)
    offset = 0
    for label in (True, False):
        members = rng.permutation(np.flatnonzero(correct == label))
        assignment[members] = (np.arange(members.size) + offset) % folds
        offset += members.size
    return assignment


def feature_columns(scores: np.ndarray, k: int, required: Sequence[str] = ()) -> dict[str, np.ndarray]:
    """Every feature the candidates read, by name, and the ``required`` ones; PA only for cosine similarities
    (unless required, when its error is raised)."""
    names = tuple(dict.fromkeys([*_FEATURES_USED, *required]))
    try:
        matrix = feature_matrix(scores, k=k, features=names)
    except ValueError as error:
        if "PA" not in str(error) or "PA" in required:
            raise
        names = tuple(name for name in names if name != "PA")
        matrix = feature_matrix(scores, k=k, features=names)
    return dict(zip(names, matrix.T, strict=True))


def columns(features: dict[str, np.ndarray], names: Sequence[str]) -> np.ndarray:
    return np.column_stack([features[name] for name in names])


def fit_model(matrix: np.ndarray, correct: np.ndarray, names: tuple[str, ...]) -> Calibrator:
    return fit_calibrator(matrix, correct, feature_names=names, model="logistic")


def cross_fitted(
    matrix: np.ndarray, correct: np.ndarray, names: tuple[str, ...], folds: int, seed: int
) -> tuple[np.ndarray, list[Calibrator]] | None:
    """The fold of each labelled query and the model of each fold (fitted without it); None when a fold's
    training part holds one outcome only."""
    minority = int(min(correct.sum(), (~correct).sum()))
    n_folds = min(folds, minority)
    if n_folds < 2:
        return None
    assignment = stratified_folds(correct, n_folds, np.random.default_rng([seed, 1]))
    models = []
    for fold in range(n_folds):
        train = assignment != fold
        if correct[train].all() or not correct[train].any():
            return None
        models.append(fit_model(matrix[train], correct[train], names))
    return assignment, models


def average_precision(correct: np.ndarray, confidence: np.ndarray) -> float:
    """Average precision of ``confidence`` (Q,) as a predictor of ``correct`` (Q,): scikit-learn's definition.

    AP = Σ_n (R_n − R_{n−1}) P_n over the distinct confidences, strictest first (tied queries enter together). The
    same number as ``sklearn.metrics.average_precision_score`` (tested), without its input checks, which cost
    milliseconds per call where a calibration makes dozens.

    Examples
    --------
    >>> average_precision(np.array([True, False, True, True]), np.array([0.9, 0.8, 0.8, 0.1]))
    0.8055555555555556
    """
    order = np.argsort(-confidence, kind="stable")
    ranked, hits = confidence[order], np.asarray(correct, dtype=bool)[order]
    ends = np.append(np.flatnonzero(ranked[1:] != ranked[:-1]), ranked.size - 1)  # last row of each tie group
    true_positives = np.cumsum(hits)[ends]
    precision = true_positives / (ends + 1)
    recall = true_positives / max(int(hits.sum()), 1)
    return float(np.sum(np.diff(recall, prepend=0.0) * precision))


def platt(name: str, feature: str, sign: float, column: np.ndarray, correct: np.ndarray) -> Calibrator:
    """P = σ(a·sign·f + b) with a > 0 fitted on all labels: a calibrator in the order of one fixed score."""
    confidence = sign * np.asarray(column, dtype=np.float64)
    spread = float(confidence.std()) or 1.0
    intercept, (slope,) = fit_logistic((confidence / spread)[:, None], correct, regularisation=1.0)
    slope = float(slope) / spread
    if not slope > 0:  # no signal on these labels: keep the order, P ≈ the share of correct answers
        base = float(np.clip(correct.mean(), 1e-6, 1 - 1e-6))
        slope = 1e-6 / spread  # large enough that neighbouring float32 scores stay apart in z
        intercept = math.log(base / (1 - base)) - slope * float(confidence.mean())
    return Calibrator(
        model="logistic",
        features=(feature,),
        mean=[0.0],
        scale=[1.0],
        coef=[sign * slope],
        intercept=float(intercept),
        regularisation=1.0,
        ranking=name,
    )


def select_calibrator(
    features: dict[str, np.ndarray],
    correct: np.ndarray,
    *,
    model_features: tuple[str, ...],
    folds: int = FOLDS,
    seed: int = 0,
) -> tuple[Calibrator, dict[str, float]]:
    """The calibrator of the candidate (fixed score or cross-fitted model) with the best average precision.

    Parameters
    ----------
    features : dict of str to ndarray of shape (Q,)
        Feature columns of the labelled queries (SU, RS, SD, s1, gap and, for cosine similarities, PA).
    correct : ndarray of shape (Q,), bool
        Both outcomes must occur.
    model_features : tuple of str
        Features of the logistic model.
    folds, seed : int
        Cross-fitting of the model.

    Returns
    -------
    calibrator : Calibrator
        Fitted on all labels; ``calibrator.ranking`` names the winner (``"CAL"`` for the model).
    scores : dict of str to float
        Average precision of every candidate (the model's from cross-fitted confidences).
    """
    correct = np.asarray(correct, dtype=bool)
    matrix = columns(features, model_features)
    scores: dict[str, float] = {}
    crossed = cross_fitted(matrix, correct, model_features, folds, seed)
    if crossed is not None:
        assignment, models = crossed
        confidence = np.empty(correct.size)
        for fold, model in enumerate(models):
            rows = assignment == fold
            confidence[rows] = model.confidence(matrix[rows])
        scores["CAL"] = average_precision(correct, confidence)
    for name, (feature, sign) in RANKINGS.items():
        if feature in features:
            scores[name] = average_precision(correct, sign * features[feature])
    best = max(scores, key=lambda name: scores[name])  # the first of equals: the model, then SU
    if best == "CAL":
        calibrator = fit_model(matrix, correct, model_features)
        calibrator.ranking = "CAL"
        return calibrator, scores
    feature, sign = RANKINGS[best]
    return platt(best, feature, sign, features[feature], correct), scores
