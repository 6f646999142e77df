"""The back end labels its own closures, a person audits 40 of them, and the gate certified so decides the rest
(issue 44, deliverable 1 and its first target).

Per seed: ``loop_closure_slam.py``'s graph with wrong closures (random, or grouped: Sünderhauf's consistent runs of
5-20 wrong closures between two stretches of the trajectory) and a corridor method's real score rows paired with the
closures (true closure: a row with a correct top-1; wrong: a wrong one; the pairing is simulated). The closures are
taken in trajectory order (by their later vertex); on the first ``--labelled`` share, GTSAM's GNC runs on the graph
seen so far (odometry to that point and those closures) and labels each closure by its final weight (> 0.5: correct,
``label --by back-end``); ``AuditCalibration`` then certifies p* from those machine labels with an audit of at most
40 closures, **the ground truth standing in for the person**. The certified gate decides the remaining closures.
Reported per configuration (mean over seeds): the back end's labels against the truth, the audit's labels and
P(certified), the share of the remaining true closures the gate keeps (beside the hindsight ceiling: the most lenient
SU cut whose precision on the remaining closures is >= p*), the realised precision of what it accepts
(and the share of seeds where it is >= p*), and the APE of gate + GNC on the whole graph against the floor (LM with
the true closures only).

Targets (issue 44): kept >= 85 % of the true closures, realised precision >= p* in >= 90 % of seeds, gate + GNC <=
1.1x the floor, on the four-lap graph and City10000 at 30-70 % wrong closures, 5 seeds, random and grouped.

    VPR_UNCERTAINTY_DATA=... python benchmarks/back_end_audit.py --graphs fourlap --rates 0.3,0.5,0.7 \
        --kinds random,grouped --seeds 5 [--method AMOSNet]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # its sibling script builds the cases

import loop_closure_slam as slam
from vpr_uncertainty import statistical_uncertainty
from vpr_uncertainty.calibration.audit import AuditCalibration
from vpr_uncertainty.slam.pose_graph import graph_edges, optimize


def prefix_graph(graph, last: int):
    """The factors of ``graph`` between vertices up to ``last`` (the part of the trajectory seen so far)."""
    kept = slam.gtsam.NonlinearFactorGraph()
    for index in range(graph.size()):
        if max(graph.at(index).keys()) <= last:
            kept.add(graph.at(index))
    return kept


def oracle_kept(rows: np.ndarray, is_true: np.ndarray, target: float) -> float:
    """The hindsight ceiling: the share of the true closures among ``rows`` (E, K) kept by the most lenient SU cut
    whose precision on them is >= ``target`` (0 when none is): no gate on these rows keeps more at that precision."""
    su = statistical_uncertainty(rows[:, :10])
    order = np.argsort(su, kind="stable")
    ends = np.append(np.flatnonzero(np.diff(su[order]) > 0), len(su) - 1)  # last row of each tied group
    true_kept = np.cumsum(is_true[order])[ends]
    reaching = true_kept / (ends + 1) >= target
    return float(true_kept[reaching].max() / max(is_true.sum(), 1)) if reaching.any() else 0.0


def one_seed(problem, rate, kind, seed, pop, labelled, target):
    rng = np.random.default_rng(seed)
    graph, closures, is_true = slam.with_wrong_closures(problem, rate, rng, kind)  # "grouped": slam's grouped runs
    rows = slam.score_rows(pop, is_true, rng)
    order = np.argsort(closures.max(axis=1), kind="stable")  # trajectory order
    first, rest = order[: round(labelled * len(order))], order[round(labelled * len(order)) :]
    seen = prefix_graph(graph, int(closures[first].max()))
    initial = slam.gtsam.Values()
    for key in sorted({k for i in range(seen.size()) for k in seen.at(i).keys()}):
        initial.insert(key, problem.initial.atPose2(key))
    edges = graph_edges(seen)
    closing = np.flatnonzero(np.abs(edges[:, 1] - edges[:, 0]) != 1)
    _, weights = optimize(seen, initial, robust="gnc", closures=closing, weights=True)
    weight_of = {tuple(sorted(edges[i].tolist())): weights[i] for i in closing}
    machine = np.array([weight_of[tuple(sorted(pair))] > 0.5 for pair in closures[first].tolist()])
    audit = AuditCalibration(rows[first], machine, target_precision=target, delta=0.1, seed=seed)
    while (query := audit.next_query()) is not None:  # the ground truth stands in for the person
        audit.add_label(query, bool(is_true[first][query]))
    status, gate = audit.status(), audit.gate() if audit.status().certified else None
    accept = gate.accept(rows) if gate is not None else np.zeros(len(rows), bool)
    kept_true = accept[rest][is_true[rest]].mean() if is_true[rest].any() else np.nan
    precision = is_true[rest][accept[rest]].mean() if accept[rest].any() else np.nan
    gated = slam.gtsam.NonlinearFactorGraph()
    all_edges, closure_set = graph_edges(graph), {tuple(sorted(p)): n for n, p in enumerate(closures.tolist())}
    floor = slam.gtsam.NonlinearFactorGraph()
    for index, (a, b) in enumerate(all_edges.tolist()):
        n = closure_set.get(tuple(sorted((a, b))))
        if n is None or accept[n]:
            gated.add(graph.at(index))
        if n is None or is_true[n]:
            floor.add(graph.at(index))
    start = time.perf_counter()
    gate_gnc = slam.ate(optimize(gated, problem.initial, robust="gnc"), problem.truth)[0]
    seconds = time.perf_counter() - start
    floor_ape = slam.ate(optimize(floor, problem.initial), problem.truth)[0]
    return {
        "oracle_kept": oracle_kept(rows[rest], is_true[rest], target),
        "machine_wrong": float(np.mean(machine != is_true[first])),
        "labels": status.labelled,
        "certified": status.certified,
        "kept_true": kept_true,
        "precision": precision,
        "precise": bool(precision >= target) if status.certified and not np.isnan(precision) else False,
        "ratio": gate_gnc / floor_ape,
        "seconds": seconds,
    }


def run(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--graphs", default="fourlap", help="fourlap, city10000 (comma-separated)")
    parser.add_argument("--rates", default="0.3,0.5,0.7")
    parser.add_argument("--kinds", default="random,grouped")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--method", default="AMOSNet", help="the corridor method whose rows are paired")
    parser.add_argument("--labelled", type=float, default=0.3, help="share of the closures the back end labels")
    parser.add_argument("--target", type=float, default=0.9)
    args = parser.parse_args(argv)
    pop = slam.population(args.method)
    print("| graph | wrong | kind | back end wrong | audit labels | P(certified) | true kept (rest) | SU oracle kept "
          "(rest) | precision (rest) | precision >= p* | gate + GNC / floor (median, max) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|", flush=True)
    for name in args.graphs.split(","):
        problem = slam.PROBLEMS[name]() if name != "fourlap" else slam.four_lap(0)
        for rate in map(float, args.rates.split(",")):
            for kind in args.kinds.split(","):
                found = [one_seed(problem, rate, kind, s, pop, args.labelled, args.target) for s in range(args.seeds)]

                def mean(key: str, found: list = found) -> float:
                    return float(np.nanmean([f[key] for f in found]))

                ratios = [f["ratio"] for f in found]
                print(
                    f"| {name} | {rate:.0%} | {kind} | {mean('machine_wrong'):.1%} | {mean('labels'):.1f} | "
                    f"{mean('certified'):.2f} | {mean('kept_true'):.2f} | {mean('oracle_kept'):.2f} | "
                    f"{mean('precision'):.3f} | "
                    f"{mean('precise'):.2f} | {np.median(ratios):.2f}, {max(ratios):.2f} |",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(run())
