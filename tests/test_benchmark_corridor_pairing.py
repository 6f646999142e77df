"""The real-pairing corridor benchmark (``benchmarks/loop_closure_corridor.py``): the two-session graph, closures
from a hand-made similarity matrix and their correctness, the absent stretch's re-ranking, the cross-fitted gate."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_close, load_benchmark

gtsam = pytest.importorskip("gtsam")
N = 111


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("loop_closure_corridor")


@pytest.fixture(scope="module")
def matches(bench):
    """Similarity −|i − j| (the right frame first), except queries 30 and 70, which answer reference 90 and 10
    best, and query 0, which answers the last reference; positives within ±2 frames."""
    i, j = np.indices((N, N))
    similarity = -np.abs(i - j).astype(float) + 0.01 * j / N  # ties broken towards the later frame
    for query, reference in ((30, 90), (70, 10), (0, N - 1)):
        similarity[query, reference] = 1.0
    return bench.Matches("hand-made", similarity, np.abs(i - j) <= 2)


def test_graph_has_both_sessions_and_one_closure_per_query(bench, matches):
    kept = np.arange(N)
    props = bench.proposals(matches, kept)
    corridor = bench.corridor_graph(props, kept, N, seed=0)
    assert corridor.truth.shape == (2 * N, 8)
    assert corridor.dropped == 1  # query 0 → reference 110 is the link's vertex pair (110, 111)
    assert len(corridor.closures) == N - 1
    assert corridor.graph.size() == (N - 1) + 1 + (N - 1) + len(corridor.closures)  # odometry, link, odometry
    assert (corridor.closures[:, 1] - N == corridor.query).all()
    wrong = {tuple(p) for p in corridor.closures[~corridor.is_true].tolist()}
    assert wrong == {(90, N + 30), (10, N + 70)}
    assert_close(corridor.truth[N + 5, 1:3], [5 * bench.SPACING, bench.LATERAL])
    assert_close(corridor.rows[:, 0], matches.similarity[corridor.query].max(axis=1))


def test_closures_are_true_exactly_when_the_reference_is_a_positive(bench, matches):
    props = bench.proposals(matches, np.arange(N), n=3)
    assert len(props.query) == 3 * N
    assert (props.true == matches.positives[props.query, props.reference]).all()
    assert (props.rows == np.repeat(props.top1_rows, 3, axis=0)).all()  # a query's proposals share its row


def test_absent_stretch_removes_the_middle_columns_and_reranks(bench, matches):
    removed = bench.absent_stretch(N, 0.2)
    assert removed.tolist() == list(range(44, 66))
    kept = np.setdiff1d(np.arange(N), removed)
    props = bench.proposals(matches, kept)
    assert not np.isin(props.reference, removed).any()
    assert props.answerable.tolist() == [not set(range(q - 2, q + 3)) <= set(removed) for q in range(N)]
    assert props.reference[55] == 66 and not props.true[55]  # nearest kept frame, 11 frames away: wrong
    expected = np.sort(matches.similarity[:, kept], axis=1)[:, ::-1][:, :10]
    assert_close(props.top1_rows, expected)
    corridor = bench.corridor_graph(props, kept, N, seed=0)
    assert corridor.truth.shape == (2 * N - 22, 8)
    assert_close(corridor.truth[44, 1], 66 * bench.SPACING)  # vertex 44 is reference frame 66
    gap = next(corridor.graph.at(i) for i in range(corridor.graph.size()) if corridor.graph.at(i).keys() == [43, 44])
    assert_close(gap.measured().x(), 23 * bench.SPACING, atol=1.0)
    assert (np.diag(gap.noiseModel().covariance()) > 20 * bench.ODOMETRY_SIGMA**2).all()  # 23 steps' noise


def test_cross_fitted_gate_judges_each_fold_by_its_own_gate(bench):
    class Threshold:
        def __init__(self, cut):
            self.cut = cut

        def accept(self, scores):
            return scores[:, 0] >= self.cut

    gate = bench.CrossFitted([Threshold(0.5), None, Threshold(0.0)], np.array([0, 0, 1, 2, 2]))
    scores = np.array([[0.6], [0.4], [0.9], [0.1], [-0.1]])
    assert gate.accept(scores).tolist() == [True, False, False, True, False]


def test_gates_are_calibrated_on_the_other_folds_only(bench, matches, monkeypatch):
    props = bench.proposals(matches, np.arange(N))
    seen = []

    def calibrate(rows, correct, **options):
        seen.append((rows, correct, options))
        return type("Gate", (), {"precision_lower_bound": 0.95})()

    monkeypatch.setattr(bench, "calibrate_arrays", calibrate)
    _, fold, notes = bench.cross_fitted_gates(props, seed=3, folds=2)
    assert sorted(np.bincount(fold).tolist()) == [55, 56] and notes == [0.95, 0.95]
    for h, (rows, correct, options) in enumerate(seen):
        assert (rows == props.top1_rows[fold != h]).all() and (correct == props.top1_correct[fold != h]).all()
        assert options["target_precision"] == 0.9 and options["delta"] == 0.1
