"""``vpr-uncertainty loop-closures``: keep a pose graph's loop closures whose VPR match the gate accepts, and
optionally optimise the graph with GTSAM (the ``slam`` extra: ``pip install 'vpr-uncertainty[slam]'``).

A loop closure is an edge between non-consecutive vertex ids. The score file (.npz) holds edges (E, 2), the vertex
ids of each closure a VPR match proposed (either direction), and scores (E, K), that match's top-K similarities
sorted descending. Edges it does not list (odometry, other sensors) are kept; a listed closure is kept when the gate
accepts its row. Graphs: g2o (VERTEX_SE2, EDGE_SE2, VERTEX_SE3:QUAT, EDGE_SE3:QUAT), TORO (VERTEX2, EDGE2, VERTEX3,
EDGE3, information in TORO's order) and the EDGE2 i 1 j 0 N x y θ [x y θ ...] layout of GTSAM's City10000 files
(its first measurement, σ = (1/30, 1/30, 1/100) as in GTSAM's example). The output is the input's lines, byte for
byte, minus the rejected closures: numbers keep every digit, and lines of other tags (landmarks, FIX, comments) are
copied unchanged (and not optimised). Without vertices, the initial guess composes the odometry edges (i, i+1) from
the first vertex at the origin. --optimize also writes the optimised poses as OUT.tum (id x y z qx qy qz qw, as evo
reads them). A number that is not finite, a negative or fractional id, an information matrix that is not positive
definite, or a file mixing 2-D and 3-D tags is refused, naming the line.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_uncertainty._files import refuse_shared_files
from vpr_uncertainty.cache import atomic_write
from vpr_uncertainty.calibration.gate import Gate
from vpr_uncertainty.pipeline.options import add_options, conf_from_args, option, output_file
from vpr_uncertainty.slam.graph_file import read_graph_file, write_graph_file
from vpr_uncertainty.slam.pose_graph import KERNELS, closure_mask, factor_graph, optimize, pose_rows

__all__ = ["LoopClosureConf", "main"]


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


def main(conf: LoopClosureConf, graph: Path, scores: Path, gate: Path, out: Path, *, log: Callable = print) -> Path:
    """Filter ``graph`` by the ``gate``'s decisions on the ``scores`` file, write it to ``out`` (its lines, minus the
    rejected closures) and, with ``conf.optimize``, the optimised poses to ``out`` with the suffix ``.tum``; returns
    ``out``. No input is modified, and an output that is an input is refused."""
    out = Path(out)
    if ((conf.robust != "none" or conf.verbose) and not conf.optimize) or not 0 < conf.inlier_probability < 1:
        raise ValueError("--robust and --verbose need --optimize; --inlier-probability must lie in (0, 1)")
    tum = out.with_suffix(".tum") if conf.optimize else None
    inputs = {"GRAPH": graph, "--scores": scores, "--gate": gate}
    refuse_shared_files(inputs, {"--out": out, "the poses file of --optimize": tum})
    with np.load(scores, allow_pickle=False) as file:
        if missing := {"edges", "scores"} - set(file.files):
            raise ValueError(f"{scores}: no array {sorted(missing)} (expected edges (E, 2) and scores (E, K))")
        listed = {name: file[name] for name in ("edges", "scores")}
    edges, rows = listed["edges"], listed["scores"]
    numbers = edges.dtype.kind in "iuf" and rows.dtype.kind in "iuf" and edges.ndim == rows.ndim == 2
    if not numbers or edges.shape[1] != 2 or len(edges) != len(rows):
        raise ValueError(
            f"{scores}: expected edges (E, 2) and scores (E, K) of numbers, got {edges.shape} {rows.shape}"
        )
    if (bad := np.flatnonzero(~(np.isfinite(edges) & (edges >= 0) & (edges == np.round(edges))).all(axis=1))).size:
        raise ValueError(
            f"{scores}: edges, row {bad[0]}: vertex ids must be integers >= 0, got {edges[bad[0]].tolist()}"
        )
    listed["edges"] = edges.astype(np.int64)
    graph_file, gate_ = read_graph_file(graph), Gate.load(gate)
    start = time.perf_counter()
    try:
        keep = closure_mask(graph_file.edges, listed["edges"], listed["scores"], gate_)
    except ValueError as error:
        tags = ", ".join(f"{tag} ({n})" for tag, n in graph_file.other_tags.items() if tag != "#")
        read_as = f"read as a {graph_file.dimension}-D graph of {len(graph_file.edges)} edges"
        raise ValueError(
            f"{scores} on {graph}: {error} ({read_as}{'; lines not read: ' + tags if tags else ''})"
        ) from None
    seconds = time.perf_counter() - start
    write_graph_file(graph_file, out, keep=keep)
    closures = set(map(tuple, np.sort(np.asarray(listed["edges"]).reshape(-1, 2), axis=1).tolist()))
    other = sum(pair not in closures for pair in map(tuple, np.sort(graph_file.edges, axis=1).tolist()))
    accepted = int(np.count_nonzero(gate_.accept(listed["scores"])))
    log(
        f"kept {accepted} of {len(closures)} scored loop closures and {other} other edges ({seconds:.2f} s); "
        f"wrote {out}"
    )
    if others := {tag: n for tag, n in graph_file.other_tags.items() if tag != "#"}:
        described = ", ".join(f"{tag} ×{n}" for tag, n in others.items())
        log(
            f"note: {sum(others.values())} lines of tags not read ({described}) are copied to {out} unchanged"
            + (" and not optimised" if conf.optimize else "")
        )
    if tum is not None:
        start = time.perf_counter()
        poses = optimize(
            *factor_graph(graph_file, keep),
            robust=conf.robust,
            inlier_probability=conf.inlier_probability,
            verbose=conf.verbose,
        )
        seconds = time.perf_counter() - start
        rows = pose_rows(poses)[:, 1:].tolist()
        with atomic_write(tum) as handle:  # every number as Python writes it back exactly (repr)
            handle.writelines(
                " ".join(map(repr, [key, *row])) + "\n" for key, row in zip(poses.keys(), rows, strict=True)
            )
        log(f"optimised by GTSAM (robust: {conf.robust}) in {seconds:.2f} s; wrote {tum}")
    return out


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``loop-closures`` command."""
    help = "keep the loop closures of a pose graph whose VPR match the gate accepts; optimise it (GTSAM)"
    parser = subparsers.add_parser("loop-closures", help=help, description=__doc__.split("\n\n")[1])
    parser.add_argument("graph", type=Path, metavar="GRAPH", help="g2o, TORO or City10000 text (above)")
    parser.add_argument("--scores", type=Path, required=True, metavar="CLOSURES.npz", help="edges (E,2), scores (E,K)")
    parser.add_argument("--gate", type=Path, required=True, metavar="GATE.json", help="a gate written by calibrate")
    parser.add_argument("--out", type=output_file, required=True, metavar="FILTERED.g2o", help="graph to write")
    add_options(parser, LoopClosureConf)
    parser.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    return main(conf_from_args(LoopClosureConf, args), args.graph, args.scores, args.gate, args.out) and 0
