"""From doubt to decision: features → calibrated P(correct top-1) → a gate with a precision guarantee.

Each name below is imported from its module on first use (PEP 562), so ``Gate.load(path)(row)`` in a robot loads
numpy and the gate only. The uncertainty method ``CAL`` registers in :mod:`~vpr_uncertainty.calibration.quality`
(an entry point of the package, loaded on the method registry's first lookup).
"""

from vpr_uncertainty.plugins import lazy_exports

_EXPORTS: dict[str, str] = {
    **dict.fromkeys(
        ("DEFAULT_FEATURES", "FEATURES", "Calibrator", "feature_matrix", "fit_calibrator"),
        "vpr_uncertainty.calibration.calibrator",
    ),
    **dict.fromkeys(("calibrate", "calibrate_arrays"), "vpr_uncertainty.calibration.fit"),
    **dict.fromkeys(("LabelPlan", "plan_labels"), "vpr_uncertainty.calibration.plan"),
    "AuditCalibration": "vpr_uncertainty.calibration.audit",
    "Gate": "vpr_uncertainty.calibration.gate",
    **dict.fromkeys(("Certificate", "certify_threshold", "min_accepted"), "vpr_uncertainty.calibration.guarantee"),
    **dict.fromkeys(("HeldOutEvaluation", "evaluate_held_out"), "vpr_uncertainty.calibration.quality"),
    **dict.fromkeys(("SequentialCalibration", "SequentialStatus"), "vpr_uncertainty.calibration.sequential"),
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports("vpr_uncertainty.calibration", _EXPORTS, globals())
