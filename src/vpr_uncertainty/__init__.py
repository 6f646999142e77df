"""vpr-uncertainty: how much to doubt each answer of a visual place recognition system, and how good that doubt is.

Uncertainties are arrays of shape (Q,) where higher = less trustworthy; scores are top-k similarities of shape
(Q, K), higher = more similar, sorted descending.

The top level is the toolkit's core: the uncertainty functions, the retrieval result and its files (with
:func:`positives_from_lists` for ground truth given as lists), evaluation (and the empirical
:func:`threshold_at_precision`), and the registry of uncertainty methods (:func:`register_method`). Figures in
scikit-learn's Display style are in :mod:`vpr_uncertainty.reports.display`. The other extension points register beside
their own registries: :func:`vpr_uncertainty.descriptors.register_model`,
:func:`vpr_uncertainty.data.register_format` and :func:`vpr_uncertainty.reports.register_report_figure`.

>>> import numpy as np
>>> from vpr_uncertainty import statistical_uncertainty
>>> statistical_uncertainty(np.array([[0.9, 0.5, 0.4], [0.6, 0.59, 0.58]]), k=3).round(3)
array([0.528, 0.979])
"""

from vpr_uncertainty.calibration import Gate, calibrate
from vpr_uncertainty.data import load_descriptors, read_results
from vpr_uncertainty.evaluation import (
    Evaluation,
    auc_pr,
    aurc,
    average_precision,
    correct_at_n,
    evaluate,
    recall_at_n,
    rejection_curve,
    threshold_at_precision,
)
from vpr_uncertainty.methods import available_methods, get_method, register_method
from vpr_uncertainty.retrieval import (
    Retrieval,
    load_retrieval,
    retrieve,
    save_retrieval,
    search_descriptors,
    top_k_from_similarity,
)
from vpr_uncertainty.retrieval.result import positives_from_lists
from vpr_uncertainty.scores import (
    StatisticalUncertainty,
    best_match,
    l2_distance,
    margin,
    perceptual_aliasing,
    ratio_spread,
    similarity_distribution,
    statistical_uncertainty,
)
from vpr_uncertainty.spatial import spatial_uncertainty

__version__ = "0.1.0"

__all__ = [
    "Evaluation",
    "Gate",
    "Retrieval",
    "StatisticalUncertainty",
    "auc_pr",
    "aurc",
    "available_methods",
    "average_precision",
    "best_match",
    "calibrate",
    "correct_at_n",
    "evaluate",
    "get_method",
    "l2_distance",
    "load_descriptors",
    "load_retrieval",
    "margin",
    "perceptual_aliasing",
    "positives_from_lists",
    "ratio_spread",
    "read_results",
    "recall_at_n",
    "register_method",
    "rejection_curve",
    "retrieve",
    "save_retrieval",
    "search_descriptors",
    "similarity_distribution",
    "spatial_uncertainty",
    "statistical_uncertainty",
    "threshold_at_precision",
    "top_k_from_similarity",
]
