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
import itertools
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # its sibling script builds the cases

import loop_closure_slam as slam
from pairwise_consistency import pcm
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


def lenient_cut(su: np.ndarray, positive: np.ndarray, wrong_rate: float, target: float) -> tuple[float, float]:
    """The most lenient cut on ``su`` (N,) whose precision at a ``wrong_rate`` share of negatives, (1 - w) F_pos(c) /
    ((1 - w) F_pos(c) + w F_neg(c)) with F the SU distributions of the ``positive`` (N,) rows and of the others, is
    >= ``target``, and the share of the positive rows it keeps; (-inf, 0.0) when no cut keeps one at that precision."""
    cuts = np.unique(su)
    true_share = (su[positive][:, None] <= cuts).mean(axis=0) if positive.any() else np.zeros(cuts.size)
    wrong_share = (su[~positive][:, None] <= cuts).mean(axis=0) if (~positive).any() else np.zeros(cuts.size)
    accepted_true, accepted_wrong = (1 - wrong_rate) * true_share, wrong_rate * wrong_share
    reaching = np.flatnonzero((accepted_true > 0) & (accepted_true >= target * (accepted_true + accepted_wrong)))
    return (float(cuts[reaching[-1]]), float(true_share[reaching[-1]])) if reaching.size else (-np.inf, 0.0)


def population_ceiling(pop, wrong_rate: float, target: float) -> float:
    """The share of the true closures kept by the most lenient SU cut whose expected precision is >= ``target``
    when true closures draw the method's correct rows and a ``wrong_rate`` share of the closures its wrong rows (the
    pairing of ``loop_closure_slam.score_rows``; ``lenient_cut``). No SU gate keeps more at that precision, whatever
    its labels."""
    return lenient_cut(statistical_uncertainty(pop.scores[:, :10]), pop.correct, wrong_rate, target)[1]


def print_ceilings(rates: list[float], targets: list[float], results: Path | None = None) -> None:
    """``population_ceiling`` of every corridor method, its native rows and with absent-place rows, and of a
    retrieval file with its positives (``results``: e.g. the toolkit's own ``run``)."""
    methods = sorted(p.name for p in (slam.data_root() / "precomputed_matches/corridor").iterdir())
    cells = [(w, t) for w in rates for t in targets]
    print("| method | rows | " + " | ".join(f"{w:.0%} wrong, p*={t}" for w, t in cells) + " |")
    print("|---|---|" + "---|" * len(cells))
    populations = [(m, absent, None) for m in methods for absent in (False, True)]
    for method, absent, path in populations + ([("own run", False, results)] if results else []):
        pop = slam.population(method, absent=absent, results=path)
        shares = " | ".join(f"{population_ceiling(pop, w, t):.2f}" for w, t in cells)
        rows = f"native ({pop.correct.sum()} right, {(~pop.correct).sum()} wrong)" if not absent else "absent"
        print(f"| {method if path is None else f'own run ({path})'} | {rows} | {shares} |", flush=True)


def subgraph(graph, closures: np.ndarray, keep: np.ndarray):
    """The factors of ``graph`` but the closures (E, 2) whose ``keep`` (E,) is False."""
    kept, closure_of = slam.gtsam.NonlinearFactorGraph(), {tuple(sorted(p)): n for n, p in enumerate(closures.tolist())}
    for index, (a, b) in enumerate(graph_edges(graph).tolist()):
        n = closure_of.get(tuple(sorted((a, b))))
        if n is None or keep[n]:
            kept.add(graph.at(index))
    return kept


def machine_labels(problem, graph, closures, pool, labeler: str = "gnc") -> np.ndarray:
    """The back end on the graph seen up to the last closure of ``pool`` (indices into ``closures``, trajectory
    order) labels each of the pool's closures: ``"gnc"``, its final GNC weight > 0.5 (``label --by back-end``);
    ``"pcm"``, in the maximum clique of PCM's pairwise consistency graph (``pairwise_consistency.pcm``)."""
    seen = prefix_graph(graph, int(closures[pool].max()))
    if labeler == "pcm":
        return pcm(seen, closures[pool], np.ones(len(pool), bool))
    initial = slam.gtsam.Values()
    for key in sorted({k for i in range(seen.size()) for k in seen.at(i).keys()}):
        initial.insert(key, problem.initial.atPose2(key))
    edges = graph_edges(seen)
    closing = np.flatnonzero(np.abs(edges[:, 1] - edges[:, 0]) != 1)
    _, weights = optimize(seen, initial, robust="gnc", closures=closing, weights=True)
    weight_of = {tuple(sorted(edges[i].tolist())): weights[i] for i in closing}
    return np.array([weight_of[tuple(sorted(pair))] > 0.5 for pair in closures[pool].tolist()])


def certified_gate(problem, graph, closures, rows, is_true, pool, target, seed, audit_size, labeler="gnc"):
    """The back end labels the pool (``machine_labels``); the audit of at most ``audit_size`` of them (the ground
    truth standing in for the person) certifies p*. Returns the gate (None when nothing is certified), the machine
    labels' error rate and the audit's status."""
    machine = machine_labels(problem, graph, closures, pool, labeler)
    audit = AuditCalibration(rows[pool], machine, target_precision=target, delta=0.1, seed=seed, audit_size=audit_size)
    while (query := audit.next_query()) is not None:  # the ground truth stands in for the person
        audit.add_label(query, bool(is_true[pool][query]))
    status = audit.status()
    return (audit.gate() if status.certified else None), float(np.mean(machine != is_true[pool])), status


class ShiftedCut:
    """An SU cut re-chosen for the wrong-closure rate of the latest closures (no new human label): ``lenient_cut``
    with w the machine-labelled wrong share of ``recent`` and F the SU distributions of every machine-labelled
    closure. An estimate, not a certificate."""

    def __init__(self, rows: np.ndarray, machine: np.ndarray, recent: np.ndarray, target: float) -> None:
        su, wrong_rate = statistical_uncertainty(rows[:, :10]), 1 - float(machine[recent].mean())
        self.cut = lenient_cut(su, machine, wrong_rate, target)[0]

    def accept(self, rows: np.ndarray) -> np.ndarray:
        return statistical_uncertainty(rows[:, :10]) <= self.cut


def one_seed(
    problem,
    rate,
    kind,
    seed,
    pop,
    labelled,
    target,
    stages=1,
    window=None,
    step_aside=False,
    follow=False,
    labeler="gnc",
):
    """One seed; with ``stages`` > 1 the remaining closures are decided in that many chunks (trajectory order),
    each by a gate certified again before it on the closures seen so far (the last ``window`` share of all closures
    when given), the 40 audit labels split evenly among the stages. With ``step_aside``, also the APE when the
    closures decided while no gate is certified all go to GNC (the gate steps aside instead of accepting none).
    With ``follow``, only the first stage is audited (all 40 labels); once it certifies, each later stage's gate is
    a ``ShiftedCut`` from the back end's labels of every closure seen so far, its wrong rate read on the last
    ``window`` share of the closures (default: the last stage's)."""
    rng = np.random.default_rng(seed)
    graph, closures, is_true = slam.with_wrong_closures(problem, rate, rng, kind)  # "grouped": slam's grouped runs
    rows = slam.score_rows(pop, is_true, rng)
    order = np.argsort(closures.max(axis=1), kind="stable")  # trajectory order
    start = round(labelled * len(order))
    rest = order[start:]
    accept, labels, certified, machine_wrong, kept = np.zeros(len(rows), bool), 0, [], [], None
    aside = np.zeros(len(rows), bool)  # decided while no gate was certified
    bounds = np.linspace(start, len(order), stages + 1).round().astype(int)
    for stage, (begin, end) in enumerate(itertools.pairwise(bounds)):
        pool = order[:begin] if window is None else order[max(0, begin - round(window * len(order))) : begin]
        if follow and stage:
            seen, recent = order[:begin], max(1, round(window * len(order)) if window else begin - bounds[stage - 1])
            machine = machine_labels(problem, graph, closures, seen, labeler)
            machine_wrong.append(float(np.mean(machine != is_true[seen])))
            gate = ShiftedCut(rows[seen], machine, np.arange(len(seen))[-recent:], target) if kept is not None else None
        else:
            gate, wrong, status = certified_gate(
                problem,
                graph,
                closures,
                rows,
                is_true,
                pool,
                target,
                seed + 1000 * stage,
                40 // (1 if follow else stages),
                labeler,
            )
            labels, machine_wrong = labels + status.labelled, [*machine_wrong, wrong]
            certified.append(status.certified)
        decided = order[:end] if stage == 0 else order[begin:end]  # the first gate also decides its own pool
        kept = gate if gate is not None else kept  # a stage that certifies nothing keeps the last certified gate
        if kept is not None:
            accept[decided] = kept.accept(rows[decided])
        else:
            aside[decided] = True
    kept_true = accept[rest][is_true[rest]].mean() if is_true[rest].any() else np.nan
    precision = is_true[rest][accept[rest]].mean() if accept[rest].any() else np.nan
    start = time.perf_counter()
    gate_gnc = slam.ate(optimize(subgraph(graph, closures, accept), problem.initial, robust="gnc"), problem.truth)[0]
    seconds = time.perf_counter() - start
    floor_ape = slam.ate(optimize(subgraph(graph, closures, is_true), problem.initial), problem.truth)[0]
    aside_gnc = gate_gnc
    if step_aside and aside.any():
        aside_gnc = slam.ate(
            optimize(subgraph(graph, closures, accept | aside), problem.initial, robust="gnc"), problem.truth
        )[0]
    return {
        "oracle_kept": oracle_kept(rows[rest], is_true[rest], target),
        "machine_wrong": float(np.mean(machine_wrong)),
        "labels": labels,
        "certified": float(np.mean(certified)),
        "kept_true": kept_true,
        "precision": precision,
        "precise": bool(precision >= target) if any(certified) and not np.isnan(precision) else False,
        "ratio": gate_gnc / floor_ape,
        "aside_ratio": aside_gnc / floor_ape,
        "seconds": seconds,
    }


def run(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--graphs", default="fourlap", help="fourlap, city10000 (comma-separated)")
    parser.add_argument("--rates", default="0.3,0.5,0.7")
    parser.add_argument("--kinds", default="random,grouped")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0, help="seeds FIRST_SEED .. FIRST_SEED + SEEDS - 1")
    parser.add_argument("--method", default="AMOSNet", help="the corridor method whose rows are paired")
    parser.add_argument("--results", type=Path, help="with --ceilings: also a retrieval file with its positives")
    parser.add_argument("--labeler", choices=("gnc", "pcm"), default="gnc", help="the back end that labels")
    parser.add_argument("--labelled", type=float, default=0.3, help="share of the closures the back end labels")
    parser.add_argument("--target", type=float, default=0.9)
    parser.add_argument("--stages", type=int, default=1, help="gates certified again along the remaining closures")
    parser.add_argument(
        "--step-aside",
        action="store_true",
        help="also report gate + GNC with every closure decided while no gate is certified passed to GNC",
    )
    parser.add_argument(
        "--follow",
        action="store_true",
        help="audit once (40 labels), then re-choose an SU cut per stage for the "
        "latest wrong-closure rate from the back end's labels (ShiftedCut: an estimate, not a certificate)",
    )
    parser.add_argument("--window", type=float, help="each stage's pool: the last WINDOW share of the closures")
    parser.add_argument(
        "--ceilings",
        action="store_true",
        help="print population_ceiling of every corridor method (at --rates, p* 0.5, 0.7, 0.9) and stop",
    )
    args = parser.parse_args(argv)
    if args.ceilings:
        print_ceilings([float(r) for r in args.rates.split(",")], [0.5, 0.7, 0.9], args.results)
        return 0
    pop = slam.population(args.method)
    print("| graph | wrong | kind | back end wrong | audit labels | P(certified) | true kept (rest) | SU oracle kept "
          "(rest) | precision (rest) | precision >= p* | gate + GNC / floor (median, max) |"
          + (" stepping aside when uncertified (median, max) |" if args.step_aside else ""))  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|" + "---|" * args.step_aside, flush=True)
    for name in args.graphs.split(","):
        problem = slam.PROBLEMS[name]() if name != "fourlap" else slam.four_lap(0)
        for rate in map(float, args.rates.split(",")):
            for kind in args.kinds.split(","):
                found = [
                    one_seed(
                        problem,
                        rate,
                        kind,
                        s,
                        pop,
                        args.labelled,
                        args.target,
                        stages=args.stages,
                        window=args.window,
                        step_aside=args.step_aside,
                        follow=args.follow,
                        labeler=args.labeler,
                    )
                    for s in range(args.first_seed, args.first_seed + args.seeds)
                ]

                def mean(key: str, found: list = found) -> float:
                    return float(np.nanmean([f[key] for f in found]))

                ratios, aside = [f["ratio"] for f in found], [f["aside_ratio"] for f in found]
                print(
                    f"| {name} | {rate:.0%} | {kind} | {mean('machine_wrong'):.1%} | {mean('labels'):.1f} | "
                    f"{mean('certified'):.2f} | {mean('kept_true'):.2f} | {mean('oracle_kept'):.2f} | "
                    f"{mean('precision'):.3f} | "
                    f"{mean('precise'):.2f} | {np.median(ratios):.2f}, {max(ratios):.2f} |"
                    + (f" {np.median(aside):.2f}, {max(aside):.2f} |" if args.step_aside else ""),
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(run())
