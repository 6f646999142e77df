"""What an uncertainty method may return besides a plain array of uncertainties (re-exported by
:mod:`vpr_uncertainty.methods.entries` and :mod:`vpr_uncertainty.methods`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vpr_uncertainty.retrieval import Retrieval

__all__ = ["DetailedUncertainty", "OwnRetrievalUncertainty"]


@dataclass
class OwnRetrievalUncertainty:
    """What a method returns when it answers the queries with its own retrieval (e.g. BTL's mean embeddings).

    The evaluation then judges correctness by the top-1 of ``retrieval``, not by the shared retrieval, and says
    so in its notes.

    Attributes
    ----------
    uncertainty : ndarray of shape (Q,)
        Higher = less trustworthy.
    retrieval : Retrieval
        The method's own top-k for the same queries, with the same ground truth.
    details : dict of str to JSON values
        Reported beside the method's metrics, as for :class:`DetailedUncertainty` (e.g. BTL's
        ``trained_on_queries``).
    """

    uncertainty: np.ndarray
    retrieval: Retrieval
    details: dict[str, Any] = field(default_factory=dict)


@dataclass
class DetailedUncertainty:
    """What a method returns when it also reports numbers about its run (e.g. a cascade's ``verified_fraction``).

    Attributes
    ----------
    uncertainty : ndarray of shape (Q,)
        Higher = less trustworthy.
    details : dict of str to JSON values
        Reported beside the method's metrics (``results.json``, ``evaluate --json``).
    """

    uncertainty: np.ndarray
    details: dict[str, Any] = field(default_factory=dict)
