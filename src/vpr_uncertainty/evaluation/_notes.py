"""The notes an :class:`~vpr_uncertainty.evaluation.Evaluation` carries when the input bends a convention.

Each function returns one line of text (or ``None`` when there is nothing to say). The notes go into
``Evaluation.notes`` (``results.json``) and are printed under the evaluation table.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

__all__ = [
    "K_METHODS",
    "RATIO_METHODS",
    "FewerCandidatesWarning",
    "candidates_note",
    "nonpositive_note",
    "tied_note",
]

#: Methods that divide by the best similarity s_1 and rank s_1 <= 0 as the most uncertain.
RATIO_METHODS: tuple[str, ...] = ("RS", "SD", "SU")
#: Methods whose result depends on k, the number of candidates per query.
K_METHODS: tuple[str, ...] = (*RATIO_METHODS, "SUE")
#: Where the s_1 <= 0 rule is written down.
NONPOSITIVE_RULE_DOCS = "README.md, Conventions; vpr_uncertainty.scores"


class FewerCandidatesWarning(UserWarning):
    """The retrieval holds fewer candidates per query than the k asked for; the methods used those it has."""


def candidates_note(k: int, available: int, methods: Sequence[str], source: object = None) -> str | None:
    """A note when k exceeds the candidates per query that the retrieval holds, for the methods that use k."""
    using_k = [name for name in methods if name in K_METHODS]
    if int(k) <= available or not using_k:
        return None
    where = f" ({source})" if source else ""
    return (
        f"k = {int(k)} was asked but the retrieval{where} holds {available} candidates per query: "
        f"{', '.join(using_k)} used k = {available}; retrieve at least {int(k)} candidates for k = {int(k)}"
    )


def nonpositive_note(scores: np.ndarray, methods: Sequence[str]) -> str | None:
    """A note counting the queries whose best similarity s_1 <= 0, when a ratio method (RS, SD, SU) is asked."""
    ratio = [name for name in methods if name in RATIO_METHODS]
    if not ratio or scores.shape[0] == 0 or scores.shape[1] == 0:
        return None
    best = np.asarray(scores)[:, 0]
    count = int((best <= 0).sum())
    if not count:
        return None
    return (
        f"{count} of {len(best)} queries have a best similarity s_1 <= 0: {', '.join(ratio)} rank them as the most "
        f"uncertain (uncertainty 1 - s_1 >= 1), the rule for s_1 <= 0 in {NONPOSITIVE_RULE_DOCS}"
    )


def tied_note(methods: Iterable[Any], n_queries: int) -> str | None:
    """A note naming the methods whose uncertainty is the same for every query (``informative`` is False)."""
    tied = [method.name for method in methods if not method.informative]
    if not tied:
        return None
    return (
        f"{', '.join(tied)}: the same uncertainty for all {n_queries} queries, so no ranking; their AUC-PR and AP "
        "are chance level (marked uninformative) and they are never declared best"
    )
