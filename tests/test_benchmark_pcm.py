"""PCM in ``benchmarks/pairwise_consistency.py``: the pairwise cycle test against a finite-difference reference through
GTSAM, a hand-made square graph, and the maximum clique of a small consistency graph."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_close, load_benchmark

gtsam = pytest.importorskip("gtsam")


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("pairwise_consistency")


def test_adjoint_and_log_are_gtsams(bench):
    rng = np.random.default_rng(0)
    planar = [gtsam.Pose2(*rng.normal(0, 2, 3)) for _ in range(5)] + [gtsam.Pose2(1, 2, 1e-12)]
    spatial = [gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 1, 3)), rng.normal(0, 3, 3)) for _ in range(5)]
    spatial.append(gtsam.Pose3(gtsam.Rot3.Expmap(np.array([1e-9, 0, 0])), np.array([1.0, 2, 3])))
    for poses, log in ((planar, gtsam.Pose2.Logmap), (spatial, gtsam.Pose3.Logmap)):
        matrices = np.array([p.matrix() for p in poses])
        assert_close(bench.adjoint(matrices), np.array([p.AdjointMap() for p in poses]))
        assert_close(bench.log_map(matrices), np.array([log(p) for p in poses]), atol=1e-12)


def chain_graph(dim: int, n: int, closures: list[tuple[int, int]], rng):
    """A graph of n poses joined by noisy odometry, and closures that agree exactly with the odometry poses."""
    Pose, Factor = (gtsam.Pose2, gtsam.BetweenFactorPose2) if dim == 2 else (gtsam.Pose3, gtsam.BetweenFactorPose3)
    sigmas = np.array([0.05, 0.04, 0.01]) if dim == 2 else np.array([0.01, 0.02, 0.015, 0.05, 0.04, 0.03])
    graph, steps = gtsam.NonlinearFactorGraph(), []
    for k in range(n - 1):
        step = Pose.Expmap(np.r_[1.0, 0.3, 0.2] if dim == 2 else np.r_[0.1, 0.2, 0.3, 1.0, 0.2, 0.1])
        steps.append(step.compose(Pose.Expmap(rng.normal(0, sigmas))))
        graph.add(Factor(k, k + 1, steps[-1], gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    poses = [Pose()]
    for step in steps:
        poses.append(poses[-1].compose(step))
    closure_sigmas = 2 * sigmas
    for a, b in closures:
        graph.add(Factor(a, b, poses[a].between(poses[b]), gtsam.noiseModel.Diagonal.Sigmas(closure_sigmas)))
    return graph, steps, sigmas, closure_sigmas, Pose


@pytest.mark.parametrize("dim", [2, 3])
def test_cycle_covariance_matches_finite_differences(bench, dim):
    """At consistent closures the cycle error is zero and its covariance is J Σ Jᵀ, J by central differences of
    GTSAM's own compose / Logmap over every noise variable (closures and odometry steps)."""
    rng = np.random.default_rng(dim)
    ends = [(2, 8), (9, 5), (3, 1), (10, 4)]  # both directions, interleaved chains (shared odometry steps)
    graph, steps, sigmas, closure_sigmas, Pose = chain_graph(dim, 12, ends, rng)
    poses, cumulative = bench.odometry_chain(graph)
    factors = [graph.at(11 + i) for i in range(len(ends))]
    measured = np.array([f.measured().matrix() for f in factors])
    covariances = np.array([f.noiseModel().covariance() for f in factors])
    first, second = np.triu_indices(len(ends), 1)
    error, covariance = bench.cycle_errors(poses, cumulative, np.array(ends), measured, covariances, first, second)
    assert_close(error, np.zeros_like(error), atol=1e-12)
    m = len(sigmas)

    def log_cycle(x, i, j):
        eta1, eta2, odo = x[:m], x[m : 2 * m], x[2 * m :].reshape(-1, m)
        walked = [Pose()]
        for step, eps in zip(steps, odo, strict=True):
            walked.append(walked[-1].compose(step.compose(Pose.Expmap(eps))))
        (a, b), (c, d) = ends[i], ends[j]
        z1 = factors[i].measured().compose(Pose.Expmap(eta1))
        z2 = factors[j].measured().compose(Pose.Expmap(eta2))
        cycle = z1.compose(walked[b].between(walked[d])).compose(z2.inverse()).compose(walked[c].between(walked[a]))
        return Pose.Logmap(cycle)

    variances = np.r_[closure_sigmas, closure_sigmas, np.tile(sigmas, len(steps))] ** 2
    h = 1e-6
    for p, (i, j) in enumerate(zip(first, second, strict=True)):
        jacobian = np.stack(
            [(log_cycle(h * e, i, j) - log_cycle(-h * e, i, j)) / (2 * h) for e in np.eye(len(variances))],
            axis=1,
        )
        # central differences of a smooth map at step 1e-6: about 1e-9 relative, hence the looser tolerance
        np.testing.assert_allclose(covariance[p], jacobian * variances @ jacobian.T, rtol=1e-6, atol=1e-10)


def square_graph(wrong_translation: float):
    """A 1 m square walked twice (poses 0-7, exact odometry, σ 5 cm / 0.01 rad) with closures (0, 4) and (1, 5)
    measuring the identity, and (2, 6) measuring a translation of ``wrong_translation`` m along x."""
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.01]))
    graph = gtsam.NonlinearFactorGraph()
    for k in range(7):
        graph.add(gtsam.BetweenFactorPose2(k, k + 1, gtsam.Pose2(1, 0, np.pi / 2), noise))
    for a, b, x in ((0, 4, 0.0), (1, 5, 0.0), (2, 6, wrong_translation)):
        graph.add(gtsam.BetweenFactorPose2(a, b, gtsam.Pose2(x, 0, 0), noise))
    return graph


def test_pcm_keeps_consistent_closures_of_a_square_and_drops_a_5_m_wrong_one(bench):
    closures = np.array([(0, 4), (1, 5), (2, 6)])
    assert bench.pcm(square_graph(0.0), closures, np.ones(3, bool)).tolist() == [True, True, True]
    graph = square_graph(5.0)
    assert bench.pcm(graph, closures, np.ones(3, bool)).tolist() == [True, True, False]
    assert bench.pcm(graph, closures, np.array([False, True, True])).sum() == 1  # two inconsistent: one kept

    # by hand: the cycle 0 → 4 → 6 → 2 → 0 of closures (0, 4) and (2, 6) is E = (1, 1, π)(−5, 0, 0)(1, 1, π) =
    # (5, 0, 0): Log(E) = (5, 0, 0), and that of (0, 4) with (1, 5) is exactly zero
    poses, cumulative = bench.odometry_chain(graph)
    measured = np.array([graph.at(7 + i).measured().matrix() for i in range(3)])
    covariances = np.array([graph.at(7 + i).noiseModel().covariance() for i in range(3)])
    error, covariance = bench.cycle_errors(poses, cumulative, closures, measured, covariances, np.r_[0, 0], np.r_[1, 2])
    assert_close(error, np.array([[0.0, 0, 0], [5, 0, 0]]), atol=1e-12)
    distance = error[1] @ np.linalg.solve(covariance[1], error[1])
    assert distance > 1000 > bench.chi2.ppf(bench.PCM_QUANTILE, 3)


def test_maximum_clique_exact_and_greedy(bench):
    adjacency = np.zeros((7, 7), bool)
    for group in ([0, 1, 2, 3], [3, 4, 5], [5, 6]):
        for i in group:
            for j in group:
                adjacency[i, j] = i != j
    assert bench.maximum_clique(adjacency).tolist() == [0, 1, 2, 3]
    assert bench.greedy_clique(adjacency).tolist() == [0, 1, 2, 3]
    assert bench.greedy_clique(adjacency, time_limit=0).tolist() == [0, 1, 2, 3]  # the first start always runs
    assert bench.maximum_clique(np.zeros((3, 3), bool)).size == 1
