"""The built-in uncertainty methods, registered on import (by :mod:`vpr_uncertainty.methods`, which imports this).

Score-only methods (RS, SD, SU, BM, L2, PA, margin) wrap :mod:`vpr_uncertainty.scores`; SUE, the geometric
verification presets and BTL are registered by dotted path and imported when first called.
"""

from __future__ import annotations

import numpy as np

from vpr_uncertainty import scores as _scores
from vpr_uncertainty.methods.entries import METHODS, register_method
from vpr_uncertainty.retrieval import Retrieval

__all__ = ["GEOMETRIC_METHODS", "SCORE_ONLY_METHODS"]


def _check_k_alpha(*, k: int = 10, alpha: float = 0.5) -> None:
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must lie in [0, 1], got {alpha}")


# --- score-only methods ------------------------------------------------------------------------------------


def _ratio_spread(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.ratio_spread(retrieval.scores, k)


def _similarity_distribution(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.similarity_distribution(retrieval.scores, k)


def _statistical_uncertainty(retrieval: Retrieval, *, k: int = 10, alpha: float = 0.5) -> np.ndarray:
    return _scores.statistical_uncertainty(retrieval.scores, k, alpha)


def _adaptive_statistical_uncertainty(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    from vpr_uncertainty.adaptive import adaptive_statistical_uncertainty

    return adaptive_statistical_uncertainty(retrieval.scores, k)


def _best_match(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.best_match(retrieval.scores, k)


def _l2_distance(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.l2_distance(retrieval.scores, k, distances=retrieval.distances)


def _perceptual_aliasing(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.perceptual_aliasing(retrieval.scores, k, distances=retrieval.distances)


def _margin(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.margin(retrieval.scores, k)


# Registration order is the order of tables and of evaluate's default list (the entries with default=True).
_K = {"k": 10}
_SCORE = {"options": _K, "validate": _check_k_alpha, "kind": "score", "default": True}
register_method("RS", _ratio_spread, description="Ratio Spread: mean s_i/s_1 of the runners-up", **_SCORE)
register_method("SD", _similarity_distribution, description="Similarity Distribution: median/s_1", **_SCORE)
register_method(
    "SU",
    _statistical_uncertainty,
    description="Statistical Uncertainty: α·RS + (1−α)·SD",
    **{**_SCORE, "options": {**_K, "alpha": 0.5}},
)
register_method("PA", _perceptual_aliasing, description="Perceptual aliasing: d_1/d_2", **_SCORE)
register_method("L2", _l2_distance, description="Top-1 L2 descriptor distance d_1", **_SCORE)
register_method("BM", _best_match, description="Best match: −s_1", **_SCORE)
register_method(
    "SU-adaptive",
    _adaptive_statistical_uncertainty,
    description="SU with α per query: 1 − |mean − median|/std of the runners-up (training-free)",
    **{**_SCORE, "default": False},
)
register_method("margin", _margin, description="Negated margin s_2 − s_1", **{**_SCORE, "default": False})

register_method(
    "SUE",
    "vpr_uncertainty.spatial:sue_from_retrieval",
    description="Spatial uncertainty: weighted spread of the top-k database positions (Zaffar et al. 2024)",
    requires=("database_positions",),
    options={"k": 10, "slope": 350.0, "clip": "symmetric", "max_deviation": 500.0},
    validate="vpr_uncertainty.spatial:check_sue_options",
    kind="spatial",
)

register_method(
    "CAL",
    "vpr_uncertainty.calibration.method:cal_uncertainty",
    description="1 − calibrated P(correct) of a fitted gate (calibrate; fitted per split in held-out evaluate)",
    requires=("gate",),
    options={"gate": ""},
    kind="calibrated",
    resolve="vpr_uncertainty.calibration.method:resolve_gate",
)

# Derived from the entries (for callers of the former constants): prefer available_methods(kind=...).
SCORE_ONLY_METHODS: tuple[str, ...] = tuple(METHODS.names(kind="score"))
GEOMETRIC_METHODS: tuple[str, ...] = tuple(METHODS.names(kind="geometric"))
