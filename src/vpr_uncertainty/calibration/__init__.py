"""From doubt to decision: features → calibrated P(correct top-1) → a gate with a precision guarantee.

* :mod:`~vpr_uncertainty.calibration.features`: the training-free feature matrix (Q × F) from top-k scores;
* :mod:`~vpr_uncertainty.calibration.calibrator`: logistic regression on standardised features, or isotonic on SU;
* :mod:`~vpr_uncertainty.calibration.guarantee`: Learn-then-Test with Clopper–Pearson p-values;
* :mod:`~vpr_uncertainty.calibration.gate`: the :class:`Gate` (batch and one-query), saved as JSON;
* :mod:`~vpr_uncertainty.calibration.fit`: :func:`calibrate`;
* :mod:`~vpr_uncertainty.calibration.quality`: ECE, Brier, reliability diagram; held-out evaluation over splits;
* :mod:`~vpr_uncertainty.calibration.simulation`: the guarantee checked over many calibration draws.
"""

from vpr_uncertainty.calibration.calibrator import Calibrator, fit_calibrator
from vpr_uncertainty.calibration.features import DEFAULT_FEATURES, FEATURES, feature_matrix
from vpr_uncertainty.calibration.fit import calibrate, calibrate_arrays
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.calibration.guarantee import Certificate, certify_threshold, min_accepted

__all__ = [
    "DEFAULT_FEATURES",
    "FEATURES",
    "Calibrator",
    "Certificate",
    "Gate",
    "calibrate",
    "calibrate_arrays",
    "certify_threshold",
    "feature_matrix",
    "fit_calibrator",
    "min_accepted",
]
