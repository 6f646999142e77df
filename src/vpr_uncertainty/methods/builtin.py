"""The built-in score methods (RS, SD, SU, BM, L2, PA, margin), registered on import by the package ``__init__``;
the higher layers register theirs where they are defined."""

from __future__ import annotations

import numpy as np

from vpr_uncertainty import scores as _scores
from vpr_uncertainty.methods.entries import register_method
from vpr_uncertainty.retrieval import Retrieval

__all__: list[str] = []


def _check_k_alpha(*, k: int = 10, alpha: float = 0.5) -> None:
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    _scores.check_alpha(alpha)


# --- score-only methods ------------------------------------------------------------------------------------


def _ratio_spread(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.ratio_spread(retrieval.scores, k)


def _similarity_distribution(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.similarity_distribution(retrieval.scores, k)


def _statistical_uncertainty(retrieval: Retrieval, *, k: int = 10, alpha: float = 0.5) -> np.ndarray:
    return _scores.statistical_uncertainty(retrieval.scores, k, alpha)


def _adaptive_statistical_uncertainty(retrieval: Retrieval, *, k: int = 10) -> np.ndarray:
    return _scores.adaptive_statistical_uncertainty(retrieval.scores, k)


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
