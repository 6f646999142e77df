"""Uncertainty methods: the names users type (``SU``, ``PA``, ``SUE``, ``GV-SIFT``, ``SU+GV-SIFT``), called alike:
``get_method("SU")(retrieval, k=10, alpha=0.5)`` returns an ndarray of shape (Q,), higher = less trustworthy. The
built-in score methods are registered here (see docs/explanation/uncertainty-scores.md).
"""

from vpr_uncertainty import scores as _scores
from vpr_uncertainty._validation import check_count
from vpr_uncertainty.methods import cascade, entries  # noqa: F401
from vpr_uncertainty.methods.entries import *  # noqa: F403
from vpr_uncertainty.methods.entries import register_method

__all__ = entries.__all__  # the public API is that of entries


def _check_k_alpha(*, k: int = 10, alpha: float = 0.5) -> None:
    check_count(k, "k", 1)
    _scores.check_alpha(alpha)


def _late(function: object) -> str:
    """The dotted path of a scores function, looked up at first call (so a patched function is the one called)."""
    return f"{function.__module__}:{function.__name__}"


# Each entry calls its function of vpr_uncertainty.scores on the retrieval's scores (and distances) directly.
# Registration order is the order of tables and of evaluate's default list (the entries with default=True).
_K = {"k": 10}
_SCORE = {"options": _K, "validate": _check_k_alpha, "kind": "score", "default": True, "reads": ("scores",)}
_RATIOS = {**_SCORE, "scores": "similarity"}  # divide by s_1
_WITH_DISTANCES = {**_SCORE, "reads": ("scores", "distances"), "scores": "cosine"}  # d² = 2 − 2s without distances

register_method(
    "RS", _late(_scores.ratio_spread), description="Ratio Spread: mean s_i/s_1 of the runners-up", **_RATIOS
)
register_method(
    "SD", _late(_scores.similarity_distribution), description="Similarity Distribution: median/s_1", **_RATIOS
)
register_method(
    "SU",
    _late(_scores.statistical_uncertainty),
    description="Statistical Uncertainty: α·RS + (1−α)·SD",
    **{**_RATIOS, "options": {**_K, "alpha": 0.5}},
)
register_method("PA", _late(_scores.perceptual_aliasing), description="Perceptual aliasing: d_1/d_2", **_WITH_DISTANCES)
register_method("L2", _late(_scores.l2_distance), description="Top-1 L2 descriptor distance d_1", **_WITH_DISTANCES)
register_method("BM", _late(_scores.best_match), description="Best match: −s_1", **_SCORE)
register_method(
    "SU-adaptive",
    _late(_scores.adaptive_statistical_uncertainty),
    description="SU with α per query: 1 − |mean − median|/std of the runners-up (training-free)",
    **{**_RATIOS, "default": False},
)
register_method("margin", _late(_scores.margin), description="Negated margin s_2 − s_1", **{**_SCORE, "default": False})
