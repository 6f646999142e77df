"""The pose graph in GTSAM (the ``slam`` extra: ``pip install 'vpr-uncertainty[slam]'``): which edges the gate keeps,
the factors of a graph file, and the optimisation.

A loop closure is an edge between non-consecutive vertex ids. GTSAM builds and optimises; reading and writing the
file is :mod:`vpr_uncertainty.slam.graph_file`'s, which loses nothing.
"""

from __future__ import annotations

import itertools
import threading
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.plugins import import_or_explain
from vpr_uncertainty.slam.graph_file import CITY10000_INFORMATION, TAGS, GraphFile, read_graph_file

__all__ = [
    "KERNELS",
    "UNSCORED",
    "aligned",
    "closure_mask",
    "factor_graph",
    "filter_loop_closures",
    "graph_edges",
    "gtsam_module",
    "odometry_mask",
    "optimize",
    "pose_rows",
    "read_graph",
    "trajectory_error",
]

#: M-estimator of each ``--robust`` kernel on the whitened residual: the 95 %-efficiency constants of Huber and
#: Cauchy, and DCS with Agarwal et al.'s Φ = 1.
KERNELS = {"huber": ("Huber", 1.345), "cauchy": ("Cauchy", 2.3849), "dcs": ("DCS", 1.0)}
#: What ``closure_mask`` does with a loop closure that has no score row.
UNSCORED = ("error", "keep", "drop")
#: Stack of the thread GTSAM optimises in, per variable: its elimination tree is recursive, as deep as a chain of
#: poses is long (the default 8 MiB overflowed between 50,000 and 100,000 poses); the stack is only reserved.
STACK_PER_VARIABLE = 1024


def gtsam_module() -> Any:
    """The ``gtsam`` module, or an ImportError naming the ``slam`` extra."""
    return import_or_explain("gtsam", "loop-closures needs GTSAM: pip install 'vpr-uncertainty[slam]'")


def odometry_mask(graph_file: GraphFile, rule: str = "ids") -> np.ndarray:
    """Which edges of a graph file are odometry, shape (E,) bool; every other edge is a loop closure.

    ``rule``: ``"ids"``, vertex ids that differ by one; ``"consecutive"``, vertices next to each other in the order
    the file defines them (by id without vertex lines), so keyframe ids 0, 2, 4, … and the sessions of a multi-session
    graph need no fake link; ``"tag:NAME"``, the edges of that tag (e.g. ``tag:EDGE_SE2`` where closures have
    another tag).
    """
    edges = graph_file.edges
    if rule == "ids":
        return np.abs(edges[:, 1] - edges[:, 0]) == 1
    if rule == "consecutive":
        order = graph_file.vertex_ids if graph_file.vertex_ids.size else np.unique(edges)
        sorter = np.argsort(order, kind="stable")
        place = sorter[np.searchsorted(order[sorter], edges)]  # each id's position in the order
        return np.abs(place[:, 1] - place[:, 0]) == 1
    if rule.startswith("tag:") and rule[4:] in TAGS and TAGS[rule[4:]][2]:
        return np.array([graph_file.lines[i].split()[0].lstrip("\ufeff") == rule[4:] for i in graph_file.edge_lines])
    edge_tags = ", ".join(tag for tag, (_, _, information, _) in TAGS.items() if information)
    raise ValueError(
        f"the odometry rule (argument odometry) must be ids, consecutive or tag:TAG of an edge tag ({edge_tags}), "
        f"got {rule!r}"
    )


def closure_mask(
    edges: Any, closures: Any, scores: Any, gate: Any, *, odometry: Any = None, unscored: str = "error"
) -> np.ndarray:
    """Which edges of a graph to keep, shape (M,) bool, from its edges (M, 2) (a row of -1 for a factor that is no
    edge), the scored closures (E, 2) and their top-K scores (E, K); ``gate`` has ``accept(scores) -> (E,) bool``.

    ``odometry`` (M,) bool says which edges are odometry (default: ids that differ by one); a loop closure without
    a score row is an error, kept or dropped (``unscored``: ``"error"``, ``"keep"``, ``"drop"``). A scored edge is
    gated whatever it is. Raises a ValueError naming the scored edges the graph lacks, closures without a score row,
    or a duplicated row.
    """
    edges, closures = (np.asarray(e, dtype=np.int64).reshape(-1, 2) for e in (edges, closures))
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim != 2 or len(scores) != len(closures):
        raise ValueError(f"scores must have shape (E, K) with E = {len(closures)} edges, got {scores.shape}")
    if unscored not in UNSCORED:
        raise ValueError(f"unscored must be error, keep or drop, got {unscored!r}")
    pairs, listed = ([tuple(sorted(edge)) for edge in array.tolist()] for array in (edges, closures))
    is_odometry = np.abs(edges[:, 1] - edges[:, 0]) == 1 if odometry is None else np.asarray(odometry, dtype=bool)

    def named(found: list, what: str) -> ValueError:
        return ValueError(f"{len(found)} {what}: {', '.join(map(str, found[:5]))}{', ...' if len(found) > 5 else ''}")

    if len(set(listed)) < len(listed):
        raise named(sorted({e for e in listed if listed.count(e) > 1}), "edges listed twice in the score file")
    if missing := sorted(set(listed) - set(pairs)):
        raise named(missing, "edges of the score file are not in the graph")
    decision = dict(zip(listed, np.asarray(gate.accept(scores), dtype=bool).tolist(), strict=True))
    closing = {p for p, odo in zip(pairs, is_odometry.tolist(), strict=True) if p[0] >= 0 and not odo}
    if (found := sorted(closing - set(listed))) and unscored == "error":
        error = named(found, "loop closures of the graph have no score row")
        raise ValueError(f"{error}: keep or drop them (argument unscored), or say which edges are odometry "
                         "(argument odometry)")  # fmt: skip
    decision.update(dict.fromkeys(found, unscored == "keep"))
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


def factor_graph(graph_file: GraphFile, keep: np.ndarray | None = None, odometry: str = "ids") -> tuple[Any, Any]:
    """``(graph, initial)``: a ``gtsam.NonlinearFactorGraph`` with one ``BetweenFactor`` per edge of the file (those
    where ``keep`` (E,) is True), in the file's order, and the initial poses: the file's vertices, or without them
    the odometry edges (:func:`odometry_mask`) between consecutive ids composed from the first vertex at the origin."""
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
    steps: dict[tuple[int, int], Any] = {}
    is_odometry = odometry_mask(graph_file, odometry)
    for (i, j), measured in zip(
        graph_file.edges[is_odometry].tolist(), graph_file.measurements[is_odometry], strict=True
    ):
        steps[i, j] = _pose(gtsam, measured)
        steps.setdefault((j, i), steps[i, j].inverse())
    pose, keys = gtsam.Pose3() if is_3d else gtsam.Pose2(), np.unique(graph_file.edges).tolist()
    initial.insert(keys[0], pose)
    for previous, key in itertools.pairwise(keys):  # compose the odometry from the first vertex at the origin
        if (previous, key) not in steps:
            raise ValueError(
                f"{graph_file.path}: no vertices and no odometry edge between {previous} and {key} to place vertex "
                f"{key} (see --odometry)"
            )
        pose = pose.compose(steps[previous, key])
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


def _aligned_pair(rows: np.ndarray, truth: np.ndarray) -> tuple[Any, Any]:
    """evo trajectories of TUM rows ``rows`` (N, 8) and of the ``truth`` rows of the same ids, the first aligned to
    the second (SE(3) Umeyama, no scale); a ValueError names the ids the truth lacks."""
    trajectory = import_or_explain("evo.core.trajectory", "APE needs evo: pip install 'vpr-uncertainty[slam]'")
    where = {int(i): n for n, i in enumerate(truth[:, 0])}
    if missing := [int(i) for i in rows[:, 0] if int(i) not in where]:
        raise ValueError(f"the ground truth has no pose of {len(missing)} vertices of the graph, e.g. {missing[:5]}")
    truth = truth[[where[int(i)] for i in rows[:, 0]]]
    estimate, reference = (
        trajectory.PoseTrajectory3D(r[:, 1:4], r[:, [7, 4, 5, 6]], np.arange(len(r), dtype=float))
        for r in (rows, truth)
    )
    estimate.align(reference, correct_scale=False)
    return estimate, reference


def trajectory_error(rows: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """The APE of TUM rows ``rows`` (N, 8: ``id x y z qx qy qz qw``) against ``truth`` (the same ids, more allowed)
    after SE(3) Umeyama alignment without scale (evo): ``{"rmse": …, "max": …}`` of the translation error, metres."""
    from evo.core import metrics

    estimate, reference = _aligned_pair(rows, truth)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((reference, estimate))
    return {name: float(ape.get_statistic(getattr(metrics.StatisticsType, name))) for name in ("rmse", "max")}


def aligned(rows: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N, 3): the positions of ``rows`` after the alignment to ``truth`` that :func:`trajectory_error` makes."""
    return _aligned_pair(rows, truth)[0].positions_xyz


def optimize(
    graph: Any,
    initial: Any,
    *,
    robust: str = "none",
    inlier_probability: float = 0.99,
    verbose: bool = False,
    closures: Any = None,
    weights: bool = False,
) -> Any:
    """The poses (``gtsam.Values``) GTSAM finds from ``initial`` (LM; GN inside gnc-gn), the first pose held by a prior;
    ``robust`` (:data:`KERNELS`, ``"gnc"``, ``"gnc-gn"``) changes the loss of the loop closures, never the odometry's;
    ``closures``: the indices of the factors that are loop closures (default: the edges whose ids differ by more than
    one); ``verbose``: GTSAM prints each LM or GN iteration (and GNC's λ) to stdout as it runs. With ``weights``,
    ``(poses, weights)``: each factor's weight at the solution, shape (M,): GNC's (0: rejected), the kernel's w(r)
    at the factor's whitened residual, 1 in least squares.

    GTSAM runs in a thread whose stack grows with the graph (:data:`STACK_PER_VARIABLE`), so a long chain of poses
    cannot overflow it."""
    outcome: dict[str, Any] = {}
    if closures is None:
        closures = [i for i, edge in enumerate(graph_edges(graph)) if edge[0] >= 0 and abs(edge[1] - edge[0]) != 1]

    def run() -> None:
        try:
            outcome["result"] = _optimize(graph, initial, robust, inlier_probability, verbose, list(closures))
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
    return outcome["result"] if weights else outcome["result"][0]


def _optimize(
    graph: Any, initial: Any, robust: str, inlier_probability: float, verbose: bool, closures: list[int]
) -> tuple[Any, np.ndarray]:
    gtsam = gtsam_module()
    original, graph, first = graph, graph.clone(), min(initial.keys())
    is_3d = gtsam.utilities.extractPose3(initial).size > 0
    pose = initial.atPose3(first) if is_3d else initial.atPose2(first)
    prior = gtsam.PriorFactorPose3 if is_3d else gtsam.PriorFactorPose2
    graph.add(prior(first, pose, gtsam.noiseModel.Isotropic.Sigma(pose.dim(), 1e-6)))
    params = gtsam.LevenbergMarquardtParams()
    params.setVerbosityLM("SUMMARY" if verbose else "SILENT")
    weights = np.ones(original.size())
    if robust in ("gnc", "gnc-gn"):  # gnc-gn: Gauss-Newton inner solves (Kimera-RPGO's Solver::GN)
        gnc = gtsam.GncGaussNewtonParams(gtsam.GaussNewtonParams()) if robust == "gnc-gn" else gtsam.GncLMParams(params)
        gnc.baseOptimizerParams.setVerbosity("ERROR" if verbose and robust == "gnc-gn" else "SILENT")
        gnc.setVerbosityGNC(gnc.Verbosity.LAMBDA if verbose else gnc.Verbosity.SILENT)
        gnc.setKnownInliers(sorted(set(range(graph.size())) - set(closures)))
        optimizer = (gtsam.GncGaussNewtonOptimizer if robust == "gnc-gn" else gtsam.GncLMOptimizer)(graph, initial, gnc)
        optimizer.setInlierCostThresholdsAtProbability(inlier_probability)
        poses = optimizer.optimize()
        return poses, np.asarray(optimizer.getWeights(), dtype=np.float64)[: original.size()]
    if robust != "none":
        kernel = getattr(gtsam.noiseModel.mEstimator, KERNELS[robust][0]).Create(KERNELS[robust][1])
        for i, f in ((i, graph.at(i)) for i in closures):
            graph.replace(i, type(f)(*f.keys(), f.measured(), gtsam.noiseModel.Robust.Create(kernel, f.noiseModel())))
    poses = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    if robust != "none":  # the kernel's weight at each closure's whitened residual r = √(2 · error)
        weights[closures] = [kernel.weight(np.sqrt(2 * original.at(i).error(poses))) for i in closures]
    return poses, weights
