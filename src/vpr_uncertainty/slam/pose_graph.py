"""The pose graph in GTSAM (the ``slam`` extra: ``pip install 'vpr-uncertainty[slam]'``): which edges the gate keeps,
the factors of a graph file, and the optimisation.

A loop closure is an edge between non-consecutive vertex ids. GTSAM builds and optimises; reading and writing the
file is :mod:`vpr_uncertainty.slam.graph_file`'s, which loses nothing.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.plugins import import_or_explain
from vpr_uncertainty.slam.graph_file import CITY10000_INFORMATION, GraphFile, read_graph_file

__all__ = [
    "KERNELS",
    "closure_mask",
    "factor_graph",
    "filter_loop_closures",
    "graph_edges",
    "gtsam_module",
    "optimize",
    "pose_rows",
    "read_graph",
]

#: M-estimator of each ``--robust`` kernel on the whitened residual: the 95 %-efficiency constants of Huber and
#: Cauchy, and DCS with Agarwal et al.'s Φ = 1.
KERNELS = {"huber": ("Huber", 1.345), "cauchy": ("Cauchy", 2.3849), "dcs": ("DCS", 1.0)}
#: Stack of the thread GTSAM optimises in, per variable: its elimination tree is recursive, as deep as a chain of
#: poses is long (the default 8 MiB overflowed between 50,000 and 100,000 poses); the stack is only reserved.
STACK_PER_VARIABLE = 1024


def gtsam_module() -> Any:
    """The ``gtsam`` module, or an ImportError naming the ``slam`` extra."""
    return import_or_explain("gtsam", "loop-closures needs GTSAM: pip install 'vpr-uncertainty[slam]'")


def closure_mask(edges: Any, closures: Any, scores: Any, gate: Any) -> np.ndarray:
    """Which edges of a graph to keep, shape (M,) bool, from its edges (M, 2) (a row of -1 for a factor that is no
    edge), the scored closures (E, 2) and their top-K scores (E, K); ``gate`` has ``accept(scores) -> (E,) bool``.

    Raises a ValueError naming the scored edges the graph lacks, closures without a score row, or a duplicated row.
    """
    edges, closures = (np.asarray(e, dtype=np.int64).reshape(-1, 2) for e in (edges, closures))
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim != 2 or len(scores) != len(closures):
        raise ValueError(f"scores must have shape (E, K) with E = {len(closures)} edges, got {scores.shape}")
    pairs, listed = ([tuple(sorted(edge)) for edge in array.tolist()] for array in (edges, closures))

    def named(found: list, what: str) -> ValueError:
        return ValueError(f"{len(found)} {what}: {', '.join(map(str, found[:5]))}{', ...' if len(found) > 5 else ''}")

    if len(set(listed)) < len(listed):
        raise named(sorted({e for e in listed if listed.count(e) > 1}), "edges listed twice in the score file")
    if missing := sorted(set(listed) - set(pairs)):
        raise named(missing, "edges of the score file are not in the graph")
    if unscored := sorted({p for p in pairs if p[0] >= 0 and p[1] - p[0] != 1} - set(listed)):
        raise named(unscored, "loop closures of the graph have no score row")
    decision = dict(zip(listed, np.asarray(gate.accept(scores), dtype=bool).tolist(), strict=True))
    return np.array([decision.get(pair, True) for pair in pairs], dtype=bool)


def graph_edges(graph: Any) -> np.ndarray:
    """The (M, 2) vertex ids of each factor of a GTSAM graph; (-1, -1) for a factor that is no edge (a prior)."""
    keys = [graph.at(i).keys() for i in range(graph.size())]
    return np.array([k if len(k) == 2 else (-1, -1) for k in keys], dtype=np.int64).reshape(-1, 2)


def filter_loop_closures(graph: Any, scores: Any, gate: Any) -> Any:
    """A new ``gtsam.NonlinearFactorGraph`` of the factors of ``graph`` that :func:`closure_mask` keeps.

    ``scores`` is a mapping with ``edges`` (E, 2) and ``scores`` (E, K) (the score file's arrays); ``gate`` a
    :class:`~vpr_uncertainty.Gate`. ``graph`` is not modified.
    """
    keep = closure_mask(graph_edges(graph), scores["edges"], scores["scores"], gate)
    filtered = gtsam_module().NonlinearFactorGraph()
    for index in np.flatnonzero(keep):
        filtered.add(graph.at(int(index)))
    return filtered


def _pose(gtsam: Any, values: np.ndarray) -> Any:
    if len(values) == 3:
        return gtsam.Pose2(*values)
    x, y, z, qx, qy, qz, qw = values
    return gtsam.Pose3(gtsam.Rot3.Quaternion(qw, qx, qy, qz), np.array([x, y, z]))


def factor_graph(graph_file: GraphFile, keep: np.ndarray | None = None) -> tuple[Any, Any]:
    """``(graph, initial)``: a ``gtsam.NonlinearFactorGraph`` with one ``BetweenFactor`` per edge of the file (those
    where ``keep`` (E,) is True), in the file's order, and the initial poses: the file's vertices, or without them the
    odometry edges (i, i+1) composed from the first vertex at the origin."""
    gtsam, is_3d = gtsam_module(), graph_file.dimension == 3
    factor = gtsam.BetweenFactorPose3 if is_3d else gtsam.BetweenFactorPose2
    # GTSAM's Pose3 tangent is rotation first; g2o and TORO write translation first (as gtsam.readG2o reorders)
    order = [3, 4, 5, 0, 1, 2] if is_3d else [0, 1, 2]
    city = gtsam.noiseModel.Diagonal.Sigmas(np.array([1 / 30, 1 / 30, 1 / 100]))  # GTSAM's City10000 example
    noises: dict[bytes, Any] = {CITY10000_INFORMATION.tobytes(): city}
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for index in range(len(graph_file.edges)) if keep is None else np.flatnonzero(keep):
        information = graph_file.information[index][np.ix_(order, order)]
        if (noise := noises.get(key := information.tobytes())) is None:
            noise = noises[key] = gtsam.noiseModel.Gaussian.Information(information)
        i, j = graph_file.edges[index].tolist()
        graph.add(factor(i, j, _pose(gtsam, graph_file.measurements[index]), noise))
    for key, values in zip(graph_file.vertex_ids.tolist(), graph_file.vertex_poses, strict=True):
        initial.insert(key, _pose(gtsam, values))
    if graph_file.vertex_ids.size:
        return graph, initial
    odometry = {
        j: m for (i, j), m in zip(graph_file.edges.tolist(), graph_file.measurements, strict=True) if j == i + 1
    }
    pose, keys = gtsam.Pose3() if is_3d else gtsam.Pose2(), np.unique(graph_file.edges).tolist()
    for key in keys:  # compose the odometry from the first vertex at the origin
        if key != keys[0] and key not in odometry:
            raise ValueError(
                f"{graph_file.path}: no vertices and no odometry edge ({key - 1}, {key}) to place vertex {key}"
            )
        pose = pose.compose(_pose(gtsam, odometry[key])) if key != keys[0] else pose
        initial.insert(key, pose)
    return graph, initial


def read_graph(path: str | Path) -> tuple[Any, Any]:
    """``(graph, initial)`` of a pose-graph file (:func:`~vpr_uncertainty.slam.graph_file.read_graph_file`, then
    :func:`factor_graph`)."""
    return factor_graph(read_graph_file(path))


def pose_rows(values: Any) -> np.ndarray:
    """(N, 8): ``id x y z qx qy qz qw`` of each pose of a ``gtsam.Values`` (the TUM rows ``evo`` reads)."""
    from scipy.spatial.transform import Rotation

    gtsam = gtsam_module()
    if (poses := gtsam.utilities.extractPose3(values)).size:
        xyz, rotation = poses[:, 9:], Rotation.from_matrix(poses[:, :9].reshape(-1, 3, 3))
    else:
        poses = gtsam.utilities.extractPose2(values)
        xyz, rotation = np.c_[poses[:, :2], np.zeros(len(poses))], Rotation.from_euler("z", poses[:, 2:])
    return np.c_[values.keys(), xyz, rotation.as_quat()]


def optimize(
    graph: Any, initial: Any, *, robust: str = "none", inlier_probability: float = 0.99, verbose: bool = False
) -> Any:
    """The poses (``gtsam.Values``) GTSAM finds from ``initial`` (LM; GN inside gnc-gn), the first pose held by a prior;
    ``robust`` (:data:`KERNELS`, ``"gnc"``, ``"gnc-gn"``) changes the loss of the closures, never the odometry's;
    ``verbose``: GTSAM prints each LM or GN iteration (and GNC's λ) to stdout as it runs.

    GTSAM runs in a thread whose stack grows with the graph (:data:`STACK_PER_VARIABLE`), so a long chain of poses
    cannot overflow it."""
    outcome: dict[str, Any] = {}

    def run() -> None:
        try:
            outcome["poses"] = _optimize(graph, initial, robust, inlier_probability, verbose)
        except BaseException as error:  # raised again in the caller's thread
            outcome["error"] = error

    previous = threading.stack_size(max(2**25, STACK_PER_VARIABLE * initial.size()))
    try:
        thread = threading.Thread(target=run, name="gtsam", daemon=True)  # daemon: Ctrl-C ends the command
        thread.start()
    finally:
        threading.stack_size(previous)
    thread.join()
    if "error" in outcome:
        raise outcome["error"]
    return outcome["poses"]


def _optimize(graph: Any, initial: Any, robust: str, inlier_probability: float, verbose: bool) -> Any:
    gtsam = gtsam_module()
    graph, first, is_3d = graph.clone(), min(initial.keys()), gtsam.utilities.extractPose3(initial).size > 0
    pose = initial.atPose3(first) if is_3d else initial.atPose2(first)
    prior = gtsam.PriorFactorPose3 if is_3d else gtsam.PriorFactorPose2
    graph.add(prior(first, pose, gtsam.noiseModel.Isotropic.Sigma(pose.dim(), 1e-6)))
    closures = [i for i, edge in enumerate(graph_edges(graph)) if edge[0] >= 0 and abs(edge[1] - edge[0]) != 1]
    params = gtsam.LevenbergMarquardtParams()
    params.setVerbosityLM("SUMMARY" if verbose else "SILENT")
    if robust in ("gnc", "gnc-gn"):  # gnc-gn: Gauss-Newton inner solves (Kimera-RPGO's Solver::GN)
        gnc = gtsam.GncGaussNewtonParams(gtsam.GaussNewtonParams()) if robust == "gnc-gn" else gtsam.GncLMParams(params)
        gnc.baseOptimizerParams.setVerbosity("ERROR" if verbose and robust == "gnc-gn" else "SILENT")
        gnc.setVerbosityGNC(gnc.Verbosity.LAMBDA if verbose else gnc.Verbosity.SILENT)
        gnc.setKnownInliers(sorted(set(range(graph.size())) - set(closures)))
        optimizer = (gtsam.GncGaussNewtonOptimizer if robust == "gnc-gn" else gtsam.GncLMOptimizer)(graph, initial, gnc)
        optimizer.setInlierCostThresholdsAtProbability(inlier_probability)
        return optimizer.optimize()
    if robust != "none":
        kernel = getattr(gtsam.noiseModel.mEstimator, KERNELS[robust][0]).Create(KERNELS[robust][1])
        for i, f in ((i, graph.at(i)) for i in closures):
            graph.replace(i, type(f)(*f.keys(), f.measured(), gtsam.noiseModel.Robust.Create(kernel, f.noiseModel())))
    return gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
