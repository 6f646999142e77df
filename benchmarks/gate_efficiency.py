"""How much a precision-guaranteed gate accepts: the toolkit's gate against MAPIE and plain fixed-sequence testing.

A gate accepts a query's top-1 answer when its confidence passes a cut chosen on n labelled calibration queries so
that, with probability >= 1 - delta over the calibration draw, the precision of the accepted answers on the
population is >= p*. Every procedure below makes that promise; this benchmark measures, on the same draws, how
often the promise is broken and how much each one accepts.

Populations
    Each of the ten VPR-Bench corridor matrices (its 111 queries), plus any ``--retrieval`` run (all its queries).
    A calibration draw takes n queries of one population i.i.d. **with replacement** (redrawn when it holds only
    one outcome), so the guarantee is exact with respect to that resampled population, whose precision among the
    accepted answers is known exactly. Every procedure sees the same draws (the same rows).

Procedures
    * ``toolkit (default)``: ``calibrate_arrays(scores, correct, answerable=..., target_precision=p*, delta=delta,
      seed=draw)``; the population's accepted answers are ``gate.accept(population scores)``. When the gate records
      ``info["certificate"]["ranking"]``, the winning ranking is tallied per draw.
    * ``toolkit + unlabelled``: the same with ``unlabelled=population scores`` (skipped when calibrate_arrays has
      no such keyword).
    * ``MAPIE ...``: ``mapie.risk_control.BinaryClassificationController(predict_function, risk=precision,
      target_level=p*, confidence_level=1 - delta, fwer_method=...)`` with its default grid
      ``list_predict_params = linspace(0, 0.99, 100)`` and default ``best_predict_param_choice`` (recall), for
      ``fwer_method`` "bonferroni_holm" (MAPIE's default), "fixed_sequence" and "split_fixed_sequence". The
      classifier is a fixed score: ``predict_proba`` returns [1 - p, p] with p = the share of the population's
      queries whose SU is >= the query's SU (a monotone map of -SU fixed by the unlabelled population, which spreads
      the 100 grid points evenly over the population's coverage). All calibration labels are its calibration data,
      except for the split fixed sequence, which learns its order on a random half (``learn_fixed_sequence_order``,
      ``beta_grid = logspace(-25, 0, --sfs-betas)``) and calibrates on the other half. The population's accepted
      answers are ``controller.predict``; a controller with no valid threshold, or one that raises, accepts nothing.
    * ``CP fixed sequence, SU`` / ``..., margin``: written here. Labelled queries ranked by SU (lower = more
      confident) or by the margin s1 - s2 (higher = more confident); the candidate cuts are every distinct labelled
      value, strictest first, starting at the first cut that accepts >= ceil(log delta / log p*) labelled queries;
      H_j "precision < p*" is tested with the exact binomial p-value ``binom.sf(correct - 1, accepted, p*)``; the
      sequence stops at the first p-value > delta and the last rejected cut is kept (nothing when none is). No
      fit/test split.
    * ``CP fixed sequence, SU and margin at delta/2, looser rule``: both of the above at delta/2 (a union bound), and
      the certified rule that accepts more labelled queries is kept.
    * The candidate defaults of issue 29 (``VARIANTS``): ``certify_rankings`` with given shares of delta and chain
      shapes (fallback share, dense part), applied to the population by the rule it returns; "issue-19 procedure"
      is the default before issue 29 (SU alone, SU + CAL at delta/2 from 150 labels, tolerant steps, fixed
      sequence). ``CHOSEN_ON_A_SPLIT``: the ranking chosen by average precision on a share of the labels, certified
      alone at delta on the rest.

Families (``--family``)
    ``resampled``: the populations as loaded. ``contrasting``: made from them by :func:`contrasting`, so that the
    first wrong answers come early by one ranking (SU or the margin) and late by the other.

Metrics (per procedure and n; violations and certifying pooled over populations' draws)
    * violations: share of draws whose population precision among the accepted answers is < p* (a draw accepting
      nothing is no violation); "worst" is the largest per-population share (each should be <= delta up to
      Monte-Carlo noise: its standard error is about 0.03 with 100 draws);
    * certifying: share of draws that accept at least one population query;
    * recall / oracle: mean recall (correct accepted / answerable population queries) over draws, divided by the
      oracle (the largest recall of any SU cut on the whole population with precision >= p*, ties kept together),
      averaged over the populations whose oracle is positive.

Usage
    PYTHONPATH=.bench-packages VPR_UNCERTAINTY_DATA=/path/to/data python benchmarks/gate_efficiency.py \\
        [--draws 100] [--sizes 50,100,200,400] [--retrieval runs/demo/retrieval.npz] [--json out.json]

``make bench-gate`` installs MAPIE 1.6.0 (``--no-deps``) into ``.bench-packages/`` and runs this; without MAPIE
its rows are skipped.
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import os
import sys
import time
import warnings
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from vpr_uncertainty.calibration import calibrate_arrays
from vpr_uncertainty.calibration.calibrator import (
    DEFAULT_FEATURES,
    RANKINGS,
    columns,
    feature_columns,
    select_calibrator,
)
from vpr_uncertainty.calibration.guarantee import DENSE_FROM, FALLBACK, certify_rankings
from vpr_uncertainty.calibration.plan import hindsight_recall
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation import correct_at_n
from vpr_uncertainty.retrieval import Retrieval, load_retrieval
from vpr_uncertainty.scores import statistical_uncertainty

MAPIE_VERSION = "1.6.0"
MAPIE_METHODS = {
    "MAPIE LTT, bonferroni_holm (default)": "bonferroni_holm",
    "MAPIE LTT, fixed_sequence": "fixed_sequence",
    "MAPIE LTT, split_fixed_sequence": "split_fixed_sequence",
}
HOW_TO_GET_MAPIE = (
    f"MAPIE is not importable: its rows are skipped. `make bench-gate` installs mapie=={MAPIE_VERSION} into "
    f".bench-packages/ (pip install --no-deps --target .bench-packages mapie=={MAPIE_VERSION}, then run with "
    "PYTHONPATH=.bench-packages)"
)

#: What a procedure returns for one draw: the accepted population queries (Q,) and a note to tally (or None).
Outcome = tuple[np.ndarray, str | None]
#: A procedure: (population, calibration rows, draw index, settings) -> Outcome.
Procedure = Callable[["Population", np.ndarray, int, "Settings"], Outcome]


@dataclass
class Population:
    """One labelled population: top-k scores, top-1 correctness, answerability and the two fixed confidences."""

    name: str
    scores: np.ndarray
    correct: np.ndarray
    answerable: np.ndarray
    su: np.ndarray = field(init=False)
    margin: np.ndarray = field(init=False)
    oracle: float = field(init=False)
    features: dict[str, np.ndarray] = field(init=False)
    target_precision: float = 0.9

    def __post_init__(self) -> None:
        self.su = statistical_uncertainty(self.scores, 10)
        self.margin = self.scores[:, 0] - self.scores[:, 1]
        self.features = feature_columns(self.scores.astype(np.float64), 10)
        self.oracle = hindsight_recall(self.su, self.correct, self.target_precision, int(self.answerable.sum()))

    @property
    def size(self) -> int:
        return int(self.correct.size)


@dataclass(frozen=True)
class Settings:
    """What every procedure needs besides the data."""

    target_precision: float
    delta: float
    seed: int
    sfs_betas: int


# --- the populations ---------------------------------------------------------------------------------------------


def _population(name: str, retrieval: Retrieval, target_precision: float) -> Population:
    if retrieval.positives is None:
        raise ValueError(f"{name}: the retrieval has no ground truth (positives)")
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    answerable = np.asarray(retrieval.positives.sum(axis=1)).ravel() > 0
    return Population(name, np.asarray(retrieval.scores), correct, answerable, target_precision=target_precision)


def load_populations(data: Path | None, extra: list[Path], target_precision: float) -> list[Population]:
    """The ten corridor matrices under ``data/vprbench`` (when given) and the ``--retrieval`` files."""
    found = []
    if data is not None:
        root = data / "vprbench"
        gt = root / "corridor/ground_truth_new.npy"
        for folder in sorted((root / "precomputed_matches/corridor").iterdir()):
            retrieval = read_results(folder / "precomputed_data_corrected.npy", ground_truth=gt)
            found.append(_population(folder.name, retrieval, target_precision))
    for path in extra:
        found.append(_population(f"{path.parent.name}/{path.name} (own run)", load_retrieval(path), target_precision))
    return found


def contrasting(population: Population, early: str, top: float = 0.2, clean: float = 0.4) -> Population | None:
    """A population whose first wrong answer comes early in one ranking and late in the other (SU, margin).

    Keeps one wrong answer among the ``top`` share most confident by ``early`` that is outside the ``clean`` share
    most confident by the other ranking, and drops every other wrong answer inside that share of the other ranking:
    by ``early`` a wrong answer sits near the top, by the other none comes before about ``clean`` of the queries.
    None when no wrong answer qualifies. Draws from it are i.i.d. like any other population's.
    """
    confidence = {"SU": -population.su, "margin": population.margin}
    late = "margin" if early == "SU" else "SU"
    rank = {name: np.argsort(np.argsort(-value, kind="stable")) for name, value in confidence.items()}
    wrong, n = ~population.correct, population.size
    candidates = np.flatnonzero(wrong & (rank[early] < top * n) & (rank[late] >= clean * n))
    if not candidates.size:
        return None
    keep = ~(wrong & (rank[late] < clean * n))
    keep[candidates[np.argmin(rank[early][candidates])]] = True
    return Population(
        f"{population.name}, early {early}",
        population.scores[keep],
        population.correct[keep],
        population.answerable[keep],
        target_precision=population.target_precision,
    )


def calibration_draws(population: Population, n: int, draws: int, seed: int, index: int) -> np.ndarray:
    """(draws, n) row indices drawn i.i.d. with replacement; a draw with a single outcome is redrawn."""
    rng = np.random.default_rng([seed, index, n])
    rows = np.empty((draws, n), dtype=np.intp)
    for draw in range(draws):
        pick = rng.choice(population.size, n, replace=True)
        while population.correct[pick].all() or not population.correct[pick].any():
            pick = rng.choice(population.size, n, replace=True)
        rows[draw] = pick
    return rows


# --- the toolkit -------------------------------------------------------------------------------------------------


def supports_unlabelled() -> bool:
    """Whether the installed ``calibrate_arrays`` takes the ``unlabelled`` keyword."""
    return "unlabelled" in inspect.signature(calibrate_arrays).parameters


def _toolkit(population: Population, rows: np.ndarray, draw: int, settings: Settings, **extra: Any) -> Outcome:
    gate = calibrate_arrays(
        population.scores[rows],
        population.correct[rows],
        answerable=population.answerable[rows],
        target_precision=settings.target_precision,
        delta=settings.delta,
        seed=draw,
        **extra,
    )
    ranking = (gate.info.get("certificate") or {}).get("ranking")
    accepted = np.asarray(gate.accept(population.scores[:, : gate.k]), dtype=bool)
    return accepted, None if ranking is None else str(ranking)


def toolkit_default(population: Population, rows: np.ndarray, draw: int, settings: Settings) -> Outcome:
    """``calibrate_arrays`` on the labelled draw only."""
    return _toolkit(population, rows, draw, settings)


def toolkit_unlabelled(population: Population, rows: np.ndarray, draw: int, settings: Settings) -> Outcome:
    """``calibrate_arrays`` given the population's scores as unlabelled queries."""
    return _toolkit(population, rows, draw, settings, unlabelled=population.scores)


THIRDS = {"margin": 1 / 3, "SU": 1 / 3, "CAL": 1 / 3}
#: Candidate procedures: (shares of delta, fallback, dense_from); shares may depend on n (a callable).
VARIANTS: dict[str, tuple[Any, float, float]] = {
    "issue-19 procedure: SU; SU + CAL at delta/2 from n = 150 (tolerant steps, fixed sequence)": (
        lambda n: {"SU": 1.0} if n < 150 else {"SU": 0.5, "CAL": 0.5},
        0.0,
        1.0,
    ),
    "chain, margin only": ({"margin": 1.0}, FALLBACK, DENSE_FROM),
    "chain, SU only": ({"SU": 1.0}, FALLBACK, DENSE_FROM),
    "chain, margin 0.5 + SU 0.5": ({"margin": 0.5, "SU": 0.5}, FALLBACK, DENSE_FROM),
    "chain without fallback, margin 0.5 + SU 0.5": ({"margin": 0.5, "SU": 0.5}, 0.0, DENSE_FROM),
    "chain, fallback 0.5, margin 0.5 + SU 0.5": ({"margin": 0.5, "SU": 0.5}, 0.5, DENSE_FROM),
    "chain dense from the start, margin 0.5 + SU 0.5": ({"margin": 0.5, "SU": 0.5}, FALLBACK, 0.0),
    "chain, margin 0.9 + SU 0.1": ({"margin": 0.9, "SU": 0.1}, FALLBACK, DENSE_FROM),
    "chain, margin 0.7 + SU 0.3": ({"margin": 0.7, "SU": 0.3}, FALLBACK, DENSE_FROM),
    "chain, SU 0.7 + margin 0.3": ({"SU": 0.7, "margin": 0.3}, FALLBACK, DENSE_FROM),
    "chain, margin + SU + BM, 1/3 each": ({"margin": 1 / 3, "SU": 1 / 3, "BM": 1 / 3}, FALLBACK, DENSE_FROM),
    "chain without fallback, margin + SU + BM, 1/3 each": ({"margin": 1 / 3, "SU": 1 / 3, "BM": 1 / 3}, 0, DENSE_FROM),
    "chain, margin + SU + CAL, 1/3 each": ({"margin": 1 / 3, "SU": 1 / 3, "CAL": 1 / 3}, FALLBACK, DENSE_FROM),
    "chain without fallback, margin + SU + CAL, 1/3 each": (
        {"margin": 1 / 3, "SU": 1 / 3, "CAL": 1 / 3},
        0,
        DENSE_FROM,
    ),
    "chain without fallback, margin 0.5 + CAL 0.5": ({"margin": 0.5, "CAL": 0.5}, 0.0, DENSE_FROM),
    "chain, fallback 0.15, margin 0.5 + SU 0.5": ({"margin": 0.5, "SU": 0.5}, 0.15, DENSE_FROM),
    "chain without fallback, label-free mix: z(margin) - z(SU) on the labelled scores": ({"mix": 1.0}, 0.0, DENSE_FROM),
    "chain, label-free mix: z(margin) - z(SU) on the labelled scores": ({"mix": 1.0}, FALLBACK, DENSE_FROM),
    "chain dense from n/2: margin + SU + CAL at 1/3 each": (THIRDS, FALLBACK, 0.5),
    "chain with fallback 0.15: margin + SU + CAL at 1/3 each": (THIRDS, 0.15, DENSE_FROM),
    "tolerant steps, margin 0.5 + SU 0.5": ({"margin": 0.5, "SU": 0.5}, 0.0, 1.0),
    "tolerant steps, SU 0.5 + CAL 0.5": ({"SU": 0.5, "CAL": 0.5}, 0.0, 1.0),
    "tolerant steps, margin 0.5 + CAL 0.5": ({"margin": 0.5, "CAL": 0.5}, 0.0, 1.0),
    "tolerant steps, margin + SU + CAL, 1/3 each": ({"margin": 1 / 3, "SU": 1 / 3, "CAL": 1 / 3}, 0.0, 1.0),
    "tolerant steps, fallback 0.15, margin + SU + CAL, 1/3 each": (
        {"margin": 1 / 3, "SU": 1 / 3, "CAL": 1 / 3},
        0.15,
        1.0,
    ),
    "chain, SU 0.5 + CAL 0.5": ({"SU": 0.5, "CAL": 0.5}, FALLBACK, DENSE_FROM),
    "chain without fallback, SU 0.5 + CAL 0.5": ({"SU": 0.5, "CAL": 0.5}, 0.0, DENSE_FROM),
    "chain dense from n/2, SU 0.5 + CAL 0.5": ({"SU": 0.5, "CAL": 0.5}, FALLBACK, 0.5),
    "chain, CAL only": ({"CAL": 1.0}, FALLBACK, DENSE_FROM),
    "chain, SU 0.45 + CAL 0.45 + margin 0.1": ({"SU": 0.45, "CAL": 0.45, "margin": 0.1}, FALLBACK, DENSE_FROM),
    "tolerant steps, SU 0.45 + CAL 0.45 + margin 0.1": ({"SU": 0.45, "CAL": 0.45, "margin": 0.1}, 0.0, 1.0),
    "chain, SU 0.3 + CAL 0.6 + margin 0.1": ({"SU": 0.3, "CAL": 0.6, "margin": 0.1}, FALLBACK, DENSE_FROM),
    "chain, SU 0.6 + CAL 0.4": ({"SU": 0.6, "CAL": 0.4}, FALLBACK, DENSE_FROM),
    "chain, SU 0.4 + CAL 0.6": ({"SU": 0.4, "CAL": 0.6}, FALLBACK, DENSE_FROM),
    "chain dense from the start, SU 0.5 + CAL 0.5": ({"SU": 0.5, "CAL": 0.5}, FALLBACK, 0.0),
    "chain, CAL 0.9 + margin 0.1": ({"CAL": 0.9, "margin": 0.1}, FALLBACK, DENSE_FROM),
    "chain, CAL 0.8 + SU 0.1 + margin 0.1": ({"CAL": 0.8, "SU": 0.1, "margin": 0.1}, FALLBACK, DENSE_FROM),
    "chain, CAL 0.8 + SU 0.2": ({"CAL": 0.8, "SU": 0.2}, FALLBACK, DENSE_FROM),
    "chain, CAL 0.7 + SU 0.2 + margin 0.1": ({"CAL": 0.7, "SU": 0.2, "margin": 0.1}, FALLBACK, DENSE_FROM),
    "tolerant steps, CAL only": ({"CAL": 1.0}, 0.0, 1.0),
    "chain without fallback, CAL only": ({"CAL": 1.0}, 0.0, DENSE_FROM),
    "chain without fallback, CAL 0.8 + SU 0.1 + margin 0.1": (
        {"CAL": 0.8, "SU": 0.1, "margin": 0.1},
        0.0,
        DENSE_FROM,
    ),
    "chain dense from n/2, CAL 0.8 + SU 0.1 + margin 0.1": ({"CAL": 0.8, "SU": 0.1, "margin": 0.1}, FALLBACK, 0.5),
    "chain, fallback 0.15, CAL 0.8 + SU 0.1 + margin 0.1": ({"CAL": 0.8, "SU": 0.1, "margin": 0.1}, 0.15, DENSE_FROM),
}
RANKINGS["mix"] = ("mix", 1.0)  # the benchmark's own label-free mix, standardised on each draw's scores


def _chosen_on_a_split(select: float, fallback: float, dense_from: float) -> Procedure:
    """Choose the ranking (select_calibrator: best average precision, the model cross-fitted) on a random share
    ``select`` of the labels, then certify it alone at the whole delta on the others (the model fitted on the
    choosing share is a fixed function for them: exact there too)."""

    def procedure(population: Population, rows: np.ndarray, draw: int, settings: Settings) -> Outcome:
        order = np.random.default_rng([settings.seed, draw, 7]).permutation(rows.size)
        chooser, rest = rows[order[: round(select * rows.size)]], rows[order[round(select * rows.size) :]]
        correct = population.correct
        if correct[chooser].all() or not correct[chooser].any():
            return np.zeros(population.size, bool), "none (one outcome in the choosing share)"
        model = tuple(name for name in DEFAULT_FEATURES if name in population.features)
        chosen, _ = select_calibrator(
            {name: column[chooser] for name, column in population.features.items()},
            correct[chooser],
            model_features=model,
            seed=draw,
        )
        confidence = chosen.confidence(columns(population.features, chosen.features))
        _, rule, cut = certify_rankings(
            {"chosen": confidence[rest]},
            {"chosen": confidence[rest]},
            correct[rest],
            population.answerable[rest],
            shares={"chosen": 1.0},
            model_features=model,
            target_precision=settings.target_precision,
            delta=settings.delta,
            folds=5,
            seed=draw,
            fallback=fallback,
            dense_from=dense_from,
        )
        if rule is None:
            return np.zeros(population.size, bool), "none"
        return confidence >= cut, chosen.ranking

    return procedure


CHOSEN_ON_A_SPLIT = {
    "choose on 1/4 of the labels, chain on the rest": (0.25, 0.0, DENSE_FROM),
    "choose on 1/3 of the labels, chain on the rest": (1 / 3, 0.0, DENSE_FROM),
    "choose on 1/4 of the labels, tolerant steps on the rest": (0.25, 0.0, 1.0),
}
RANKINGS["chosen"] = ("chosen", 1.0)


def _variant(shares: Any, fallback: float, dense_from: float) -> Procedure:
    def procedure(population: Population, rows: np.ndarray, draw: int, settings: Settings) -> Outcome:
        given = shares(rows.size) if callable(shares) else shares
        labelled = {name: column[rows] for name, column in population.features.items()}
        model = tuple(name for name in DEFAULT_FEATURES if name in labelled)
        features = population.features
        if "mix" in given:  # z-scores on the draw's own scores (no label read), applied to the population alike
            z = {name: (labelled[name].mean(), labelled[name].std() or 1.0) for name in ("gap", "SU")}
            mix = lambda f: (f["gap"] - z["gap"][0]) / z["gap"][1] - (f["SU"] - z["SU"][0]) / z["SU"][1]  # noqa: E731
            labelled["mix"], features = mix(labelled), {**features, "mix": mix(features)}
        certificate, rule, cut = certify_rankings(
            labelled,
            labelled,
            population.correct[rows],
            population.answerable[rows],
            shares=given,
            model_features=model,
            target_precision=settings.target_precision,
            delta=settings.delta,
            folds=5,
            seed=draw,
            fallback=fallback,
            dense_from=dense_from,
        )
        if rule is None:
            return np.zeros(population.size, bool), "none"
        return rule.confidence(columns(features, rule.features)) >= cut, certificate.ranking

    procedure.__doc__ = "certify_rankings with the given shares of delta and chain shape."
    return procedure


# --- plain fixed-sequence testing --------------------------------------------------------------------------------


def fixed_sequence_cut(
    uncertainty: np.ndarray, correct: np.ndarray, target_precision: float, delta: float
) -> tuple[float | None, int]:
    """Fixed-sequence testing over every distinct labelled value (accept ``uncertainty <= cut``), strictest first.

    Parameters
    ----------
    uncertainty : ndarray of shape (n,)
        Lower = more confident.
    correct : ndarray of shape (n,), bool
        Top-1 correctness of the labelled queries.
    target_precision, delta : float
        p* and the risk.

    Returns
    -------
    cut : float or None
        The last rejected cut (None when the first tested one is not rejected).
    accepted : int
        Labelled queries accepted at the cut (0 without one).
    """
    order = np.argsort(uncertainty, kind="stable")
    ranked = uncertainty[order]
    hits = np.cumsum(correct[order])
    ends = np.append(np.flatnonzero(np.diff(ranked) != 0), ranked.size - 1)  # last index of each tied group
    accepted, good = ends + 1, hits[ends]
    n_min = math.ceil(math.log(delta) / math.log(target_precision) - 1e-12)
    start = int(np.searchsorted(accepted, n_min, side="left"))
    if start >= accepted.size:
        return None, 0
    p_values = stats.binom.sf(good[start:] - 1, accepted[start:], target_precision)
    failed = np.flatnonzero(p_values > delta)
    n_rejected = int(failed[0]) if failed.size else p_values.size
    if n_rejected == 0:
        return None, 0
    chosen = start + n_rejected - 1
    return float(ranked[ends[chosen]]), int(accepted[chosen])


def _cp(
    population: Population, rows: np.ndarray, uncertainty: np.ndarray, settings: Settings, delta: float
) -> tuple[np.ndarray, int]:
    cut, accepted = fixed_sequence_cut(uncertainty[rows], population.correct[rows], settings.target_precision, delta)
    return (np.zeros(population.size, bool) if cut is None else uncertainty <= cut), accepted


def cp_su(population: Population, rows: np.ndarray, draw: int, settings: Settings) -> Outcome:
    """Fixed sequence on SU."""
    return _cp(population, rows, population.su, settings, settings.delta)[0], None


def cp_margin(population: Population, rows: np.ndarray, draw: int, settings: Settings) -> Outcome:
    """Fixed sequence on the margin s1 - s2."""
    return _cp(population, rows, -population.margin, settings, settings.delta)[0], None


def cp_looser(population: Population, rows: np.ndarray, draw: int, settings: Settings) -> Outcome:
    """Both fixed sequences at delta/2; the certified one accepting more labelled queries (SU on a tie)."""
    su, n_su = _cp(population, rows, population.su, settings, settings.delta / 2)
    margin, n_margin = _cp(population, rows, -population.margin, settings, settings.delta / 2)
    if n_su == n_margin == 0:
        return su, "none"
    return (su, "SU") if n_su >= n_margin else (margin, "margin")


# --- MAPIE -------------------------------------------------------------------------------------------------------


def mapie_version() -> str | None:
    """The importable MAPIE's version, or None."""
    try:
        import mapie
        from mapie.risk_control import BinaryClassificationController  # noqa: F401
    except ImportError:
        return None
    return str(getattr(mapie, "__version__", "unknown"))


class FixedScoreClassifier:
    """A fitted binary classifier whose P(correct) is a fixed monotone map of -SU.

    Parameters
    ----------
    population_su : ndarray of shape (Q,)
        The population's SU (no labels): p(u) = share of the population with SU >= u, in (0, 1].

    Notes
    -----
    ``X`` is a column of SU values, shape (m, 1). LTT only needs the ranking; the map places MAPIE's grid of
    thresholds evenly over the population's coverage.
    """

    classes_ = np.array([0, 1])

    def __init__(self, population_su: np.ndarray) -> None:
        self._sorted = np.sort(np.asarray(population_su, dtype=np.float64))

    def fit(self, X: np.ndarray, y: np.ndarray) -> FixedScoreClassifier:
        return self

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        u = np.asarray(X, dtype=np.float64)[:, 0]
        p = 1.0 - np.searchsorted(self._sorted, u, side="left") / self._sorted.size
        return np.column_stack([1.0 - p, p])


def _mapie(method: str) -> Procedure:
    def procedure(population: Population, rows: np.ndarray, draw: int, settings: Settings) -> Outcome:
        from mapie.risk_control import BinaryClassificationController, precision

        model = FixedScoreClassifier(population.su)
        x, y = population.su[rows, None], population.correct[rows].astype(int)
        nothing = np.zeros(population.size, bool)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                controller = BinaryClassificationController(
                    predict_function=model.predict_proba,
                    risk=precision,
                    target_level=float(settings.target_precision),
                    confidence_level=1.0 - settings.delta,
                    fwer_method=method,
                )
                if method == "split_fixed_sequence":
                    half = np.random.default_rng([settings.seed, draw, rows.size]).permutation(rows.size)
                    learn, test = half[: rows.size // 2], half[rows.size // 2 :]
                    beta_grid = np.logspace(-25, 0, settings.sfs_betas)
                    controller.learn_fixed_sequence_order(x[learn], y[learn], beta_grid=beta_grid)
                    controller.calibrate(x[test], y[test])
                else:
                    controller.calibrate(x, y)
                if controller.best_predict_param is None:
                    learned = getattr(controller, "_learned_fixed_sequence", None)  # diagnostic only
                    if learned is not None and len(learned) == 1:
                        return nothing, "no valid threshold (learned order holds a single threshold)"
                    return nothing, "no valid threshold"
                accepted = np.asarray(controller.predict(population.su[:, None]), dtype=bool)
            except Exception as error:  # MAPIE gives up in several ways; count it as certifying nothing
                return nothing, f"raised {type(error).__name__}"
        return accepted, "certified"

    procedure.__doc__ = f"MAPIE BinaryClassificationController, fwer_method={method!r}."
    return procedure


# --- running and measuring ---------------------------------------------------------------------------------------


def procedures(with_mapie: bool, with_unlabelled: bool) -> dict[str, Procedure]:
    """The procedures to compare, in the order of the table."""
    chosen: dict[str, Procedure] = {"toolkit (default)": toolkit_default}
    if with_unlabelled:
        chosen["toolkit + unlabelled"] = toolkit_unlabelled
    chosen.update({name: _variant(*variant) for name, variant in VARIANTS.items()})
    chosen.update({name: _chosen_on_a_split(*variant) for name, variant in CHOSEN_ON_A_SPLIT.items()})
    if with_mapie:
        chosen.update({name: _mapie(method) for name, method in MAPIE_METHODS.items()})
    chosen["CP fixed sequence, SU"] = cp_su
    chosen["CP fixed sequence, margin"] = cp_margin
    chosen["CP fixed sequence, SU and margin at delta/2, looser rule"] = cp_looser
    return chosen


def measure(population: Population, accepted: np.ndarray, target_precision: float) -> dict[str, float]:
    """Violation rate, certifying share and mean recall of (draws, Q) acceptance masks on the population."""
    n_accepted = accepted.sum(axis=1)
    good = (accepted & population.correct).sum(axis=1)
    violated = (n_accepted > 0) & (good < target_precision * n_accepted - 1e-9)
    recall = good / max(int(population.answerable.sum()), 1)
    return {
        "violations": float(violated.mean()),
        "certifying": float((n_accepted > 0).mean()),
        "mean_recall": float(recall.mean()),
        "oracle": population.oracle,
        "recall_over_oracle": float(recall.mean() / population.oracle) if population.oracle > 0 else math.nan,
        "mean_accepted": float(n_accepted.mean()),
    }


def run_task(
    population: Population, index: int, n: int, draws: int, names: list[str], settings: Settings, with_mapie: bool
) -> dict[str, Any]:
    """Every procedure on the same ``draws`` calibration draws of size ``n`` from one population."""
    chosen = procedures(with_mapie, "toolkit + unlabelled" in names)
    rows = calibration_draws(population, n, draws, settings.seed, index)
    out: dict[str, Any] = {}
    for name in names:
        accepted = np.zeros((draws, population.size), bool)
        notes: Counter[str] = Counter()
        start = time.perf_counter()
        for draw in range(draws):
            accepted[draw], note = chosen[name](population, rows[draw], draw, settings)
            if note is not None:
                notes[note] += 1
        out[name] = {
            **measure(population, accepted, settings.target_precision),
            "notes": dict(notes),
            "seconds": time.perf_counter() - start,
        }
    return out


def _fmt(value: float) -> str:
    return "n/a" if math.isnan(value) else f"{value:.3f}"


def summarise(results: dict[str, dict[int, dict[str, dict[str, Any]]]], delta: float) -> dict[str, dict[int, Any]]:
    """Per procedure and n: pooled violations and certifying, worst violations, mean recall / oracle, notes."""
    summary: dict[str, dict[int, Any]] = {}
    for name, by_n in results.items():
        summary[name] = {}
        for n, by_population in by_n.items():
            rows = list(by_population.values())
            ratios = [r["recall_over_oracle"] for r in rows if not math.isnan(r["recall_over_oracle"])]
            notes: Counter[str] = Counter()
            for r in rows:
                notes.update(r["notes"])
            summary[name][n] = {
                "violations": float(np.mean([r["violations"] for r in rows])),
                "worst_violations": float(max(r["violations"] for r in rows)),
                "populations_over_delta": int(sum(r["violations"] > delta for r in rows)),
                "certifying": float(np.mean([r["certifying"] for r in rows])),
                "recall_over_oracle": float(np.mean(ratios)) if ratios else math.nan,
                "mean_recall": float(np.mean([r["mean_recall"] for r in rows])),
                "pooled_ratio": float(np.mean([r["mean_recall"] for r in rows]) / np.mean([r["oracle"] for r in rows])),
                "populations_in_ratio": len(ratios),
                "notes": dict(notes),
                "seconds": float(sum(r["seconds"] for r in rows)),
            }
    return summary


def print_table(summary: dict[str, dict[int, Any]]) -> None:
    print(
        "| procedure | n | violations | certifying | recall / oracle | mean recall / mean oracle | mean recall "
        "| violations, worst population |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, by_n in summary.items():
        for n, s in by_n.items():
            print(
                f"| {name} | {n} | {_fmt(s['violations'])} | {_fmt(s['certifying'])} | "
                f"{_fmt(s['recall_over_oracle'])} | {_fmt(s['pooled_ratio'])} | {_fmt(s['mean_recall'])} | "
                f"{_fmt(s['worst_violations'])} |"
            )


def print_verbose(results: dict[str, dict[int, dict[str, dict[str, Any]]]]) -> None:
    print("\n## Per population\n")
    print("| procedure | n | population | violations | certifying | mean recall | oracle | recall / oracle |")
    print("|---|---|---|---|---|---|---|---|")
    for name, by_n in results.items():
        for n, by_population in by_n.items():
            for population, r in by_population.items():
                print(
                    f"| {name} | {n} | {population} | {_fmt(r['violations'])} | {_fmt(r['certifying'])} | "
                    f"{_fmt(r['mean_recall'])} | {_fmt(r['oracle'])} | {_fmt(r['recall_over_oracle'])} |"
                )


def print_notes(summary: dict[str, dict[int, Any]], draws: int) -> None:
    lines = []
    for name, by_n in summary.items():
        for n, s in by_n.items():
            if s["notes"]:
                tally = ", ".join(f"{note}: {count}" for note, count in sorted(s["notes"].items()))
                lines.append(f"* {name}, n = {n}: {tally}")
    if lines:
        print(
            f"\nPer-draw outcomes (toolkit: winning ranking; looser rule: chosen score; MAPIE: result), summed over "
            f"populations ({draws} draws each):\n"
        )
        print("\n".join(lines))


def _sizes(text: str) -> list[int]:
    sizes = [int(part) for part in text.split(",") if part.strip()]
    if not sizes or min(sizes) < 2:
        raise argparse.ArgumentTypeError(f"sizes must be a comma-separated list of integers >= 2, got {text!r}")
    return sizes


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--draws",
        type=int,
        default=100,
        help="calibration draws per population and n (default 100: about 6 minutes on 2 idle cores; 200 halves the "
        "Monte-Carlo variance in about twice the time)",
    )
    parser.add_argument(
        "--sizes",
        type=_sizes,
        default=[50, 100, 200, 400],
        help="calibration sizes n, comma-separated (default 50,100,200,400)",
    )
    parser.add_argument("--target-precision", type=float, default=0.9, help="p* (default 0.9)")
    parser.add_argument("--delta", type=float, default=0.1, help="risk delta (default 0.1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the draws (default 0)")
    parser.add_argument(
        "--retrieval", type=Path, action="append", default=[], help="own retrieval.npz with ground truth (repeatable)"
    )
    parser.add_argument(
        "--no-corridor", action="store_true", help="skip the ten corridor matrices (use only --retrieval files)"
    )
    parser.add_argument("--no-mapie", action="store_true", help="skip the MAPIE rows even when MAPIE is importable")
    parser.add_argument(
        "--family",
        choices=("resampled", "contrasting", "both"),
        default="resampled",
        help="the populations as loaded (resampled), or those made from them whose first wrong answer comes early "
        "by SU and late by the margin or the other way round (contrasting, see `contrasting`), or both",
    )
    parser.add_argument(
        "--only",
        default="",
        help="run only the procedures whose name contains one of these ;-separated texts (names hold commas)",
    )
    parser.add_argument(
        "--sfs-betas",
        type=int,
        default=100,
        help="beta_grid size of MAPIE's learn_fixed_sequence_order (its default "
        "1000 costs about 0.7 s per draw; default here 100)",
    )
    parser.add_argument("--jobs", type=int, default=_cores(), help="worker processes (default: the usable cores)")
    parser.add_argument("--json", type=Path, help="write every number (per population too) to this JSON file")
    parser.add_argument("--verbose", action="store_true", help="also print one row per population")
    args = parser.parse_args(argv)

    started = time.perf_counter()
    data = os.environ.get("VPR_UNCERTAINTY_DATA")
    if not args.no_corridor and not data:
        parser.error("set VPR_UNCERTAINTY_DATA to the data folder (holding vprbench/), or pass --no-corridor")
    populations = load_populations(None if args.no_corridor else Path(data), args.retrieval, args.target_precision)
    if args.family != "resampled":
        made = [contrasting(p, early) for p in populations for early in ("SU", "margin")]
        populations = (populations if args.family == "both" else []) + [p for p in made if p is not None]
    if not populations:
        parser.error("no population: give --retrieval files with --no-corridor")
    settings = Settings(args.target_precision, args.delta, args.seed, args.sfs_betas)

    version = None if args.no_mapie else mapie_version()
    with_unlabelled = supports_unlabelled()
    wanted = [text for text in args.only.split(";") if text]
    names = [
        name
        for name in procedures(version is not None, with_unlabelled)
        if not wanted or any(t in name for t in wanted)
    ]
    sizes = ", ".join(str(p.size) for p in populations)
    print(f"# Precision-guaranteed gates: p* = {args.target_precision:g}, delta = {args.delta:g}\n")
    print(
        f"Populations: {len(populations)} labelled query sets ({', '.join(p.name for p in populations)}; "
        f"{sizes} queries). Each calibration draw takes n queries i.i.d. WITH replacement from one population "
        f"(redrawn when it holds one outcome), so the guarantee is exact w.r.t. that resampled population; precision "
        f"and recall are measured on the whole population. {args.draws} draws per population and n, seed {args.seed},"
        f" the same draws for every procedure."
    )
    if not with_unlabelled:
        print("\n`toolkit + unlabelled` skipped: calibrate_arrays has no `unlabelled` keyword in this version.")
    if args.no_mapie:
        print("\nMAPIE rows skipped (--no-mapie).")
    elif version is None:
        print(f"\n{HOW_TO_GET_MAPIE}")
    else:
        print(
            f"\nMAPIE {version}: BinaryClassificationController(predict_function=<fixed -SU score>.predict_proba, "
            f"risk=precision, target_level={args.target_precision:g}, confidence_level={1 - args.delta:g}, "
            f"fwer_method=...), default list_predict_params linspace(0, 0.99, 100) and best_predict_param_choice; "
            f"split_fixed_sequence learns its order on half the draw (beta_grid logspace(-25, 0, {args.sfs_betas})) "
            "and calibrates on the other half."
        )

    tasks = [(population, i, n) for i, population in enumerate(populations) for n in args.sizes]
    results: dict[str, dict[int, dict[str, dict[str, Any]]]] = {name: {n: {} for n in args.sizes} for name in names}
    jobs = max(1, min(args.jobs, len(tasks)))
    call = [(p, i, n, args.draws, names, settings, version is not None) for p, i, n in tasks]
    if jobs == 1:
        outputs = [run_task(*c) for c in call]
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            outputs = list(pool.map(run_task, *zip(*call, strict=True)))
    for (population, _, n), output in zip(tasks, outputs, strict=True):
        for name in names:
            results[name][n][population.name] = output[name]
    summary = summarise(results, args.delta)
    elapsed = time.perf_counter() - started

    print(
        f"\nViolations and certifying: shares of all draws (pooled over populations); recall / oracle: mean over the "
        f"populations with a positive oracle ({sum(p.oracle > 0 for p in populations)} of {len(populations)}; an oracle"
        f" near 0 makes its ratio large); mean recall / mean oracle: the same pooled, which near-0 oracles cannot "
        f"inflate; mean recall: mean over populations; worst: the largest per-population "
        f"violation share.\n"
    )
    print_table(summary)
    print_notes(summary, args.draws)
    if args.verbose:
        print_verbose(results)
    seconds = ", ".join(f"{name} {sum(s['seconds'] for s in by_n.values()):.0f} s" for name, by_n in summary.items())
    print(f"\nElapsed: {elapsed:.0f} s on {jobs} process(es) (CPU time per procedure: {seconds}).")

    if args.json:
        payload = {
            "target_precision": args.target_precision,
            "delta": args.delta,
            "draws": args.draws,
            "seed": args.seed,
            "sizes": args.sizes,
            "populations": {p.name: {"queries": p.size, "oracle": p.oracle} for p in populations},
            "mapie_version": version,
            "mapie_options": None
            if version is None
            else {
                "risk": "precision",
                "confidence_level": 1 - args.delta,
                "list_predict_params": "default linspace(0, 0.99, 100)",
                "predict_proba": "p = share of the population with SU >= the query's SU",
                "fwer_methods": MAPIE_METHODS,
                "split_fixed_sequence": {"learn": "random half", "beta_grid": f"logspace(-25, 0, {args.sfs_betas})"},
            },
            "unlabelled_supported": with_unlabelled,
            "elapsed_seconds": elapsed,
            "summary": summary,
            "per_population": results,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2, allow_nan=True) + "\n")
        print(f"Numbers written to {args.json}.")


if __name__ == "__main__":
    sys.exit(main())
