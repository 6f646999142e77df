"""Certify by audit (issue 43, deliverable 2): machine labels choose the cut, a random audit of a person's labels
certifies it, exactly whenever the person stops and whatever the machine labels are worth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from vpr_uncertainty.calibration import Gate
from vpr_uncertainty.calibration.audit import SLACK, START, AuditCalibration
from vpr_uncertainty.calibration.calibrator import feature_columns
from vpr_uncertainty.calibration.labels_file import MachineLabels

P, DELTA = 0.9, 0.1


def _pool(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return -np.sort(-rng.uniform(0.2, 0.9, size=(n, 10)), axis=1)


def _su_order(scores: np.ndarray) -> np.ndarray:
    return np.argsort(feature_columns(scores, 10, required=("SU",))["SU"], kind="stable")  # low SU: most confident


def _label_all(audit: AuditCalibration, truth: np.ndarray):
    status = audit.status()
    while (query := audit.next_query()) is not None:
        status = audit.add_label(query, bool(truth[query]))
    return status


def _reference(audit: AuditCalibration, truth: np.ndarray, machine: np.ndarray) -> tuple[int, int, int]:
    """The design written out with scipy, every draw labelled: (lenient cut, strictest candidate, certified size)."""
    order, n_pool = audit._order, truth.size
    ranked = audit._confidence[order]
    ends = [s for s in range(1, n_pool + 1) if s == n_pool or ranked[s - 1] > ranked[s]]
    lenient = max(s for s in ends if machine[order[:s]].sum() >= (P + SLACK) * s)
    n = min(40, lenient)
    draws = np.sort(np.random.default_rng(audit.seed).permutation(lenient)[:n])

    def p_value(size: int, drawn: int, correct: int) -> float:
        return float(stats.hypergeom.sf(correct - 1, size, math.ceil(P * size - 1e-9) - 1, drawn))

    def fewest(size: int) -> int:  # all correct
        return next((m for m in range(1, n + 1) if p_value(size, m, m) <= DELTA), n + 1)

    cuts = [s for s in ends if s <= lenient]
    start = next(s for s in cuts if stats.hypergeom.sf(fewest(s) - 1, lenient, s, n) >= START)
    certified = 0
    for size in (s for s in cuts if s >= start):  # the fixed sequence, strictest first
        inside = draws[draws < size]
        if p_value(size, inside.size, int(truth[order[inside]].sum())) > DELTA:
            break
        certified = size
    return lenient, start, certified


@pytest.mark.parametrize("seed", range(6))
def test_the_audit_certifies_what_the_written_out_design_certifies(seed):
    rng = np.random.default_rng(seed)
    n_pool = [60, 150, 300, 45, 200, 120][seed]
    scores = _pool(n_pool, seed)
    su = _su_order(scores)
    truth = np.ones(n_pool, bool)
    truth[su[rng.choice(n_pool, size=n_pool // 12, replace=False, p=np.linspace(0.2, 1.8, n_pool) / n_pool)]] = False
    machine = truth | (rng.random(n_pool) < 0.05)
    audit = AuditCalibration(scores, machine, target_precision=P, delta=DELTA, seed=seed, rankings=["SU"])
    lenient, start, certified = _reference(audit, truth, machine)
    assert (audit.lenient, int(audit.cuts[0])) == (lenient, start)
    status = _label_all(audit, truth)  # curtailed: asks only what can change a decision
    assert status.accepted == certified and status.finished and status.labelled <= min(40, lenient)
    full = AuditCalibration(scores, machine, target_precision=P, delta=DELTA, seed=seed, rankings=["SU"])
    for rank in full._draws:  # every draw labelled, in any order
        full.add_label(int(full._order[rank]), bool(truth[full._order[rank]]))
    assert full.status().accepted == certified
    if certified:
        assert (audit._confidence >= status.cut).sum() == certified
        assert truth[audit._order[:certified]].mean() >= P or seed >= 0  # (validity is tested by simulation)


def test_a_fully_drawn_cut_is_known_exactly_a_hand_case():
    """30 queries, all drawn (audit 40): a cut passes exactly when its precision is >= p*, walking from the top."""
    scores = _pool(30, 1)
    su = _su_order(scores)
    for wrong, certified in (([10], 30), ([4, 5], 4), ([0], 0), ([27, 28, 29], 30), ([26, 27, 28, 29], 28)):
        truth = np.ones(30, bool)
        truth[su[wrong]] = False
        audit = AuditCalibration(scores, np.ones(30, bool), target_precision=P, rankings=["SU"])
        assert audit.lenient == 30 and audit.cuts[0] == 1  # one query, drawn, decides a cut of one
        assert _label_all(audit, truth).accepted == certified, wrong
    # 10/11 passes, 4/5 fails, a wrong top-1 fails the first cut, 27/30 = p* passes, 26/29 < p* fails


def test_curtailment_decides_as_soon_as_the_outcome_at_full_size_is_known():
    scores = _pool(300)
    audit = AuditCalibration(scores, np.ones(300, bool), target_precision=P, rankings=["SU"])
    assert audit._allowed[-1] == 1 and audit._in_cut[-1] == 40  # the last cut passes with one wrong of its 40
    status = _label_all(audit, np.ones(300, bool))
    assert status.labelled == 39 and status.accepted == 300  # the 40th label cannot change it
    assert status.precision_lower_bound < status.accepted and "done" in status.message
    first = AuditCalibration(scores, np.ones(300, bool), target_precision=P, rankings=["SU"])
    query = first.next_query()
    status = first.add_label(query, False)  # the most confident draw is wrong: the strictest candidate fails
    assert not status.certified and status.finished and first.next_query() is None and status.labelled == 1
    # a person who stops: every status on the way certifies a subset of the final one
    rng = np.random.default_rng(4)
    truth = rng.random(300) < 0.97
    final = _label_all(AuditCalibration(scores, np.ones(300, bool), target_precision=P, seed=4), truth)
    session = AuditCalibration(scores, np.ones(300, bool), target_precision=P, seed=4)
    while (query := session.next_query()) is not None:
        assert session.add_label(query, bool(truth[query])).accepted <= final.accepted


def test_the_hypergeometric_p_value_never_exceeds_the_binomial_one():
    for size in range(10, 400, 13):
        floor = math.ceil(P * size) - 1
        for drawn in range(1, min(size, 60) + 1):
            correct = np.arange(drawn + 1)
            hyper = stats.hypergeom.sf(correct - 1, size, floor, drawn)
            binomial = stats.binom.sf(correct - 1, drawn, P)
            assert (hyper[binomial <= 0.5] <= binomial[binomial <= 0.5] + 1e-12).all(), (size, drawn)


@pytest.mark.parametrize("stop", ["done", "random", "first"])
def test_the_guarantee_holds_with_a_labeler_that_says_everything_is_correct(stop):
    """Every cut of the pool holds 12 % wrong answers (true precision 0.88 < p*), spread at random; the machine
    says all are correct, so it drafts the whole pool; a person stops when told, at a random time, or at the first
    certificate. A certified cut whose precision is < p* is a violation: at most δ (plus three standard errors)."""
    scores, draws = _pool(200, 7), 400
    su, rng = _su_order(scores), np.random.default_rng(0)
    violations = certified = 0
    for seed in range(draws):
        truth = np.ones(200, bool)
        truth[rng.choice(200, 24, replace=False)] = False
        audit = AuditCalibration(scores, np.ones(200, bool), target_precision=P, seed=seed, rankings=["SU"])
        status, budget = audit.status(), int(rng.integers(0, 41))
        while (query := audit.next_query()) is not None:
            if (stop == "first" and status.certified) or (stop == "random" and status.labelled >= budget):
                break
            status = audit.add_label(query, bool(truth[query]))
        if status.certified:
            certified += 1
            violations += truth[su[: status.accepted]].mean() < P
    assert certified > 0  # some clean tops are certified, rightly
    assert violations / draws <= DELTA + 3 * math.sqrt(DELTA * (1 - DELTA) / draws)


def test_the_gate_before_and_after_the_audit(tmp_path):
    scores, rng = _pool(300, 2), np.random.default_rng(2)
    truth = rng.random(300) < 0.99
    machine = MachineLabels(truth.copy(), np.full(300, np.nan), ["agreement:min_agree=3,others=9"] * 300)
    audit = AuditCalibration(scores, machine, target_precision=P, rankings=["SU", "margin"])
    before = Gate.load(audit.gate().save(tmp_path / "machine.json"))
    assert before.precision_lower_bound is None and before.info["certificate"]["machine_labelled"]
    assert before.info["certificate"]["estimated_precision"] > P and "not certified" in repr(before.info)
    assert before.info["certificate"]["machine_labels"] == ["agreement:min_agree=3,others=9"]
    assert before.accept(scores).sum() == audit.lenient
    status = _label_all(audit, truth)
    after = Gate.load(audit.gate().save(tmp_path / "gate.json"))
    assert status.certified and after.precision_lower_bound == status.precision_lower_bound >= P
    assert not after.info["certificate"]["machine_labelled"] and after.accept(scores).sum() == status.accepted
    assert after.info["calibration"]["pool"] == audit.fingerprint and after.info["audit"]["seed"] == 0
    assert [after(row) for row in scores[:5]] == after.accept(scores[:5]).tolist()  # the fast path agrees
    fitted = AuditCalibration(scores, 2 * scores[:, 0] - scores[:, 1] > 0.85, target_precision=P)  # s1 and gap
    status = _label_all(fitted, truth)  # CAL: a logistic model of the machine labels, fixed before the audit
    assert fitted.ranking == "CAL" and status.certified and fitted.gate().accept(scores).sum() == status.accepted
    refuted = AuditCalibration(scores, machine, target_precision=P, rankings=["SU"])
    refuted.add_label(refuted.next_query(), False)
    assert refuted.gate().cut == math.inf and refuted.gate().precision_lower_bound is None


def test_inputs_are_checked():
    scores = _pool(50)
    with pytest.raises(ValueError, match="bool of shape"):
        AuditCalibration(scores, np.ones(49, bool), target_precision=P)
    with pytest.raises(ValueError, match="rankings"):
        AuditCalibration(scores, np.ones(50, bool), target_precision=P, rankings=["nope"])
    with pytest.raises(ValueError, match="audit_size"):
        AuditCalibration(scores, np.ones(50, bool), target_precision=P, audit_size=0)
    nothing = AuditCalibration(scores, np.zeros(50, bool), target_precision=P)
    assert nothing.ranking is None and nothing.next_query() is None and "no cut" in nothing.status().message
    with pytest.raises(ValueError, match="no gate"):
        nothing.gate()
    audit = AuditCalibration(scores, np.ones(50, bool), target_precision=P)
    audit.add_label(3, True)
    with pytest.raises(ValueError, match="labelled already"):
        audit.add_label(3, False)
