"""P(correct top-1) from the training-free features: a small, regularised scikit-learn model, as plain numbers.

Two models:

* ``"logistic"``: L2-regularised logistic regression on standardised features
  (:data:`~vpr_uncertainty.calibration.features.DEFAULT_FEATURES`); P = σ(b + Σ w_i (f_i − μ_i) / σ_i). A fixed
  score (SU, the margin, …) chosen by :func:`~vpr_uncertainty.calibration.fit.select_calibrator` is the same model on
  that one feature (Platt scaling).
* ``"isotonic"``: isotonic regression on SU alone (P non-increasing in SU), a step function.

A fitted model is a :class:`Calibrator`: numbers only (no scikit-learn object), so it is saved as JSON and
evaluated without scikit-learn. Its ``confidence`` is a score whose order is that of P (the linear score z for the
logistic model, −SU for the isotonic one); the threshold of a gate is set on it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vpr_uncertainty.calibration.features import FEATURES

__all__ = ["MODELS", "Calibrator", "fit_calibrator"]

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
            data.update(
                mean=self.mean,
                scale=self.scale,
                coef=self.coef,
                intercept=self.intercept,
                regularisation=self.regularisation,
            )
        else:
            data.update(x=self.x, y=self.y)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, where: str = "calibrator") -> Calibrator:
        """The inverse of :meth:`to_dict`; a ValueError names the missing or malformed field."""
        model = data.get("model")
        if model not in MODELS:
            raise ValueError(f"{where}: model must be one of {MODELS}, got {model!r}")
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
        arrays = {}
        for key in keys:
            value = data.get(key)
            size = len(features) if model == "logistic" else None
            if (
                not isinstance(value, list)
                or not value
                or not all(isinstance(v, (int, float)) and np.isfinite(v) for v in value)
                or (size is not None and len(value) != size)
            ):
                expected = f"{size} finite numbers" if size else "a non-empty list of finite numbers"
                raise ValueError(f"{where}: {key} must be {expected}, got {value!r}")
            arrays[key] = [float(v) for v in value]
        if model == "logistic":
            intercept = data.get("intercept")
            if not isinstance(intercept, (int, float)) or not np.isfinite(intercept):
                raise ValueError(f"{where}: intercept must be a finite number, got {intercept!r}")
            if any(s <= 0 for s in arrays["scale"]):
                raise ValueError(f"{where}: scale must be positive, got {arrays['scale']}")
            return cls(
                model=model,
                features=tuple(features),
                intercept=float(intercept),
                regularisation=float(data.get("regularisation", 1.0)),
                ranking=ranking,
                **arrays,
            )
        if len(arrays["x"]) != len(arrays["y"]) or np.any(np.diff(arrays["x"]) < 0):
            raise ValueError(f"{where}: x must be non-decreasing and as long as y")
        if features != ["SU"]:
            raise ValueError(f"{where}: the isotonic model reads the feature SU only, got {features}")
        return cls(model=model, features=("SU",), ranking=ranking, **arrays)


def _check_training(features: np.ndarray, correct: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    features = np.asarray(features, dtype=np.float64)
    correct = np.asarray(correct)
    if features.ndim != 2 or correct.shape != (features.shape[0],):
        raise ValueError(f"features (Q, F) and correct (Q,) must match, got {features.shape} and {correct.shape}")
    if not np.isfinite(features).all():
        raise ValueError("features must be finite")
    correct = correct.astype(bool)
    if correct.all() or not correct.any():
        raise ValueError(
            f"the calibration queries hold only {'correct' if correct.any() else 'wrong'} answers "
            f"({correct.size} queries): P(correct) cannot be fitted; label more queries (both outcomes are needed)"
        )
    return features, correct


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
        From :func:`~vpr_uncertainty.calibration.features.feature_matrix` (for ``"isotonic"``: one column, SU).
    correct : ndarray of shape (Q,), bool
        Whether each query's top-1 answer is correct; both outcomes must occur.
    feature_names : tuple of str
        The names of the columns.
    model : {"logistic", "isotonic"}
    regularisation : float, default=1.0
        Inverse L2 strength C of the logistic regression (> 0).

    Returns
    -------
    Calibrator
    """
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    features, correct = _check_training(features, correct)
    if len(feature_names) != features.shape[1]:
        raise ValueError(f"feature_names has {len(feature_names)} names for {features.shape[1]} columns")
    if model == "isotonic":
        from sklearn.isotonic import IsotonicRegression

        if tuple(feature_names) != ("SU",):
            raise ValueError(f"the isotonic model reads SU alone, got features {tuple(feature_names)}")
        fitted = IsotonicRegression(y_min=0.0, y_max=1.0, increasing=True, out_of_bounds="clip")
        fitted.fit(-features[:, 0], correct.astype(np.float64))
        return Calibrator(
            model=model,
            features=("SU",),
            x=fitted.X_thresholds_.tolist(),
            y=fitted.y_thresholds_.tolist(),
        )
    if not regularisation > 0:
        raise ValueError(f"regularisation must be > 0, got {regularisation}")
    mean = features.mean(axis=0)
    scale = features.std(axis=0)
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
