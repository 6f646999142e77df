"""Time per query of every score method, batched (throughput) and at batch size 1 (latency), side by side.

The batched figure is ``evaluate``'s ``time_per_query_ms``: one call on all queries, divided by their number. The
latency is the paper's setting (it reports SU at 0.03 ms per query): one call per query, median over ``--runs``
runs of ``--calls`` single-query calls, through each method's registered function on a (1, K) row
(``evaluate(..., latency=True)``), and for SU also through ``StatisticalUncertainty`` (the robot's path) and the
array function ``statistical_uncertainty`` on a (1, K) array.

    python benchmarks/bench_latency.py                      # the corridor NetVLAD matrix (111 queries)
    python benchmarks/bench_latency.py --calls 1000 --runs 5
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from vpr_uncertainty import StatisticalUncertainty, evaluate, read_results, statistical_uncertainty
from vpr_uncertainty.methods import available_methods


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=os.environ.get("VPR_UNCERTAINTY_DATA"), help="shared data folder")
    parser.add_argument("--calls", type=int, default=200, help="single-query calls per run (default 200)")
    parser.add_argument("--runs", type=int, default=3, help="runs, median reported (default 3, at least 3)")
    return parser.parse_args(argv)


def median_per_call(function, rows: list, runs: int) -> float:
    """Median over ``runs`` of the mean seconds of ``function(row)`` over ``rows``."""
    function(rows[0])
    timings = []
    for _ in range(runs):
        start = time.perf_counter()
        for row in rows:
            function(row)
        timings.append((time.perf_counter() - start) / len(rows))
    return statistics.median(timings)


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    args = parse_args(argv)
    if args.data is None:
        sys.exit("give --data or set VPR_UNCERTAINTY_DATA to the shared data folder")
    if args.runs < 3:
        sys.exit("--runs must be at least 3")
    corridor = Path(args.data) / "vprbench"
    matrix = corridor / "precomputed_matches" / "corridor" / "NetVLAD" / "precomputed_data_corrected.npy"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy file is a pickle and says so
        retrieval = read_results(matrix, ground_truth=corridor / "corridor" / "ground_truth_new.npy")
    methods = available_methods(kind="score")
    evaluation = evaluate(retrieval, methods, latency=True)
    rows = {
        name: {
            "batched_ms": method.time_per_query_ms,
            "latency_ms_batch1": method.timings["latency_ms_batch1"],
        }
        for name, method in evaluation.methods.items()
    }
    queries = [retrieval.scores[i % retrieval.n_queries, :10] for i in range(args.calls)]
    su = StatisticalUncertainty(k=10)
    as_lists = [row.tolist() for row in queries]
    rows["StatisticalUncertainty (list)"] = {"latency_ms_batch1": median_per_call(su, as_lists, args.runs) * 1e3}
    rows["StatisticalUncertainty (ndarray)"] = {"latency_ms_batch1": median_per_call(su, queries, args.runs) * 1e3}
    arrays = [row[np.newaxis] for row in queries]
    rows["statistical_uncertainty, (1, K) array"] = {
        "latency_ms_batch1": median_per_call(lambda row: statistical_uncertainty(row, 10), arrays, args.runs) * 1e3
    }
    print(
        f"corridor NetVLAD, {retrieval.n_queries} queries, k = 10; latency: median of {args.runs} runs of "
        f"{args.calls} single-query calls; {platform.processor() or platform.machine()}, {os.cpu_count()} cores"
    )
    print(f"{'method':<40}{'batched ms/query':>18}{'batch-1 ms/query':>18}")
    for name, row in rows.items():
        batched = f"{row['batched_ms']:.5f}" if "batched_ms" in row else "—"
        print(f"{name:<40}{batched:>18}{row['latency_ms_batch1']:>18.5f}")
    print("paper: SU 0.03 ms per query")
    return rows


if __name__ == "__main__":
    main()
