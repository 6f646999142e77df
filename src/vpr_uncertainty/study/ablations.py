"""The α and k ablations of a grid cell: AUC-PR of SU for each α, and of RS and SD for each k."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from vpr_uncertainty.evaluation import auc_pr
from vpr_uncertainty.methods import get_method

if TYPE_CHECKING:
    from vpr_uncertainty.retrieval import Retrieval

__all__ = ["ablation_curves", "ks_left_out_note"]


def ablation_curves(
    retrieval: Retrieval, correct: np.ndarray, *, k: int, alphas: Sequence[float], ks: Sequence[int]
) -> tuple[dict[float, float | None], dict[str, dict[int, float | None]]]:
    """AUC-PR of SU for every α (at ``k``) and of RS and SD for every k the retrieval holds.

    Parameters
    ----------
    retrieval : Retrieval
        The cell's retrieval.
    correct : ndarray of shape (Q,), bool
        Whether each query's top-1 answer is correct.
    k : int
        The k of the α ablation (at most the candidates per query are used).
    alphas : sequence of float
        Weights α of SU.
    ks : sequence of int
        Values of k for RS and SD; those above the candidates per query are left out.

    Returns
    -------
    alpha_curve : dict of float to float or None
        α -> AUC-PR of SU; None when every answer is correct, or none is.
    k_curve : dict of str to dict of int to float or None
        ``"RS"`` and ``"SD"`` -> k -> AUC-PR.
    """
    both = bool(correct.any() and not correct.all())
    su, rs, sd = get_method("SU"), get_method("RS"), get_method("SD")
    k = min(k, retrieval.k)
    alpha_curve = {a: (auc_pr(correct, su(retrieval, k=k, alpha=a)) if both else None) for a in alphas}
    k_curve: dict[str, dict[int, float | None]] = {"RS": {}, "SD": {}}
    for value in ks:
        if value > retrieval.k:
            continue
        for name, method in (("RS", rs), ("SD", sd)):
            k_curve[name][value] = auc_pr(correct, method(retrieval, k=value)) if both else None
    return alpha_curve, k_curve


def ks_left_out_note(ks: Sequence[int], available: int) -> str | None:
    """A note when the k ablation leaves out ks larger than the ``available`` candidates per query (else None)."""
    left_out = [value for value in ks if value > available]
    if not left_out:
        return None
    return (
        f"k ablation: k = {', '.join(map(str, left_out))} left out, the retrieval holds {available} candidates "
        "per query"
    )
