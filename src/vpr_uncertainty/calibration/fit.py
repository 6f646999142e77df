""":func:`calibrate`: labelled calibration queries in, a :class:`~vpr_uncertainty.calibration.gate.Gate` out (how
many labels that takes and how often the guarantee holds: :mod:`~vpr_uncertainty.calibration.plan`).

Every label is spent; nothing is held back for a second look. P(correct) (the doubt ``CAL``) is the best of the
fixed scores and a cross-fitted logistic model (:func:`~vpr_uncertainty.calibration.calibrator.select_calibrator`).
With a target precision every candidate ranking is certified at its share of δ on all labelled queries
(:mod:`~vpr_uncertainty.calibration.guarantee`): cuts are fixed from the scores alone, the fitted model is
cross-fitted (each labelled query is judged by the fold model that did not see it), and the certified rule that
accepts the most correct labelled queries is kept. The gate gives P from the selected calibrator and accepts what
that rule accepts: for a training-free ranking exactly the certified rule; for ``"CAL"`` the model refitted on all
labels at the certified coverage, so the guarantee is approximate there.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from vpr_uncertainty import __version__
from vpr_uncertainty._validation import check_count, check_k
from vpr_uncertainty.calibration.calibrator import (
    DEFAULT_FEATURES,
    FOLDS,
    Calibrator,
    check_both_outcomes,
    check_features,
    check_model,
    columns,
    feature_columns,
    fit_calibrator,
    fit_model,
    select_calibrator,
)
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.calibration.guarantee import (
    DEFAULT_SHARES,
    FALLBACK,
    certify_rankings,
    check_rankings,
    default_rankings,
    needed_message,
)
from vpr_uncertainty.evaluation.metrics import answerable_queries, correct_at_n

if TYPE_CHECKING:
    from vpr_uncertainty.retrieval import Retrieval

__all__ = ["calibrate", "calibrate_arrays", "fingerprint"]


def fingerprint(scores: np.ndarray, correct: np.ndarray) -> str:
    """SHA-256 (first 16 hex digits) of the calibration scores (float64) and labels: which data made a gate."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(scores, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(correct, dtype=bool).tobytes())
    return digest.hexdigest()[:16]


def calibrate_arrays(
    scores: np.ndarray,
    correct: np.ndarray,
    *,
    answerable: np.ndarray | None = None,
    target_precision: float | None = None,
    delta: float = 0.1,
    k: int = 10,
    seed: int = 0,
    model: str = "logistic",
    features: Sequence[str] | None = None,
    rankings: Sequence[str] | dict[str, float] | None = None,
    unlabelled: np.ndarray | None = None,
    folds: int = FOLDS,
) -> Gate:
    """:func:`calibrate` on arrays: top-k ``scores`` (Q, K), top-1 ``correct`` (Q,), ``unlabelled`` (U, K)."""
    correct = np.asarray(correct, dtype=bool)
    scores = np.asarray(scores)
    if scores.ndim != 2 or correct.shape != (scores.shape[0],):
        raise ValueError(f"scores (Q, K) and correct (Q,) must match, got {scores.shape} and {correct.shape}")
    check_both_outcomes(correct)
    k = min(check_k(k), scores.shape[1])  # the gate reads (and refuses rows other than) what the features read
    check_count(folds, "folds", 2)
    check_model(model)
    answerable = np.ones(correct.size, bool) if answerable is None else np.asarray(answerable, dtype=bool)
    if unlabelled is not None:
        unlabelled = np.asarray(unlabelled)
        if unlabelled.ndim != 2 or unlabelled.shape[1] < k:
            raise ValueError(f"unlabelled must be top-k scores of shape (U, >= {k}), got {unlabelled.shape}")
    pool_scores = scores
    if unlabelled is not None and unlabelled.size:
        width = min(scores.shape[1], unlabelled.shape[1])
        pool_scores = np.concatenate([scores[:, :width], unlabelled[:, :width]]).astype(np.float64)
    model_features = DEFAULT_FEATURES if features is None else check_features(features)
    pool_features = feature_columns(pool_scores, k, model_features if features is not None else ())
    labelled_features = {name: column[: correct.size] for name, column in pool_features.items()}
    model_features = tuple(name for name in model_features if name in pool_features)
    shares, fallback_share = DEFAULT_SHARES, FALLBACK
    if rankings is None and target_precision is not None:
        shares, fallback_share = default_rankings(correct.size, target_precision, delta)
    shares = check_rankings(shares if rankings is None else rankings, labelled_features)
    info: dict[str, Any] = {
        "toolkit_version": __version__,
        "target_precision": target_precision,
        "delta": delta if target_precision is not None else None,
        "calibration": {
            "n_queries": int(correct.size),
            "n_correct": int(correct.sum()),
            "n_unlabelled": 0 if unlabelled is None else int(unlabelled.shape[0]),
            "fingerprint": fingerprint(scores[:, :k], correct),
            "min_candidates": int(np.isfinite(pool_scores[:, :k]).sum(axis=1).min()),
            "seed": seed,
            "folds": folds,
        },
    }

    def fallback() -> Calibrator:
        """P without a certified ranking: the choice of :func:`select_calibrator` (or what the caller fixed)."""
        if model == "isotonic":
            return fit_calibrator(labelled_features["SU"][:, None], correct, feature_names=("SU",), model="isotonic")
        if features is not None:
            return replace(
                fit_model(columns(labelled_features, model_features), correct, model_features), ranking="CAL"
            )
        calibrator, selection = select_calibrator(
            labelled_features, correct, model_features=model_features, folds=folds, seed=seed
        )
        info["selection"] = {"chosen": calibrator.ranking, "average_precision": selection}
        return calibrator

    info["selection"] = None
    calibrator = fallback()  # P: the selection's calibrator, certified or not
    if target_precision is None:
        info.update(precision_lower_bound=None, expected_recall=None, expected_coverage=None, certificate=None)
        return Gate(calibrator, k, _half_way_cut(calibrator), info)
    if not 0.0 < delta < 1.0:
        raise ValueError(f"delta must lie in (0, 1), got {delta}")
    certificate, rule, cut = certify_rankings(
        labelled_features,
        pool_features,
        correct,
        answerable,
        shares=shares,
        model_features=model_features,
        target_precision=target_precision,
        delta=delta,
        folds=folds,
        seed=seed,
        fallback=fallback_share,
    )
    message = certificate.message
    if rule is None:  # nothing certified: the gate accepts nothing
        message += "; " + needed_message(
            calibrator.confidence(columns(labelled_features, calibrator.features)), correct, target_precision, delta
        )
    info["rankings"] = {name: outcome["delta"] for name, outcome in certificate.rankings.items()}
    info.update(
        precision_lower_bound=certificate.precision_lower_bound,
        expected_recall=certificate.expected_recall,
        expected_coverage=certificate.expected_coverage,
        certificate={**certificate.to_dict(), "message": message},
    )
    return Gate(calibrator, k, cut, info, rule=rule)


def _half_way_cut(calibrator: Calibrator) -> float:
    """The confidence at which P = 0.5 (logistic: 0; isotonic: halfway below the first step at ≥ 0.5)."""
    if calibrator.model != "isotonic":
        return 0.0
    above = np.flatnonzero(np.asarray(calibrator.y) >= 0.5)
    if not above.size:
        return math.inf
    first = int(above[0])
    # halfway to the next lower breakpoint, so that no calibration query sits exactly on the cut
    return calibrator.x[first] - 1.0 if first == 0 else 0.5 * (calibrator.x[first - 1] + calibrator.x[first])


def calibrate(
    retrieval: Retrieval,
    *,
    target_precision: float | None = None,
    delta: float = 0.1,
    k: int = 10,
    seed: int = 0,
    model: str = "logistic",
    features: Sequence[str] | None = None,
    rankings: Sequence[str] | dict[str, float] | None = None,
    unlabelled: Retrieval | np.ndarray | None = None,
    folds: int = FOLDS,
) -> Gate:
    """Fit P(correct top-1) on labelled queries and, given a target precision, a threshold that guarantees it.

    Parameters
    ----------
    retrieval : Retrieval
        Calibration queries with their ground truth (``retrieval.positives``).
    target_precision : float in (0, 1), optional
        p*: with probability ≥ 1 − δ over the draw of the calibration queries, the precision of the accepted
        answers on new queries from the same distribution is ≥ p*. Without it the gate accepts P ≥ 0.5 and
        certifies nothing.
    delta : float in (0, 1), default=0.1
        The risk δ, shared by the candidate rankings (``rankings``).
    k : int, default=10
        Candidates per query the features read.
    seed : int, default=0
        Seed of the cross-fitting folds.
    model : {"logistic", "isotonic"}, default="logistic"
        ``"logistic"``: P from the best of the fixed scores and a logistic model (:func:`select_calibrator`);
        ``"isotonic"``: isotonic regression on SU. P only: the certified rule does not depend on it.
    features : sequence of str, optional
        Features of the logistic model; given, the model is used as it is (no choice among fixed scores).
        Default :data:`~vpr_uncertainty.calibration.calibrator.DEFAULT_FEATURES`.
    rankings : sequence of str or dict of str to float, optional
        Candidate rankings of the certified rule, from :data:`RANKINGS` and ``"CAL"`` (the cross-fitted model): a
        list shares δ evenly, a dict gives each name its share. Default: by the number of labelled queries
        (:func:`~vpr_uncertainty.calibration.guarantee.default_rankings`): SU alone at the whole δ below
        6 × ⌈log δ / log p*⌉ (132 for p* = 0.9, δ = 0.1), SU and CAL at δ/2 each below 8 ×, then
        :data:`~vpr_uncertainty.calibration.guarantee.DEFAULT_SHARES`.
    unlabelled : Retrieval or ndarray of shape (U, K), optional
        Further queries without labels (e.g. the rest of the traversal): the candidate cuts are quantiles over
        these and the labelled ones. Their labels are never read. The cuts then accept a random number of
        labelled queries, sometimes fewer than the test needs: on the corridor simulations this lowered the
        certified recall (docs/evidence/calibration.md), so the default places the cuts on the labelled queries' scores.
    folds : int, default=5
        Cross-fitting folds of the model.

    Returns
    -------
    Gate
        With ``precision_lower_bound``, ``expected_recall`` and ``threshold``; ``gate.info["certificate"]``
        names the winning ``ranking`` and gives each ranking's outcome and δ (``rankings``). When nothing can be
        certified the gate accepts nothing and the message says why and how many labelled queries would be needed.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> scores = -np.sort(-rng.uniform(0.2, 0.9, size=(300, 10)), axis=1)
    >>> from vpr_uncertainty.retrieval import Retrieval
    >>> labelled = Retrieval(scores, np.tile(np.arange(10), (300, 1)), np.eye(300, 10, dtype=bool)[:, ::-1])
    >>> gate = calibrate(labelled, target_precision=0.9)   # random labels: nothing can be certified
    >>> gate.precision_lower_bound is None
    True
    """
    if retrieval.positives is None:
        raise ValueError("calibration needs the ground truth of the queries (argument ground_truth)")
    return calibrate_arrays(
        retrieval.scores,
        correct_at_n(retrieval.indices, retrieval.positives, 1),
        answerable=answerable_queries(retrieval.positives),
        target_precision=target_precision,
        delta=delta,
        k=k,
        seed=seed,
        model=model,
        features=features,
        rankings=rankings,
        unlabelled=unlabelled if unlabelled is None or isinstance(unlabelled, np.ndarray) else unlabelled.scores,
        folds=folds,
    )
