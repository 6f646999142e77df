"""Certify by audit: machine labels choose the rule, a random audit of a person's labels certifies it.

Machine labels choose the ranking and a nested family of candidate cuts (no δ spent); ``audit_size`` queries drawn at
random without replacement from the most lenient candidate are labelled by a person; each candidate's exact
hypergeometric test reads the draws that fall in it, strictest first in a fixed sequence at δ, curtailed so that
the guarantee holds whenever the person stops (docs/explanation/calibration.md, "Certify by audit").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from scipy import stats
from scipy.special import gammaln

from vpr_uncertainty._validation import check_count, check_top_k_scores
from vpr_uncertainty.calibration import calibrator as cal
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.calibration.guarantee import cuts_at_coverage, min_accepted
from vpr_uncertainty.calibration.labels_file import MachineLabels, pool_fingerprint
from vpr_uncertainty.calibration.sequential import Labelling, SequentialStatus

__all__ = ["AuditCalibration"]

#: The lenient cut's machine-labelled precision exceeds p* by this (docs/evidence/calibration.md).
SLACK = 0.03
#: The probability with which the strictest candidate receives enough draws to pass.
START = 0.9


class AuditCalibration(Labelling):
    """Certify the rule machine labels chose by a random audit of at most ``audit_size`` labels a person gives.

    Parameters
    ----------
    scores : array_like of shape (N, K)
        Top-k similarities of the pool (sorted descending per row).
    machine : array_like of shape (N,), bool, or MachineLabels
        The machine label of each pool query (a MachineLabels' sources are recorded in the gate).
    target_precision, delta : float in (0, 1)
        p* and the risk δ.
    k, seed, audit_size : int, default=10, 0, 40
        Candidates per query the features read; the seed of the draws; the draws (the most labels asked for).
    rankings : sequence of str, default=("SU", "margin", "CAL")
        What the machine labels choose from: :data:`~vpr_uncertainty.calibration.calibrator.RANKINGS` and ``CAL``.

    Examples
    --------
    >>> scores = -np.sort(-np.random.default_rng(0).uniform(0.2, 0.9, size=(300, 10)), axis=1)
    >>> audit = AuditCalibration(scores, np.ones(300, bool), target_precision=0.9)
    >>> while (query := audit.next_query()) is not None:
    ...     status = audit.add_label(query, True)  # every answer is correct
    >>> status.certified, status.coverage, status.labelled  # the 40th draw is not needed
    (True, 1.0, 39)
    """

    def __init__(
        self,
        scores: object,
        machine: object,
        *,
        target_precision: float,
        delta: float = 0.1,
        k: int = 10,
        seed: int = 0,
        audit_size: int = 40,
        rankings: Sequence[str] = ("SU", "margin", "CAL"),
    ) -> None:
        top = min_accepted(target_precision, delta)  # checks p* and δ
        scores = check_top_k_scores(scores, name="scores")
        self.sources = sorted(set(machine.sources)) if isinstance(machine, MachineLabels) else ["machine labels"]
        machine = np.asarray(getattr(machine, "correct", machine))
        if machine.dtype != bool or machine.shape != (len(scores),) or not len(scores):
            raise ValueError(f"machine labels must be bool of shape ({len(scores)},), got {machine.shape}")
        if isinstance(rankings, str) or not set(rankings) <= {*cal.RANKINGS, "CAL"}:
            raise ValueError(f"rankings must be names from {[*cal.RANKINGS, 'CAL']}, got {rankings!r}")
        self.target_precision, self.delta, self.k, self.seed = float(target_precision), float(delta), int(k), seed
        features, self._machine = cal.feature_columns(scores, self.k), machine
        self.fingerprint, self._least = pool_fingerprint(scores, self.k), int(np.isfinite(scores[:, :k]).sum(1).min())
        self.ranking, self._labels, best = None, np.full(len(scores), -1, np.int8), (0, np.zeros(1, int))
        for name in rankings:
            names = tuple(f for f in cal.DEFAULT_FEATURES if f in features)
            if name == "CAL" and 0 < machine.sum() < machine.size:
                rule = cal.fit_model(cal.columns(features, names), machine, names)
            elif name in cal.RANKINGS and cal.RANKINGS[name][0] in features:
                rule = cal.ranking_rule(name)
            else:
                continue
            confidence = rule.confidence(cal.columns(features, rule.features))
            order = np.argsort(-confidence, kind="stable")
            ranked, hits = confidence[order], np.cumsum(machine[order])
            ends = np.flatnonzero(np.append(ranked[:-1] > ranked[1:], True)) + 1  # cuts between distinct scores
            good = np.flatnonzero(hits[ends - 1] >= (self.target_precision + SLACK) * ends)
            cuts = ends[: good[-1] + 1 if good.size else 0]
            if cuts.size and hits[cuts[-1] - 1] > best[0]:  # the most machine-labelled correct answers
                best, self.ranking, scored = (hits[cuts[-1] - 1], cuts), name, (rule, confidence, order)
        self._rule, self._confidence, self._order = scored if self.ranking else (None, None, None)
        self.lenient = int(best[1][-1])  # the audit draws from the `lenient` most confident queries
        n = min(check_count(audit_size, "audit_size", 1), self.lenient)
        self._draws = np.sort(np.random.default_rng(seed).permutation(self.lenient)[:n])  # their ranks
        self.cuts = best[1][self._start(best[1], n, top) :] if self.ranking else best[1][:0]
        self._in_cut = np.searchsorted(self._draws, self.cuts)  # n_j: the draws each candidate reads (fixed)
        wrong = np.arange(int(np.ceil(n * (1 - self.target_precision))) + 2)[:, None]  # more never pass
        p_values = np.cumsum(np.exp(_log_pmf(self.cuts, self._floor(self.cuts), self._in_cut, wrong)), axis=0)
        self._allowed = (p_values <= self.delta).sum(axis=0) - 1  # wrong labels with which H_j is rejected

    def _floor(self, size: np.ndarray) -> np.ndarray:
        """⌈p*·size⌉ − 1: the most correct answers of a cut of ``size`` queries under H_j."""
        return np.ceil(self.target_precision * np.asarray(size) - 1e-9) - 1

    def _start(self, cuts: np.ndarray, n: int, top: int) -> int:
        """The index of the strictest cut that receives, with probability ≥ START, enough draws to pass all correct
        (at most ``top``, as many as the binomial test needs), read in blocks."""
        drawn = np.arange(1, min(n, top) + 1)[:, None]
        for block in range(0, cuts.size, 4096):
            size = cuts[block : block + 4096]
            passing = _log_pmf(size, self._floor(size), drawn, 0) <= math.log(self.delta) + 1e-12
            fewest = np.where(passing.any(axis=0), passing.argmax(axis=0) + 1, n + 1)
            likely = np.flatnonzero(stats.hypergeom.sf(fewest - 1, self.lenient, size, n) >= START)
            if likely.size:
                return block + int(likely[0])
        return cuts.size

    def _state(self) -> tuple[np.ndarray, int, bool]:
        """The draws' labels in rank order (-1 unlabelled), how many candidates lead passed, and whether the next
        one failed."""
        drawn = self._labels[self._order[self._draws]] if self.ranking else np.zeros(0, np.int8)
        wrong = np.concatenate([[0], np.cumsum(drawn == 0)])[self._in_cut]
        worst = wrong + np.concatenate([[0], np.cumsum(drawn < 0)])[self._in_cut]
        passed = int(np.argmax(np.append(worst > self._allowed, True)))
        return drawn, passed, passed < self.cuts.size and wrong[passed] > self._allowed[passed]

    def next_query(self) -> int | None:
        """The pool index of the query to label next (the most confident unlabelled draw of the first undecided
        candidate), None when no label can change the certificate."""
        drawn, passed, failed = self._state()
        if failed or passed == self.cuts.size:
            return None
        return int(self._order[self._draws[np.argmax(drawn < 0)]])

    def status(self) -> SequentialStatus:
        """Certified or not, and what the next decision needs: ``accepted`` and ``coverage`` are the pool queries
        the certified cut accepts, ``correct_accepted`` its audit draws labelled correct, ``rankings`` the ranking's
        lenient and strictest candidates, the audit's draws and those the certified cut holds (``audited``)."""
        drawn, passed, failed = self._state()
        size, audited = (int(self.cuts[passed - 1]), int(self._in_cut[passed - 1])) if passed else (0, 0)
        right, bound, p, n = int((drawn[:audited] == 1).sum()), None, self.target_precision, self._labels.size
        done = bool(failed or passed == self.cuts.size)
        what = f"nothing certified yet at precision {p:g}"
        if passed:  # the bound: the fewest correct in the cut with which its labels have a p-value > δ, over its size
            tail = np.exp(_log_pmf(size, np.arange(size + 1)[:, None], audited, np.arange(audited - right + 1)))
            bound = float(np.argmax(tail.sum(axis=1) > self.delta) / size)
            what = f"precision >= {p:g} certified (probability >= {1 - self.delta:g}) for the {size} most confident of "
            spare = int((drawn[:audited] < 0).sum())  # draws not needed: counted as wrong
            what += f"{n} queries by {self.ranking}: {right} of its {audited} audit draws labelled correct"
            what += f" ({spare} not needed), lower bound {bound:.3f}" if spare else f", lower bound {bound:.3f}"
        if not self.cuts.size:
            what += f": no cut of machine-labelled precision >= {p + SLACK:g} that {self._draws.size} draws can certify"
        elif done:
            what += "; done: no further label can certify more"
        else:
            nxt, room, reads = self.cuts[passed], self._allowed[passed], self._in_cut[passed]
            what += f"; next: the test of the {nxt} most confident, passed with <= {room} wrong of its {reads} draws"
        cut = float(cuts_at_coverage(self._confidence, np.array([size / n]))[0]) if passed else None
        ahead = (None, None) if done else (int(self.cuts[passed]), int(self._allowed[passed]))
        audit = dict(lenient=self.lenient, strictest=int(self.cuts[0]) if self.cuts.size else None, audited=audited)
        audit = {str(self.ranking): {**audit, "draws": int(self._draws.size)}}
        labelled, ranking = int((drawn >= 0).sum()), self.ranking if passed else None
        return SequentialStatus(
            labelled, bool(passed), ranking, cut, size, right, size / n, bound, done, *ahead, what, audit
        )

    def gate(self) -> Gate:
        """The certified rule as a :class:`~vpr_uncertainty.calibration.gate.Gate`. Before a certificate, the
        machine's lenient cut, machine-labelled (``precision_lower_bound`` None, ``certificate`` the labeler's
        precision of what it accepts); once the audit refuted it, a gate that accepts nothing. P(correct): Platt
        scaling of the ranking on the machine labels, a person's label where given."""
        status, target, labelled = self.status(), self._machine.copy(), self._labels >= 0
        if self.ranking is None:
            raise ValueError(f"no gate: {status.message}")
        target[labelled] = self._labels[labelled] == 1
        scale, rule = cal.platt("z", "z", 1.0, self._confidence, target), replace(self._rule, ranking=self.ranking)
        a, b = scale.coef[0], scale.intercept  # P = σ(a · rule's confidence + b)
        calibrator = replace(rule, coef=[a * c for c in rule.coef], intercept=a * rule.intercept + b)
        lenient = float(cuts_at_coverage(self._confidence, np.array([self.lenient / target.size]))[0])
        cut = status.cut if status.certified else math.inf if status.finished and status.labelled else lenient
        accepted = self._confidence >= cut
        guess = None if status.certified or not accepted.any() else float(self._machine[accepted].mean())
        message = status.message
        if guess is not None:
            labels = f"{', '.join(self.sources)} label {guess:.3f} of the {accepted.sum()} accepted correct"
            message = f"machine-labelled, not certified: {labels}; {message}"
        certificate = dict(certified=status.certified, machine_labelled=guess is not None, message=message)
        certificate |= {"estimated_precision": guess, "machine_labels": self.sources}
        info = dict(expected_coverage=float(accepted.mean()), audit={"seed": self.seed, **status.to_dict()})
        return self._gate(calibrator, cut, rule, status, certificate=certificate, **info)


def _log_pmf(size: object, correct: object, drawn: object, wrong: object) -> np.ndarray:
    """log P[``wrong`` wrong among ``drawn`` draws without replacement from ``size`` queries, ``correct`` of them
    correct] (hypergeometric), broadcast; -inf where impossible."""

    def choose(a: object, b: object) -> np.ndarray:
        a, b = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float))
        return np.where((b >= 0) & (b <= a), gammaln(a + 1) - gammaln(b + 1) - gammaln(a - b + 1), -np.inf)

    with np.errstate(invalid="ignore", divide="ignore"):  # drawn > size (never drawn): nan, which never passes
        return (
            choose(correct, np.subtract(drawn, wrong)) + choose(np.subtract(size, correct), wrong) - choose(size, drawn)
        )
