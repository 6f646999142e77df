"""Throughput and latency of Statistical Uncertainty, next to the plain numpy formula measured in the same run.

Targets (issue 2): at least 15x the plain formula's throughput on 1,000,000 x 10 float32 scores, and at most
3 microseconds for a single-query call (the paper reports 0.03 ms per query).

    python benchmarks/bench_scores.py [--queries 1000000] [--repeats 15]
"""

from __future__ import annotations

import argparse
import statistics
import time
import timeit

import numpy as np

from vpr_uncertainty import StatisticalUncertainty, statistical_uncertainty


def plain_formula(scores: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """SU written directly from the paper: mean of ratios and np.median, no validation."""
    ratio_spread = np.mean(scores[:, 1:] / scores[:, :1], axis=1)
    similarity_distribution = np.median(scores, axis=1) / scores[:, 0]
    return alpha * ratio_spread + (1 - alpha) * similarity_distribution


def median_seconds(function, repeats: int) -> float:
    function()  # warm-up
    durations = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        durations.append(time.perf_counter() - start)
    return statistics.median(durations)


def per_call_us(statement, number: int, repeats: int) -> float:
    return statistics.median(timeit.repeat(statement, number=number, repeat=repeats)) / number * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--queries", type=int, default=1_000_000, help="rows of the throughput test")
    parser.add_argument("--repeats", type=int, default=15, help="timed runs per measurement (median reported)")
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.uniform(0.05, 1.0, size=(args.queries, 10)).astype(np.float32), axis=1)
    np.testing.assert_allclose(statistical_uncertainty(scores), plain_formula(scores), rtol=1e-5)

    ours = median_seconds(lambda: statistical_uncertainty(scores), args.repeats)
    plain = median_seconds(lambda: plain_formula(scores), args.repeats)
    print(f"throughput on {args.queries:,} x 10 float32 (median of {args.repeats}):")
    print(f"  statistical_uncertainty  {ours * 1e3:8.2f} ms  {args.queries / ours / 1e6:7.1f} M queries/s")
    print(f"  plain numpy formula      {plain * 1e3:8.2f} ms  {args.queries / plain / 1e6:7.1f} M queries/s")
    print(f"  speed-up                 {plain / ours:8.1f} x   (target >= 15 x)")

    one_row = scores[:1].copy()
    one_list = one_row[0].tolist()
    scorer = StatisticalUncertainty()
    number = 20_000
    vectorised = per_call_us(lambda: statistical_uncertainty(one_row), number, args.repeats)
    scorer_array = per_call_us(lambda: scorer(one_row[0]), number, args.repeats)
    scorer_list = per_call_us(lambda: scorer(one_list), number, args.repeats)
    scorer_row = per_call_us(lambda: scorer(one_row), number, args.repeats)  # Faiss's (1, k) for one query
    plain_one = per_call_us(lambda: plain_formula(one_row), number, args.repeats)
    print(f"single-query latency (median of {args.repeats} x {number:,} calls):")
    print(f"  StatisticalUncertainty()(list)       {scorer_list:6.2f} us   (target <= 3 us)")
    print(f"  StatisticalUncertainty()(ndarray)    {scorer_array:6.2f} us")
    print(f"  StatisticalUncertainty()((1, 10))    {scorer_row:6.2f} us")
    print(f"  statistical_uncertainty((1, 10))     {vectorised:6.2f} us")
    print(f"  plain numpy formula (1, 10)          {plain_one:6.2f} us")


if __name__ == "__main__":
    main()
