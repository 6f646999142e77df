"""``vpr-uncertainty loop-closures``: keep a pose graph's loop closures whose VPR match the gate accepts, and
optionally optimise the graph with GTSAM (the ``slam`` extra: ``pip install 'vpr-uncertainty[slam]'``).

--odometry tells odometry edges from loop closures (by default, vertex ids that differ by one). The score file
(.npz) holds edges (E, 2), the vertex ids of each closure a VPR match proposed (either direction), and scores
(E, K), that match's top-K similarities sorted descending. A listed edge is kept when the gate accepts its row
(--gate none: always, the baseline); odometry is kept; a closure without a row is an error, kept or dropped
(--unscored). Graphs: g2o (VERTEX_SE2, EDGE_SE2, VERTEX_SE3:QUAT, EDGE_SE3:QUAT), TORO (VERTEX2, EDGE2, VERTEX3,
EDGE3, information in TORO's order) and the EDGE2 i 1 j 0 N x y θ [x y θ ...] layout of GTSAM's City10000 files
(its first measurement, σ = (1/30, 1/30, 1/100) as in GTSAM's example). The output is the input's lines, byte for
byte, minus the rejected closures: numbers keep every digit, and lines of other tags (landmarks, FIX, comments) are
copied unchanged (and not optimised). Without vertices, the initial guess composes the odometry from the first
vertex at the origin. --optimize also writes the optimised poses as OUT.tum (id x y z qx qy qz qw, as evo reads
them); --ground-truth gives the APE of the odometry and of the result, --plot draws them, --decisions writes each
scored closure's P(correct), decision and final weight in the back end. A number that is not finite, a negative or
fractional id, an information matrix that is not positive definite, or a file mixing 2-D and 3-D tags is refused,
naming the line.
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
from vpr_uncertainty.formats import read_closures
from vpr_uncertainty.pipeline.options import add_options, command_wording, conf_from_args, option, output_file
from vpr_uncertainty.slam.graph_file import read_graph_file, write_graph_file
from vpr_uncertainty.slam.pose_graph import (
    KERNELS,
    UNSCORED,
    aligned,
    closure_mask,
    factor_graph,
    odometry_mask,
    optimize,
    pose_rows,
    trajectory_error,
)

__all__ = ["LoopClosureConf", "main"]


@dataclass(frozen=True)
class LoopClosureConf:
    """What ``loop-closures`` does; each field is also the command-line option of the same name."""

    odometry: str = option(
        "ids",
        "which edges are odometry, the others being loop closures: ids (vertex ids that differ by one), consecutive "
        "(vertices next to each other in the file's order: keyframe ids 0, 2, 4, ...; multi-session graphs) or "
        "tag:NAME (the edges of that tag)",
    )
    unscored: str = option(
        "error", "a loop closure without a score row (another sensor's): error, keep or drop", choices=UNSCORED
    )
    optimize: bool = option(False, "also optimise the filtered graph with GTSAM and write its poses to OUT.tum")
    robust: str = option(
        "none",
        "loss of the loop closures when optimising: none (least squares), huber, cauchy, dcs, gnc (GTSAM's "
        "GncOptimizer, truncated least squares, odometry as known inliers) or gnc-gn (the same, Gauss-Newton inside)",
        choices=("none", *KERNELS, "gnc", "gnc-gn"),
    )
    inlier_probability: float = option(0.99, "gnc(-gn): inlier threshold at this χ² quantile of the noise", type=float)
    verbose: bool = option(False, "print GTSAM's iterations as they run (LM's or GN's costs; GNC's λ schedule)")


class _NoGate:
    """``--gate none``: every closure accepted, no probability (the baseline inside the command)."""

    def accept(self, scores: np.ndarray) -> np.ndarray:
        return np.ones(len(scores), dtype=bool)

    def probability_correct(self, scores: np.ndarray) -> np.ndarray:
        return np.full(len(scores), np.nan)


def main(
    conf: LoopClosureConf,
    graph: Path,
    scores: Path | None,
    gate: Path | None,
    out: Path,
    *,
    decisions: Path | None = None,
    ground_truth: Path | None = None,
    plot: Path | None = None,
    log: Callable = print,
) -> Path:
    """Filter ``graph`` by the ``gate``'s decisions on the ``scores`` file (``gate`` None: keep every closure), write
    it to ``out`` (its lines, minus the rejected closures) and, with ``conf.optimize``, the optimised poses to
    ``out`` with the suffix ``.tum``; ``decisions``: a CSV of each scored closure's P(correct), decision and (with
    ``conf.optimize``) the back end's final weight; ``ground_truth`` (TUM rows ``id x y z qx qy qz qw``): the APE of
    the odometry and of the result; ``plot``: a figure of them. Returns ``out``. No input is modified, and an output
    that is an input is refused."""
    out = Path(out)
    if ((conf.robust != "none" or conf.verbose or ground_truth or plot) and not conf.optimize) or not (
        0 < conf.inlier_probability < 1
    ):
        raise ValueError(
            "--robust, --verbose, --ground-truth and --plot need --optimize; --inlier-probability must lie in (0, 1)"
        )
    if scores is None and gate is not None:
        raise ValueError("--scores CLOSURES.npz is required unless --gate none")
    tum = out.with_suffix(".tum") if conf.optimize else None
    inputs = {"GRAPH": graph, "--scores": scores, "--gate": gate, "--ground-truth": ground_truth}
    outputs = {"--out": out, "the poses file of --optimize": tum, "--decisions": decisions, "--plot": plot}
    refuse_shared_files(inputs, outputs)
    closures, rows = (np.empty((0, 2), np.int64), np.empty((0, 1))) if scores is None else read_closures(scores)
    graph_file, the_gate = read_graph_file(graph), _NoGate() if gate is None else Gate.load(gate)
    truth = None if ground_truth is None else _read_truth(ground_truth)
    start = time.perf_counter()
    with command_wording(unscored="--unscored", odometry="--odometry"):
        odometry = odometry_mask(graph_file, conf.odometry)
        try:
            keep = closure_mask(graph_file.edges, closures, rows, the_gate, odometry=odometry, unscored=conf.unscored)
        except ValueError as error:
            tags = ", ".join(f"{tag} ({n})" for tag, n in graph_file.other_tags.items() if tag != "#")
            read_as = f"read as a {graph_file.dimension}-D graph of {len(graph_file.edges)} edges"
            raise ValueError(
                f"{scores} on {graph}: {error} ({read_as}{'; lines not read: ' + tags if tags else ''})"
            ) from None
    seconds = time.perf_counter() - start
    write_graph_file(graph_file, out, keep=keep)
    accepted = the_gate.accept(rows)
    scored = set(map(tuple, np.sort(closures, axis=1).tolist()))
    pairs = list(map(tuple, np.sort(graph_file.edges, axis=1).tolist()))
    unscored = {p for p, odo in zip(pairs, odometry.tolist(), strict=True) if not odo and p not in scored}
    what = {"keep": "kept", "drop": "dropped", "error": ""}[conf.unscored]
    log(
        f"kept {int(accepted.sum())} of {len(scored)} scored loop closures"
        + (f", {what} {len(unscored)} loop closures without a score row" if unscored else "")
        + f" and {sum(p not in scored and p not in unscored for p in pairs)} odometry edges ({seconds:.2f} s"
        + (f"; the gate: {the_gate.acceptance}" if gate is not None else "")
        + f"); wrote {out}"
    )
    if others := {tag: n for tag, n in graph_file.other_tags.items() if tag != "#"}:
        described = ", ".join(f"{tag} ×{n}" for tag, n in others.items())
        log(
            f"note: {sum(others.values())} lines of tags not read ({described}) are copied to {out} unchanged"
            + (" and not optimised" if conf.optimize else "")
        )
    weights = np.full(len(pairs), np.nan)
    if tum is not None:
        start = time.perf_counter()
        factors, initial = factor_graph(graph_file, keep, conf.odometry)
        poses, weights[keep] = optimize(
            factors,
            initial,
            robust=conf.robust,
            inlier_probability=conf.inlier_probability,
            verbose=conf.verbose,
            closures=np.flatnonzero(~odometry[keep]),
            weights=True,
        )
        seconds, result = time.perf_counter() - start, pose_rows(poses)
        with atomic_write(tum) as handle:  # every number as Python writes it back exactly (repr)
            lines = zip(poses.keys(), result[:, 1:].tolist(), strict=True)
            handle.writelines(" ".join(map(repr, [key, *row])) + "\n" for key, row in lines)
        log(f"optimised by GTSAM (robust: {conf.robust}) in {seconds:.2f} s; wrote {tum}")
        trajectories = {"odometry": pose_rows(initial), "result": result}
        errors = {} if truth is None else {name: trajectory_error(rows_, truth) for name, rows_ in trajectories.items()}
        if errors:
            described = (f"APE of the {name} {e['rmse']:.4g} m (max {e['max']:.4g} m)" for name, e in errors.items())
            log(f"{', '.join(described)} against {ground_truth}, after SE(3) alignment")
        if plot is not None:
            log(f"wrote {_plot_trajectories(plot, trajectories, truth, errors)}")
    if decisions is not None:
        first = {pair: index for index, pair in reversed(list(enumerate(pairs)))}
        weight = [weights[first[pair]] for pair in map(tuple, np.sort(closures, axis=1).tolist())]
        probability = the_gate.probability_correct(rows) if len(rows) else np.empty(0)
        table = np.column_stack([np.arange(len(closures)), closures, probability, accepted, weight]).tolist()
        with atomic_write(decisions, newline="") as handle:  # NaN (no gate, not optimised): an empty cell
            handle.write("row,i,j,p_correct,accepted,weight\n")
            handle.writelines(",".join(map(_cell, cells)) + "\n" for cells in table)
        log(f"wrote {decisions}")
    return out


def _cell(value: object) -> str:
    number = float(value)  # type: ignore[arg-type]
    return "" if np.isnan(number) else str(int(number)) if number.is_integer() and abs(number) < 2**53 else repr(number)


def _read_truth(path: Path) -> np.ndarray:
    """The (N, 8) ``id x y z qx qy qz qw`` rows of a ground-truth file (the TUM rows this command writes)."""
    try:
        rows = np.loadtxt(path, ndmin=2, comments="#")
    except ValueError as error:
        raise ValueError(f"{path}: expected rows of 'id x y z qx qy qz qw' ({error})") from None
    if rows.shape[1:] != (8,) or not np.isfinite(rows).all() or (rows[:, 0] != np.round(rows[:, 0])).any():
        raise ValueError(f"{path}: expected finite rows of 'id x y z qx qy qz qw' with integer ids, got {rows.shape}")
    if len(np.unique(rows[:, 0])) < len(rows):
        raise ValueError(f"{path}: a pose id is given twice")
    return rows


def _plot_trajectories(path: Path, trajectories: dict[str, np.ndarray], truth: np.ndarray | None, errors: dict) -> Path:
    """x–y of the ground truth (aligned to), the odometry and the result, one line each, the APE in the legend."""
    from vpr_uncertainty.cache import write_figure
    from vpr_uncertainty.reports.style import DPI, figure_rc, figure_width, pyplot

    with figure_rc("column"):
        figure, axis = pyplot().subplots(figsize=(figure_width("column"), figure_width("column")), layout="constrained")
        if truth is not None:
            axis.plot(truth[:, 1], truth[:, 2], color="0.7", lw=3.0, label="ground truth", zorder=1)
        for (name, rows), style in zip(trajectories.items(), ({"ls": "--", "lw": 0.8}, {"lw": 1.0}), strict=True):
            xy = rows[:, 1:3] if truth is None else aligned(rows, truth)[:, :2]
            ape = f" (APE {errors[name]['rmse']:.3g} m)" if name in errors else ""
            axis.plot(xy[:, 0], xy[:, 1], label=f"{name}{ape}", zorder=2, **style)
        axis.set(xlabel="x [m]", ylabel="y [m]", aspect="equal")
        axis.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=1, frameon=False)
        write_figure(figure, path, dpi=DPI)
    return path


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``loop-closures`` command."""
    help = "keep the loop closures of a pose graph whose VPR match the gate accepts; optimise it (GTSAM)"
    parser = subparsers.add_parser("loop-closures", help=help, description=__doc__.split("\n\n")[1])
    parser.add_argument("graph", type=Path, metavar="GRAPH", help="g2o, TORO or City10000 text (above)")
    parser.add_argument("--scores", type=Path, metavar="CLOSURES.npz", help="edges (E,2), scores (E,K)")
    parser.add_argument(
        "--gate", type=_gate_path, required=True, metavar="GATE.json|none",
        help="a gate written by calibrate, or none: keep every closure (the baseline)",
    )  # fmt: skip
    parser.add_argument("--out", type=output_file, required=True, metavar="FILTERED.g2o", help="graph to write")
    parser.add_argument(
        "--decisions", type=output_file, metavar="FILE.csv",
        help="one row per scored closure: row, i, j, p_correct, accepted, and with --optimize the back end's weight",
    )  # fmt: skip
    parser.add_argument(
        "--ground-truth", type=Path, metavar="POSES.tum",
        help="ground-truth poses (id x y z qx qy qz qw rows, as OUT.tum): APE of the odometry and the result (evo)",
    )  # fmt: skip
    parser.add_argument(
        "--plot", type=output_file, metavar="FILE.png", help="figure of the ground truth, the odometry and the result"
    )
    add_options(parser, LoopClosureConf)
    parser.set_defaults(handler=_handle)


def _gate_path(text: str) -> Path | None:
    return None if text == "none" else Path(text)


def _handle(args: argparse.Namespace) -> int:
    main(conf_from_args(LoopClosureConf, args), args.graph, args.scores, args.gate, args.out,
         decisions=args.decisions, ground_truth=args.ground_truth, plot=args.plot)  # fmt: skip
    return 0
