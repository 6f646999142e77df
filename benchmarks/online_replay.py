"""City10000 replayed keyframe by keyframe through ``vpr_uncertainty.slam.online.OnlineGraph`` (iSAM2), beside the
batch optimisation of the same decisions and kernel.

Targets (issue 44): median time per keyframe < 50 ms on one core; the trajectory within 1.1x the batch result of the
same gate and kernel (APE after SE(3) alignment, evo). The case is ``loop_closure_slam.py``'s: GTSAM's City10000
(10,000 poses, its 10,688 true closures) with random wrong closures at ``--rate``, each closure carrying a real
AMOSNet corridor score row (the pairing is simulated), the gate calibrated on 200 of those rows (seed ``--seed``).
Each keyframe adds its odometry edge, then the closures that end at it, then one iSAM2 update.

    VPR_UNCERTAINTY_DATA=... OMP_NUM_THREADS=1 python benchmarks/online_replay.py [--rate 0.3] [--seed 0]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # its sibling script builds the case

import loop_closure_slam as slam
from vpr_uncertainty.slam.online import OnlineGraph
from vpr_uncertainty.slam.pose_graph import optimize, pose_rows, trajectory_error


def measured(factor) -> tuple[list[float], np.ndarray]:
    """x y θ and the information matrix of a BetweenFactorPose2."""
    pose, r = factor.measured(), factor.noiseModel().R()
    return [pose.x(), pose.y(), pose.theta()], r.T @ r


def run(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=0.3, help="fraction of wrong closures (default 0.3)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robust", default="cauchy", help="kernel of the accepted closures (default cauchy)")
    parser.add_argument("--keyframes", type=int, default=None, help="replay only this many keyframes")
    args = parser.parse_args(argv)
    problem = slam.city10000()
    graph, closures, is_true, rows, gate = slam.drawn_case(problem, args.rate, slam.population("AMOSNet"), args.seed)
    row_of = {tuple(sorted(pair)): n for n, pair in enumerate(closures.tolist())}
    by_keyframe: dict[int, list] = {}
    for index in range(graph.size()):
        factor = graph.at(index)
        i, j = factor.keys()
        by_keyframe.setdefault(max(i, j), []).append(factor)
    online, times = OnlineGraph(gate, robust=args.robust), []
    last = max(by_keyframe) if args.keyframes is None else args.keyframes
    for keyframe in range(1, last + 1):
        start = time.perf_counter()
        for factor in by_keyframe.get(keyframe, []):
            i, j = factor.keys()
            pose, information = measured(factor)
            if abs(i - j) == 1:
                online.add_odometry(i, j, pose, information)
            else:
                online.add_closure(i, j, pose, information, scores=rows[row_of[tuple(sorted((i, j)))]])
        online.update()
        times.append(time.perf_counter() - start)
        if keyframe % 1000 == 0:
            print(f"  {keyframe} keyframes: median {statistics.median(times[-1000:]) * 1e3:.1f} ms", flush=True)
    decisions = np.array([accepted for *_, accepted, _ in online.decisions])
    truth_of = {tuple(sorted(pair)): bool(t) for pair, t in zip(closures.tolist(), is_true, strict=True)}
    wrong_passed = sum(a and not truth_of[tuple(sorted((i, j)))] for i, j, a, _ in online.decisions)
    all_factors, estimate = online.batch(), online.estimate()
    start = time.perf_counter()
    initial = slam.gtsam.Values()
    for key in estimate.keys():
        initial.insert(key, problem.initial.atPose2(key))
    batch = optimize(all_factors, initial, robust="none")  # the kernel is in the factors already
    batch_seconds = time.perf_counter() - start
    truth = problem.truth[: last + 1]
    online_ape = trajectory_error(pose_rows(estimate), truth)["rmse"]
    batch_ape = trajectory_error(pose_rows(batch), truth)["rmse"]
    print(
        f"City10000, {args.rate:.0%} wrong closures, seed {args.seed}, {last} keyframes, kernel {args.robust}: "
        f"{int(decisions.sum())} of {len(decisions)} closures accepted ({wrong_passed} wrong)\n"
        f"  per keyframe: median {statistics.median(times) * 1e3:.1f} ms, 95th percentile "
        f"{np.percentile(times, 95) * 1e3:.1f} ms, max {max(times) * 1e3:.0f} ms, total {sum(times):.1f} s\n"
        f"  APE online {online_ape:.4f} m, batch (LM from the odometry, {batch_seconds:.1f} s) {batch_ape:.4f} m: "
        f"online / batch {online_ape / batch_ape:.2f}x"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run())
