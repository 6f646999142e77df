"""Graduated non-convexity with truncated least squares (Yang, Antonante, Tzoumas and Carlone, RA-L 2020), as GTSAM's
``GncOptimizer`` runs it, with two changes that make it a different method, measured beside it by
``loop_closure_slam.py`` (configurations "… GNC warm").

GTSAM's ``GncOptimizer`` (TLS, linear schedule, default parameters) solves the graph with every weight 1, sets the
control parameter μ from the residuals at the initial values, and then, until the weights are binary or the cost
stops changing (relative 10⁻⁵), computes each closure's weight from its residual at the last solution, solves the
weighted graph with Levenberg–Marquardt **from the initial values**, and multiplies μ by 1.4. Every inner solve
keeps every closure in the linear system, a weight-0 closure included. On a large graph with random wrong closures
each solve then costs what the filled-in Cholesky factor of all closures costs (``loop_closure_slam.py --fill-in``),
and each inner LM walks the whole way from the odometry again: about 19 hours projected on City10000 at 30 %.

``gnc(..., warm=True, prune=True)`` (the defaults) changes exactly two things:

* **warm**: each inner solve after GNC's first starts from the previous one's solution (the continuation the method
  is named after), not from the initial values. The first starts from the initial values, as GTSAM's does: started
  from the least-squares solution of every closure (this script at commit ecda523), GNC alone on Sphere2500 with
  30 % random wrong closures followed that broken solution to 46.8 m (1,798 s), since at a small μ every closure
  weighs almost nothing and the odometry guess is the good start;
* **prune**: a closure whose weight is 0 is left out of the inner solve (it adds nothing to the cost and only fills
  the factor in).

``warm=False, prune=False`` is GTSAM's procedure step by step; ``tests/test_benchmark_warm_gnc.py`` checks that it
reproduces ``gtsam.GncLMOptimizer``'s weights and poses, so that what differs in the measurements is the two changes.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.stats import chi2

from vpr_uncertainty.slam.pose_graph import graph_edges, gtsam_module

#: GTSAM's ``GncParams`` defaults: μ's factor per iteration, the relative cost change and weight tolerance that stop.
MU_STEP, RELATIVE_COST_TOL, WEIGHTS_TOL, MAX_ITERATIONS = 1.4, 1e-5, 1e-4, 100


def tls_weights(errors: np.ndarray, thresholds: np.ndarray, mu: float) -> np.ndarray:
    """Truncated least squares weights of the linear schedule (Yang et al. 2020, eq. 14; GTSAM's
    ``calculateWeights``): ``errors`` (C,) GTSAM factor errors ½‖r‖²_Σ at the current solution, ``thresholds`` (C,)
    the inlier thresholds c̄² on the same scale; returns (C,) weights in [0, 1]."""
    with np.errstate(divide="ignore"):
        weights = np.clip(np.sqrt(thresholds * mu * (mu + 1) / errors) - mu, 0.0, 1.0)
    weights[errors >= (mu + 1) / mu * thresholds] = 0.0
    weights[errors <= mu / (mu + 1) * thresholds] = 1.0
    return weights


def initial_mu(errors: np.ndarray, thresholds: np.ndarray) -> float:
    """GTSAM's ``initializeMu`` for TLS (Remark 5): the smallest c̄² / (2 r² − c̄²) over the factors whose error at the
    initial values exceeds c̄² / 2, at least 10⁻⁶; −1 when none does (least squares is then the answer)."""
    excess = 2 * errors - thresholds
    if not (excess > 0).any():
        return -1.0
    return max(float(np.min(thresholds[excess > 0] / excess[excess > 0])), 1e-6)


def gnc(
    graph: Any,
    initial: Any,
    *,
    warm: bool = True,
    prune: bool = True,
    inlier_probability: float = 0.99,
    verbose: bool = False,
) -> tuple[Any, np.ndarray]:
    """GNC (TLS) on ``graph`` from ``initial``, the first pose held by a prior and the odometry known inliers, as
    ``vpr_uncertainty.slam.pose_graph.optimize(robust="gnc")`` sets it up. Returns the poses and the final
    weights (F,) of the graph's F factors followed by the prior. ``warm`` and ``prune``: the module docstring."""
    gtsam = gtsam_module()
    graph, first = graph.clone(), min(initial.keys())
    is_3d = gtsam.utilities.extractPose3(initial).size > 0
    pose = initial.atPose3(first) if is_3d else initial.atPose2(first)
    prior = gtsam.PriorFactorPose3 if is_3d else gtsam.PriorFactorPose2
    graph.add(prior(first, pose, gtsam.noiseModel.Isotropic.Sigma(pose.dim(), 1e-6)))
    factors = [graph.at(i) for i in range(graph.size())]
    closures = np.array([i for i, e in enumerate(graph_edges(graph)) if e[0] >= 0 and abs(e[1] - e[0]) != 1], int)
    thresholds = np.array([0.5 * chi2.ppf(inlier_probability, f.dim()) for f in factors])
    params = gtsam.LevenbergMarquardtParams()
    params.setVerbosityLM("SUMMARY" if verbose else "SILENT")

    def errors(values: Any, which: np.ndarray) -> np.ndarray:
        return np.array([factors[i].error(values) for i in which])

    def weighted(weights: np.ndarray) -> Any:
        """GTSAM's ``makeWeightedGraph``: each factor's information matrix times its weight."""
        out = gtsam.NonlinearFactorGraph()
        for factor, weight in zip(factors, weights, strict=True):
            if not (prune and weight == 0):
                information = weight * factor.noiseModel().information()
                out.add(factor.cloneWithNewNoiseModel(gtsam.noiseModel.Gaussian.Information(information)))
        return out

    weights = np.ones(len(factors))
    first_graph = weighted(weights)
    result = gtsam.LevenbergMarquardtOptimizer(first_graph, initial, params).optimize()
    mu = initial_mu(errors(initial, np.arange(len(factors))), thresholds)
    if mu <= 0 or len(closures) == 0:
        return result, weights
    previous_cost = first_graph.error(result)
    for iteration in range(MAX_ITERATIONS):
        weights[closures] = tls_weights(errors(result, closures), thresholds[closures], mu)
        iteration_graph = weighted(weights)
        start = result if warm and iteration > 0 else initial
        result = gtsam.LevenbergMarquardtOptimizer(iteration_graph, start, params).optimize()
        cost = iteration_graph.error(result)
        if verbose:
            zero, one = int((weights[closures] == 0).sum()), int((weights[closures] == 1).sum())
            print(
                f"GNC iteration {iteration}: mu {mu:.3g}, cost {cost:.6g}, closures weighted 0 / 1: {zero} / {one}",
                flush=True,
            )
        binary = np.all(np.abs(weights - np.round(weights)) <= WEIGHTS_TOL)
        if abs(cost - previous_cost) / max(previous_cost, 1e-7) < RELATIVE_COST_TOL or binary:
            break
        mu, previous_cost = mu * MU_STEP, cost
    return result, weights
