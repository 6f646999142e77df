"""Loop closures a pose graph can trust: the gate inside GTSAM, measured as trajectory error (issue 31).

What is real and what is simulated
    The graphs and their ground truth are real standard pose graphs shipped with GTSAM 4.3 (``gtsam/Data``):
    City10000 (2-D, 10,000 poses, ``T1_city10000_04.txt``, first measurement of each edge, ground truth
    ``ISAM2_GT_city10000.txt``) and Sphere2500 (3-D, ``sphere2500.txt``, ground truth: the odometry of
    ``sphere2500_groundtruth.txt`` composed), plus a synthetic 240-pose four-lap 2-D graph built here (60 poses a
    lap on a 10 m circle, odometry σ = 5 cm / 0.01 rad, 60 true closures to the previous lap). The VPR score rows are
    real top-10 rows of one corridor VPR-Bench method (default AMOSNet), but their **pairing with closures is
    simulated**: a true closure gets a row drawn from the rows whose top-1 answer is correct, a wrong closure one from
    the rows whose top-1 is wrong (with replacement). ``--rows absent`` adds, for each corridor query, the row it
    gets when its place (its positives ± 10 frames) is not in the map: 111 distinct wrong rows (a front end's wrong
    closures mostly come from places it has not seen), and calibrates the gate on that population (answerable and
    absent-place rows, the absent ones wrong and not answerable). ``benchmarks/loop_closure_corridor.py`` measures
    the real pairing on the corridor's own images: its two traversals as a two-session graph whose closures are each
    method's real top-1 proposals.

Wrong closures
    ``rate`` = wrong / (true + wrong) closures; wrong closures join random vertex pairs (|i - j| > 1, not already an
    edge; Sünderhauf and Protzel's protocol) with the measurement and noise model of a random true closure.
    ``--wrong-closures aliasing``: each moves the earlier end of a random true closure by 5-20 poses (perceptual
    aliasing near an earlier revisit), keeping its measurement. ``--wrong-closures grouped``: Sünderhauf's "grouped"
    policy, runs of 5-20 mutually consistent wrong closures (a + t, b + t), t < the run's length, all with the
    measurement of one random true closure: two stretches of the trajectory taken for one place.

Configurations (same graph, same seed, LM = GTSAM's Levenberg–Marquardt with default parameters from the odometry
guess, the first pose held by a prior)
    all closures + LM; true closures only + LM (the floor); fixed SU threshold (accept SU <= the median SU of the
    method's rows, no labels) + LM; the certified gate (p* = 0.9, δ = 0.1, ``calibrate_arrays`` on 200 rows drawn
    with replacement from the method's rows, as ``benchmarks/gate_efficiency.py`` resamples) + LM; all closures with
    a Huber / Cauchy / DCS kernel; all closures with GNC (TLS, odometry as known inliers, thresholds at the 0.99 χ²
    quantile); the gate followed by GNC; "GNC-GN" on all closures and behind the gate: the same GTSAM GncOptimizer
    with Gauss-Newton inner solves instead of LM (Kimera-RPGO's ``Solver::GN``); the true closures among the gate's
    + LM (the best the gate's output allows: what separates gate + GNC from the floor is the true closures the gate
    dropped, or wrong ones GNC kept); PCM
    (Mangelson et al., ICRA 2018: pairwise consistency maximisation, ``pairwise_consistency.py`` states the test) on
    all closures and on the gate's, each followed by LM. All optimisation through
    ``vpr_uncertainty.slam.pose_graph``, except "GNC warm" on all closures and behind the gate: GNC with each
    inner solve started from the previous one and weight-0 closures left out (``warm_gnc.py``; a different method
    from GTSAM's, which restarts every inner solve from the odometry with every closure in it).

Metrics
    ATE RMSE and max translation error after SE(3) Umeyama alignment without scale (``evo``); closures passed to the
    optimiser (wrong / true); closures the solution fits (whitened error within the 0.99 χ² quantile), wrong / true;
    optimiser seconds (wall clock, one thread of a shared machine: compare within a run only; PCM's configurations
    include PCM's own time, also recorded alone as ``pcm_seconds``). ``--fill-in``: the fill of the Cholesky factor
    and one elimination's time for the true, gated and all closures, what prices every linear solve.

Usage
    nice python benchmarks/loop_closure_slam.py [--quick] [--graphs fourlap,sphere2500,city10000]
        [--rates 0.3,0.5,0.7] [--method AMOSNet] [--seed 0] [--rankings margin,SU,CAL] [--json out.jsonl]
        [--rows native|absent] [--labels 200] [--wrong-closures random|aliasing|grouped] [--p-star 0.5,0.7,0.9]
    nice python benchmarks/loop_closure_slam.py --gates 10: what the gates of seeds 0-9 accept of the method's rows.
    ``--p-star 0.5,0.7,0.9``: the gate's configurations once per target precision, every gate calibrated on the same
    labels (issue 44: which p* before GNC); ``--p-star-summary FILE`` tabulates them against GNC alone over the seeds.
    ``--quick``: the four-lap graph at 0.3, 0.5, 0.7 and 0.85 only (about a minute). Results are appended one JSON line
    per configuration as they finish, so a cut run keeps what it measured.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from pairwise_consistency import pcm  # sibling scripts (benchmarks/ on sys.path)
from vpr_uncertainty.calibration import calibrate_arrays
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation.metrics import answerable_queries, correct_at_n
from vpr_uncertainty.scores import statistical_uncertainty
from vpr_uncertainty.slam.pose_graph import (
    closure_mask,
    graph_edges,
    gtsam_module,
    optimize,
    pose_rows,
    read_graph,
)
from warm_gnc import gnc as warm_gnc

gtsam = gtsam_module()
GTSAM_DATA = Path(gtsam.__file__).parent / "Data"


@dataclass
class Problem:
    name: str
    graph: Any  # odometry + true closures
    initial: Any  # the odometry guess
    truth: np.ndarray  # (N, 8) id x y z qx qy qz qw


def four_lap(seed: int = 0) -> Problem:
    rng = np.random.default_rng(seed)
    n_lap, laps, radius = 60, 4, 10.0
    step = 2 * np.pi / n_lap
    truth = [
        gtsam.Pose2(radius * np.cos(i * step), radius * np.sin(i * step), i * step + np.pi / 2)
        for i in range(n_lap * laps)
    ]
    odo_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.01]))
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    initial.insert(0, truth[0])
    for i in range(1, len(truth)):
        delta = truth[i - 1].between(truth[i])
        noisy = delta.compose(gtsam.Pose2(*(rng.normal(0, [0.05, 0.05, 0.01]))))
        graph.add(gtsam.BetweenFactorPose2(i - 1, i, noisy, odo_noise))
        initial.insert(i, initial.atPose2(i - 1).compose(noisy))
    candidates = [(i - n_lap, i) for i in range(n_lap, len(truth))]
    for a, b in (candidates[i] for i in rng.choice(len(candidates), 60, replace=False)):
        delta = truth[a].between(truth[b]).compose(gtsam.Pose2(*(rng.normal(0, [0.05, 0.05, 0.01]))))
        graph.add(gtsam.BetweenFactorPose2(a, b, delta, odo_noise))
    values = gtsam.Values()
    for i, pose in enumerate(truth):
        values.insert(i, pose)
    return Problem("four-lap (240 poses)", graph, initial, pose_rows(values))


def city10000() -> Problem:
    graph, initial = read_graph(GTSAM_DATA / "T1_city10000_04.txt")
    values = gtsam.Values()
    for i, (x, y, theta) in enumerate(np.loadtxt(GTSAM_DATA / "ISAM2_GT_city10000.txt")):
        values.insert(i, gtsam.Pose2(x, y, theta))
    return Problem("city10000", graph, initial, pose_rows(values))


def sphere2500() -> Problem:
    # GTSAM's reader, as the evidence page was measured: it applies EDGE3's information rotation first, where TORO
    # writes translation first (vpr_uncertainty.slam.graph_file, and loop-closures, read it as TORO does)
    graph, _ = gtsam.readG2o(str(GTSAM_DATA / "sphere2500.txt"), True)
    # neither file has vertices (readG2o then returns no poses): the initial guess and the ground truth are their
    # odometry composed, as the toolkit's reader places them
    _, initial = read_graph(GTSAM_DATA / "sphere2500.txt")
    _, truth = read_graph(GTSAM_DATA / "sphere2500_groundtruth.txt")
    return Problem("sphere2500", graph, initial, pose_rows(truth))


def sphere2500_fitted() -> Problem:
    """Sphere2500 with the noise its measurements really have: every edge's noise model replaced by one diagonal
    Gaussian whose σ per component are the RMS of the edges' errors at the ground truth (``unwhitenedError``, in
    GTSAM's order: rotation, then translation). The file's model overstates the rotation noise about 10×, which
    leaves PCM's consistency test nothing to reject."""
    problem, (_, truth) = sphere2500(), read_graph(GTSAM_DATA / "sphere2500_groundtruth.txt")
    errors = np.array([problem.graph.at(i).unwhitenedError(truth) for i in range(problem.graph.size())])
    sigmas = np.sqrt(np.mean(errors**2, axis=0))
    model = gtsam.noiseModel.Diagonal.Sigmas(sigmas)
    graph = gtsam.NonlinearFactorGraph()
    for i in range(problem.graph.size()):
        factor = problem.graph.at(i)
        graph.add(gtsam.BetweenFactorPose3(*factor.keys(), factor.measured(), model))
    return Problem("sphere2500 (fitted noise)", graph, problem.initial, problem.truth)


PROBLEMS = {
    "fourlap": four_lap,
    "city10000": city10000,
    "sphere2500": sphere2500,
    "sphere2500-fitted": sphere2500_fitted,
}


#: Poses an "aliasing" wrong closure is shifted from a true closure's earlier end (either way, uniformly).
ALIASING_SHIFT = (5, 20)
#: Wrong closures in one "grouped" run (Sünderhauf and Protzel's grouped outliers).
GROUP = (5, 20)


def grouped_wrong_closures(
    problem: Problem, rate: float, rng: np.random.Generator
) -> tuple[Any, np.ndarray, np.ndarray]:
    """The graph with runs of 5-20 mutually consistent wrong closures: (a + t, b + t) for t < run length, each with
    the measurement of one random true closure (two stretches of the trajectory taken for one place)."""
    edges = graph_edges(problem.graph)
    true_index = np.flatnonzero(np.abs(edges[:, 1] - edges[:, 0]) != 1)
    n_wrong, n_poses = round(len(true_index) * rate / (1 - rate)), problem.truth.shape[0]
    existing = {tuple(sorted(e)) for e in edges.tolist()}
    graph, wrong = problem.graph.clone(), []
    while len(wrong) < n_wrong:
        length = int(rng.integers(GROUP[0], GROUP[1] + 1))
        a, b = sorted(rng.integers(0, n_poses - length, 2).tolist())
        run = [(a + t, b + t) for t in range(min(length, n_wrong - len(wrong)))]
        if b - a <= GROUP[1] or any(pair in existing for pair in run):
            continue
        model = graph.at(int(rng.choice(true_index)))
        for pair in run:
            graph.add(type(model)(*pair, model.measured(), model.noiseModel()))
            existing.add(pair)
        wrong += run
    closures = np.concatenate([edges[true_index], np.array(wrong, dtype=np.int64).reshape(-1, 2)])
    return graph, closures, np.r_[np.ones(len(true_index), bool), np.zeros(len(wrong), bool)]


def with_wrong_closures(
    problem: Problem, rate: float, rng: np.random.Generator, kind: str = "random"
) -> tuple[Any, np.ndarray, np.ndarray]:
    """The graph with wrong closures added; its closure edges (E, 2) and whether each is true (E,).

    ``kind="random"``: between random vertex pairs, with the measurement of a random true closure (Sünderhauf and
    Protzel). ``"aliasing"``: a random true closure (a, b) moved to (a ± 5…20 poses, b) with its own measurement: the
    front end matched b to a place near an earlier revisit. ``"grouped"``: ``grouped_wrong_closures``."""
    if kind == "grouped":
        return grouped_wrong_closures(problem, rate, rng)
    edges = graph_edges(problem.graph)
    closure = np.abs(edges[:, 1] - edges[:, 0]) != 1
    true_index = np.flatnonzero(closure)
    n_wrong = round(len(true_index) * rate / (1 - rate))
    n_poses = problem.truth.shape[0]
    existing = {tuple(sorted(e)) for e in edges.tolist()}
    graph = problem.graph.clone()
    wrong = []
    while len(wrong) < n_wrong:
        if kind == "aliasing":
            model = graph.at(int(rng.choice(true_index)))
            a, b = (int(key) for key in model.keys())
            a += int(rng.choice([-1, 1]) * rng.integers(ALIASING_SHIFT[0], ALIASING_SHIFT[1] + 1))
        else:  # the draws in this order keep the seeds of the first evidence tables
            a, b = sorted(rng.integers(0, n_poses, 2).tolist())
        if not 0 <= a < n_poses or abs(b - a) <= 1 or tuple(sorted((a, b))) in existing:
            continue
        existing.add(tuple(sorted((a, b))))
        if kind != "aliasing":
            model = graph.at(int(rng.choice(true_index)))
        graph.add(type(model)(a, b, model.measured(), model.noiseModel()))
        wrong.append((a, b))
    closures = np.concatenate([edges[true_index], np.array(wrong, dtype=np.int64).reshape(-1, 2)])
    return graph, closures, np.r_[np.ones(len(true_index), bool), np.zeros(len(wrong), bool)]


@dataclass
class Population:
    """A method's score rows (R, 10), whether each row's top-1 is correct, and whether its place is in the map."""

    name: str
    scores: np.ndarray
    correct: np.ndarray
    answerable: np.ndarray


#: Frames either side of a query's true place removed from the map to make an "absent place" row (the corridor's
#: ground truth tolerance is about ±2 frames; within ±10 frames the corridor still looks like the same place).
ABSENT_WINDOW = 10


def data_root() -> Path:
    """The VPR-Bench folder of ``VPR_UNCERTAINTY_DATA`` (or that folder itself)."""
    data = Path(os.environ.get("VPR_UNCERTAINTY_DATA", "../shared/data"))
    return data / "vprbench" if (data / "vprbench").is_dir() else data


def population(method: str, absent: bool = False, results: Path | None = None) -> Population:
    """The method's 111 corridor rows (or those of a retrieval file with its positives, e.g. the toolkit's own
    ``run``); with ``absent``, also each query's row when its place (its positives ± 10 frames) is not in the map:
    as many rows again, all wrong, distinct (a query of a place never visited). "± 10 frames" is by database index,
    which is the order along the route in the corridor (and in any database recorded as one sequence)."""
    root = data_root()
    if results is not None:
        retrieval = read_results(results)
    else:
        retrieval = read_results(
            root / f"precomputed_matches/corridor/{method}/precomputed_data_corrected.npy",
            ground_truth=root / "corridor/ground_truth_new.npy",
            top_k=111,
        )
    if retrieval.positives is None:
        raise SystemExit(f"{results} holds no ground truth: the benchmark needs to know which rows are correct")
    scores, indices = np.asarray(retrieval.scores, dtype=np.float64), np.asarray(retrieval.indices)
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    rows, is_correct = [scores[:, :10]], [np.asarray(correct, bool)]
    if absent:
        window = np.ones(2 * ABSENT_WINDOW + 1)
        near = np.array([np.convolve(row, window, "same") > 0 for row in retrieval.positives.toarray()])
        kept = ~np.take_along_axis(near, indices, axis=1)
        if kept.sum(axis=1).min() < 10:
            raise SystemExit(
                f"--rows absent needs 10 candidates per query outside its place; {method} keeps "
                f"{kept.sum(axis=1).min()} of {indices.shape[1]}: retrieve more candidates (run --top-k)"
            )
        rows.append(np.stack([row[keep][:10] for row, keep in zip(scores, kept, strict=True)]))
        is_correct.append(np.zeros(len(scores), bool))
    answerable = np.r_[answerable_queries(retrieval.positives), np.zeros(len(rows) * len(scores) - len(scores), bool)]
    return Population(method, np.concatenate(rows), np.concatenate(is_correct), answerable)


def score_rows(pop: Population, is_true: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    good, bad = np.flatnonzero(pop.correct), np.flatnonzero(~pop.correct)
    rows = np.where(is_true, rng.choice(good, is_true.size), rng.choice(bad, is_true.size))
    return pop.scores[rows]


def calibrated_gate(pop: Population, seed: int, n: int = 200, target: float = 0.9, rankings: Any = None) -> Any:
    rng = np.random.default_rng(10_000 + seed)
    while True:
        rows = rng.integers(0, len(pop.scores), n)
        if 0 < pop.correct[rows].sum() < n:
            break
    return calibrate_arrays(
        pop.scores[rows],
        pop.correct[rows],
        answerable=pop.answerable[rows],
        target_precision=target,
        delta=0.1,
        seed=seed,
        rankings=rankings,
    )


class SUThreshold:
    """Accept rows whose SU is at most the median SU of the method's rows (fixed, no labels)."""

    def __init__(self, pop: Population) -> None:
        self.cut = float(np.median(statistical_uncertainty(pop.scores, k=10)))

    def accept(self, scores: np.ndarray) -> np.ndarray:
        return statistical_uncertainty(scores, k=10) <= self.cut


class Everything:
    def accept(self, scores: np.ndarray) -> np.ndarray:
        return np.ones(len(scores), bool)


class TruthOracle:
    def __init__(self, rows: np.ndarray, is_true: np.ndarray) -> None:
        self.is_true = is_true

    def accept(self, scores: np.ndarray) -> np.ndarray:
        return self.is_true


class TrueAccepted:
    """The true closures among those ``gate`` accepts: the best trajectory the gate's output allows."""

    def __init__(self, gate: Any, is_true: np.ndarray) -> None:
        self.gate, self.is_true = gate, is_true

    def accept(self, scores: np.ndarray) -> np.ndarray:
        return self.gate.accept(scores) & self.is_true


class Fixed:
    """Accepts the closures of a fixed (E,) mask (whatever the rows)."""

    def __init__(self, mask: np.ndarray) -> None:
        self.mask = mask

    def accept(self, scores: np.ndarray) -> np.ndarray:
        return self.mask


def ate(values: Any, truth: np.ndarray) -> tuple[float, float]:
    from evo.core import metrics
    from evo.core.trajectory import PoseTrajectory3D

    def trajectory(rows: np.ndarray) -> PoseTrajectory3D:
        return PoseTrajectory3D(rows[:, 1:4], rows[:, [7, 4, 5, 6]], rows[:, 0].astype(float))

    estimate, reference = trajectory(pose_rows(values)), trajectory(truth)
    estimate.align(reference, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((reference, estimate))
    return ape.get_statistic(metrics.StatisticsType.rmse), ape.get_statistic(metrics.StatisticsType.max)


def fits(graph: Any, values: Any, closures: np.ndarray, is_true: np.ndarray) -> tuple[int, int]:
    """Wrong and true closures whose whitened error at the solution is within the 0.99 χ² quantile."""
    where = {tuple(sorted(graph.at(i).keys())): i for i in range(graph.size())}
    fit = np.zeros(len(closures), bool)
    for e, (a, b) in enumerate(closures.tolist()):
        factor = graph.at(where[(min(a, b), max(a, b))])
        fit[e] = factor.error(values) <= chi2.ppf(0.99, factor.dim()) / 2
    return int((fit & ~is_true).sum()), int((fit & is_true).sum())


def in_child(function: Any, timeout: float) -> Any:
    """``function()`` in a forked process, given ``timeout`` seconds (a TimeoutError after them)."""
    context = multiprocessing.get_context("fork")
    receive, send = context.Pipe(duplex=False)

    def child() -> None:
        try:
            send.send((True, function()))
        except Exception as error:  # handed to the parent, which raises it
            send.send((False, f"{type(error).__name__}: {error}"))

    process = context.Process(target=child)
    process.start()
    send.close()  # the parent's copy: a child that dies closes the pipe, and poll returns at once
    try:
        if not receive.poll(timeout):
            raise TimeoutError(f"did not finish within {timeout:g} s")
        finished, value = receive.recv()
        if not finished:
            raise RuntimeError(f"the optimiser's process raised {value}")
        return value
    except EOFError:
        raise RuntimeError(f"the optimiser's process died (exit code {process.exitcode})") from None
    finally:
        process.kill()
        process.join()


def drawn_case(
    problem: Problem,
    rate: float,
    pop: Population,
    seed: int,
    kind: str = "random",
    labels: int = 200,
    rankings: Any = None,
    target: float = 0.9,
) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, Any]:
    """One seed's graph with wrong closures, its closures (E, 2), whether each is true (E,), their score rows (E, K)
    and the gate calibrated at p* = ``target`` on ``labels`` rows drawn from ``pop``."""
    rng = np.random.default_rng(seed)
    graph, closures, is_true = with_wrong_closures(problem, rate, rng, kind)
    rows = score_rows(pop, is_true, rng)
    return graph, closures, is_true, rows, calibrated_gate(pop, seed, n=labels, target=target, rankings=rankings)


def true_closures_name(p_star: float) -> str:
    """The configuration "the true closures among the gate's, LM" of the gate at ``p_star`` (the first evidence
    tables' name at 0.9)."""
    return "gate's true closures, LM" if p_star == 0.9 else f"gate p*={p_star:g}'s true closures, LM"


def elimination_fill(edges: np.ndarray) -> tuple[int, int]:
    """The off-diagonal blocks of the square-root information matrix R of a pose graph with these (E, 2) edges (the
    first pose held by a prior), under GTSAM's COLAMD ordering, and the elimination's work Σ (separator + 1)² in
    blocks² (dense Cholesky of each variable's row): the fill-in that prices every linear solve of LM and GNC."""
    symbolic = gtsam.SymbolicFactorGraph()
    for a, b in edges.tolist():
        symbolic.push_factor(a, b)
    symbolic.push_factor(int(edges.min()))
    net = symbolic.eliminateSequential(gtsam.Ordering.ColamdSymbolicFactorGraph(symbolic))
    separators = np.array([len(net.at(i).keys()) - 1 for i in range(net.size())])
    return int(separators.sum()), int(((separators + 1) ** 2).sum())


def print_fill_in(problems: list[Problem], rates: list[float], pop: Population, seed: int, kind: str) -> None:
    """A markdown table, printed row by row as measured: per graph and rate, the fill-in and one numeric elimination's
    time (median of 3) of the closures the floor, the gate and no filter pass to the optimiser (GNC keeps every
    closure's factor, down-weighted, so its linear solves are those of "all")."""
    print("| graph | wrong | closures | wrong / true | R blocks | work (blocks²) | elimination (s, median of 3) |")
    print("|---|---|---|---|---|---|---|", flush=True)
    for problem in problems:
        first, is_3d = min(problem.initial.keys()), gtsam.utilities.extractPose3(problem.initial).size > 0
        pose = problem.initial.atPose3(first) if is_3d else problem.initial.atPose2(first)
        prior = gtsam.PriorFactorPose3 if is_3d else gtsam.PriorFactorPose2
        for rate in rates:
            graph, closures, is_true, rows, gate = drawn_case(problem, rate, pop, seed, kind)
            edges = graph_edges(graph)
            for name, passed in (
                ("true only", is_true),
                ("gate p*=0.9", gate.accept(rows)),
                ("all", is_true | ~is_true),
            ):
                keep = closure_mask(edges, closures, rows, Fixed(passed))
                kept = gtsam.NonlinearFactorGraph()
                for i in np.flatnonzero(keep):
                    kept.add(graph.at(int(i)))
                kept.add(prior(first, pose, gtsam.noiseModel.Isotropic.Sigma(pose.dim(), 1e-6)))
                linear, seconds = kept.linearize(problem.initial), []
                for _ in range(3):
                    start = time.perf_counter()
                    linear.eliminateMultifrontal()
                    seconds.append(time.perf_counter() - start)
                (blocks, work), wrong, true = elimination_fill(edges[keep]), passed & ~is_true, passed & is_true
                print(
                    f"| {problem.name} | {rate:.0%} | {name} | {wrong.sum()} / {true.sum()} | {blocks:,} | {work:,} | "
                    f"{np.median(seconds):.3f} |",
                    flush=True,
                )


def run_one(
    problem: Problem,
    rate: float,
    pop: Population,
    seed: int,
    out: Any,
    only: set[str] | None,
    timeout: float,
    rankings: Any = None,
    kind: str = "random",
    labels: int = 200,
    verbose: bool = False,
    p_stars: tuple[float, ...] = (0.9,),
) -> None:
    """Every configuration (or those named in ``only``) on one seed's case, one JSON record each; the gate's
    configurations once per target precision in ``p_stars``, every gate calibrated on the same labels."""
    graph, closures, is_true, rows, first = drawn_case(problem, rate, pop, seed, kind, labels, rankings, p_stars[0])
    gates = {p: calibrated_gate(pop, seed, n=labels, target=p, rankings=rankings) for p in p_stars[1:]}
    gates[p_stars[0]] = first
    edges = graph_edges(graph)
    filters: dict[str, Any] = {
        "all": Everything(),
        "true only (floor)": TruthOracle(rows, is_true),
        "fixed SU (median)": SUThreshold(pop),
    }
    for p, gate in gates.items():
        filters[f"gate p*={p:g}"], filters[true_closures_name(p)] = gate, TrueAccepted(gate, is_true)
    configs = [  # "{gate}": once per p* (named "gate p*=0.9" at 0.9, as the first evidence tables were)
        ("all closures, LM", "all", "none"),
        ("true only, LM (floor)", "true only (floor)", "none"),
        ("fixed SU, LM", "fixed SU (median)", "none"),
        ("{gate}, LM", "{gate}", "none"),
        ("{true}", "{true}", "none"),
        ("all, Huber", "all", "huber"),
        ("all, Cauchy", "all", "cauchy"),
        ("all, DCS", "all", "dcs"),
        ("{gate} + GNC", "{gate}", "gnc"),
        ("all, GNC (TLS)", "all", "gnc"),
        ("{gate} + GNC-GN", "{gate}", "gnc-gn"),
        ("all, GNC-GN (TLS)", "all", "gnc-gn"),
        ("{gate} + GNC warm", "{gate}", "gnc-warm"),
        ("all, GNC warm (TLS)", "all", "gnc-warm"),
        ("all, PCM + LM", "all", "pcm"),
        ("{gate} + PCM + LM", "{gate}", "pcm"),
        ("all, PCM + GNC", "all", "pcm-gnc"),  # Kimera-RPGO's order: PCM, then GNC on what it kept
        ("{gate} + PCM + GNC", "{gate}", "pcm-gnc"),
    ]
    expanded = []
    for name, filter_name, robust in configs:
        for p in p_stars if "{" in name else (None,):
            names = {"gate": f"gate p*={p:g}", "true": true_closures_name(p)} if p is not None else {}
            expanded.append((name.format(**names), filter_name.format(**names), robust, p))
    for name, filter_name, robust, p_star in expanded:
        certificate = gates[
            p_star if p_star is not None else (0.9 if 0.9 in gates else p_stars[-1])
        ].precision_lower_bound
        if only and name not in only:
            continue
        passed = closure_mask(closures, closures, rows, filters[filter_name])

        def measure(passed: np.ndarray = passed, robust: str = robust) -> tuple:
            start, pcm_seconds = time.perf_counter(), None
            if robust.startswith("pcm"):  # PCM's own time counts in the configuration's seconds
                passed = pcm(graph, closures, passed)
                pcm_seconds = time.perf_counter() - start
            keep = closure_mask(edges, closures, rows, Fixed(passed))
            kept = gtsam.NonlinearFactorGraph()
            for i in np.flatnonzero(keep):
                kept.add(graph.at(int(i)))
            start_optimiser = time.perf_counter()  # building the graph is timed in no configuration
            if robust == "gnc-warm":
                values = warm_gnc(kept, problem.initial, verbose=verbose)[0]
            else:
                after = {"pcm": "none", "pcm-gnc": "gnc"}.get(robust, robust)
                values = optimize(kept, problem.initial, robust=after, verbose=verbose)
            seconds = time.perf_counter() - start_optimiser + (pcm_seconds or 0)
            counts = (int((passed & ~is_true).sum()), int((passed & is_true).sum()))
            return (seconds, pcm_seconds, counts, *ate(values, problem.truth), *fits(graph, values, closures, is_true))

        start = time.perf_counter()
        counts = (int((passed & ~is_true).sum()), int((passed & is_true).sum()))
        try:
            seconds, pcm_seconds, counts, rmse, worst, wrong_fit, true_fit = in_child(measure, timeout)
            error = None
        except Exception as failure:  # report it, do not hide it
            seconds, error = time.perf_counter() - start, f"{type(failure).__name__}: {failure}"
            rmse = worst = wrong_fit = true_fit = pcm_seconds = None
            counts = (None, None) if robust.startswith("pcm") else counts
        record = {
            "graph": problem.name, "rate": rate, "method": pop.name, "seed": seed, "config": name,
            "closures_true": int(is_true.sum()), "closures_wrong": int((~is_true).sum()),
            "wrong_passed": counts[0], "true_passed": counts[1],
            "wrong_fit": wrong_fit, "true_fit": true_fit, "ate_rmse": rmse, "ate_max": worst,
            "seconds": round(seconds, 3), "gate_lower_bound": certificate, "error": error, "timeout": timeout,
            "wrong_closures": kind, "rows": "absent" if (~pop.answerable).any() else "native", "labels": labels,
            "p_star": p_star,
        }  # fmt: skip
        if robust.startswith("pcm"):
            record["pcm_seconds"] = None if pcm_seconds is None else round(pcm_seconds, 3)
        print(json.dumps(record), flush=True)
        if out is not None:
            out.write(json.dumps(record) + "\n")
            out.flush()


def report(path: Path) -> str:
    """Markdown tables of a results file: one per graph, one row per (rate, configuration)."""
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    text = []
    for r in records:  # one table per graph and variant (records before the variants existed are the defaults)
        variant = (r.get("wrong_closures", "random"), r.get("rows", "native"), r.get("labels", 200))
        named = ", {} wrong closures, {} rows, {} labels".format(*variant)
        r["table"] = r["graph"] + ("" if variant == ("random", "native", 200) else named)
        r["table"] += f", seed {r['seed']}" if r["seed"] else ""
    for graph in dict.fromkeys(r["table"] for r in records):
        text += [
            f"\n**{graph}**\n",
            "| wrong | configuration | ATE RMSE (m) | max (m) | wrong / true passed | wrong / true fit | time (s) |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in sorted((r for r in records if r["table"] == graph), key=lambda r: r["rate"]):
            rate = f"{r['rate']:.0%} ({r['closures_wrong']} of {r['closures_wrong'] + r['closures_true']})"
            passed = "not known" if r["wrong_passed"] is None else f"{r['wrong_passed']} / {r['true_passed']}"
            if r["error"] and r["error"].startswith("TimeoutError"):
                text.append(f"| {rate} | {r['config']} | not finished | | {passed} | | > {r['timeout']:g} |")
                continue
            if r["error"]:
                text.append(f"| {rate} | {r['config']} | failed: {r['error']} | | {passed} | | {r['seconds']:.2f} |")
                continue
            text.append(
                f"| {rate} | {r['config']} | {r['ate_rmse']:.3f} | {r['ate_max']:.2f} | {r['wrong_passed']} / "
                f"{r['true_passed']} | {r['wrong_fit']} / {r['true_fit']} | {r['seconds']:.2f}"
                + (f" (PCM {r['pcm_seconds']:.2f})" if r.get("pcm_seconds") is not None else "")
                + " |"
            )
    return "\n".join(text)


def runs_by_case(path: Path) -> dict[tuple, dict[str, dict]]:
    """A results file's records by (graph, method, wrong closures, rows, labels, rate, seed), then configuration."""
    runs: dict[tuple, dict[str, dict]] = {}
    for line in path.read_text().splitlines():
        if line.strip():
            r = json.loads(line)
            variant = (r["graph"], r["method"], r.get("wrong_closures", "random"), r.get("rows", "native"))
            runs.setdefault((*variant, r.get("labels", 200), r["rate"], r["seed"]), {})[r["config"]] = r
    return runs


def summary(path: Path) -> str:
    """Per variant and rate, over the seeds of a results file: gate + GNC against the floor, the gate's true closures
    and GNC alone (medians, ranges, how many seeds meet issue 31's ratios), and what the gate passed."""
    runs = runs_by_case(path)
    lines = [
        "| graph | method, wrong closures, rows, labels | wrong | seeds | gate + GNC ÷ floor: median [range] | "
        "≤ 1.5× floor | gate's true closures ÷ floor | gate + GNC ÷ GNC alone: median [range] | ≤ 1.2× GNC alone | "
        "gate + GNC time ÷ GNC time | passed wrong / true (median) | gates certified |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    needed = ("true only, LM (floor)", "gate's true closures, LM", "gate p*=0.9 + GNC", "all, GNC (TLS)")
    for variant in dict.fromkeys(key[:6] for key in sorted(runs)):
        done = [c for k, c in runs.items() if k[:6] == variant and all(c.get(n, {}).get("ate_rmse") for n in needed)]
        if not done:
            continue
        floor, true_kept, gated, alone = (np.array([c[n]["ate_rmse"] for c in done]) for n in needed)
        seconds = np.array([c[needed[2]]["seconds"] / c[needed[3]]["seconds"] for c in done])
        passed = np.median([[c[needed[2]]["wrong_passed"], c[needed[2]]["true_passed"]] for c in done], axis=0)
        to_floor, to_alone = gated / floor, gated / alone
        lines.append(
            f"| {variant[0]} | {', '.join(map(str, variant[1:5]))} | {variant[5]:.0%} | {len(done)} | "
            f"{np.median(to_floor):.2f} [{to_floor.min():.2f}, {to_floor.max():.2f}] | {(to_floor <= 1.5).sum()} | "
            f"{np.median(true_kept / floor):.2f} | {np.median(to_alone):.2f} [{to_alone.min():.2f}, "
            f"{to_alone.max():.2f}] | {(to_alone <= 1.2).sum()} | {np.median(seconds):.2f} | "
            f"{passed[0]:.0f} / {passed[1]:.0f} | {sum(c[needed[2]]['gate_lower_bound'] is not None for c in done)} |"
        )
    return "\n".join(lines)


def pcm_summary(path: Path) -> str:
    """Per variant and rate, over the seeds of a results file: PCM + LM and gate + PCM + LM against the floor, against
    each other and beside GNC (medians and ranges of the ATE RMSE ratios), what PCM kept and how long it took."""
    runs = runs_by_case(path)
    lines = [
        "| graph | method, wrong closures, rows, labels | wrong | seeds | PCM + LM ÷ floor: median [range] | "
        "gate + PCM + LM ÷ floor | gate + PCM ÷ PCM alone | GNC alone ÷ floor | gate + GNC ÷ floor | "
        "PCM kept wrong / true (median) | gate + PCM kept | PCM s / gate + PCM s (median) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    floor, alone, gated = "true only, LM (floor)", "all, PCM + LM", "gate p*=0.9 + PCM + LM"

    def ratio(values: np.ndarray) -> str:
        return "–" if not values.size else f"{np.median(values):.2f} [{values.min():.2f}, {values.max():.2f}]"

    for variant in dict.fromkeys(key[:6] for key in sorted(runs)):
        done = [c for k, c in runs.items() if k[:6] == variant and c.get(floor, {}).get("ate_rmse")]
        done = [c for c in done if alone in c or gated in c]
        if not done:
            continue
        failed = sum(c[n]["error"] is not None for c in done for n in (alone, gated) if n in c)

        def ate(config: str, runs: list = done) -> np.ndarray:
            return np.array(
                [c[config]["ate_rmse"] / c[floor]["ate_rmse"] for c in runs if c.get(config, {}).get("ate_rmse")]
            )

        def kept(config: str, done: list = done) -> str:
            counts = [
                [c[config]["wrong_passed"], c[config]["true_passed"]] for c in done if c.get(config, {}).get("ate_rmse")
            ]
            return "–" if not counts else "{:.0f} / {:.0f}".format(*np.median(counts, axis=0))

        both = [c for c in done if c.get(alone, {}).get("ate_rmse") and c.get(gated, {}).get("ate_rmse")]
        to_alone = np.array([c[gated]["ate_rmse"] / c[alone]["ate_rmse"] for c in both])
        seconds = [
            "–" if not (t := [c[n]["pcm_seconds"] for c in done if c.get(n, {}).get("pcm_seconds") is not None])
            else f"{np.median(t):.2f}" for n in (alone, gated)
        ]  # fmt: skip
        lines.append(
            f"| {variant[0]} | {', '.join(map(str, variant[1:5]))} | {variant[5]:.0%} | {len(done)}"
            f"{f' ({failed} PCM runs not finished)' if failed else ''} | {ratio(ate(alone))} | {ratio(ate(gated))} | "
            f"{ratio(to_alone)} | {ratio(ate('all, GNC (TLS)'))} | "
            f"{ratio(ate('gate p*=0.9 + GNC'))} | {kept(alone)} | {kept(gated)} | {' / '.join(seconds)} |"
        )
    return "\n".join(lines)


def p_star_summary(path: Path, within: float = 1.5) -> str:
    """Per variant and rate, over the seeds of a results file: all closures + LM, GNC alone and gate + GNC at each
    p* found, in two markdown tables. Accuracy: APE ÷ the same seed's floor (true closures only + LM), median
    [range] over the seeds that finished, then how many seeds are within ``within``x the floor (a seed beyond it, or
    one that did not finish, is where the configuration breaks). Cost: the closures it passed (median wrong / true)
    and its time (median over the seeds; a run stopped at the time limit counts its limit)."""
    runs = runs_by_case(path)
    floor_name = "true only, LM (floor)"
    gated = sorted(
        {n for c in runs.values() for n in c if n.startswith("gate p*=") and n.endswith(" + GNC")},
        key=lambda n: float(n.split("=")[1].split()[0]),
    )
    names = ("all closures, LM", "all, GNC (TLS)", *gated)
    head = "| graph | wrong closures, rows, labels | wrong | seeds | floor (m) | " + " | ".join(names) + " |"
    rule = "|---" * (5 + len(names)) + "|"
    accuracy, cost = [head, rule], [head, rule]
    for variant in dict.fromkeys(key[:6] for key in sorted(runs)):
        cases = [c for k, c in runs.items() if k[:6] == variant and c.get(floor_name, {}).get("ate_rmse")]
        if not cases:
            continue
        floor = np.array([c[floor_name]["ate_rmse"] for c in cases])
        row = (
            f"| {variant[0]} | {', '.join(map(str, variant[2:5]))} | {variant[5]:.0%} | {len(cases)} | "
            f"{np.median(floor):.3f} |"
        )
        right, spent = [row], [row]
        for name in names:
            found = [c for c in cases if name in c]
            done = [c for c in found if c[name]["ate_rmse"] is not None]
            ratio = np.array([c[name]["ate_rmse"] / c[floor_name]["ate_rmse"] for c in done])
            stopped = len(found) - len(done)
            if not found:
                right.append(" – |")
                spent.append(" – |")
                continue
            cell = "not finished" if not done else f"{np.median(ratio):.2f} [{ratio.min():.2f}, {ratio.max():.2f}]"
            cell += f" {(ratio <= within).sum()}/{len(found)}" + (
                f" ({stopped} not finished)" if stopped and done else ""
            )
            passed = np.median([[c[name]["wrong_passed"], c[name]["true_passed"]] for c in found], axis=0)
            seconds = np.median([c[name]["seconds"] for c in found])
            right.append(f" {cell} |")
            spent.append(f" {passed[0]:.0f} / {passed[1]:.0f}, {seconds:.2f} s |")
        accuracy.append("".join(right))
        cost.append("".join(spent))
    return (
        f"APE ÷ floor, median [range] over the seeds that finished, and the seeds within {within}× the floor:\n\n"
        + "\n".join(accuracy)
        + "\n\nClosures passed (median wrong / true) and time (median; a stopped run counts its limit):\n\n"
        + "\n".join(cost)
    )


METHODS = "AMOSNet,AlexNet_VPR,CALC,CoHOG,HOG,HybridNet,NetVLAD,RegionVLAD,ap-gem-r101,denseVLAD"


def label_plans(methods: list[str], sizes: tuple[int, ...] = (100, 200, 400, 800)) -> str:
    """The label plan (``plan_labels``, 50 simulations, seed 0) of each method at p* = 0.9 and 0.99, δ = 0.1: the
    method's 111 rows labelled, a pool of the rows repeated 8 times (the resampled population)."""
    from vpr_uncertainty.calibration.plan import plan_labels

    lines = [
        "| method | p* | P(certified) at " + " / ".join(map(str, sizes)) + " labels | mean recall |",
        "|---|---|---|---|",
    ]
    for method in methods:
        pop = population(method)
        for target in (0.9, 0.99):
            plan = plan_labels(
                pop.scores, pop.correct, target_precision=target, unlabelled=np.tile(pop.scores, (8, 1)),
                sizes=sizes, draws=50, seed=0, progress=False,
            )  # fmt: skip
            certified = " / ".join(f"{c:.2f}" for c in plan.certified)
            recall = " / ".join(f"{r:.3f}" for r in plan.mean_recall)
            lines.append(f"| {method} | {target} | {certified} | {recall} |")
    return "\n".join(lines)


def gate_table(method: str, seeds: range, labels: tuple[int, ...] = (200, 400), rankings: Any = None) -> str:
    """What the benchmark's gates accept of the method's rows: calibrated on the answerable rows alone (native) or
    on the proposals' population (native + absent-place rows), per seed and number of labels."""
    lines = [
        "| calibrated on | labels | seed | certified bound | accepted: correct / wrong answers / absent-place rows |",
        "|---|---|---|---|---|",
    ]
    absent_rows = population(method, absent=True)
    for absent in (False, True):
        pop = population(method, absent=absent)
        for n in labels:
            for seed in seeds:
                gate = calibrated_gate(pop, seed, n=n, rankings=rankings)
                accepted = gate.accept(absent_rows.scores)
                counts = [
                    int((accepted & where).sum()) for where in (absent_rows.correct,
                    absent_rows.answerable & ~absent_rows.correct, ~absent_rows.answerable)
                ]  # fmt: skip
                bound = "none" if gate.precision_lower_bound is None else f"{gate.precision_lower_bound:.3f}"
                name = "answerable + absent (222 rows)" if absent else "answerable (111 rows)"
                lines.append(f"| {name} | {n} | {seed} | {bound} | " + " / ".join(map(str, counts)) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="the four-lap graph only")
    parser.add_argument(
        "--graphs",
        default="fourlap,sphere2500,city10000",
        help="comma-separated: fourlap, sphere2500, sphere2500-fitted (its edges' real noise), city10000",
    )
    parser.add_argument("--rates", default="0.3,0.5,0.7")
    parser.add_argument("--sphere-rates", default=None, help="rates for sphere2500 (default: --rates)")
    parser.add_argument("--method", default="AMOSNet", help="the corridor VPR-Bench method whose rows are used")
    parser.add_argument(
        "--results", type=Path, default=None,
        help="use the rows of this retrieval file instead (with positives; e.g. runs/demo/retrieval.npz of make demo)",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", default=None, help="configuration names separated by semicolons")
    parser.add_argument("--json", type=Path, default=None, help="append one JSON line per configuration")
    parser.add_argument("--timeout", type=float, default=180, help="seconds each optimisation may take (default 180)")
    parser.add_argument("--verbose", action="store_true", help="GTSAM prints each LM iteration and GNC's λ as it runs")
    parser.add_argument("--label-plan", action="store_true", help="print the label plans of the ten methods and stop")
    parser.add_argument(
        "--rankings",
        default=None,
        help="the gate's rankings, δ shared evenly (default: calibrate's default); margin,SU,CAL is the default of "
        "the first evidence tables",
    )
    parser.add_argument(
        "--wrong-closures", choices=("random", "aliasing", "grouped"), default="random",
        help="random vertex pairs (default), a true closure's earlier end moved by 5-20 poses, or grouped: runs of "
        "5-20 mutually consistent wrong closures (Sünderhauf's grouped outliers)",
    )  # fmt: skip
    parser.add_argument(
        "--p-star", default="0.9", metavar="P[,P...]",
        help="target precisions of the gate, comma-separated (default 0.9): its configurations run once per p*, every "
        "gate calibrated on the same labels (as `calibrate --target-precision P` would)",
    )  # fmt: skip
    parser.add_argument(
        "--p-star-summary", type=Path, default=None, metavar="JSONL",
        help="print, per variant and rate over the seeds of a --json file, all + LM, the floor, GNC alone and gate + "
        "GNC at each p* (APE, ratio to the floor, where each breaks, what the gate passed, time), and stop",
    )  # fmt: skip
    parser.add_argument(
        "--rows", choices=("native", "absent"), default="native",
        help="wrong closures' score rows: the method's wrong answers (default; few, so repeated), or also each query's "
        "row when its place is not in the map (111 more, distinct); the gate is calibrated on the same rows",
    )  # fmt: skip
    parser.add_argument("--labels", type=int, default=200, help="labelled rows the gate is calibrated on (default 200)")
    parser.add_argument(
        "--gates", type=int, default=None, metavar="SEEDS",
        help="print what the gates of seeds 0..SEEDS-1 accept of the method's rows (both populations) and stop",
    )  # fmt: skip
    parser.add_argument(
        "--summary", type=Path, default=None, help="print the per-variant summary over seeds of a --json file and stop"
    )
    parser.add_argument("--report", type=Path, default=None, help="print the tables of a --json file and stop")
    parser.add_argument(
        "--fill-in", action="store_true",
        help="print, per graph and rate, the fill-in of the Cholesky factor and one elimination's time for the true "
        "closures, the gate's and all closures, and stop (why the optimisers' times differ)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    if args.label_plan:
        print(label_plans(METHODS.split(",")))
        return 0
    if args.report:
        print(report(args.report))
        return 0
    if args.p_star_summary:
        print(p_star_summary(args.p_star_summary))
        return 0
    if args.summary:
        print(summary(args.summary))
        if len(pcm_table := pcm_summary(args.summary).splitlines()) > 2:
            print("\nPCM (pairwise consistency maximisation), over the same seeds:\n\n" + "\n".join(pcm_table))
        return 0
    graphs = ["fourlap"] if args.quick else args.graphs.split(",")
    rates = [0.3, 0.5, 0.7, 0.85] if args.quick else [float(r) for r in args.rates.split(",")]
    pop = population(args.method, absent=args.rows == "absent", results=args.results)
    if args.results:
        pop.name = f"own run ({args.results})"
    only = set(args.only.split(";")) if args.only else None
    rankings = args.rankings.split(",") if args.rankings else None
    p_stars = tuple(float(p) for p in args.p_star.split(","))
    if not all(0 < p < 1 for p in p_stars):
        parser.error(f"--p-star takes target precisions in (0, 1), got {args.p_star}")
    if args.gates:
        print(gate_table(args.method, range(args.gates), rankings=rankings))
        return 0
    if args.fill_in:
        print_fill_in([PROBLEMS[name]() for name in graphs], rates, pop, args.seed, args.wrong_closures)
        return 0
    out = args.json.open("a") if args.json else None
    for name in graphs:
        problem = PROBLEMS[name]()
        graph_rates = (
            [float(r) for r in args.sphere_rates.split(",")]
            if name.startswith("sphere2500") and args.sphere_rates
            else rates
        )
        for rate in graph_rates:
            run_one(
                problem, rate, pop, args.seed, out, only, args.timeout, rankings, args.wrong_closures, args.labels,
                args.verbose, p_stars,
            )  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
