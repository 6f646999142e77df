"""Adaptive SU: the weight α of RS against SD chosen per query from its own top-k scores, without training.

Direction: higher = less trustworthy, as for :func:`vpr_uncertainty.scores.statistical_uncertainty`.

The rule
--------
RS and SD compare the best similarity s_1 with an estimate of the *background*, the similarity of the wrong
candidates: RS uses the mean of the runners-up s_2..s_k, SD the median of s_1..s_k. The mean is the efficient
estimate of a homogeneous cohort, the median the robust one when a few candidates stand apart from it: typically
other images of the same place (a revisit, neighbouring frames) that pull the mean up and make RS doubt a correct
answer, or one strong aliasing candidate. Choosing between mean and median from the shape of the sample is the
classic adaptive-estimator idea (Hogg, 1974, "Adaptive robust procedures", JASA 69:909), here with a parameter-free
selector: the nonparametric skew of the runners-up,

    γ_q = |mean(s_2..s_k) − median(s_2..s_k)| / std(s_2..s_k)   ∈ [0, 1]

(|mean − median| ≤ std for every sample; population std). It is invariant to the location and scale of the scores,
so it needs no division by s_1 and behaves the same for every VPR method's similarity range. Then

    α_q = 1 − γ_q,        SU-adaptive_q = α_q·RS_q + (1 − α_q)·SD_q.

A homogeneous cohort (mean = median) gives α_q = 1 (RS); a cohort whose mean is pulled one standard deviation
away from its median gives α_q = 0 (SD). A cohort without spread (std = 0, or one runner-up) carries no evidence
either way and gets α_q = 1/2, the paper's default. Rows whose best similarity is <= 0 get 1 − s_1, as RS, SD and
SU do (see :mod:`vpr_uncertainty.scores`), whatever α_q.

Evidence (README, "Adaptive α"; ``benchmarks/adaptive_alpha.py``): on the ten VPR-Bench corridor matrices and
the demo run, the mean AUC-PR (0.8145) is above that of the fixed α = 0.5 (0.8116; higher on 8 of 11) and below
that of the best fixed α chosen in hindsight per matrix (0.8179). The reversed rule (α_q = γ_q) is below
α = 0.5 (0.8071), which supports the direction of the rule. Most of the gain is a shift of the average weight
towards RS (mean α_q ≈ 0.73; SU at that fixed α: 0.8130, above the adaptive rule on 8 of 11): the per-query part
adds little beyond it. Hence ``SU-adaptive`` is registered but not a default method.
"""

from __future__ import annotations

import numpy as np

from vpr_uncertainty._validation import as_score_array, check_k, check_rows, raise_for_short_rows
from vpr_uncertainty.scores import ratio_spread, similarity_distribution

__all__ = ["adaptive_alpha", "adaptive_statistical_uncertainty"]

#: α of a row whose runners-up have no spread (or a single runner-up): the paper's default.
NO_EVIDENCE_ALPHA = 0.5


def _alpha_of_runners_up(runners_up: np.ndarray) -> np.ndarray:
    """α = 1 − |mean − median| / std of each row of sorted (descending), finite runners-up, shape (R, m)."""
    values = runners_up.astype(np.float64, copy=False)
    m = values.shape[1]
    mean = values.mean(axis=1)
    median = 0.5 * (values[:, (m - 1) // 2] + values[:, m // 2])  # rows are sorted
    spread = values.std(axis=1)
    # A spread at the rounding level of the values is no spread.
    flat = spread <= 8 * np.finfo(np.float64).eps * np.maximum(np.abs(mean), np.finfo(np.float64).tiny)
    with np.errstate(divide="ignore", invalid="ignore"):
        skew = np.abs(mean - median) / np.where(flat, 1.0, spread)
    return np.where(flat, NO_EVIDENCE_ALPHA, np.clip(1.0 - skew, 0.0, 1.0))


def adaptive_alpha(scores: object, k: int = 10, *, sort: bool = False) -> np.ndarray:
    """The weight α_q of RS of each query: 1 − the nonparametric skew of its runners-up (see the module docstring).

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, higher = more similar, sorted descending along axis 1; ``-inf`` marks a
        missing candidate at the end of a row (the row is then used with the candidates it has).
    k : int, default=10
        Number of candidates used (the first ``min(k, K)`` columns). Must be >= 2.
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.

    Returns
    -------
    ndarray of shape (Q,), float64
        α_q in [0, 1].

    Examples
    --------
    >>> import numpy as np
    >>> adaptive_alpha(np.array([[0.9, 0.5, 0.4, 0.3], [0.9, 0.8, 0.3, 0.3], [0.9, 0.5, 0.5, 0.5]]), k=4).round(3)
    array([1.   , 0.293, 0.5  ])

    The first query's runners-up are symmetric (mean = median): RS. The second's mean is pulled up by one strong
    runner-up: mostly SD. The third's have no spread: the default 1/2.
    """
    k = check_k(k)
    scores = as_score_array(scores, sort=sort)
    check_rows(scores)
    n_queries = scores.shape[0]
    n = min(k, scores.shape[1])
    if n_queries == 0:
        return np.empty(0, dtype=np.float64)
    if n < 2:
        raise_for_short_rows(np.full(n_queries, n))
    top = scores[:, :n]
    n_candidates = np.isfinite(top).sum(axis=1)
    raise_for_short_rows(n_candidates)
    alpha = np.empty(n_queries, dtype=np.float64)
    for count in np.unique(n_candidates):  # usually one group: every row has n candidates
        rows = np.flatnonzero(n_candidates == count)
        alpha[rows] = _alpha_of_runners_up(top[rows, 1:count])
    return alpha


def adaptive_statistical_uncertainty(
    scores: object, k: int = 10, *, sort: bool = False, on_nonpositive: str = "most_uncertain"
) -> np.ndarray:
    """SU with a per-query α: α_q·RS_q + (1 − α_q)·SD_q, α_q from :func:`adaptive_alpha`. Training-free.

    Parameters
    ----------
    scores : array-like of shape (Q, K)
        Top-K similarities per query, higher = more similar, sorted descending along axis 1.
    k : int, default=10
        Number of candidates used. Must be >= 2.
    sort : bool, default=False
        Sort each row for the caller instead of rejecting unsorted rows.
    on_nonpositive : {"most_uncertain", "raise"}, default="most_uncertain"
        What to do with rows whose best similarity is <= 0 (see :mod:`vpr_uncertainty.scores`).

    Returns
    -------
    ndarray of shape (Q,)
        Uncertainty, higher = less trustworthy.

    Examples
    --------
    >>> import numpy as np
    >>> adaptive_statistical_uncertainty(np.array([[0.8, 0.4, 0.3, 0.2]]), k=4)  # α = 1: RS
    array([0.375])
    """
    if sort:
        scores = as_score_array(scores, sort=True)
    rs = ratio_spread(scores, k, on_nonpositive=on_nonpositive)
    sd = similarity_distribution(scores, k, on_nonpositive=on_nonpositive)
    alpha = adaptive_alpha(scores, k).astype(rs.dtype)
    return alpha * rs + (1 - alpha) * sd
