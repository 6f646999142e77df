"""Labelling that stops when the proof is in: the tool picks the next query to label and says after every label
whether the target precision is certified.

Why labelling the most confident answers first is exact: the batch gate (:mod:`.guarantee`) tests, per ranking, a
chain of "precision < p*" hypotheses at cuts fixed from unlabelled scores, strictest first
(:func:`~vpr_uncertainty.calibration.guarantee.cut_chain`), by the fallback procedure, whose decision on a cut depends
on the cuts before it only. The test of a cut reads only the labels of the queries it accepts. So labelling the pool
in the ranking's order, most confident first, and testing each cut as soon as every query it accepts is labelled,
makes exactly the tests the batch gate would make with the *whole pool* labelled, each once: whenever the user stops,
the certified cuts are a subset of that procedure's, and its family-wise error ≤ δ holds (the order is fixed by the
scores alone, so choosing the queries costs no δ). Labels below the certified region are asked for only as far as
the chain can still pass.

Several rankings (default SU and the margin, each at δ / R: a union bound) are labelled side by side: the next query
is the first unlabelled one of the ranking whose next test needs the fewest further labels, and the certified ranking
that accepts the most correct answers is kept.

The guarantee is the batch gate's with n = N: with probability ≥ 1 − δ over the draw of the pool (i.i.d. with the
queries to come), the precision of the answers accepted at the certified cut is ≥ p*.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from vpr_uncertainty._validation import check_top_k_scores
from vpr_uncertainty.calibration.calibrator import RANKINGS, Calibrator, feature_columns, platt, ranking_rule
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.calibration.guarantee import (
    FALLBACK,
    check_rankings,
    clopper_pearson_lower,
    cut_chain,
    fallback_test,
    fixed_sequence,
    min_accepted,
)
from vpr_uncertainty.calibration.labels_file import pool_fingerprint

__all__ = ["SequentialCalibration", "SequentialStatus"]


@dataclass
class SequentialStatus:
    """Where a :class:`SequentialCalibration` stands.

    Attributes
    ----------
    labelled : int
        Labels given.
    certified : bool
        Whether a cut is certified.
    ranking : str or None
        The certified ranking kept (the one accepting the most correct answers), None when none is.
    cut : float or None
        Its certified cut on the ranking's confidence (accept ``sign · feature ≥ cut``, as in
        :data:`~vpr_uncertainty.calibration.calibrator.RANKINGS`).
    accepted, correct_accepted : int
        Pool queries accepted at the certified cut, and the correct ones among them (all labelled).
    coverage : float
        accepted / pool size.
    precision_lower_bound : float or None
        Clopper–Pearson lower bound (confidence 1 − δ / R) of the precision at the cut.
    finished : bool
        No further cut can be certified: in every ranking a test failed, the next one can no longer pass, or every
        cut is tested.
    next_test : int or None
        How many of the most confident queries of the ranking labelled next its next test reads (None when finished).
    wrong_allowed : int or None
        Wrong answers that test tolerates among them.
    message : str
        One sentence for the user.
    rankings : dict
        Per ranking: ``certified``, ``accepted``, ``correct_accepted``, ``finished``, ``next_test``.
    """

    labelled: int
    certified: bool
    ranking: str | None
    cut: float | None
    accepted: int
    correct_accepted: int
    coverage: float
    precision_lower_bound: float | None
    finished: bool
    next_test: int | None
    wrong_allowed: int | None
    message: str
    rankings: dict[str, dict[str, Any]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class _Chain:
    """One ranking's chain of tests over the pool (:func:`~vpr_uncertainty.calibration.guarantee.cut_chain`, tested
    by the fallback procedure, as the batch gate does), strictest cut first."""

    def __init__(self, name: str, confidence: np.ndarray, target_precision: float, level: float) -> None:
        self.name, self.level, self.target_precision = name, level, target_precision
        self.order = np.argsort(-confidence, kind="stable")
        self.ranked = confidence[self.order]
        counts, levels = cut_chain(confidence.size, target_precision, level)
        # a cut accepts every query tied with the last one it accepts: test it once that whole group is labelled
        grown = np.searchsorted(-self.ranked, -self.ranked[counts - 1], side="right")
        self.tests, where = np.unique(grown, return_inverse=True)
        self.levels = np.zeros(self.tests.size)
        np.add.at(self.levels, where, levels)

    def _allowed(self, count: int, level: float) -> int:
        """Wrong answers among ``count`` accepted that still pass the exact binomial test at ``level``."""
        return int(count - (stats.binom.isf(level, count, self.target_precision) + 1))

    def outcome(self, labels: np.ndarray) -> dict[str, Any]:
        in_order = labels[self.order]
        gaps = np.flatnonzero(in_order < 0)
        prefix = int(gaps[0]) if gaps.size else in_order.size
        tested = self.tests[self.tests <= prefix]
        correct = tested - np.cumsum(in_order[:prefix] == 0)[tested - 1] if tested.size else tested
        _, p_values = fixed_sequence(tested, correct, target_precision=self.target_precision, delta=self.level)
        rejected, tested_at = fallback_test(p_values, self.levels[: tested.size])
        # the next test that can still pass: one with a level, and no more wrong answers labelled than it allows
        j, carried = tested.size, tested_at[-1] if tested.size and rejected[-1] else 0.0
        while j < self.tests.size:
            level = self.levels[j] + carried
            if level > 0 and (in_order[: self.tests[j]] == 0).sum() <= self._allowed(self.tests[j], level):
                break
            j, carried = j + 1, 0.0
        chosen = int(np.flatnonzero(rejected)[-1]) if rejected.any() else None
        finished = j >= self.tests.size
        return {
            "certified": chosen is not None,
            "accepted": 0 if chosen is None else int(tested[chosen]),
            "correct_accepted": 0 if chosen is None else int(correct[chosen]),
            "level": 0.0 if chosen is None else float(tested_at[chosen]),
            "finished": finished,
            "next_test": None if finished else int(self.tests[j]),
            "wrong_allowed": None if finished else self._allowed(self.tests[j], level),
            "more": None if finished else int(self.tests[j] - (in_order[: self.tests[j]] >= 0).sum()),
        }

    def cut(self, accepted: int) -> float:
        """Halfway between the lowest accepted confidence and the next lower one (as :func:`cuts_at_coverage`)."""
        ranked = self.ranked
        below = ranked[accepted] if accepted < ranked.size else ranked[-1] - max(1.0, abs(ranked[-1]))
        return 0.5 * (float(ranked[accepted - 1]) + float(below))


class Labelling:
    """What a labelling session shares: its labels (``_labels``, -1 unlabelled), ``add_label`` and what its gate
    records, on the ``status()`` each session defines."""

    _labels: np.ndarray

    def add_label(self, query: int, correct: bool) -> SequentialStatus:
        """Record whether the top-1 answer of pool query ``query`` is correct (labels are final; a label the session
        did not ask for is kept, and read only where its tests read it); returns the new status."""
        if isinstance(query, bool) or not 0 <= int(query) < self._labels.size:
            raise ValueError(f"query must be a pool index in [0, {self._labels.size}), got {query!r}")
        if self._labels[query] >= 0 and self._labels[query] != bool(correct):
            raise ValueError(f"query {query} is labelled already ({bool(self._labels[query])}); labels are final")
        self._labels[query] = bool(correct)
        return self.status()

    def _gate(self, calibrator: Calibrator, cut: float, rule: Calibrator, state: SequentialStatus, **info: Any) -> Gate:
        """A gate recording p*, δ, the bound, the labels and the pool (``k``, ``_least``, ``fingerprint``), ``info``."""
        calibration = {"size": state.labelled, "min_candidates": self._least, "pool": self.fingerprint}
        info |= dict(target_precision=self.target_precision, delta=self.delta, calibration=calibration)
        info["precision_lower_bound"] = state.precision_lower_bound
        return Gate(calibrator, self.k, cut, info=info, rule=rule)


class SequentialCalibration(Labelling):
    """Certify a precision target while labelling as few queries as possible, one label at a time.

    Parameters
    ----------
    scores : array_like of shape (N, K)
        Top-k similarities of the unlabelled pool (sorted descending per row).
    target_precision, delta : float in (0, 1)
        p* and the risk δ.
    k : int, default=10
        Candidates per query the features read.
    rankings : sequence of str or dict of str to float, default=("SU", "margin")
        The training-free rankings the queries are labelled in (names of
        :data:`~vpr_uncertainty.calibration.calibrator.RANKINGS`), each tested at δ / R (or at its share of δ). SU
        is the stronger on the corridor; on other data SU's most confident answers can hold early wrong ones, and
        the margin's rarely do.

    Attributes
    ----------
    fingerprint : str
        :func:`~vpr_uncertainty.calibration.labels_file.pool_fingerprint` of the pool (its top-k scores and k): the
        labels file carries it, and so does the gate (``calibration.pool``).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> scores = -np.sort(-rng.uniform(0.2, 0.9, size=(200, 10)), axis=1)
    >>> session = SequentialCalibration(scores, target_precision=0.9)
    >>> while (query := session.next_query()) is not None:
    ...     status = session.add_label(query, True)          # here every answer is correct
    >>> status.certified, status.coverage
    (True, 1.0)
    """

    def __init__(
        self,
        scores: object,
        *,
        target_precision: float,
        delta: float = 0.1,
        k: int = 10,
        rankings: Sequence[str] | dict[str, float] = ("SU", "margin"),
    ) -> None:
        min_accepted(target_precision, delta)  # checks p* and δ
        scores = check_top_k_scores(scores, name="scores")
        if len(scores) == 0:
            raise ValueError("scores holds no query: sequential labelling needs a pool of unlabelled queries")
        self.target_precision, self.delta, self.k = float(target_precision), float(delta), int(k)
        shares = check_rankings(rankings, feature_columns(scores[:1], k))
        if "CAL" in shares:
            raise ValueError("sequential labelling needs training-free rankings, not 'CAL'")
        features = feature_columns(scores, k, required=[RANKINGS[name][0] for name in shares])
        self.chains = [
            _Chain(name, RANKINGS[name][1] * features[RANKINGS[name][0]], self.target_precision, share * self.delta)
            for name, share in shares.items()
        ]
        self._features = features
        self.fingerprint = pool_fingerprint(scores, self.k)
        self._least = int(min(np.isfinite(scores[:, :k]).sum(axis=1).min(), k))
        self._labels = np.full(len(scores), -1, dtype=np.int8)  # -1: not labelled; 0/1: wrong/correct

    def next_query(self) -> int | None:
        """The pool index of the query to label next, None when finished: the most confident unlabelled query of
        the ranking whose next test needs the fewest further labels."""
        outcomes = [(chain, chain.outcome(self._labels)) for chain in self.chains]
        waiting = [(outcome["more"], i) for i, (_, outcome) in enumerate(outcomes) if not outcome["finished"]]
        if not waiting:
            return None
        chain = self.chains[min(waiting)[1]]
        unlabelled = np.flatnonzero(self._labels[chain.order] < 0)
        return int(chain.order[unlabelled[0]]) if unlabelled.size else None

    def status(self) -> SequentialStatus:
        """Certified or not, by which ranking, and what the next test needs."""
        outcomes = {chain.name: chain.outcome(self._labels) for chain in self.chains}
        best = max(self.chains, key=lambda chain: outcomes[chain.name]["correct_accepted"])
        won = outcomes[best.name]
        waiting = sorted((o["more"], name) for name, o in outcomes.items() if not o["finished"])
        upcoming = outcomes[waiting[0][1]] if waiting else {"next_test": None, "wrong_allowed": None}
        bound = (
            clopper_pearson_lower(won["correct_accepted"], won["accepted"], won["level"]) if won["certified"] else None
        )
        status = SequentialStatus(
            labelled=int((self._labels >= 0).sum()),
            certified=won["certified"],
            ranking=best.name if won["certified"] else None,
            cut=best.cut(won["accepted"]) if won["certified"] else None,
            accepted=won["accepted"],
            correct_accepted=won["correct_accepted"],
            coverage=won["accepted"] / self._labels.size,
            precision_lower_bound=None if bound is None else float(bound),
            finished=not waiting,
            next_test=upcoming["next_test"],
            wrong_allowed=upcoming["wrong_allowed"],
            message="",
            rankings={
                name: {key: o[key] for key in ("certified", "accepted", "correct_accepted", "finished", "next_test")}
                for name, o in outcomes.items()
            },
        )
        status.message = self._message(status, waiting[0] if waiting else None)
        return status

    def _message(self, status: SequentialStatus, waiting: tuple[int, str] | None) -> str:
        what = (
            f"precision >= {self.target_precision:g} certified (probability >= {1 - self.delta:g}) for the "
            f"{status.accepted} most confident of {self._labels.size} queries by {status.ranking}: "
            f"{status.correct_accepted} correct, lower bound {status.precision_lower_bound:.3f}"
            if status.certified
            else f"nothing certified yet at precision {self.target_precision:g}"
        )
        if not any(chain.tests.size for chain in self.chains):
            needed = min_accepted(self.target_precision, min(chain.level for chain in self.chains) * (1 - FALLBACK))
            return f"{what}; the pool's {self._labels.size} queries are fewer than the {needed} a first test needs"
        if waiting is None:
            return f"{what}; done: no further label can certify more"
        more, name = waiting
        return (
            f"{what}; next: {more} more label(s) for the test of {name}'s {status.next_test} most confident queries, "
            f"which passes with at most {status.wrong_allowed} wrong answer(s) among them"
        )

    def gate(self) -> Gate:
        """The certified rule as a :class:`~vpr_uncertainty.calibration.gate.Gate`: it accepts what the status
        certifies (the ranking's confidence ≥ its cut); P(correct) by Platt scaling of that ranking on the labelled
        queries, which are the most confident ones (so P is optimistic below the cut)."""
        status = self.status()
        if not status.certified:
            raise ValueError(f"no gate yet: {status.message}")
        labelled = self._labels >= 0
        feature, sign = RANKINGS[status.ranking]
        calibrator = platt(
            status.ranking, feature, sign, self._features[feature][labelled], self._labels[labelled] == 1
        )
        info = {"expected_coverage": status.coverage, "sequential": status.to_dict()}
        return self._gate(calibrator, status.cut, ranking_rule(status.ranking), status, **info)
