"""How good is an uncertainty? Correctness, AUC-PR, rejection curves, recall@N, AURC, time per query and bootstrap
intervals (conventions: :mod:`~vpr_uncertainty.evaluation.metrics`)."""

from vpr_uncertainty.evaluation._evaluate import RECALL_LEVELS, FewerCandidatesWarning, evaluate, time_per_query
from vpr_uncertainty.evaluation.metrics import (
    RECALL_NS,
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
    "Evaluation",
    "FewerCandidatesWarning",
    "MethodEvaluation",
    "RejectionCurve",
    "ThresholdChoice",
    "auc_pr",
    "aurc",
    "average_precision",
    "correct_at_n",
    "evaluate",
    "precision_at_recall",
    "recall_at_full_precision",
    "recall_at_n",
    "rejection_curve",
    "threshold_at_precision",
    "time_per_query",
]
