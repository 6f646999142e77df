"""``vpr-uncertainty loop-closures``: keep a pose graph's loop closures whose VPR match the gate accepts, and
optionally optimise the graph with GTSAM (the ``slam`` extra: ``pip install 'vpr-uncertainty[slam]'``).

A loop closure is an edge between non-consecutive vertex ids. The score file (``.npz``) holds ``edges`` (E, 2), the
vertex ids of each closure a VPR match proposed (either direction), and ``scores`` (E, K), that match's top-K
similarities sorted descending. Edges it does not list (odometry, other sensors) are kept; a listed closure is kept
when the gate accepts its row. Graphs: g2o (``EDGE_SE2``, ``EDGE_SE3:QUAT``) and GTSAM's ``EDGE2`` / ``EDGE3`` text,
read by ``gtsam.readG2o`` / ``load2D``, and the ``EDGE2 i 1 j 0 N x y θ [x y θ ...]`` layout of GTSAM's City10000
files (its first measurement, σ = (1/30, 1/30, 1/100) as in GTSAM's example). Without vertices, the initial guess
composes the odometry edges (i, i+1) from the first vertex at the origin. The filtered graph is written as g2o;
``--optimize`` also writes the optimised poses as ``OUT.tum`` (``id x y z qx qy qz qw``, as ``evo`` reads them).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.pipeline.options import add_options, conf_from_args, option, output_file
from vpr_uncertainty.plugins import import_or_explain

__all__ = [
    "LoopClosureConf",
    "closure_mask",
    "filter_loop_closures",
    "graph_edges",
    "main",
    "optimize",
    "pose_rows",
    "read_graph",
]

#: Fields of a line of each g2o / TORO tag (with the full information matrix).
WIDTHS = {"EDGE_SE2": 12, "EDGE2": 12, "EDGE_SE3:QUAT": 31, "EDGE3": 30, "VERTEX_SE2": 5, "VERTEX_SE3:QUAT": 9}
#: M-estimator of each ``--robust`` kernel on the whitened residual: the 95 %-efficiency constants of Huber and
#: Cauchy, and DCS with Agarwal et al.'s Φ = 1.
KERNELS = {"huber": ("Huber", 1.345), "cauchy": ("Cauchy", 2.3849), "dcs": ("DCS", 1.0)}


@dataclass(frozen=True)
class LoopClosureConf:
    """What ``loop-closures`` does after filtering; each field is also the command-line option of the same name."""

    optimize: bool = option(False, "also optimise the filtered graph with GTSAM and write its poses to OUT.tum")
    robust: str = option(
        "none",
        "loss of the loop closures when optimising: none (least squares), huber, cauchy, dcs, gnc (GTSAM's "
        "GncOptimizer, truncated least squares, odometry as known inliers) or gnc-gn (the same, Gauss-Newton inside)",
        choices=("none", *KERNELS, "gnc", "gnc-gn"),
    )
    inlier_probability: float = option(0.99, "gnc(-gn): inlier threshold at this χ² quantile of the noise", type=float)
    verbose: bool = option(False, "print GTSAM's iterations as they run (LM's or GN's costs; GNC's λ schedule)")


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


def read_graph(path: str | Path) -> tuple[Any, Any]:
    """``(graph, initial)``: the ``gtsam.NonlinearFactorGraph`` of a pose-graph file and its initial poses."""
    gtsam, path = gtsam_module(), Path(path)
    lines = path.read_text().splitlines()
    tags = {line.split(maxsplit=1)[0] for line in lines if line.strip()}
    is_3d = any("3" in tag for tag in tags)
    first = next((line.split() for line in lines if line.startswith("EDGE2")), [])
    if len(first) in (9, 12) and first[2:5:2] == ["1", "0"] and len(first) == 6 + 3 * int(first[5]):  # City10000
        graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1 / 30, 1 / 30, 1 / 100]))
        for number, words in enumerate((line.split() for line in lines), 1):
            try:
                if words[0] != "EDGE2" or len(words) != 6 + 3 * int(words[5]) or int(words[5]) < 1:
                    raise ValueError
                pose = gtsam.Pose2(*map(float, words[6:9]))
                graph.add(gtsam.BetweenFactorPose2(int(words[1]), int(words[3]), pose, noise))
            except (ValueError, IndexError):
                raise ValueError(f"{path}, line {number}: expected 'EDGE2 i 1 j 0 N x y θ ...', got {words}") from None
    else:
        for number, words in enumerate((line.split() for line in lines), 1):
            if words and len(words) != WIDTHS.get(words[0], len(words)):
                raise ValueError(f"{path}, line {number}: {words[0]} needs {WIDTHS[words[0]]} fields, got {len(words)}")
        try:
            graph, initial = gtsam.load2D(str(path)) if tags & {"EDGE2"} else gtsam.readG2o(str(path), is_3d)
        except (RuntimeError, IndexError) as error:
            raise ValueError(f"{path}: not a pose graph GTSAM reads ({error})") from None
    keys = sorted({key for factor in map(graph.at, range(graph.size())) for key in factor.keys()})
    if defined := {int(words[1]) for words in map(str.split, lines) if words and words[0].startswith("VERTEX")}:
        if missing := sorted(set(keys) - defined):
            raise ValueError(f"{path}: edges name vertices the file does not define: {missing[:5]}")
        return graph, initial
    odometry = {edge[1]: graph.at(i).measured() for i, edge in enumerate(graph_edges(graph)) if edge[1] == edge[0] + 1}
    pose = gtsam.Pose3() if is_3d else gtsam.Pose2()
    for key in keys:  # compose the odometry from the first vertex at the origin
        if key != keys[0] and not (key in odometry and initial.exists(key - 1)):
            raise ValueError(f"{path}: no vertices and no odometry edge ({key - 1}, {key}) to place vertex {key}")
        pose = pose.compose(odometry[key]) if key != keys[0] else pose
        initial.insert(key, pose)
    return graph, initial


def pose_rows(values: Any) -> np.ndarray:
    """(N, 8): ``id x y z qx qy qz qw`` of each pose of a ``gtsam.Values`` (the TUM rows ``evo`` reads)."""
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
    ``verbose``: GTSAM prints each LM or GN iteration (and GNC's λ) to stdout as it runs."""
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


def main(conf: LoopClosureConf, graph: Path, scores: Path, gate: Path, out: Path, *, log: Callable = print) -> Path:
    """Filter ``graph`` by the ``gate``'s decisions on the ``scores`` file, write it to ``out`` (g2o) and, with
    ``conf.optimize``, the optimised poses to ``out`` with the suffix ``.tum``; returns ``out``."""
    gtsam, out, partial = gtsam_module(), Path(out), Path(f"{out}.partial")
    if ((conf.robust != "none" or conf.verbose) and not conf.optimize) or not 0 < conf.inlier_probability < 1:
        raise ValueError("--robust and --verbose need --optimize; --inlier-probability must lie in (0, 1)")
    if out.exists() and out.resolve() == Path(graph).resolve():
        raise ValueError(f"--out {out} is the input graph, which is never modified: name another file")
    with np.load(scores, allow_pickle=False) as file:
        if missing := {"edges", "scores"} - set(file.files):
            raise ValueError(f"{scores}: no array {sorted(missing)} (expected edges (E, 2) and scores (E, K))")
        listed = {name: file[name] for name in ("edges", "scores")}
    pose_graph, initial = read_graph(graph)
    start = time.perf_counter()
    filtered = filter_loop_closures(pose_graph, listed, Gate.load(gate))
    seconds, n, n_edges = time.perf_counter() - start, len(listed["edges"]), pose_graph.size()
    gtsam.writeG2o(filtered, initial, str(partial))
    os.replace(partial, out)
    kept = f"kept {n - n_edges + filtered.size()} of {n} scored loop closures and {n_edges - n} other edges"
    log(f"{kept} ({seconds:.2f} s); wrote {out}")
    if conf.optimize:
        start, tum = time.perf_counter(), out.with_suffix(".tum")
        poses = optimize(
            filtered, initial, robust=conf.robust, inlier_probability=conf.inlier_probability, verbose=conf.verbose
        )
        seconds = time.perf_counter() - start
        np.savetxt(partial, pose_rows(poses), fmt=["%d"] + ["%.9g"] * 7)
        os.replace(partial, tum)
        log(f"optimised by GTSAM (robust: {conf.robust}) in {seconds:.2f} s; wrote {tum}")
    return out


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``loop-closures`` command."""
    help = "keep the loop closures of a pose graph whose VPR match the gate accepts; optimise it (GTSAM)"
    parser = subparsers.add_parser("loop-closures", help=help, description=__doc__.split("\n\n")[1])
    parser.add_argument("graph", type=Path, metavar="GRAPH", help="g2o (EDGE_SE2, EDGE_SE3:QUAT) or EDGE2/3 text")
    parser.add_argument("--scores", type=Path, required=True, metavar="CLOSURES.npz", help="edges (E,2), scores (E,K)")
    parser.add_argument("--gate", type=Path, required=True, metavar="GATE.json", help="a gate written by calibrate")
    parser.add_argument("--out", type=output_file, required=True, metavar="FILTERED.g2o", help="graph to write")
    add_options(parser, LoopClosureConf)
    parser.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    return main(conf_from_args(LoopClosureConf, args), args.graph, args.scores, args.gate, args.out) and 0
