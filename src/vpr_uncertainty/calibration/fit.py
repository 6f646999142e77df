""":func:`calibrate`: labelled calibration queries in, a :class:`~vpr_uncertainty.calibration.gate.Gate` out; and
:func:`plan_labels` and :func:`simulate_guarantee`, how many labels that takes and how often the guarantee holds.

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
from dataclasses import asdict, dataclass, field, replace
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
    feature_matrix,
    fit_calibrator,
    fit_logistic,
    fit_model,
    select_calibrator,
)
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.calibration.guarantee import (
    DEFAULT_SHARES,
    certify_rankings,
    check_rankings,
    min_accepted,
    needed_message,
)
from vpr_uncertainty.evaluation.metrics import answerable_queries, correct_at_n, rank_queries
from vpr_uncertainty.progress import progress_bar

if TYPE_CHECKING:
    from vpr_uncertainty.retrieval import Retrieval

__all__ = [
    "DEFAULT_SIZES",
    "GuaranteeSimulation",
    "LabelPlan",
    "calibrate",
    "calibrate_arrays",
    "fingerprint",
    "hindsight_recall",
    "plan_labels",
    "simulate_guarantee",
]


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
    shares = check_rankings(DEFAULT_SHARES if rankings is None else rankings, labelled_features)
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
    )
    message = certificate.message
    if rule is None:  # nothing certified: the gate accepts nothing
        message += "; " + needed_message(
            calibrator.confidence(columns(labelled_features, calibrator.features)), correct, target_precision, delta
        )
    info["rankings"] = {name: share * delta for name, share in shares.items()}
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
        list shares δ evenly, a dict gives each name its share. Default
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


#: The calibration sizes :func:`plan_labels` simulates by default.
DEFAULT_SIZES: tuple[int, ...] = (25, 50, 100, 200, 400, 800, 1600)


@dataclass
class LabelPlan:
    """The outcome of :func:`plan_labels`.

    Attributes
    ----------
    sizes : list of int
        Calibration sizes simulated.
    certified : list of float
        Per size, the share of draws that certify p*.
    useful : list of float
        Per size, the share of draws that certify with an expected recall ≥ ``useful_fraction`` × oracle.
    mean_recall : list of float
        Per size, the mean expected recall on all queries (0 for draws that certify nothing).
    oracle_recall : float
        The plug-in recall of the best SU cut at p*.
    needed : int or None
        The smallest size whose ``useful`` share reaches 1 − δ (None: none of the sizes simulated).
    n_labelled, n_queries : int
        Labels the estimate used, and queries in the pool.
    message : str
        The answer in one or two sentences.
    """

    sizes: list[int]
    certified: list[float]
    useful: list[float]
    mean_recall: list[float]
    oracle_recall: float
    needed: int | None
    n_labelled: int
    n_queries: int
    target_precision: float
    delta: float
    useful_fraction: float
    draws: int
    message: str = ""
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def table(self) -> str:
        """A Markdown table of the simulated sizes."""
        lines = ["| labelled queries | P(certified) | P(useful certificate) | mean recall |", "|---|---|---|---|"]
        rows = zip(self.sizes, self.certified, self.useful, self.mean_recall, strict=True)
        lines += [f"| {size} | {c:.2f} | {u:.2f} | {r:.3f} |" for size, c, u, r in rows]
        return "\n".join(lines)


def _probability(su_labelled: np.ndarray, correct: np.ndarray, su_all: np.ndarray) -> np.ndarray:
    """P(correct) of every query by Platt scaling of −SU on the labels (decreasing in SU)."""
    confidence = -su_labelled
    mean, spread = float(confidence.mean()), float(confidence.std()) or 1.0
    intercept, (slope,) = fit_logistic(((confidence - mean) / spread)[:, None], correct, regularisation=1.0)
    z = intercept + max(float(slope), 0.0) * (-su_all - mean) / spread  # slope >= 0: P decreasing in SU
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def _oracle(probability: np.ndarray, su: np.ndarray, target_precision: float) -> float:
    order = np.argsort(su, kind="stable")
    expected = np.cumsum(probability[order])
    precision = expected / np.arange(1, su.size + 1)
    reaching = np.flatnonzero(precision >= target_precision)
    return float(expected[reaching[-1]] / su.size) if reaching.size else 0.0


def plan_labels(
    scores: np.ndarray,
    labelled_scores: np.ndarray,
    correct: np.ndarray,
    *,
    target_precision: float,
    delta: float = 0.1,
    k: int = 10,
    sizes: Sequence[int] = DEFAULT_SIZES,
    draws: int = 40,
    useful_fraction: float = 0.5,
    seed: int = 0,
    progress: bool | None = None,
) -> LabelPlan:
    """Estimate how many labelled queries certify ``target_precision`` at a useful recall, before labelling them.

    P(correct) of every query is estimated by Platt scaling of SU on the few labels; the whole calibration
    (:func:`calibrate_arrays`, with ``scores`` as its unlabelled pool) is then simulated on draws of n queries with
    labels drawn from those probabilities. A draw is useful when it certifies p* and its expected recall reaches
    ``useful_fraction`` of the best recall any SU cut could have at p* (the plug-in oracle); the answer is the
    smallest n with a useful certificate with probability ≥ 1 − δ. A plug-in estimate, to be read as an order of
    magnitude (33 labels or 300), not as a guarantee.

    Parameters
    ----------
    scores : ndarray of shape (Q, K)
        Top-K similarities of the queries the gate will decide (unlabelled), sorted descending.
    labelled_scores : ndarray of shape (L, K)
        The few labelled queries' scores (may be rows of ``scores``).
    correct : ndarray of shape (L,), bool
        Their top-1 correctness; both outcomes must occur.
    target_precision, delta : float in (0, 1)
        p* and δ, as in :func:`~vpr_uncertainty.calibrate`.
    k : int, default=10
    sizes : sequence of int
        Calibration sizes to simulate.
    draws : int, default=40
        Simulated calibrations per size.
    useful_fraction : float in (0, 1], default=0.5
        A certificate is useful when its expected recall reaches this share of the plug-in SU oracle.
    seed : int, default=0
    progress : bool, optional
        A progress bar over the sizes (default: on a terminal).
    """
    correct = np.asarray(correct, dtype=bool)
    scores = np.asarray(scores, dtype=np.float64)
    labelled_scores = np.asarray(labelled_scores, dtype=np.float64)
    if labelled_scores.ndim != 2 or correct.shape != (labelled_scores.shape[0],):
        raise ValueError(
            f"labelled_scores (L, K) and correct (L,) must match, got {labelled_scores.shape} and {correct.shape}"
        )
    if min(int(correct.sum()), int((~correct).sum())) < 2:
        raise ValueError(
            f"a label plan needs at least 2 correct and 2 wrong labelled answers, got {int(correct.sum())} correct "
            f"of {correct.size}: label a few more queries (a random handful is enough to start)"
        )
    if not 0.0 < useful_fraction <= 1.0:
        raise ValueError(f"useful_fraction must lie in (0, 1], got {useful_fraction}")
    check_count(draws, "draws", 1)
    sizes = sorted({int(size) for size in sizes})
    if not sizes or sizes[0] < 2:
        raise ValueError(f"sizes must be integers >= 2, got {sizes}")
    min_accepted(target_precision, delta)  # checks p* and δ
    su_all = feature_matrix(scores, k=k, features=("SU",))[:, 0]
    su_labelled = feature_matrix(labelled_scores, k=k, features=("SU",))[:, 0]
    probability = _probability(su_labelled, correct, su_all)
    oracle = _oracle(probability, su_all, target_precision)
    rng = np.random.default_rng(seed)
    certified, useful, mean_recall = [], [], []
    for size in progress_bar(sizes, desc="simulating calibration sizes", unit="size", enabled=progress):
        hits, good, recall_sum = 0, 0, 0.0
        for _ in range(draws):
            rows = rng.choice(scores.shape[0], size, replace=True)
            labels = rng.random(size) < probability[rows]
            if labels.all() or not labels.any():
                continue  # nothing can be calibrated on one outcome: certifies nothing
            gate = calibrate_arrays(
                scores[rows],
                labels,
                target_precision=target_precision,
                delta=delta,
                k=k,
                seed=int(rng.integers(1 << 31)),
                unlabelled=scores,
            )
            if gate.precision_lower_bound is None:
                continue
            recall = float(probability[gate.accept(scores[:, : gate.k])].sum() / scores.shape[0])
            hits += 1
            recall_sum += recall
            good += recall >= useful_fraction * oracle
        certified.append(hits / draws)
        useful.append(good / draws)
        mean_recall.append(recall_sum / draws)
    needed = next((size for size, share in zip(sizes, useful, strict=True) if share >= 1 - delta), None)
    have = labelled_scores.shape[0]
    if needed is None:
        message = (
            f"none of the simulated sizes (up to {sizes[-1]} labelled queries) certifies precision "
            f"{target_precision:g} at a useful recall with probability {1 - delta:g}"
        )
    else:
        message = f"about {needed} labelled queries certify precision {target_precision:g} at a useful recall"
        message += f" (≥ {useful_fraction:g} × the best SU cut's {oracle:.2f}) with probability ≥ {1 - delta:g}"
    if needed is None or have < needed:
        message += f"; with the {have} labelled now, the expected certified recall is about "
        below = [recall for size, recall in zip(sizes, mean_recall, strict=True) if size <= have]
        message += f"{below[-1]:.2f}" if below else "0 (none)"
    notes = [
        f"P(correct) estimated from {have} labels by Platt scaling of SU (a plug-in estimate: an order of magnitude)"
    ]
    return LabelPlan(
        sizes=sizes,
        certified=certified,
        useful=useful,
        mean_recall=mean_recall,
        oracle_recall=oracle,
        needed=needed,
        n_labelled=have,
        n_queries=int(scores.shape[0]),
        target_precision=target_precision,
        delta=delta,
        useful_fraction=useful_fraction,
        draws=draws,
        message=message,
        notes=notes,
    )


@dataclass
class GuaranteeSimulation:
    """Per draw: population precision (NaN when nothing is accepted), recall and coverage; and the summary."""

    precision: np.ndarray
    recall: np.ndarray
    coverage: np.ndarray
    certified: np.ndarray
    target_precision: float
    delta: float
    hindsight_recall: float

    @property
    def violation_rate(self) -> float:
        """Share of draws whose accepted answers have population precision < p* (draws accepting none never do)."""
        return float(np.mean(np.nan_to_num(self.precision, nan=1.0) < self.target_precision))

    @property
    def mean_recall(self) -> float:
        return float(self.recall.mean())


def hindsight_recall(uncertainty: np.ndarray, correct: np.ndarray, target_precision: float, n_answerable: int) -> float:
    """Largest end-to-end recall of a cut on ``uncertainty`` (accept ≤ cut) with precision ≥ p*, ties kept together."""
    ranking = rank_queries(correct, uncertainty)
    ok = ranking.correct_accepted / ranking.accepted >= target_precision
    return float(ranking.correct_accepted[ok].max() / max(n_answerable, 1)) if ok.any() else 0.0


def simulate_guarantee(
    scores: np.ndarray,
    correct: np.ndarray,
    *,
    n_calibration: int,
    target_precision: float = 0.9,
    delta: float = 0.1,
    n_draws: int = 200,
    seed: int = 0,
    k: int = 10,
    model: str = "logistic",
    rankings: Sequence[str] | dict[str, float] | None = None,
    unlabelled: bool = False,
    answerable: np.ndarray | None = None,
) -> GuaranteeSimulation:
    """Calibrate on ``n_draws`` i.i.d. draws of ``n_calibration`` queries and measure each gate on the population.

    Draws are **with replacement**, so i.i.d. from the population (the assumption of the guarantee), and the
    population precision among each gate's accepted answers is known exactly: the guarantee says the share of
    draws below p* is at most δ. The hindsight reference is the largest recall of any SU cut with precision ≥ p* on
    the whole population. With ``unlabelled=True`` every draw also passes the whole population's scores as
    unlabelled queries (the robot's own traversal). Draws that hold only one outcome cannot be calibrated; they
    are redrawn.
    """
    correct = np.asarray(correct, dtype=bool)
    answerable = np.ones(correct.size, bool) if answerable is None else np.asarray(answerable, dtype=bool)
    rng = np.random.default_rng(seed)
    precision, recall, coverage, certified = (np.zeros(n_draws) for _ in range(4))
    n_answerable = int(answerable.sum())
    for draw in range(n_draws):
        rows = rng.choice(correct.size, n_calibration, replace=True)
        while correct[rows].all() or not correct[rows].any():
            rows = rng.choice(correct.size, n_calibration, replace=True)
        gate = calibrate_arrays(
            scores[rows],
            correct[rows],
            answerable=answerable[rows],
            target_precision=target_precision,
            delta=delta,
            k=k,
            seed=draw,
            model=model,
            rankings=rankings,
            unlabelled=scores if unlabelled else None,
        )
        accepted = gate.accept(scores[:, : gate.k])
        n_accepted = int(accepted.sum())
        good = int((accepted & correct).sum())
        precision[draw] = good / n_accepted if n_accepted else np.nan
        recall[draw] = good / max(n_answerable, 1)
        coverage[draw] = n_accepted / correct.size
        certified[draw] = gate.precision_lower_bound is not None
    su = feature_matrix(scores, k=k, features=("SU",))[:, 0]
    return GuaranteeSimulation(
        precision=precision,
        recall=recall,
        coverage=coverage,
        certified=certified.astype(bool),
        target_precision=target_precision,
        delta=delta,
        hindsight_recall=hindsight_recall(su, correct, target_precision, n_answerable),
    )
