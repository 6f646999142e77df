"""How good is an uncertainty? Correctness, AUC-PR, rejection curves, recall@N, AURC and time per query.

Conventions
-----------
* A query's answer is **correct** when its top-1 database image is among its positives.
* An uncertainty is higher for answers to trust less. The evaluation negates it exactly once, to rank queries by
  confidence; a correct answer is the positive class.
* **AUC-PR** is the trapezoid area ``sklearn.metrics.auc(recall, precision)`` under
  ``precision_recall_curve(correct, -uncertainty)``, the convention of the published VPR uncertainty tables;
  average precision (the step-wise area) is reported beside it.
* **End-to-end precision-recall**: the VPR system accepts the queries whose uncertainty is <= a threshold.
  Precision = correct accepted / accepted; recall = correct accepted / queries with at least one positive in
  the database. Each distinct uncertainty value is one threshold (tied queries are accepted together).
* **recall@N** is the share of queries with at least one positive that have one among their first N
  candidates.
* **AURC** is the area under the risk-coverage curve: Σ over thresholds of (coverage gained) × (error rate among
  the accepted queries), with coverage in steps of tied groups; lower is better.
* **Uninformative**: a method that gives every query the same uncertainty ranks nothing; its AUC-PR is chance
  level. It is flagged (``informative: false``, ``distinct_values: 1``) and never reported as best.
* **k**: ``Evaluation.k`` is the k the methods used, ``min(k asked, candidates per query)``; a shortfall gives a
  :class:`FewerCandidatesWarning` and a note. Queries with s_1 <= 0 (ranked most uncertain by RS, SD, SU) are
  counted in the notes.

The metrics live in :mod:`~vpr_uncertainty.evaluation.metrics`, the result types (with ``to_dict``,
``from_dict`` and ``to_frame``) in :mod:`~vpr_uncertainty.evaluation.results` (their pandas table in
:mod:`~vpr_uncertainty.evaluation.frame`), the empirical :func:`threshold_at_precision` in
:mod:`~vpr_uncertainty.evaluation.threshold`, and :func:`evaluate` in a private module; everything is re-exported
here.
"""

from vpr_uncertainty.evaluation._evaluate import RECALL_LEVELS, evaluate, time_per_query
from vpr_uncertainty.evaluation._notes import FewerCandidatesWarning
from vpr_uncertainty.evaluation.metrics import (
    RECALL_NS,
    RejectionCurve,
    auc_pr,
    aurc,
    average_precision,
    correct_at_n,
    precision_at_recall,
    recall_at_full_precision,
    recall_at_n,
    rejection_curve,
)
from vpr_uncertainty.evaluation.results import Evaluation, MethodEvaluation
from vpr_uncertainty.evaluation.threshold import ThresholdChoice, threshold_at_precision

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
