"""vpr-uncertainty: how much to doubt each answer of a visual place recognition system, and how good that doubt is.

Uncertainties are arrays of shape (Q,) where higher = less trustworthy; scores are top-k similarities of shape
(Q, K), higher = more similar, sorted descending.

The top level is the toolkit's core: the uncertainty functions, the retrieval result and its files (with
:func:`positives_from_lists` for ground truth given as lists), evaluation (and the empirical
:func:`threshold_at_precision`), and the registry of uncertainty methods (:func:`register_method`). Figures in
scikit-learn's Display style are in :mod:`vpr_uncertainty.reports.display`. The other extension points register beside
their own registries: :func:`vpr_uncertainty.descriptors.register_model`,
:func:`vpr_uncertainty.data.register_format` and :func:`vpr_uncertainty.reports.register_report_figure`.

Importing the package loads numpy only; each name below is imported from its module when first used (PEP 562),
so a robot that needs the scores or a gate does not pay for scikit-learn, h5py, Faiss or torch.

>>> import numpy as np
>>> from vpr_uncertainty import statistical_uncertainty
>>> statistical_uncertainty(np.array([[0.9, 0.5, 0.4], [0.6, 0.59, 0.58]]), k=3).round(3)
array([0.528, 0.979])
"""

from vpr_uncertainty.plugins import lazy_exports

__version__ = "0.1.0"

#: Each public name, and the module it is imported from on first use.
_EXPORTS: dict[str, str] = {
    **dict.fromkeys(("Gate", "calibrate"), "vpr_uncertainty.calibration"),
    **dict.fromkeys(("load_descriptors", "read_results"), "vpr_uncertainty.data"),
    **dict.fromkeys(
        (
            "Comparison",
            "Evaluation",
            "auc_pr",
            "aurc",
            "average_precision",
            "compare",
            "correct_at_n",
            "evaluate",
            "recall_at_n",
            "rejection_curve",
            "threshold_at_precision",
        ),
        "vpr_uncertainty.evaluation",
    ),
    **dict.fromkeys(("available_methods", "get_method", "register_method"), "vpr_uncertainty.methods"),
    **dict.fromkeys(
        ("Retrieval", "load_retrieval", "retrieve", "save_retrieval", "search_descriptors", "top_k_from_similarity"),
        "vpr_uncertainty.retrieval",
    ),
    "positives_from_lists": "vpr_uncertainty.retrieval.result",
    **dict.fromkeys(
        (
            "StatisticalUncertainty",
            "best_match",
            "l2_distance",
            "margin",
            "perceptual_aliasing",
            "ratio_spread",
            "similarity_distribution",
            "statistical_uncertainty",
        ),
        "vpr_uncertainty.scores",
    ),
    "spatial_uncertainty": "vpr_uncertainty.spatial",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports("vpr_uncertainty", _EXPORTS, globals())
