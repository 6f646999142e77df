"""Sequential labelling (issue 29, deliverable 4): the tool picks the next query, certifies as soon as the proof is
in, and is exact whenever the user stops."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from vpr_uncertainty.calibration import SequentialCalibration, calibrate_arrays
from vpr_uncertainty.calibration.calibrator import RANKINGS, feature_columns
from vpr_uncertainty.evaluation import correct_at_n


def _pool(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return -np.sort(-rng.uniform(0.2, 0.9, size=(n, 10)), axis=1)


def _label_all(session: SequentialCalibration, correct: np.ndarray):
    status = session.status()
    while (query := session.next_query()) is not None:
        status = session.add_label(query, bool(correct[query]))
    return status


def test_the_chain_stops_at_the_hand_computed_count():
    # 40 queries, p* = 0.9, δ = 0.1, one ranking: the chain's first test is at 26 (0.9^26 = 0.065 <= 0.07 = 0.7 δ)
    # and from there every count (n/4 = 10 < 26); the fallback count (one wrong answer at 0.03 δ) lies beyond 40
    session = SequentialCalibration(_pool(40), target_precision=0.9, delta=0.1, rankings=["SU"])
    assert session.chains[0].tests.tolist() == list(range(26, 41))
    correct = np.ones(40, bool)
    correct[session.chains[0].order[30]] = False  # the 31st most confident answer is wrong
    status = _label_all(session, correct)
    # 30 of 30 pass; 30 of 31: P[Bin(31, 0.9) >= 30] = 0.17 > 0.07 fails, and no later test holds any level
    assert (status.certified, status.accepted, status.correct_accepted, status.finished) == (True, 30, 30, True)
    assert status.labelled == 31  # the last nine queries are never asked for
    assert status.precision_lower_bound == pytest.approx(stats.beta.ppf(0.07, 30, 1))


@pytest.mark.parametrize(("wrong_ranks", "certified", "labelled"), [([1], 200, 200), ([1, 2], 0, 3)])
def test_one_early_wrong_answer_does_not_end_the_chain_two_do(wrong_ranks, certified, labelled):
    # the fallback test (52 accepted, one wrong answer allowed at 0.03) takes over when the first test (26) fails
    session = SequentialCalibration(_pool(200), target_precision=0.9, delta=0.1, rankings=["SU"])
    correct = np.ones(200, bool)
    correct[session.chains[0].order[wrong_ranks]] = False
    status = _label_all(session, correct)
    assert (status.accepted, status.labelled, status.finished) == (certified, labelled, True)
    assert session.next_query() is None and "done" in status.message


def _reference(confidence, correct, counts, levels, p_star):
    """The batch chain with the whole pool labelled, written out (Wiens' fallback): the largest count certified."""
    ranked = correct[np.argsort(-confidence, kind="stable")]
    certified, carried, passed = 0, 0.0, False
    for m, own in zip(counts, levels, strict=True):
        level = own + (carried if passed else 0.0)
        passed = stats.binom.sf(ranked[:m].sum() - 1, m, p_star) <= level
        carried = level
        certified = m if passed else certified
    return certified


def test_sequential_certifies_what_the_batch_sequence_would_with_every_label(corridor_dir, corridor_matches_dir):
    from vpr_uncertainty.data import read_results

    for method in ("NetVLAD", "AMOSNet", "HybridNet", "CoHOG"):
        retrieval = read_results(
            corridor_matches_dir / method / "precomputed_data_corrected.npy",
            ground_truth=corridor_dir / "ground_truth_new.npy",
        )
        correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
        for ranking in ("SU", "margin"):
            session = SequentialCalibration(retrieval.scores, target_precision=0.9, delta=0.1, rankings=[ranking])
            status = _label_all(session, correct)
            feature, sign = RANKINGS[ranking]
            confidence = sign * feature_columns(retrieval.scores, 10, required=(feature,))[feature]
            chain = session.chains[0]
            assert status.accepted == _reference(confidence, correct, chain.tests, chain.levels, 0.9), (method, ranking)
            if status.certified:  # the cut accepts exactly the certified queries of the pool
                assert (confidence >= status.cut).sum() == status.accepted


def test_stopping_at_any_label_keeps_a_subset_of_the_final_certificate():
    rng = np.random.default_rng(3)
    scores = _pool(150, seed=3)
    correct = rng.random(150) < 0.95
    session = SequentialCalibration(scores, target_precision=0.9, delta=0.1)
    final = _label_all(SequentialCalibration(scores, target_precision=0.9, delta=0.1), correct)
    accepted = []
    while (query := session.next_query()) is not None:
        accepted.append(session.add_label(query, bool(correct[query])).rankings)
    for step in accepted:  # never more than the full run certifies, per ranking
        for name, outcome in step.items():
            assert outcome["accepted"] <= final.rankings[name]["accepted"]


def test_the_guarantee_holds_on_resampled_corridor_populations(corridor_dir, corridor_matches_dir):
    from vpr_uncertainty.data import read_results

    retrieval = read_results(
        corridor_matches_dir / "AMOSNet" / "precomputed_data_corrected.npy",
        ground_truth=corridor_dir / "ground_truth_new.npy",
    )
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    scores = np.asarray(retrieval.scores)
    rng = np.random.default_rng(0)
    violations = certified = 0
    draws = 60
    for _ in range(draws):
        rows = rng.integers(0, len(scores), 200)
        status = _label_all(SequentialCalibration(scores[rows], target_precision=0.8, delta=0.1), correct[rows])
        if status.certified:
            certified += 1
            feature, sign = RANKINGS[status.ranking]
            accept = sign * feature_columns(scores, 10, required=(feature,))[feature] >= status.cut
            violations += correct[accept].mean() < 0.8
    assert certified > draws // 2  # the test is not empty
    assert violations / draws <= 0.1 + 3 * np.sqrt(0.1 * 0.9 / draws)


def test_the_gate_accepts_what_the_status_certifies():
    scores = _pool(120, seed=1)
    correct = np.ones(120, bool)
    session = SequentialCalibration(scores, target_precision=0.9, delta=0.1)
    with pytest.raises(ValueError, match="no gate yet: nothing certified"):
        session.gate()
    correct[session.chains[0].order[40]] = False
    status = _label_all(session, correct)
    gate = session.gate()
    feature, sign = RANKINGS[status.ranking]
    by_status = sign * feature_columns(scores, 10, required=(feature,))[feature] >= status.cut
    assert np.array_equal(gate.accept(scores), by_status)
    assert gate.precision_lower_bound == status.precision_lower_bound


def test_bad_labels_and_rankings_are_refused():
    session = SequentialCalibration(_pool(50), target_precision=0.9)
    with pytest.raises(ValueError, match=r"pool index in \[0, 50\)"):
        session.add_label(50, True)
    with pytest.raises(ValueError, match="pool index"):
        session.add_label(True, True)
    session.add_label(3, True)
    with pytest.raises(ValueError, match="labelled already"):
        session.add_label(3, False)
    with pytest.raises(ValueError, match="training-free"):
        SequentialCalibration(_pool(50), target_precision=0.9, rankings=["CAL"])
    with pytest.raises(ValueError, match="holds no query"):
        SequentialCalibration(np.zeros((0, 10)), target_precision=0.9)
    small = SequentialCalibration(
        _pool(10), target_precision=0.9
    )  # 0.9^32 <= 0.7 · δ/2: 32 all-correct answers start a chain
    assert small.next_query() is None
    assert "the pool's 10 queries are fewer than the 32 a first test needs" in small.status().message
    with pytest.raises(ValueError, match="target_precision"):
        SequentialCalibration(_pool(50), target_precision=1.5)


def test_sequential_needs_fewer_labels_than_batch_on_a_clean_top():
    # a pool whose SU top is clean and whose tail is mostly wrong: the batch gate must label a random sample
    scores = _pool(300, seed=5)
    su_order = np.argsort(feature_columns(scores, 10, required=("SU",))["SU"], kind="stable")
    correct = np.zeros(300, bool)
    correct[su_order[:120]] = True
    status = _label_all(SequentialCalibration(scores, target_precision=0.9, delta=0.1), correct)
    assert status.certified and status.accepted >= 100
    rng = np.random.default_rng(0)
    rows = rng.choice(300, status.labelled, replace=False)
    batch = calibrate_arrays(scores[rows], correct[rows], target_precision=0.9, delta=0.1)
    assert batch.accept(scores).sum() < status.accepted


def test_cli_labels_from_the_ground_truth_then_resumes_from_the_labels_file(
    corridor_dir, corridor_matches_dir, tmp_path, capsys
):
    from vpr_uncertainty.calibration import Gate
    from vpr_uncertainty.cli import main

    matrix = str(corridor_matches_dir / "AMOSNet" / "precomputed_data_corrected.npy")
    labels, gate = tmp_path / "labels.csv", tmp_path / "gate.json"
    common = ["--sequential", str(labels), "--target-precision", "0.9"]
    assert (
        main(["calibrate", matrix, "--gt", str(corridor_dir / "ground_truth_new.npy"), *common, "--out", str(gate)])
        == 0
    )
    simulated = capsys.readouterr().out
    assert "certified" in simulated and "done" in simulated and Gate.load(gate).precision_lower_bound > 0.9
    rows = labels.read_text().splitlines()
    assert rows[0].startswith("# vpr-uncertainty labels of pool ") and rows[1] == "query,correct" and len(rows) > 24
    assert main(["calibrate", matrix, *common]) == 0  # the labels file alone gives the same status
    assert capsys.readouterr().out.splitlines()[-1] == simulated.splitlines()[-2]


def test_cli_asks_for_one_label_at_a_time(corridor_matches_dir, tmp_path, capsys):
    from vpr_uncertainty.cli import main

    matrix = str(corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy")
    labels = tmp_path / "labels.csv"
    argv = ["calibrate", matrix, "--sequential", str(labels), "--target-precision", "0.9"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "0 of 111 queries labelled" in out and "label next: query" in out
    query = int(out.split("label next: query ")[1].split()[0])
    labels.write_text(f"query,correct\n{query},yes\n")
    assert main(argv) == 0
    assert "1 of 111 queries labelled" in capsys.readouterr().out
    labels.write_text("query,correct\n5,maybe\n")
    assert main(argv) == 2
    assert "labels.csv, line 2: correct must be 1/0" in capsys.readouterr().err
