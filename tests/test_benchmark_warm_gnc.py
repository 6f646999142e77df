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


def gtsam_gnc(graph, initial, dim=2):
    """GTSAM's GncLMOptimizer set up as ``optimize(robust="gnc")`` sets it up; returns its poses and weights."""
    graph = graph.clone()
    prior, pose = (
        (gtsam.PriorFactorPose2, initial.atPose2(0)) if dim == 2 else (gtsam.PriorFactorPose3, initial.atPose3(0))
    )
    graph.add(prior(0, pose, gtsam.noiseModel.Isotropic.Sigma(pose.dim(), 1e-6)))
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


def helix(slam, seed=0):
    """A 3-D four-lap graph: 120 poses on a rising helix, odometry σ = 0.01 rad / 5 cm, 40 closures to the last lap."""
    rng, n_lap, sigmas = np.random.default_rng(seed), 30, np.array([0.01, 0.01, 0.01, 0.05, 0.05, 0.05])
    angle = 2 * np.pi * np.arange(4 * n_lap) / n_lap
    truth = [gtsam.Pose3(gtsam.Rot3.Ypr(a + np.pi / 2, 0, 0), [10 * np.cos(a), 10 * np.sin(a), a / 4]) for a in angle]
    noise, graph, initial = gtsam.noiseModel.Diagonal.Sigmas(sigmas), gtsam.NonlinearFactorGraph(), gtsam.Values()
    initial.insert(0, truth[0])

    def noisy(a, b):
        return truth[a].between(truth[b]).compose(gtsam.Pose3.Expmap(rng.normal(0, sigmas)))

    for i in range(1, len(truth)):
        graph.add(gtsam.BetweenFactorPose3(i - 1, i, step := noisy(i - 1, i), noise))
        initial.insert(i, initial.atPose3(i - 1).compose(step))
    for b in rng.choice(np.arange(n_lap, len(truth)), 40, replace=False).tolist():
        graph.add(gtsam.BetweenFactorPose3(b - n_lap, b, noisy(b - n_lap, b), noise))
    values = gtsam.Values()
    for i, pose in enumerate(truth):
        values.insert(i, pose)
    return slam.Problem("helix", graph, initial, slam.pose_rows(values))


def test_gtsams_procedure_reproduces_gtsam_in_3d(bench, slam):
    problem = helix(slam)
    graph, _, _ = slam.with_wrong_closures(problem, 0.7, np.random.default_rng(0), "random")
    reference, reference_weights = gtsam_gnc(graph, problem.initial, dim=3)
    assert sorted(np.unique(reference_weights)) == [0.0, 1.0]
    values, weights = bench.gnc(graph, problem.initial, warm=False, prune=False)
    assert_close(weights, reference_weights)
    assert_close(slam.pose_rows(values), slam.pose_rows(reference), atol=1e-6)
    assert slam.ate(reference, problem.truth)[0] < 0.2  # GNC rejected the wrong closures (odometry alone: 0.89 m)
