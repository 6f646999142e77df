"""Uncertainty methods: the names users type (``SU``, ``PA``, ``SUE``, ``GV-SIFT``, ``SU+GV-SIFT``), called alike.

``get_method("SU")(retrieval, k=10, alpha=0.5)`` returns an ndarray of shape (Q,), higher = less trustworthy.
"""

# Importing the built-ins and the cascades registers them (before any caller can look one up).
from vpr_uncertainty.methods import builtin, cascade, entries  # noqa: F401
from vpr_uncertainty.methods.entries import *  # noqa: F403

__all__ = entries.__all__  # the public API is that of entries
