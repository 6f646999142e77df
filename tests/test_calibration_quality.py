"""ECE, Brier and the reliability diagram against slow references."""

from __future__ import annotations

import numpy as np
import pytest

from vpr_uncertainty.calibration.quality import brier_score, expected_calibration_error, reliability_diagram


def test_quality_against_reference():
    rng = np.random.default_rng(0)
    probability = rng.uniform(size=500)
    probability[:3] = [0.0, 1.0, 0.5]
    correct = rng.uniform(size=500) < probability
    diagram = reliability_diagram(probability, correct, n_bins=10)
    assert sum(diagram.counts) == 500
    ece = 0.0
    for b in range(10):
        low, high = b / 10, (b + 1) / 10
        inside = (probability >= low) & ((probability < high) if b < 9 else (probability <= high))
        assert diagram.counts[b] == inside.sum()
        if inside.any():
            ece += inside.mean() * abs(correct[inside].mean() - probability[inside].mean())
    assert expected_calibration_error(probability, correct) == pytest.approx(ece, rel=1e-12)
    assert brier_score(probability, correct) == pytest.approx(np.mean((probability - correct) ** 2), rel=1e-12)


@pytest.mark.parametrize(("probability", "message"), [([1.5], r"\[0, 1\]"), ([], "empty"), ([[0.5]], "1-D")])
def test_quality_errors(probability, message):
    with pytest.raises(ValueError, match=message):
        brier_score(probability, np.ones(np.shape(probability), bool))
