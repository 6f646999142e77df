"""Labelling that stops when the proof is in: the tool picks the next query to label and says after every label
whether the target precision is certified.

Why labelling the most confident answers first is exact: the batch gate (:mod:`.guarantee`) tests, strictest cut
first, "precision < p*" at cuts fixed from unlabelled scores, and stops at the first test that fails. The test of a
cut reads only the labels of the queries that cut accepts. So labelling the pool in the order of one training-free
ranking, most confident first, and testing each cut as soon as every query it accepts is labelled, gives exactly the
tests the batch procedure would make with the *whole pool* labelled, each made once: whenever the user stops, the
certified cuts are a subset of that procedure's, and its family-wise error ≤ δ holds (the order of the queries is
fixed by the scores alone, so choosing them costs no δ). Labels beyond the accepted region are never needed: a pool of
N queries certifies with about coverage · N labels plus the few that end the sequence, where the batch procedure
needs a random sample large enough that coverage · n accepted labelled queries pass the same test.

Several rankings (default SU and the margin, each at δ / R) are labelled side by side: the next query is the
first unlabelled one of the ranking whose next test needs the fewest further labels, and the certified ranking that
accepts the most correct answers is kept (a union bound over the rankings' chains, each exact on its own).

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
from vpr_uncertainty.calibration.calibrator import RANKINGS, feature_columns, platt
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.calibration.guarantee import (
    check_rankings,
    clopper_pearson_lower,
    coverage_grid,
    fixed_sequence,
    min_accepted,
)

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
    """One ranking's fixed sequence of tests over the pool, strictest cut first."""

    def __init__(self, name: str, confidence: np.ndarray, target_precision: float, delta: float) -> None:
        self.name, self.confidence, self.delta, self.target_precision = name, confidence, delta, target_precision
        self.order = np.argsort(-confidence, kind="stable")
        self.ranked = confidence[self.order]
        n = confidence.size
        counts = np.rint(coverage_grid(n, target_precision, delta) * n).astype(int)
        # a cut accepts every query tied with the last one it accepts: test it once that whole group is labelled
        self.tests = np.unique(np.searchsorted(-self.ranked, -self.ranked[counts - 1], side="right"))
        self.allowed = self.tests - (stats.binom.isf(delta, self.tests, target_precision).astype(int) + 1)

    def outcome(self, labels: np.ndarray) -> dict[str, Any]:
        in_order = labels[self.order]
        gaps = np.flatnonzero(in_order < 0)
        prefix = int(gaps[0]) if gaps.size else in_order.size
        tested = self.tests[self.tests <= prefix]
        correct = tested - np.cumsum(in_order[:prefix] == 0)[tested - 1] if tested.size else tested
        passed, _ = fixed_sequence(tested, correct, target_precision=self.target_precision, delta=self.delta)
        finished = passed < tested.size or tested.size == self.tests.size
        # the wrong answers labelled already among the queries the next test reads may fail it for certain
        finished = finished or (in_order[: self.tests[tested.size]] == 0).sum() > self.allowed[tested.size]
        accepted = int(tested[passed - 1]) if passed else 0
        return {
            "certified": bool(passed),
            "accepted": accepted,
            "correct_accepted": int(correct[passed - 1]) if passed else 0,
            "finished": bool(finished),
            "next_test": None if finished else int(self.tests[tested.size]),
            "wrong_allowed": None if finished else int(self.allowed[tested.size]),
            "more": None
            if finished
            else int(self.tests[tested.size] - (in_order[: self.tests[tested.size]] >= 0).sum()),
        }

    def cut(self, accepted: int) -> float:
        """Halfway between the lowest accepted confidence and the next lower one (as :func:`cuts_at_coverage`)."""
        below = (
            self.ranked[accepted] if accepted < self.ranked.size else self.ranked[-1] - max(1.0, abs(self.ranked[-1]))
        )
        return 0.5 * (float(self.ranked[accepted - 1]) + float(below))


class SequentialCalibration:
    """Certify a precision target while labelling as few queries as possible, one label at a time.

    Parameters
    ----------
    scores : array_like of shape (N, K)
        Top-k similarities of the unlabelled pool (sorted descending per row).
    target_precision, delta : float in (0, 1)
        p* and the risk δ.
    k : int, default=10
        Candidates per query the features read.
    rankings : sequence of str, default=("SU", "margin")
        The training-free rankings the queries are labelled in (names of
        :data:`~vpr_uncertainty.calibration.calibrator.RANKINGS`), each tested at δ / R. SU is the stronger on the
        corridor; on other data SU's most confident answers can hold an early wrong one, which ends its chain, while
        the margin's rarely do.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> scores = -np.sort(-rng.uniform(0.2, 0.9, size=(200, 10)), axis=1)
    >>> session = SequentialCalibration(scores, target_precision=0.9)
    >>> while (query := session.next_query()) is not None:
    ...     status = session.add_label(query, True)          # here every answer is correct
    >>> status.certified, status.coverage
    (True, 0.955)
    """

    def __init__(
        self,
        scores: object,
        *,
        target_precision: float,
        delta: float = 0.1,
        k: int = 10,
        rankings: Sequence[str] = ("SU", "margin"),
    ) -> None:
        min_accepted(target_precision, delta)  # checks p* and δ
        scores = check_top_k_scores(scores, name="scores")
        self.target_precision, self.delta, self.k = float(target_precision), float(delta), int(k)
        names = check_rankings(rankings, feature_columns(scores[:1], k))
        if "CAL" in names:
            raise ValueError("sequential labelling needs training-free rankings, not 'CAL'")
        features = feature_columns(scores, k, required=[RANKINGS[name][0] for name in names])
        share = self.delta / len(names)
        self.chains = [
            _Chain(name, RANKINGS[name][1] * features[RANKINGS[name][0]], self.target_precision, share)
            for name in names
        ]
        self._features = features
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

    def add_label(self, query: int, correct: bool) -> SequentialStatus:
        """Record whether the top-1 answer of pool query ``query`` is correct; returns the new status."""
        if isinstance(query, bool) or not 0 <= int(query) < self._labels.size:
            raise ValueError(f"query must be a pool index in [0, {self._labels.size}), got {query!r}")
        if self._labels[query] >= 0 and self._labels[query] != bool(correct):
            raise ValueError(f"query {query} is labelled already ({bool(self._labels[query])}); labels are final")
        self._labels[query] = bool(correct)
        return self.status()

    def status(self) -> SequentialStatus:
        """Certified or not, by which ranking, and what the next test needs."""
        outcomes = {chain.name: chain.outcome(self._labels) for chain in self.chains}
        best = max(self.chains, key=lambda chain: outcomes[chain.name]["correct_accepted"])
        won = outcomes[best.name]
        waiting = sorted((o["more"], name) for name, o in outcomes.items() if not o["finished"])
        upcoming = outcomes[waiting[0][1]] if waiting else {"next_test": None, "wrong_allowed": None}
        bound = (
            clopper_pearson_lower(won["correct_accepted"], won["accepted"], best.delta) if won["certified"] else None
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
        if waiting is None:
            return f"{what}; done: no further label can certify more"
        more, name = waiting
        return (
            f"{what}; next: {more} more label(s) for the test of {name}'s {status.next_test} most confident queries, "
            f"which passes with at most {status.wrong_allowed} wrong answer(s) among them"
        )

    def gate(self) -> Gate:
        """The certified rule as a :class:`~vpr_uncertainty.calibration.gate.Gate` (P by Platt scaling of the
        certified ranking on the labelled queries)."""
        status = self.status()
        labelled = self._labels >= 0
        if not status.certified:
            raise ValueError(f"no gate yet: {status.message}")
        if np.unique(self._labels[labelled]).size < 2:
            raise ValueError(
                f"no gate yet: all {int(labelled.sum())} labelled answers are correct, and P(correct) needs a wrong "
                "one too; label on (next_query) or accept by status().cut on the ranking"
            )
        feature, sign = RANKINGS[status.ranking]
        calibrator = platt(
            status.ranking, feature, sign, self._features[feature][labelled], self._labels[labelled] == 1
        )
        cut = calibrator.coef[0] * sign * status.cut + calibrator.intercept
        info = {
            "target_precision": self.target_precision,
            "delta": self.delta,
            "precision_lower_bound": status.precision_lower_bound,
            "expected_coverage": status.coverage,
            "sequential": status.to_dict(),
            "calibration": {"size": status.labelled, "min_candidates": self._least},
        }
        return Gate(calibrator, self.k, cut, info=info)
