"""PCM (Mangelson, Dominic, Eustice and Vasudevan, ICRA 2018): pairwise consistency maximisation of loop closures,
the comparator of ``loop_closure_slam.py`` and ``loop_closure_corridor.py``.

Two closures are consistent when the cycle they close through the odometry (closure, odometry chain, inverse closure,
odometry chain, from the odometry-composed poses) has a squared Mahalanobis error within the ``PCM_QUANTILE`` χ²
quantile, its covariance the two closures' noise and each odometry step's noise transported to the cycle to first
order (shared steps of interleaved chains correlated); PCM keeps a maximum clique of the consistency graph (exact,
networkx, up to ``PCM_EXACT_MAX`` closures; Pattabiraman et al.'s greedy heuristic above, 60 s).

Poses are homogeneous matrices (3×3 in 2-D, 4×4 in 3-D); tangent vectors in GTSAM's order: (x, y, θ) for Pose2,
(ω, v) for Pose3, so that a factor's ``noiseModel().covariance()`` applies as it is.
"""

from __future__ import annotations

import time
from typing import Any

import networkx as nx  # imported here, not in the timed child process of the benchmarks (0.15 s)
import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from vpr_uncertainty.slam.pose_graph import graph_edges

#: χ² quantile of the squared Mahalanobis distance of a pair's cycle error below which the pair is consistent.
PCM_QUANTILE = 0.99
#: Up to this many closures the maximum clique is exact (networkx's branch and bound); above, ``greedy_clique``.
PCM_EXACT_MAX = 1000


def adjoint(poses: np.ndarray) -> np.ndarray:
    """(..., m, m) adjoint maps of (..., n, n) poses, as GTSAM's ``AdjointMap``: T Exp(ξ) = Exp(Ad_T ξ) T."""
    rotation, t = poses[..., :-1, :-1], poses[..., :-1, -1]
    if poses.shape[-1] == 3:
        ad = np.zeros((*poses.shape[:-2], 3, 3))
        ad[..., :2, :2], ad[..., 0, 2], ad[..., 1, 2], ad[..., 2, 2] = rotation, t[..., 1], -t[..., 0], 1
        return ad
    ad = np.zeros((*poses.shape[:-2], 6, 6))
    ad[..., :3, :3] = ad[..., 3:, 3:] = rotation
    ad[..., 3:, :3] = skew(t) @ rotation
    return ad


def skew(w: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices of (..., 3) vectors."""
    out = np.zeros((*w.shape, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    return out - np.swapaxes(out, -1, -2)


def log_map(poses: np.ndarray) -> np.ndarray:
    """(..., m) logarithm of (..., n, n) poses (GTSAM's ``Pose2.Logmap`` / ``Pose3.Logmap``)."""
    rotation, t = poses[..., :-1, :-1], poses[..., :-1, -1]
    if poses.shape[-1] == 3:
        theta = np.arctan2(rotation[..., 1, 0], rotation[..., 0, 0])
        small = np.abs(theta) < 1e-9
        safe = np.where(small, 1.0, theta)
        a = np.where(small, 1.0, np.sin(safe) / safe)
        b = np.where(small, 0.0, (1 - np.cos(safe)) / safe)
        v = (
            np.stack([a * t[..., 0] + b * t[..., 1], -b * t[..., 0] + a * t[..., 1]], axis=-1)
            / (a * a + b * b)[..., None]
        )
        return np.concatenate([v, theta[..., None]], axis=-1)
    w = Rotation.from_matrix(rotation.reshape(-1, 3, 3)).as_rotvec().reshape(*rotation.shape[:-2], 3)
    theta = np.linalg.norm(w, axis=-1)
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    c = np.where(small, 1 / 12, (1 - safe * np.sin(safe) / (2 * (1 - np.cos(safe)))) / safe**2)
    W = skew(w)
    v_inverse = np.eye(3) - W / 2 + c[..., None, None] * (W @ W)
    return np.concatenate([w, (v_inverse @ t[..., None])[..., 0]], axis=-1)


def odometry_chain(graph: Any) -> tuple[np.ndarray, np.ndarray]:
    """The poses the odometry edges (i, i+1) of ``graph`` compose from the first vertex at the identity, (N, n, n),
    and the cumulative covariance of their first-order world-frame error, (N, m, m): C[j] = Σ_{k<j} Ad_{X_{k+1}}
    Σ_k Ad_{X_{k+1}}ᵀ, so that X_i⁻¹X_j (i < j) perturbed is X_i⁻¹ Exp(w) X_j with Cov(w) = C[j] − C[i]."""
    steps: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for index, (a, b) in enumerate(graph_edges(graph).tolist()):
        if a >= 0 and abs(b - a) == 1 and min(a, b) not in steps:
            factor = graph.at(index)
            z, cov = factor.measured().matrix(), factor.noiseModel().covariance()
            if b < a:  # (z Exp(η))⁻¹ = z⁻¹ Exp(−Ad_z η)
                z, cov = np.linalg.inv(z), adjoint(z) @ cov @ adjoint(z).T
            steps[min(a, b)] = (z, cov)
    n = len(steps) + 1
    if sorted(steps) != list(range(n - 1)):
        raise ValueError("PCM needs vertices 0..N-1 joined by odometry edges (i, i+1)")
    poses = np.empty((n, *steps[0][0].shape))
    poses[0] = np.eye(len(poses[0]))
    for k in range(n - 1):
        poses[k + 1] = poses[k] @ steps[k][0]
    ad = adjoint(poses[1:])
    increments = ad @ np.stack([steps[k][1] for k in range(n - 1)]) @ np.swapaxes(ad, -1, -2)
    return poses, np.concatenate([np.zeros((1, *increments.shape[1:])), np.cumsum(increments, axis=0)])


def cycle_errors(
    poses: np.ndarray,
    cumulative: np.ndarray,
    ends: np.ndarray,
    measured: np.ndarray,
    covariances: np.ndarray,
    first: np.ndarray,
    second: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The error (P, m) of the cycle of each pair (``first[p]``, ``second[p]``) of closures, and its first-order
    covariance (P, m, m).

    Closure k joins ``ends[k] = (a, b)`` with measurement ``measured[k]`` ≈ X_a⁻¹X_b and noise ``covariances[k]``
    (right perturbation, GTSAM's ``BetweenFactor``). For closures (a, b, z₁) and (c, d, z₂) the cycle is
    E = z₁ · X_b⁻¹X_d · z₂⁻¹ · X_c⁻¹X_a with the odometry poses X (:func:`odometry_chain`), identity when both
    closures agree with the odometry; the error is Log(E). Its covariance transports each noise to E's left:
    Ad_{z₁}Σ₁Ad_{z₁}ᵀ + Ad_{z₁X_b⁻¹X_d}Σ₂(·)ᵀ + A₁Cov(w_bd)A₁ᵀ + A₂Cov(w_ca)A₂ᵀ + A₁Cov(w_bd, w_ca)A₂ᵀ + (·)ᵀ,
    A₁ = Ad_{z₁X_b⁻¹}, A₂ = Ad_{E X_a⁻¹}, with the two odometry chains' shared steps correlated (they overlap when the
    closures interleave). First order: Log's Jacobian is taken as the identity (exact at E = I)."""
    a, b = ends[first, 0], ends[first, 1]
    c, d = ends[second, 0], ends[second, 1]
    inverse = np.linalg.inv(poses)
    z1 = measured[first]
    q1 = z1 @ inverse[b]
    z1_bd = q1 @ poses[d]
    q2 = z1_bd @ np.linalg.inv(measured[second]) @ inverse[c]
    error = log_map(q2 @ poses[a])
    a0, a1, a3, a2 = adjoint(z1), adjoint(q1), adjoint(z1_bd), adjoint(q2)

    def chain(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        return cumulative[hi] - cumulative[lo]

    lo1, hi1, lo2, hi2 = np.minimum(b, d), np.maximum(b, d), np.minimum(a, c), np.maximum(a, c)
    sign = (np.sign(d - b) * np.sign(a - c))[:, None, None]
    overlap = (np.minimum(hi1, hi2) > np.maximum(lo1, lo2))[:, None, None]
    shared = sign * overlap * chain(np.maximum(lo1, lo2), np.maximum(np.minimum(hi1, hi2), np.maximum(lo1, lo2)))
    cross = a1 @ shared @ np.swapaxes(a2, -1, -2)
    covariance = (
        a0 @ covariances[first] @ np.swapaxes(a0, -1, -2)
        + a3 @ covariances[second] @ np.swapaxes(a3, -1, -2)
        + a1 @ chain(lo1, hi1) @ np.swapaxes(a1, -1, -2)
        + a2 @ chain(lo2, hi2) @ np.swapaxes(a2, -1, -2)
        + cross
        + np.swapaxes(cross, -1, -2)
    )
    return error, covariance


def consistency_graph(
    poses: np.ndarray,
    cumulative: np.ndarray,
    ends: np.ndarray,
    measured: np.ndarray,
    covariances: np.ndarray,
    *,
    quantile: float = PCM_QUANTILE,
    chunk: int = 1 << 17,
) -> np.ndarray:
    """(E, E) bool: closures i and j are pairwise consistent (the squared Mahalanobis distance of their cycle error
    at most the χ² ``quantile`` with m degrees of freedom); pairs are tested ``chunk`` at a time."""
    n, m = len(ends), covariances.shape[-1]
    threshold = chi2.ppf(quantile, m)
    adjacency = np.zeros((n, n), bool)
    rows = max(1, chunk // max(n, 1))
    for start in range(0, n, rows):
        first, second = np.nonzero(np.arange(start, min(start + rows, n))[:, None] < np.arange(n)[None, :])
        first += start
        error, covariance = cycle_errors(poses, cumulative, ends, measured, covariances, first, second)
        distance = (error[:, None, :] @ np.linalg.solve(covariance, error[..., None]))[:, 0, 0]
        adjacency[first, second] = adjacency[second, first] = distance <= threshold
    return adjacency


def greedy_clique(adjacency: np.ndarray, time_limit: float = 60.0) -> np.ndarray:
    """Indices of a large clique of a (E, E) bool graph: Pattabiraman et al.'s heuristic (the one PCM's
    implementation uses for large graphs): from each vertex in decreasing degree, grow a clique by the candidate of
    highest degree among those adjacent to all members; vertices of degree below the best clique's size are skipped;
    after the first start, it stops at ``time_limit`` seconds (keeping the best clique found)."""
    degree = adjacency.sum(axis=1)
    best = np.zeros(0, np.int64)
    deadline = time.perf_counter() + time_limit
    for v in np.argsort(-degree, kind="stable"):
        if degree[v] + 1 <= len(best) or (len(best) and time.perf_counter() > deadline):  # one start at least
            break
        clique, candidates = [v], adjacency[v].copy()
        candidates[degree + 1 <= len(best)] = False
        while (left := np.flatnonzero(candidates)).size:
            u = left[np.argmax(degree[left])]
            clique.append(u)
            candidates &= adjacency[u]
        if len(clique) > len(best):
            best = np.array(sorted(clique), dtype=np.int64)
    return best


def maximum_clique(adjacency: np.ndarray, time_limit: float = 60.0) -> np.ndarray:
    """Indices of a maximum clique (exact, networkx's ``max_weight_clique``) up to :data:`PCM_EXACT_MAX` vertices,
    :func:`greedy_clique` above."""
    if len(adjacency) > PCM_EXACT_MAX:
        return greedy_clique(adjacency, time_limit)
    graph = nx.Graph()
    graph.add_nodes_from(range(len(adjacency)))
    graph.add_edges_from(zip(*np.nonzero(np.triu(adjacency, 1)), strict=True))
    clique, _ = nx.algorithms.clique.max_weight_clique(graph, weight=None)
    return np.array(sorted(clique), dtype=np.int64)


def pcm(graph: Any, closures: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """(E,) bool: the closures PCM keeps among the ``candidates`` (E,) bool of ``closures`` (E, 2): the maximum
    clique of their pairwise consistency graph (cycles through the odometry of ``graph``)."""
    where = {tuple(sorted(graph.at(i).keys())): i for i in range(graph.size())}
    chosen = np.flatnonzero(candidates)
    if chosen.size < 2:
        return candidates.copy()
    factors = [graph.at(where[tuple(sorted(pair))]) for pair in closures[chosen].tolist()]
    poses, cumulative = odometry_chain(graph)
    adjacency = consistency_graph(
        poses,
        cumulative,
        np.array([list(f.keys()) for f in factors], dtype=np.int64).reshape(-1, 2),
        np.array([f.measured().matrix() for f in factors]).reshape(-1, *poses.shape[1:]),
        np.array([f.noiseModel().covariance() for f in factors]).reshape(-1, *cumulative.shape[1:]),
    )
    keep = np.zeros(len(closures), bool)
    keep[chosen[maximum_clique(adjacency)]] = True
    return keep
