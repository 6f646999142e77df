"""Bayesian triplet loss (BTL) baseline (Warburg et al., ICCV 2021): a learned uncertainty head on frozen global
descriptors (``[torch]`` extra). Importing the package registers the ``BTL`` method and imports no torch; the
names below load their module on first use."""

from importlib import import_module
from typing import Any

from vpr_uncertainty.methods import register_method

_EXPORTS = {
    "DEFAULT_KL_WEIGHT": "model",
    "DEFAULT_MARGIN": "model",
    "DEFAULT_PRIOR_VARIANCE": "model",
    "BTLHead": "model",
    "bayesian_triplet_loss": "model",
    "embed": "model",
    "kl_to_isotropic_prior": "model",
    "load_btl_head": "model",
    "save_btl_head": "model",
    "triplet_distance_moments": "model",
    "triplet_probability": "model",
    "BTLTrainingConfig": "training",
    "TrainingHistory": "training",
    "Triplets": "training",
    "mine_triplets": "training",
    "save_training_curve": "training",
    "train_btl_head": "training",
    "btl_retrieval": "method",
    "btl_uncertainty": "method",
    "read_training_inputs": "method",
    "resolve_btl_inputs": "method",
    "BTLProtocol": "method",
    "btl_protocol": "method",
    "train_for_protocol": "method",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_EXPORTS[name]}"), name)


register_method(
    "BTL",
    "vpr_uncertainty.btl.method:btl_uncertainty",
    description="Bayesian triplet loss: query variance of a trained head, with its own retrieval (Warburg et al. 2021)",
    extra="torch",
    requires=("btl_head", "descriptors"),
    kind="learned",
    resolve="vpr_uncertainty.btl.method:resolve_btl_inputs",
)
