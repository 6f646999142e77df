"""Bayesian triplet loss (BTL) baseline: a learned uncertainty head on frozen global descriptors (``[torch]`` extra).

Warburg et al., "Bayesian Triplet Loss: Uncertainty Quantification in Image Retrieval", ICCV 2021. Each image is
an isotropic Gaussian embedding (L2-normalised mean, one scalar variance); the head is trained with the
Bayesian triplet loss on triplets mined from the training positives and hard negatives; the variance of a
query is its uncertainty (higher = less trustworthy), and BTL answers with its own retrieval.

Typical use::

    from vpr_uncertainty.btl import train_btl_head, save_btl_head
    head, history = train_btl_head(database_descriptors, positives, query_descriptors=query_descriptors)
    save_btl_head(head, "head.pt")
    evaluate(retrieval, ["BTL", "SU"], btl_head="head.pt",
             query_descriptors=query_descriptors, database_descriptors=database_descriptors)

Modules: :mod:`~vpr_uncertainty.btl.loss` (the loss and its derivation), :mod:`~.model` (the head and its
file), :mod:`~.mining` (triplets), :mod:`~.training` (training loop, early stopping, curve),
:mod:`~.method` (the registered ``BTL`` method), :mod:`~.protocol` (evaluation protocols with no training query
among the test queries).
"""

from vpr_uncertainty.btl.loss import (
    DEFAULT_KL_WEIGHT,
    DEFAULT_MARGIN,
    DEFAULT_PRIOR_VARIANCE,
    BayesianTripletLoss,
    bayesian_triplet_loss,
    kl_to_isotropic_prior,
    triplet_distance_moments,
    triplet_probability,
)
from vpr_uncertainty.btl.method import btl_retrieval, btl_uncertainty
from vpr_uncertainty.btl.mining import Triplets, mine_triplets
from vpr_uncertainty.btl.model import BTLHead, embed, load_btl_head, save_btl_head
from vpr_uncertainty.btl.training import BTLTrainingConfig, TrainingHistory, save_training_curve, train_btl_head

__all__ = [
    "DEFAULT_KL_WEIGHT",
    "DEFAULT_MARGIN",
    "DEFAULT_PRIOR_VARIANCE",
    "BTLHead",
    "BTLTrainingConfig",
    "BayesianTripletLoss",
    "TrainingHistory",
    "Triplets",
    "bayesian_triplet_loss",
    "btl_retrieval",
    "btl_uncertainty",
    "embed",
    "kl_to_isotropic_prior",
    "load_btl_head",
    "mine_triplets",
    "save_btl_head",
    "save_training_curve",
    "train_btl_head",
    "triplet_distance_moments",
    "triplet_probability",
]
