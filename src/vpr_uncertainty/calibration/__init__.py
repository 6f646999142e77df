"""From doubt to decision: features → calibrated P(correct top-1) → a gate with a precision guarantee.

* :mod:`~vpr_uncertainty.calibration.features`: the training-free feature matrix (Q × F) from top-k scores;
* :mod:`~vpr_uncertainty.calibration.calibrator`: logistic regression on standardised features, or isotonic on SU;
* :mod:`~vpr_uncertainty.calibration.guarantee`: Learn-then-Test with exact binomial p-values on a label-free grid;
* :mod:`~vpr_uncertainty.calibration.gate`: the :class:`Gate` (batch and one-query), saved as JSON;
* :mod:`~vpr_uncertainty.calibration.fit`: :func:`calibrate` (choice of P among fixed scores and a model; every
  label tested; cross-fitting);
* :mod:`~vpr_uncertainty.calibration.plan`: :func:`plan_labels`, how many labels a certificate needs;
* :mod:`~vpr_uncertainty.calibration.quality`: ECE, Brier, reliability diagram; held-out evaluation over splits;
* :mod:`~vpr_uncertainty.calibration.simulation`: the guarantee checked over many calibration draws.
"""

from vpr_uncertainty.calibration import method  # noqa: F401  (registers CAL)
from vpr_uncertainty.calibration.calibrator import Calibrator, fit_calibrator
from vpr_uncertainty.calibration.features import DEFAULT_FEATURES, FEATURES, feature_matrix
from vpr_uncertainty.calibration.fit import calibrate, calibrate_arrays
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.calibration.guarantee import Certificate, certify_threshold, min_accepted
from vpr_uncertainty.calibration.plan import LabelPlan, plan_labels

__all__ = [
    "DEFAULT_FEATURES",
    "FEATURES",
    "Calibrator",
    "Certificate",
    "Gate",
    "LabelPlan",
    "calibrate",
    "calibrate_arrays",
    "certify_threshold",
    "feature_matrix",
    "fit_calibrator",
    "min_accepted",
    "plan_labels",
]
