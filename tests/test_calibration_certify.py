"""The certified gate spends every label: the grid, the rankings at δ/R, unlabelled cuts, CAL's choice."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from vpr_uncertainty import Gate, calibrate
from vpr_uncertainty.calibration.calibrator import feature_matrix
from vpr_uncertainty.calibration.fit import calibrate_arrays
from vpr_uncertainty.calibration.guarantee import certify_rankings, clopper_pearson_lower, cut_chain, cuts_at_coverage
from vpr_uncertainty.cli import main
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation import correct_at_n

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy")


@pytest.fixture
def corridor(corridor_dir, corridor_matches_dir):
    def read(method):
        retrieval = read_results(
            corridor_matches_dir / method / "precomputed_data_corrected.npy",
            ground_truth=corridor_dir / "ground_truth_new.npy",
        )
        return retrieval, correct_at_n(retrieval.indices, retrieval.positives, 1)

    return read


def _by_hand(confidence, correct, p_star, level):
    """The chain written out: accept the m most confident for each m of the chain, Wiens' fallback along it; the
    loosest rejected count and its correct answers (None when none is rejected)."""
    counts, levels = cut_chain(correct.size, p_star, level)
    order = np.argsort(-confidence, kind="stable")
    last, inherited = None, 0.0
    for m, own in zip(counts.tolist(), levels.tolist(), strict=True):
        good = int(correct[order[:m]].sum())
        level_now = own + inherited
        passed = stats.binom.sf(good - 1, m, p_star) <= level_now
        inherited = level_now if passed else 0.0
        last = (m, good) if passed else last
    return last


@pytest.mark.parametrize("method", ["AMOSNet", "HybridNet", "AlexNet_VPR"])
def test_a_training_free_ranking_is_tested_on_every_label(corridor, method):
    retrieval, correct = corridor(method)
    gate = calibrate(retrieval, target_precision=0.9, delta=0.1, rankings={"margin": 0.5, "SU": 0.5})
    certificate = gate.info["certificate"]
    assert certificate["n_test"] == 111 and gate.info["rankings"] == {"margin": 0.05, "SU": 0.05}
    found = {}
    for name, feature, sign in (("margin", "gap", 1), ("SU", "SU", -1)):
        confidence = sign * feature_matrix(retrieval.scores, features=(feature,))[:, 0]
        found[name] = _by_hand(confidence, correct, 0.9, 0.05)
        assert certificate["rankings"][name]["delta"] == 0.05
        assert certificate["rankings"][name]["certified"] == (found[name] is not None)
    if not any(found.values()):  # HybridNet: a wrong answer early in both rankings ends both chains at δ/2
        assert not certificate["certified"] and not gate.accept(retrieval.scores[:, : gate.k]).any()
        return
    winner = max((name for name in found if found[name]), key=lambda name: found[name][1])
    assert certificate["ranking"] == winner == gate.rule.ranking
    assert (certificate["accepted"], certificate["correct_accepted"]) == found[winner]
    # the gate applies the certified rule itself
    accepted = gate.accept(retrieval.scores[:, : gate.k])
    assert (accepted.sum(), (accepted & correct).sum()) == found[winner]
    assert gate.precision_lower_bound >= 0.9


def _two_signal_scores(gap):
    """Rows [0.9, 0.9 − gap, 0.1, …]: the margin ranks by ``gap``."""
    scores = np.full((gap.size, 10), 0.1)
    scores[:, 0], scores[:, 1] = 0.9, 0.9 - gap
    return scores


def test_hand_computed_chain_certifies_past_an_early_confident_error():
    """60 labelled queries ranked by the margin; wrong answers at ranks 2 and 56 (1-based).

    The chain at δ = 0.1 (fallback 0.3): 26 accepted at 0.07 (25 of 26 correct: p = 0.25, fails); nothing from 27 to
    51 (no level of its own, none passed on); 52 at the fallback level 0.03 (51 of 52: p = 0.028, passes); 53, 54, 55
    inherit 0.03 and pass (p 0.026, 0.023, 0.021); 56 (54 of 56: p = 0.052) fails and the chain ends. Certified: the
    cut accepting 55, 54 of them correct. The plain fixed sequence stops at its first test (21 of 22) and certifies
    nothing.
    """
    correct = np.ones(60, bool)
    correct[[1, 55]] = False
    scores = _two_signal_scores(0.5 - 0.005 * np.arange(60))
    p = [stats.binom.sf(good - 1, m, 0.9) for m, good in ((26, 25), (52, 51), (55, 54), (56, 54), (22, 21))]
    assert p[0] > 0.07 and p[1] <= 0.03 and p[2] <= 0.03 < p[3] and p[4] > 0.1
    gate = calibrate_arrays(scores, correct, target_precision=0.9, delta=0.1, rankings={"margin": 1.0})
    certificate = gate.info["certificate"]
    assert certificate["ranking"] == "margin" and (certificate["accepted"], certificate["correct_accepted"]) == (55, 54)
    assert gate.accept(scores).tolist() == [True] * 55 + [False] * 5
    assert certificate["precision_lower_bound"] == pytest.approx(float(clopper_pearson_lower(54, 55, 0.03)))
    fixed = certify_rankings(
        *({"gap": scores[:, 0] - scores[:, 1]},) * 2,
        correct,
        np.ones(60, bool),
        shares={"margin": 1.0},
        model_features=("gap",),
        target_precision=0.9,
        delta=0.1,
        folds=5,
        seed=0,
        fallback=0.0,
    )
    assert not fixed[0].certified and fixed[1] is None


def test_rankings_share_delta_and_the_winner_is_reported(corridor):
    retrieval, _correct = corridor("AMOSNet")
    gate = calibrate(retrieval, target_precision=0.8, delta=0.1, rankings=("SU", "margin", "BM"))
    certificate = gate.info["certificate"]
    assert {name: o["delta"] for name, o in certificate["rankings"].items()} == pytest.approx(
        dict.fromkeys(("SU", "margin", "BM"), 0.1 / 3)
    )
    winner = certificate["ranking"]
    best = max(outcome["correct_accepted"] for outcome in certificate["rankings"].values())
    assert certificate["rankings"][winner]["correct_accepted"] == best == certificate["correct_accepted"]
    assert gate.rule.ranking == winner
    weighted = calibrate(retrieval, target_precision=0.8, rankings={"margin": 0.9, "SU": 0.1})
    assert weighted.info["rankings"] == pytest.approx({"margin": 0.09, "SU": 0.01})
    with pytest.raises(ValueError, match="unknown ranking"):
        calibrate(retrieval, target_precision=0.9, rankings=("SU", "bogus"))
    with pytest.raises(ValueError, match="sum to at most 1"):
        calibrate(retrieval, target_precision=0.9, rankings={"SU": 0.7, "margin": 0.7})


def test_probability_is_the_selected_calibrators_with_or_without_a_target(corridor):
    """Held-out AUC-PR of probability_correct is the same with a target as without (the same selection)."""
    from sklearn.metrics import auc, precision_recall_curve

    for method in ("AMOSNet", "HybridNet", "CALC"):
        retrieval, correct = corridor(method)
        scores = retrieval.scores[:, :10]
        labelled = np.random.default_rng(1).permutation(111)[:60]
        held_out = np.setdiff1d(np.arange(111), labelled)
        plain = calibrate_arrays(scores[labelled], correct[labelled])
        certified = calibrate_arrays(scores[labelled], correct[labelled], target_precision=0.8)
        assert certified.info["selection"] == plain.info["selection"] and certified.calibrator == plain.calibrator
        aucs = []
        for gate in (plain, certified):
            precision, recall, _ = precision_recall_curve(correct[held_out], gate.probability_correct(scores[held_out]))
            aucs.append(auc(recall, precision))
        assert aucs[0] == aucs[1], method
        if method == "HybridNet":  # certified there, and the P it gives is not that of the certified ranking
            assert certified.precision_lower_bound >= 0.8


def test_cuts_come_from_unlabelled_scores_and_never_from_labels(corridor):
    retrieval, correct = corridor("HybridNet")
    labelled, pool = np.arange(0, 111, 2), np.arange(1, 111, 2)
    scores = retrieval.scores[:, :10]
    gate = calibrate_arrays(
        scores[labelled], correct[labelled], target_precision=0.8, unlabelled=scores[pool], rankings=("SU",)
    )
    certificate = gate.info["certificate"]
    assert certificate["certified"] and gate.info["calibration"]["n_unlabelled"] == pool.size
    # the cut is the pooled −SU quantile at a coverage of the label-free grid
    su = feature_matrix(np.concatenate([scores[labelled], scores[pool]]), features=("SU",))[:, 0]
    assert any(np.isclose(certificate["coverage"], cut_chain(labelled.size, 0.8, 0.1)[0] / labelled.size))
    cut_on_su = cuts_at_coverage(-su, np.array([certificate["coverage"]]))[0]
    own_su = feature_matrix(scores[labelled], features=("SU",))[:, 0]
    assert (gate.accept(scores[labelled]) == (-own_su >= cut_on_su)).all()
    # flipping the labels of the unlabelled queries changes nothing: they are never read
    other = calibrate_arrays(
        scores[labelled], correct[labelled], target_precision=0.8, unlabelled=scores[pool][::-1], rankings=("SU",)
    )
    assert other.cut == gate.cut


def test_cal_chooses_the_fixed_score_that_works(corridor):
    # on CALC the best match is right and SU fails (held-out AUC-PR 0.79 vs 0.52)
    retrieval, _ = corridor("CALC")
    gate = calibrate(retrieval)
    assert gate.info["selection"]["chosen"] == "BM" and gate.calibrator.features == ("s1",)
    scores = gate.info["selection"]["average_precision"]
    assert scores["BM"] == max(scores.values()) and {"SU", "margin", "PA", "CAL"} <= set(scores)
    # the P of a fixed score is increasing in its confidence (Platt scaling)
    p = gate.probability_correct(retrieval.scores[:, : gate.k])
    order = np.argsort(retrieval.scores[:, 0])
    assert (np.diff(p[order]) >= -1e-12).all()


def test_a_gate_fresh_from_calibrate_keeps_plain_floats(corridor):
    retrieval, _ = corridor("AMOSNet")
    for gate in (calibrate(retrieval), calibrate(retrieval, features=("s1", "gap", "PA", "SU"))):
        weights = [getattr(gate, name) for name in Gate.__slots__ if name.startswith(("_w_", "_bias", "_cut"))]
        assert all(type(value) is float for value in weights), [type(value) for value in weights]


def test_gate_file_with_unknown_or_repeated_feature_is_refused(corridor, tmp_path):
    retrieval, _ = corridor("AMOSNet")
    data = calibrate(retrieval, features=("s1", "SU")).to_dict()
    for features in (["s1", "su"], ["s1", "bogus"], ["SU", "SU"]):
        data["calibrator"]["features"] = features
        path = tmp_path / "gate.json"
        path.write_text(json.dumps(data))
        with pytest.raises(ValueError, match="features must be distinct names"):
            Gate.load(path)


def _outcome(call):
    try:
        return call()
    except (TypeError, ValueError) as error:
        return type(error).__name__


@pytest.mark.parametrize(
    "row",
    [
        [0.52, 0.40, 0.39, 0.38, 0.37, 0.36, 0.36, 0.35, 0.35, 0.34],
        [1e308, 1e307, *[1e306] * 8],
        [1e308] * 10,
        [1e308, *[-1e308] * 9],
        [-1e308] * 10,
        ["0.5"] * 10,
        [0.5] * 9 + [None],
        [0.4] * 9 + [0.5],
        [float("nan")] + [0.1] * 9,
        [0.5, 0.4, 0.3],  # a row of 3 on a gate of k = 10: refused by every path
    ],
)
@pytest.mark.parametrize("kind", ["certified", "model", "isotonic"])
def test_one_query_paths_agree_on_every_input(corridor, row, kind):
    """gate(row) and gate.accept give the same decision, or both refuse the row; probability_one and
    probability_correct the same P, or both refuse it (P may overflow where the rule does not: another map)."""
    retrieval, _ = corridor("AMOSNet")
    options = {"certified": {"target_precision": 0.9}, "model": {"features": ("s1", "gap", "SU", "zscore")}}
    gate = calibrate(retrieval, **options.get(kind, {"model": "isotonic"}))
    one = _outcome(lambda: gate(row))
    accepted = _outcome(lambda: bool(gate.accept(np.array([row]))[0]))
    probability = _outcome(lambda: gate.probability_one(row))
    batch_probability = _outcome(lambda: float(gate.probability_correct(np.array([row]))[0]))
    assert (one == accepted) or (isinstance(one, str) and isinstance(accepted, str)), (one, accepted)
    if isinstance(probability, float) and isinstance(batch_probability, float):
        assert probability == pytest.approx(batch_probability, rel=1e-9, abs=1e-12)
    else:
        assert isinstance(probability, str) and isinstance(batch_probability, str)
    assert not isinstance(one, str) or isinstance(probability, str)  # a row the gate refuses has no P either


@pytest.mark.parametrize("scores", [np.zeros((2, 10)), np.array(["0.5", "0.4"]), "0.5"])
def test_probability_one_refuses_what_gate_refuses(corridor, scores):
    retrieval, _ = corridor("AMOSNet")
    gate = calibrate(retrieval)
    with pytest.raises((TypeError, ValueError)):
        gate.probability_one(scores)
    with pytest.raises((TypeError, ValueError)):
        gate(scores)


def test_average_precision_equals_scikit_learn_with_ties():
    from sklearn.metrics import average_precision_score

    from vpr_uncertainty.calibration.calibrator import average_precision

    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(2, 80))
        correct = rng.random(n) < 0.6
        confidence = rng.integers(0, 8, n).astype(np.float64)  # many ties
        if correct.any():
            assert average_precision(correct, confidence) == pytest.approx(
                average_precision_score(correct, confidence), rel=1e-12
            )


def test_readme_loop_closure_example(corridor):
    """Calibrate on the first 56 queries of the traversal, gate the other 55 (README "Loop-closure example")."""
    found = {}
    for method in ("AMOSNet", "HybridNet", "AlexNet_VPR"):
        retrieval, correct = corridor(method)
        scores = retrieval.scores
        for target in (0.9, 0.8):
            gate = calibrate_arrays(scores[:56], correct[:56], target_precision=target, unlabelled=scores[56:])
            accepted = gate.accept(scores[56:, : gate.k])
            found[method, target] = (int(accepted.sum()), int((accepted & correct[56:]).sum()))
    assert found["AMOSNet", 0.9] == found["HybridNet", 0.9] == found["AlexNet_VPR", 0.9] == (0, 0)
    assert found["AMOSNet", 0.8] == (45, 43) and found["HybridNet", 0.8] == (12, 12)
    assert found["AlexNet_VPR", 0.8] == (0, 0)


def test_a_failing_plot_leaves_the_gate_file_as_it_was(corridor_dir, corridor_matches_dir, tmp_path, capsys):
    matches = corridor_matches_dir / "AMOSNet" / "precomputed_data_corrected.npy"
    gate = tmp_path / "gate.json"
    gate.write_text("the previous gate")
    blocked = tmp_path / "plot.unknown-format"  # matplotlib cannot write it: the plot fails
    argv = ["calibrate", str(matches), "--gt", str(corridor_dir / "ground_truth_new.npy"), "--out", str(gate)]
    assert main([*argv, "--plot", str(blocked)]) != 0
    assert gate.read_text() == "the previous gate"
    assert main(argv) == 0 and Gate.load(gate).k == 10
