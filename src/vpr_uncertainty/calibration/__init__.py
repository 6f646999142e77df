"""From doubt to decision: features → calibrated P(correct top-1) → a gate with a precision guarantee.

Importing the package registers the uncertainty method ``CAL`` (:mod:`~vpr_uncertainty.calibration.quality`).
"""

from vpr_uncertainty.calibration.calibrator import (
    DEFAULT_FEATURES,
    FEATURES,
    Calibrator,
    feature_matrix,
    fit_calibrator,
)
from vpr_uncertainty.calibration.fit import LabelPlan, calibrate, calibrate_arrays, plan_labels
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.calibration.guarantee import Certificate, certify_threshold, min_accepted
from vpr_uncertainty.calibration.quality import HeldOutEvaluation, evaluate_held_out

__all__ = [
    "DEFAULT_FEATURES",
    "FEATURES",
    "Calibrator",
    "Certificate",
    "Gate",
    "HeldOutEvaluation",
    "LabelPlan",
    "calibrate",
    "calibrate_arrays",
    "certify_threshold",
    "evaluate_held_out",
    "feature_matrix",
    "fit_calibrator",
    "min_accepted",
    "plan_labels",
]
