"""P(correct top-1) from training-free features of the top-k scores: the features, the calibrator, and the choice
of ranking.

Features (k candidates, s_1 ≥ s_2 ≥ … ≥ s_k; descriptive numbers, the calibrator learns their signs):
``s1``; ``gap`` = s_1 − s_2; ``ratio`` = s_2 / s_1; ``RS``, ``SD``, ``SU`` (α = 0.5); ``zscore`` =
(s_1 − mean(s_2..s_k)) / (s_1 − s_k) (0 when the top-k ties); ``PA`` = d_1 / d_2 with d² = 2 − 2s (cosine
similarities only, else a ValueError). The ratio features follow :mod:`vpr_uncertainty.scores` for s_1 ≤ 0
(1 − s_1) and for missing candidates (``-inf``). :func:`row_features` gives the same numbers for one query in pure
Python (the gate's fast path).

Two models:

* ``"logistic"``: L2-regularised logistic regression on standardised features (:data:`DEFAULT_FEATURES`);
  P = σ(b + Σ w_i (f_i − μ_i) / σ_i). A fixed score (SU, the margin, …) is the same model on that one feature
  (Platt scaling, :func:`platt`).
* ``"isotonic"``: isotonic regression on SU alone (P non-increasing in SU), a step function.

:func:`select_calibrator` (the doubt ``CAL``) keeps, among the fixed scores of :data:`RANKINGS` and the logistic
model, the one with the best average precision on the labelled queries: a fixed score's is an honest estimate (no
fitting), the model's is measured on cross-fitted confidences (:func:`cross_fitted`).

A fitted model is a :class:`Calibrator`: numbers only (no scikit-learn object), so it is saved as JSON and
evaluated without scikit-learn. Its ``confidence`` is a score whose order is that of P (the linear score z for the
logistic model, −SU for the isotonic one); the threshold of a gate is set on it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from vpr_uncertainty import scores as _scores
from vpr_uncertainty._repr import compact_repr
from vpr_uncertainty._validation import check_k, check_top_k_scores

#: The calibrator models :func:`fit_calibrator` fits.
MODELS: tuple[str, ...] = ("logistic", "isotonic")


@dataclass
class Calibrator:
    """A fitted map from features to P(correct), as plain numbers.

    Attributes
    ----------
    model : {"logistic", "isotonic"}
    features : tuple of str
        The feature names, in the order of the columns it reads.
    mean, scale : list of float
        Standardisation of the features (logistic): (f − mean) / scale.
    coef : list of float
        Coefficients on the standardised features (logistic).
    intercept : float
        Intercept (logistic).
    x, y : list of float
        Isotonic: P = interp(−SU, x, y), x increasing (−SU), y non-decreasing, clipped at the ends.
    regularisation : float
        The inverse regularisation strength C of the logistic model.
    ranking : str or None
        What the confidence ranks by: a fixed score (``"SU"``, ``"margin"``, …; one feature, Platt-scaled) or
        ``"CAL"`` (the fitted model); None when not recorded.
    """

    __repr__ = compact_repr

    model: str
    features: tuple[str, ...]
    mean: list[float] = field(default_factory=list)
    scale: list[float] = field(default_factory=list)
    coef: list[float] = field(default_factory=list)
    intercept: float = 0.0
    x: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)
    regularisation: float = 1.0
    ranking: str | None = None

    def raw_weights(self) -> tuple[float, list[float]]:
        """(b', w') with z = b' + Σ w'_i f_i on the raw features (standardisation folded in); logistic only."""
        weights = [c / s for c, s in zip(self.coef, self.scale, strict=True)]
        return self.intercept - sum(w * m for w, m in zip(weights, self.mean, strict=True)), weights

    def confidence(self, features: np.ndarray) -> np.ndarray:
        """A score of shape (Q,) in the order of P (higher = more likely correct): z, or −SU for isotonic."""
        features = np.asarray(features, dtype=np.float64)
        if features.ndim != 2 or features.shape[1] != len(self.features):
            raise ValueError(f"features must have shape (Q, {len(self.features)}), got {features.shape}")
        if self.model == "isotonic":
            return -features[:, 0]
        bias, weights = self.raw_weights()
        return features @ np.asarray(weights) + bias

    def probability_from_confidence(self, confidence: np.ndarray) -> np.ndarray:
        """P(correct) of shape (Q,) from :meth:`confidence`."""
        confidence = np.asarray(confidence, dtype=np.float64)
        if self.model == "isotonic":
            return np.interp(confidence, self.x, self.y)
        return 0.5 * (1.0 + np.tanh(0.5 * confidence))  # σ(z) without overflow

    def probability(self, features: np.ndarray) -> np.ndarray:
        """P(correct top-1) of shape (Q,), in [0, 1]."""
        return self.probability_from_confidence(self.confidence(features))

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"model": self.model, "features": list(self.features)}
        if self.ranking is not None:
            data["ranking"] = self.ranking
        if self.model == "logistic":
            data.update({key: getattr(self, key) for key in ("mean", "scale", "coef", "intercept", "regularisation")})
        else:
            data.update(x=self.x, y=self.y)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, where: str = "calibrator") -> Calibrator:
        """The inverse of :meth:`to_dict`; a ValueError names the missing or malformed field."""
        if not isinstance(data, dict):
            raise ValueError(f"{where} must be an object of fields, got {data!r}")
        model = data.get("model")
        check_model(model, where=where)
        features = data.get("features")
        if not isinstance(features, list) or not features or not all(isinstance(f, str) for f in features):
            raise ValueError(f"{where}: features must be a non-empty list of names, got {features!r}")
        unknown = [name for name in features if name not in FEATURES]
        if unknown or len(set(features)) != len(features):
            raise ValueError(
                f"{where}: features must be distinct names from {list(FEATURES)}, got {features!r}"
                + (f" (unknown: {unknown})" if unknown else " (a name repeated)")
            )
        ranking = data.get("ranking")
        if ranking is not None and not isinstance(ranking, str):
            raise ValueError(f"{where}: ranking must be a name or absent, got {ranking!r}")
        keys = ("mean", "scale", "coef") if model == "logistic" else ("x", "y")
        size = len(features) if model == "logistic" else None
        arrays: dict[str, Any] = {}
        for key in keys:
            value = data.get(key)
            numbers = isinstance(value, list) and value and all(_is_number(v) for v in value)
            if not numbers or size not in (None, len(value)):
                expected = f"{size} finite numbers" if size else "a non-empty list of finite numbers"
                raise ValueError(f"{where}: {key} must be {expected}, got {value!r}")
            arrays[key] = [float(v) for v in value]
        if model == "logistic":
            intercept = data.get("intercept")
            if not _is_number(intercept):
                raise ValueError(f"{where}: intercept must be a finite number, got {intercept!r}")
            if any(s <= 0 for s in arrays["scale"]):
                raise ValueError(f"{where}: scale must be positive, got {arrays['scale']}")
            regularisation = data.get("regularisation", 1.0)
            if not (_is_number(regularisation) and regularisation > 0):
                raise ValueError(f"{where}: regularisation must be a number > 0 (C), got {regularisation!r}")
            arrays.update(intercept=float(intercept), regularisation=float(regularisation))
        else:
            if len(arrays["x"]) != len(arrays["y"]) or np.any(np.diff(arrays["x"]) < 0):
                raise ValueError(f"{where}: x must be non-decreasing and as long as y")
            if np.any(np.diff(arrays["y"]) < 0) or not 0 <= min(arrays["y"]) <= max(arrays["y"]) <= 1:
                raise ValueError(f"{where}: y must be non-decreasing probabilities in [0, 1], got {arrays['y']}")
            if features != ["SU"]:
                raise ValueError(f"{where}: the isotonic model reads the feature SU only, got {features}")
        return cls(model=model, features=tuple(features), ranking=ranking, **arrays)


def _is_number(value: object) -> bool:
    """A finite int or float (not a bool): a number of a calibrator file."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_both_outcomes(correct: np.ndarray) -> None:
    """Raise ValueError unless the bool labels ``correct`` (Q,) hold both correct and wrong answers."""
    if correct.all() or not correct.any():
        raise ValueError(
            f"the calibration queries hold only {'correct' if correct.any() else 'wrong'} answers "
            f"({correct.size} queries): P(correct) cannot be fitted; label more queries (both outcomes are needed)"
        )


def check_model(model: object, *, where: str | None = None) -> None:
    """Raise ValueError (prefixed by ``where``) unless ``model`` is one of :data:`MODELS`."""
    if model not in MODELS:
        prefix = f"{where}: " if where else ""
        raise ValueError(f"{prefix}model must be one of {MODELS}, got {model!r}")


def fit_calibrator(
    features: np.ndarray,
    correct: np.ndarray,
    *,
    feature_names: tuple[str, ...],
    model: str = "logistic",
    regularisation: float = 1.0,
) -> Calibrator:
    """Fit P(correct) on labelled calibration queries.

    Parameters
    ----------
    features : ndarray of shape (Q, F)
        From :func:`~vpr_uncertainty.calibration.calibrator.feature_matrix` (for ``"isotonic"``: one column, SU).
    correct : ndarray of shape (Q,), bool
        Whether each query's top-1 answer is correct; both outcomes must occur.
    feature_names : tuple of str
        The names of the columns.
    model : {"logistic", "isotonic"}
    regularisation : float, default=1.0
        Inverse L2 strength C of the logistic regression (> 0).
    """
    check_model(model)
    features, correct = np.asarray(features, dtype=np.float64), np.asarray(correct)
    if features.ndim != 2 or correct.shape != (features.shape[0],):
        raise ValueError(f"features (Q, F) and correct (Q,) must match, got {features.shape} and {correct.shape}")
    if not np.isfinite(features).all():
        raise ValueError("features must be finite")
    correct = correct.astype(bool)
    check_both_outcomes(correct)
    if len(feature_names) != features.shape[1]:
        raise ValueError(f"feature_names has {len(feature_names)} names for {features.shape[1]} columns")
    if model == "isotonic":
        from sklearn.isotonic import IsotonicRegression

        if tuple(feature_names) != ("SU",):
            raise ValueError(f"the isotonic model reads SU alone, got features {tuple(feature_names)}")
        fitted = IsotonicRegression(y_min=0.0, y_max=1.0, increasing=True, out_of_bounds="clip")
        fitted.fit(-features[:, 0], correct.astype(np.float64))
        x, y = fitted.X_thresholds_.tolist(), fitted.y_thresholds_.tolist()
        return Calibrator(model=model, features=("SU",), x=x, y=y)
    if not regularisation > 0:
        raise ValueError(f"regularisation must be > 0, got {regularisation}")
    mean, scale = features.mean(axis=0), features.std(axis=0)
    scale[scale == 0] = 1.0
    intercept, coef = fit_logistic((features - mean) / scale, correct, regularisation=regularisation)
    return Calibrator(
        model=model,
        features=tuple(feature_names),
        mean=mean.tolist(),
        scale=scale.tolist(),
        coef=coef.tolist(),
        intercept=intercept,
        regularisation=float(regularisation),
    )


def fit_logistic(
    features: np.ndarray, labels: np.ndarray, *, regularisation: float = 1.0, tolerance: float = 1e-10
) -> tuple[float, np.ndarray]:
    """L2-regularised logistic regression by Newton's method: scikit-learn's objective, solved exactly.

    Minimises ½‖w‖² + C Σ_i log(1 + exp(−y_i (b + w·x_i))) with y_i = ±1 and the intercept b not penalised:
    the objective of ``sklearn.linear_model.LogisticRegression(C=C)`` (lbfgs, L2). With a handful of features
    Newton's method converges in a few steps and runs in well under a millisecond, where lbfgs takes tens of
    milliseconds: that is what makes hundreds of calibrations (the guarantee simulation, repeated splits) fast.
    The two agree to about 1e-6 (``tests/test_calibration_calibrator.py``).

    Parameters
    ----------
    features : ndarray of shape (Q, F)
    labels : ndarray of shape (Q,), bool
    regularisation : float
        C > 0.

    Returns
    -------
    intercept : float
    coef : ndarray of shape (F,)
    """
    design = np.column_stack([np.ones(len(features)), features])
    target = labels.astype(np.float64)
    penalty = np.full(design.shape[1], 1.0 / regularisation)
    penalty[0] = 0.0
    theta = np.zeros(design.shape[1])
    ridge = np.diag(penalty) + 1e-12 * np.eye(len(theta))
    objective = _objective(design, target, theta, penalty)
    for _ in range(100):
        z = design @ theta
        p = 0.5 * (1.0 + np.tanh(0.5 * z))
        gradient = design.T @ (p - target) + penalty * theta
        weight = np.maximum(p * (1.0 - p), 1e-12)
        step = np.linalg.solve((design.T * weight) @ design + ridge, gradient)
        # Damped step: halve while the objective does not decrease (separable data, far starts).
        scale = 1.0
        trial = _objective(design, target, theta - step, penalty)
        while scale > 1e-6 and trial > objective + 1e-15:
            scale *= 0.5
            trial = _objective(design, target, theta - scale * step, penalty)
        theta, objective = theta - scale * step, trial
        if np.abs(scale * step).max() < tolerance:
            break
    return float(theta[0]), theta[1:]


def _objective(design: np.ndarray, target: np.ndarray, theta: np.ndarray, penalty: np.ndarray) -> float:
    z = design @ theta
    # log(1 + exp(z)) − y z, computed stably
    return float(np.sum(np.logaddexp(0.0, z) - target * z) + 0.5 * np.sum(penalty * theta**2))


#: Every feature :func:`feature_matrix` can build, in a fixed order.
FEATURES: tuple[str, ...] = ("s1", "gap", "ratio", "RS", "SD", "SU", "zscore", "PA")
#: The features of the fitted calibrator: the best match, the margin, the perceptual-aliasing ratio and SU (the
#: signals that win on some VPR method; see docs/evidence/calibration.md). Without cosine similarities PA is left out.
DEFAULT_FEATURES: tuple[str, ...] = ("s1", "gap", "PA", "SU")


def check_features(features: Sequence[str]) -> tuple[str, ...]:
    """``features`` as a tuple, checked: a non-empty sequence of distinct names from :data:`FEATURES`."""
    if isinstance(features, str) or not features:
        raise ValueError(f"features must be a non-empty list of names from {FEATURES}, got {features!r}")
    unknown = [name for name in features if name not in FEATURES]
    if unknown:
        raise ValueError(f"unknown feature(s) {unknown}; valid: {', '.join(FEATURES)}")
    if len(set(features)) != len(features):
        raise ValueError(f"features lists a name twice: {list(features)}")
    return tuple(features)


def feature_matrix(scores: object, *, k: int = 10, features: Sequence[str] = DEFAULT_FEATURES) -> np.ndarray:
    """The feature matrix of many queries, vectorised.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, higher = more similar, sorted descending along axis 1; ``-inf`` marks a
        missing candidate at the end of a row. At least two finite candidates per row.
    k : int, default=10
        Candidates used (the first ``min(k, K)`` columns); >= 2.
    features : sequence of str, default=DEFAULT_FEATURES
        Names from :data:`FEATURES`, in the order of the columns returned.

    Returns
    -------
    ndarray of shape (Q, F), float64

    Examples
    --------
    >>> feature_matrix(np.array([[0.8, 0.4, 0.2]]), k=3, features=("s1", "gap", "RS", "SD", "zscore")).round(4)
    array([[0.8   , 0.4   , 0.375 , 0.5   , 0.8333]])
    """
    names = check_features(features)
    k = check_k(k)
    array = check_top_k_scores(scores)
    if array.shape[1] < 2:
        raise ValueError(f"scores must have at least 2 columns, got shape {array.shape}")
    array = array.astype(np.float64, copy=False)
    n = min(k, array.shape[1])
    top = array[:, :n]
    finite = np.isfinite(top)
    counts = finite.sum(axis=1)
    if (counts < 2).any():
        row = int(np.flatnonzero(counts < 2)[0])
        raise ValueError(f"scores row {row} has {int(counts[row])} finite candidate(s); a row needs at least 2")
    with np.errstate(over="ignore", invalid="ignore"):  # huge finite scores: overflow is refused below
        columns = {name: _column(name, top, finite, counts, n) for name in names}
    if not len(top):
        return np.empty((0, len(names)))
    matrix = np.column_stack([columns[name] for name in names])
    if not np.isfinite(matrix).all():  # finite scores so large that a sum or ratio overflows
        row = int(np.flatnonzero(~np.isfinite(matrix).all(axis=1))[0])
        raise ValueError(f"scores row {row} is too large: its features overflow float64 ({top[row].tolist()})")
    return matrix


def _column(name: str, top: np.ndarray, finite: np.ndarray, counts: np.ndarray, n: int) -> np.ndarray:
    """One feature column of :func:`feature_matrix`, shape (Q,)."""
    best = top[:, 0]
    nonpositive = best <= 0
    if name == "s1":
        return best
    elif name == "gap":
        return best - top[:, 1]
    elif name == "ratio":
        return np.where(nonpositive, 1 - best, top[:, 1] / np.where(nonpositive, 1, best))
    elif name == "RS":
        return _scores.ratio_spread(top, n)
    elif name == "SD":
        return _scores.similarity_distribution(top, n)
    elif name == "SU":
        return _scores.statistical_uncertainty(top, n)
    elif name == "PA":
        return _scores.perceptual_aliasing(top[:, :2], 2).astype(np.float64, copy=False)
    else:  # zscore
        safe = np.where(finite, top, 0.0)
        last = safe[np.arange(len(top)), counts - 1]
        runners_up = (safe.sum(axis=1) - best) / (counts - 1)
        spread = best - last
        return np.divide(best - runners_up, spread, out=np.zeros_like(best), where=spread > 0)


def row_features(values: Sequence[float], *, k: int = 10, features: Sequence[str] = DEFAULT_FEATURES) -> list[float]:
    """The features of one query (the same numbers as one row of :func:`feature_matrix`), in pure Python.

    Examples
    --------
    >>> [round(value, 4) for value in row_features([0.8, 0.4, 0.2], k=3, features=("RS", "SD", "zscore"))]
    [0.375, 0.5, 0.8333]
    """
    best, second, runners_up, median, last, _ = _scores.row_statistics(list(values), check_k(k))
    positive = best > 0
    spread = best - last
    table = {
        "s1": best,
        "gap": best - second,
        "ratio": second / best if positive else 1 - best,
        "RS": runners_up / best if positive else 1 - best,
        "SD": median / best if positive else 1 - best,
        "SU": 0.5 * (runners_up / best) + 0.5 * (median / best) if positive else 1 - best,
        "zscore": (best - runners_up) / spread if spread > 0 else 0.0,
    }
    names = check_features(features)
    if "PA" in names:
        table["PA"] = aliasing_ratio(best, second)
    return [table[name] for name in names]


def aliasing_ratio(best: float, second: float) -> float:
    """PA of one query, d_1 / d_2 with d² = 2 − 2s, in pure Python (1 when both distances are 0).

    A ValueError names the range when a similarity lies outside [−1, 1] (beyond rounding): the scores are then not
    cosine similarities and the distances would be meaningless.
    """
    if not (_COSINE_LOW <= second and best <= _COSINE_HIGH):
        raise ValueError(f"feature PA needs cosine similarities in [-1, 1], got s_1 = {best:g}, s_2 = {second:g}")
    second_squared = 2.0 - 2.0 * second  # inline arithmetic: this runs in every gate(row) of a PA-reading rule
    if second_squared <= 0.0:
        return 1.0
    first_squared = 2.0 - 2.0 * best
    return math.sqrt(first_squared / second_squared) if first_squared > 0.0 else 0.0


_COSINE_LOW, _COSINE_HIGH = -1.0 - _scores.COSINE_TOLERANCE, 1.0 + _scores.COSINE_TOLERANCE


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
        ranking=name,
    )


def ranking_rule(name: str) -> Calibrator:
    """The confidence sign × feature of a training-free ranking, as a linear :class:`Calibrator` (its P is not
    meant to be read: a gate cuts this confidence)."""
    feature, sign = RANKINGS[name]
    return Calibrator("logistic", (feature,), mean=[0.0], scale=[1.0], coef=[sign], intercept=0.0, ranking=name)


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
        return replace(fit_model(matrix, correct, model_features), ranking="CAL"), scores
    feature, sign = RANKINGS[best]
    return platt(best, feature, sign, features[feature], correct), scores
