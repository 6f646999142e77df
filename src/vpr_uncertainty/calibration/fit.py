""":func:`calibrate`: labelled calibration queries in, a :class:`~vpr_uncertainty.calibration.gate.Gate` out.

Without a target precision, the calibrator is fitted on every calibration query and the gate accepts P ≥ 0.5.

With a target precision p* and a risk δ the calibration queries are split (stratified by correctness, seeded)
into a *fit* part and a *test* part, so that the threshold test never reuses the data the probabilities were
fitted on:

1. the ranking model is fitted on the fit part (the logistic calibrator; the isotonic one ranks by −SU and needs
   no fit), and the candidate cuts are read from the fit part;
2. Learn-then-Test (:mod:`~vpr_uncertainty.calibration.guarantee`) picks the cut on the test part;
3. the probabilities are then recalibrated on all calibration queries by a map that is strictly increasing in the
   confidence (Platt scaling of the linear score; isotonic regression on −SU), which leaves every acceptance set,
   and so the guarantee, unchanged while using every label for P.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from vpr_uncertainty.calibration.calibrator import Calibrator, fit_calibrator, fit_logistic
from vpr_uncertainty.calibration.features import DEFAULT_FEATURES, feature_matrix
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.calibration.guarantee import candidate_cuts, certify_threshold, min_accepted

if TYPE_CHECKING:
    from vpr_uncertainty.retrieval import Retrieval

__all__ = ["calibrate", "calibrate_arrays", "fingerprint", "stratified_split"]


def fingerprint(scores: np.ndarray, correct: np.ndarray) -> str:
    """SHA-256 (first 16 hex digits) of the calibration scores (float64) and labels: which data made a gate."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(scores, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(correct, dtype=bool).tobytes())
    return digest.hexdigest()[:16]


def stratified_split(correct: np.ndarray, fraction: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Indices (first, second): ``fraction`` of each class (rounded, at least one of each when possible) first."""
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction must lie in (0, 1), got {fraction}")
    first, second = [], []
    for label in (True, False):
        members = rng.permutation(np.flatnonzero(correct == label))
        count = round(fraction * members.size)
        if members.size >= 2:
            count = min(max(count, 1), members.size - 1)
        first.append(members[:count])
        second.append(members[count:])
    return np.sort(np.concatenate(first)), np.sort(np.concatenate(second))


def _needed_message(confidence: np.ndarray, correct: np.ndarray, p_star: float, delta: float, test: float) -> str:
    """How many labelled queries would be needed, estimated from the in-sample precision of the confidence."""
    order = np.argsort(-confidence, kind="stable")
    precision = np.cumsum(correct[order]) / np.arange(1, correct.size + 1)
    reaching = np.flatnonzero(precision >= p_star)
    n_min = min_accepted(p_star, delta)
    if reaching.size == 0:
        return "no confidence cut reaches that precision even on the calibration queries themselves"
    share = (reaching[-1] + 1) / correct.size
    needed = math.ceil(n_min / (share * test))
    return (
        f"at most {share:.0%} of the queries are accepted at precision {p_star:g} (in-sample), so about {needed} "
        f"labelled queries would be needed ({n_min} accepted ones in the test part of {test:.0%})"
    )


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
    test_fraction: float = 0.5,
    features_matrix: np.ndarray | None = None,
) -> Gate:
    """:func:`calibrate` on arrays: top-k ``scores`` (Q, K) and top-1 ``correct`` (Q,).

    ``features_matrix`` (Q, F), when given, must be ``feature_matrix(scores, k=k, features=features)``: callers
    that calibrate many subsets of one retrieval compute it once.
    """
    names = tuple(features or (("SU",) if model == "isotonic" else DEFAULT_FEATURES))
    correct = np.asarray(correct, dtype=bool)
    scores = np.asarray(scores)
    matrix = feature_matrix(scores, k=k, features=names) if features_matrix is None else features_matrix
    if matrix.shape != (correct.size, len(names)):
        raise ValueError(f"features_matrix must have shape ({correct.size}, {len(names)}), got {matrix.shape}")
    answerable = np.ones(correct.size, bool) if answerable is None else np.asarray(answerable, dtype=bool)
    info = {
        "toolkit_version": _version(),
        "target_precision": target_precision,
        "delta": delta if target_precision is not None else None,
        "calibration": {
            "n_queries": int(correct.size),
            "n_correct": int(correct.sum()),
            "fingerprint": fingerprint(scores[:, :k], correct),
            "seed": seed,
        },
    }
    if target_precision is None:
        calibrator = fit_calibrator(matrix, correct, feature_names=names, model=model)
        if model == "isotonic":
            above = np.flatnonzero(np.asarray(calibrator.y) >= 0.5)
            first = int(above[0]) if above.size else -1
            # halfway to the next lower breakpoint, so that no calibration query sits exactly on the cut
            cut = (
                math.inf
                if first < 0
                else (
                    calibrator.x[first] - 1.0 if first == 0 else 0.5 * (calibrator.x[first - 1] + calibrator.x[first])
                )
            )
        else:
            cut = 0.0
        info.update(precision_lower_bound=None, expected_recall=None, expected_coverage=None, certificate=None)
        return Gate(calibrator, k, cut, info)
    if not 0.0 < test_fraction < 1.0:
        raise ValueError(f"test_fraction must lie in (0, 1), got {test_fraction}")
    test, fit = stratified_split(correct, test_fraction, np.random.default_rng(seed))
    ranking = fit_calibrator(matrix[fit], correct[fit], feature_names=names, model=model)
    confidence = ranking.confidence(matrix)
    cuts = candidate_cuts(confidence[fit], test.size, target_precision, delta)
    certificate = certify_threshold(
        confidence[test],
        correct[test],
        cuts,
        target_precision=target_precision,
        delta=delta,
        answerable=answerable[test],
    )
    calibrator, cut = _recalibrate(ranking, matrix, correct, confidence, certificate.cut)
    message = certificate.message
    if not certificate.certified:
        message += "; " + _needed_message(confidence, correct, target_precision, delta, test_fraction)
    info["calibration"].update(n_fit=int(fit.size), n_test=int(test.size), test_fraction=test_fraction)
    info.update(
        precision_lower_bound=certificate.precision_lower_bound,
        expected_recall=certificate.expected_recall,
        expected_coverage=certificate.expected_coverage,
        certificate={**certificate.to_dict(), "message": message},
    )
    return Gate(calibrator, k, cut, info)


def _recalibrate(
    ranking: Calibrator, matrix: np.ndarray, correct: np.ndarray, confidence: np.ndarray, cut: float | None
) -> tuple[Calibrator, float]:
    """P refitted on all queries by a strictly increasing map of the confidence; the cut mapped along."""
    cut = math.inf if cut is None else cut
    if ranking.model == "isotonic":
        return fit_calibrator(matrix, correct, feature_names=ranking.features, model="isotonic"), cut
    spread = float(confidence.std()) or 1.0
    intercept, (slope,) = fit_logistic((confidence / spread)[:, None], correct, regularisation=1.0)
    slope /= spread
    if not slope > 0:  # the fit-part ranking carries no signal on all queries: keep its own probabilities
        return ranking, cut
    calibrator = Calibrator(
        model="logistic",
        features=ranking.features,
        mean=ranking.mean,
        scale=ranking.scale,
        coef=[slope * c for c in ranking.coef],
        intercept=slope * ranking.intercept + intercept,
        regularisation=ranking.regularisation,
    )
    return calibrator, (cut if math.isinf(cut) else slope * cut + intercept)


def _version() -> str:
    from vpr_uncertainty import __version__

    return __version__


def calibrate(
    retrieval: Retrieval,
    *,
    target_precision: float | None = None,
    delta: float = 0.1,
    k: int = 10,
    seed: int = 0,
    model: str = "logistic",
    features: Sequence[str] | None = None,
    test_fraction: float = 0.5,
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
        The risk δ.
    k : int, default=10
        Candidates per query the features read.
    seed : int, default=0
        Seed of the fit/test split.
    model : {"logistic", "isotonic"}, default="logistic"
        Logistic regression on standardised features, or isotonic regression on SU.
    features : sequence of str, optional
        Features of the logistic model (default :data:`~vpr_uncertainty.calibration.features.DEFAULT_FEATURES`).
    test_fraction : float in (0, 1), default=0.5
        Share of the calibration queries (of each outcome) kept for the threshold test.

    Returns
    -------
    Gate
        With ``threshold``, ``precision_lower_bound`` and ``expected_recall``; when nothing can be certified the
        gate accepts nothing and ``gate.info["certificate"]["message"]`` says why and how many labelled queries
        would be needed.
    """
    if retrieval.positives is None:
        raise ValueError("calibration needs the ground truth of the queries (argument ground_truth)")
    from vpr_uncertainty.evaluation import correct_at_n

    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    answerable = np.asarray(retrieval.positives.sum(axis=1)).ravel() > 0
    return calibrate_arrays(
        retrieval.scores,
        correct,
        answerable=answerable,
        target_precision=target_precision,
        delta=delta,
        k=k,
        seed=seed,
        model=model,
        features=features,
        test_fraction=test_fraction,
    )
