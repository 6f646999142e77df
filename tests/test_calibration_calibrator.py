"""The calibrator: Newton's logistic regression equals scikit-learn's; isotonic; JSON fields checked."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.isotonic import IsotonicRegression
from sklearn.linear_model import LogisticRegression

from conftest import assert_close
from vpr_uncertainty.calibration.calibrator import Calibrator, fit_calibrator, fit_logistic


@pytest.mark.parametrize("regularisation", [0.1, 1.0, 10.0])
def test_fit_logistic_equals_sklearn(regularisation):
    rng = np.random.default_rng(3)
    features = rng.normal(size=(80, 3))
    labels = features @ [1.0, -2.0, 0.5] + rng.normal(size=80) > 0
    reference = LogisticRegression(C=regularisation, tol=1e-12, max_iter=10_000).fit(features, labels)
    intercept, coef = fit_logistic(features, labels, regularisation=regularisation)
    np.testing.assert_allclose(coef, reference.coef_[0], atol=1e-6)
    assert intercept == pytest.approx(reference.intercept_[0], abs=1e-6)


def test_fit_logistic_separable_data_stays_finite():
    features = np.array([[0.0], [1.0], [2.0], [3.0]])
    intercept, coef = fit_logistic(features, np.array([False, False, True, True]), regularisation=1.0)
    assert np.isfinite(intercept) and np.isfinite(coef).all() and coef[0] > 0


def test_logistic_probability_and_raw_weights():
    rng = np.random.default_rng(0)
    features = rng.normal(size=(60, 2)) * [0.1, 3.0] + [0.5, 1.0]
    correct = features[:, 0] + rng.normal(scale=0.05, size=60) > 0.5
    calibrator = fit_calibrator(features, correct, feature_names=("s1", "SU"))
    standardised = (features - calibrator.mean) / np.asarray(calibrator.scale)
    z = standardised @ calibrator.coef + calibrator.intercept
    assert_close(calibrator.confidence(features), z, rtol=1e-12)
    assert_close(calibrator.probability(features), 1 / (1 + np.exp(-z)), rtol=1e-12)


def test_isotonic_equals_sklearn():
    rng = np.random.default_rng(1)
    su = rng.uniform(0.5, 1.0, 100)
    correct = rng.uniform(size=100) > su
    calibrator = fit_calibrator(su[:, None], correct, feature_names=("SU",), model="isotonic")
    reference = IsotonicRegression(increasing=False, out_of_bounds="clip", y_min=0, y_max=1).fit(su, correct)
    assert_close(calibrator.probability(su[:, None]), reference.predict(su), rtol=1e-12)
    assert Calibrator.from_dict(calibrator.to_dict()) == calibrator


def test_one_outcome_only_is_an_error():
    with pytest.raises(ValueError, match="only correct answers"):
        fit_calibrator(np.ones((5, 1)), np.ones(5, bool), feature_names=("s1",))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"model": "forest"}, "model must be one of"),
        ({"coef": [1.0]}, "coef must be 2 finite numbers"),
        ({"scale": [1.0, 0.0]}, "scale must be positive"),
        ({"intercept": "x"}, "intercept must be a finite number"),
        ({"features": []}, "features must be a non-empty list"),
    ],
)
def test_from_dict_names_the_bad_field(change, message):
    data = {"model": "logistic", "features": ["s1", "SU"], "mean": [0, 0], "scale": [1, 1], "coef": [1, 2]}
    data["intercept"] = 0.0
    with pytest.raises(ValueError, match=message):
        Calibrator.from_dict({**data, **change})
