"""How good is an uncertainty? Correctness, AUC-PR, rejection curves, recall@N, AURC, time per query and bootstrap
intervals, paired comparisons (:func:`compare`) (conventions: :mod:`~vpr_uncertainty.evaluation.metrics`)."""

from vpr_uncertainty.evaluation._evaluate import RECALL_LEVELS, evaluate, time_per_query
from vpr_uncertainty.evaluation.compare import Comparison, Difference, McNemar, compare, mcnemar
from vpr_uncertainty.evaluation.metrics import (
    RECALL_NS,
    FewerCandidatesWarning,
    RejectionCurve,
    ThresholdChoice,
    auc_pr,
    aurc,
    average_precision,
    correct_at_n,
    precision_at_recall,
    recall_at_full_precision,
    recall_at_n,
    rejection_curve,
    threshold_at_precision,
)
from vpr_uncertainty.evaluation.results import Evaluation, MethodEvaluation

__all__ = [
    "RECALL_LEVELS",
    "RECALL_NS",
    "Comparison",
    "Difference",
    "Evaluation",
    "FewerCandidatesWarning",
    "McNemar",
    "MethodEvaluation",
    "RejectionCurve",
    "ThresholdChoice",
    "auc_pr",
    "aurc",
    "average_precision",
    "compare",
    "correct_at_n",
    "evaluate",
    "mcnemar",
    "precision_at_recall",
    "recall_at_full_precision",
    "recall_at_n",
    "rejection_curve",
    "threshold_at_precision",
    "time_per_query",
]
