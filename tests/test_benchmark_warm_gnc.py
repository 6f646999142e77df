"""``benchmarks/warm_gnc.py``: the TLS weights and μ's start against hand-computed cases, and GTSAM's procedure
(``warm=False, prune=False``) against ``gtsam.GncLMOptimizer`` itself on the four-lap graph with wrong closures."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_close, load_benchmark

gtsam = pytest.importorskip("gtsam")


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("warm_gnc")


@pytest.fixture(scope="module")
def slam():
    return load_benchmark("loop_closure_slam")


def test_tls_weights_by_hand(bench):
    # μ = 1, c̄² = 1: weight 1 up to 1/2, 0 from 2, between √(c̄² μ (μ + 1) / r²) − μ = √(2 / r²) − 1
    errors = np.array([0.25, 0.5, 1.0, 1.5, 2.0, 4.0])
    expected = [1.0, 1.0, np.sqrt(2) - 1, np.sqrt(2 / 1.5) - 1, 0.0, 0.0]
    assert_close(bench.tls_weights(errors, np.ones(6), 1.0), expected)
    assert bench.tls_weights(np.array([0.0]), np.ones(1), 1e-6)[0] == 1.0  # a zero residual is an inlier, not a NaN


def test_initial_mu_by_hand(bench):
    thresholds = np.ones(3)
    assert bench.initial_mu(np.array([0.0, 1.0, 3.0]), thresholds) == pytest.approx(0.2)  # min(1 / 1, 1 / 5)
    assert bench.initial_mu(np.array([0.0, 0.5, 0.2]), thresholds) == -1.0  # no residual beyond c̄² / 2
    assert bench.initial_mu(np.array([0.0, 1e9]), np.ones(2)) == 1e-6  # floored as GTSAM floors it


def gtsam_gnc(graph, initial):
    """GTSAM's GncLMOptimizer set up as ``optimize(robust="gnc")`` sets it up; returns its poses and weights."""
    graph = graph.clone()
    graph.add(gtsam.PriorFactorPose2(0, initial.atPose2(0), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    params = gtsam.GncLMParams(gtsam.LevenbergMarquardtParams())
    keys = [graph.at(i).keys() for i in range(graph.size())]
    params.setKnownInliers([i for i, k in enumerate(keys) if len(k) == 1 or abs(k[1] - k[0]) == 1])  # odometry, prior
    optimizer = gtsam.GncLMOptimizer(graph, initial, params)
    optimizer.setInlierCostThresholdsAtProbability(0.99)
    return optimizer.optimize(), optimizer.getWeights()


@pytest.mark.parametrize("rate", [0.5, 0.85])
def test_gtsams_procedure_reproduces_gtsam_and_warm_finds_the_same_inliers(bench, slam, rate):
    problem = slam.four_lap()
    graph, _, _ = slam.with_wrong_closures(problem, rate, np.random.default_rng(0), "random")
    reference, reference_weights = gtsam_gnc(graph, problem.initial)
    assert sorted(np.unique(reference_weights)) == [0.0, 1.0]
    for warm in (False, True):
        values, weights = bench.gnc(graph, problem.initial, warm=warm, prune=warm)
        if not warm:  # GTSAM's own procedure: the same weights and poses
            assert_close(weights, reference_weights)
            assert_close(gtsam.utilities.extractPose2(values), gtsam.utilities.extractPose2(reference), atol=1e-6)
        # each wrong closure is rejected and each true one kept as GTSAM decides, and the trajectory is as good
        assert np.array_equal(weights[: graph.size()], reference_weights[: graph.size()])
        assert slam.ate(values, problem.truth)[0] == pytest.approx(slam.ate(reference, problem.truth)[0], rel=1e-3)


def test_the_first_gnc_iteration_starts_from_the_initial_values(bench, slam, monkeypatch):
    # from the least-squares solution of every closure, warm GNC broke on Sphere2500 (46.8 m at 30 % wrong closures)
    problem = slam.four_lap()
    graph, _, _ = slam.with_wrong_closures(problem, 0.5, np.random.default_rng(0), "random")
    monkeypatch.setattr(bench, "MAX_ITERATIONS", 1)
    warm, _ = bench.gnc(graph, problem.initial, warm=True, prune=False)
    cold, _ = bench.gnc(graph, problem.initial, warm=False, prune=False)
    assert np.array_equal(gtsam.utilities.extractPose2(warm), gtsam.utilities.extractPose2(cold))
