"""Throughput and latency of Statistical Uncertainty and the score baselines, next to plain numpy in the same run.

Targets (issue 2): at least 15x the plain formula's throughput on 1,000,000 x 10 float32 scores, and at most
3 microseconds for a single-query call (the paper reports 0.03 ms per query).
Targets (issue 22), on 1,000,000 x 10 float32 and float64 scores: SU (with the numba kernel of the ``fast`` extra)
at least 20x the plain formula and at most 3x a single streaming read of the scores; margin and PA at most 1.5x
their one-line numpy formulas (validation included).
Targets (issue 45), on 1,000,000 x 10 float32, on both paths (numba on, and numpy only as without the ``fast``
extra): SU at least 10x the plain formula and at most 1.5x one copy of the scores (``S.copy()``), RS and SD at
most 1.5x that copy too; margin and PA at most 2x their one-line formulas.

Throughput rows are timed in rounds: each round runs every contender once, in turn, so that a ratio compares
times taken moments apart (the machine may be shared); the table gives each contender's median time and the
median over rounds of its ratio to the reference named.

    python benchmarks/bench_scores.py [--queries 1000000] [--repeats 15] [--rounds 9]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import timeit

import numpy as np

from vpr_uncertainty import (
    StatisticalUncertainty,
    _fast,
    margin,
    perceptual_aliasing,
    ratio_spread,
    similarity_distribution,
    statistical_uncertainty,
)


def plain_formula(scores: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """SU written directly from the paper: mean of ratios and np.median, no validation."""
    ratio_spread = np.mean(scores[:, 1:] / scores[:, :1], axis=1)
    similarity_distribution = np.median(scores, axis=1) / scores[:, 0]
    return alpha * ratio_spread + (1 - alpha) * similarity_distribution


def streaming_read(scores: np.ndarray) -> float:
    """One pass over every score, the least any validated metric must do."""
    return scores.max()


def margin_one_line(scores: np.ndarray) -> np.ndarray:
    return scores[:, 1] - scores[:, 0]


def perceptual_aliasing_one_line(scores: np.ndarray) -> np.ndarray:
    return np.sqrt(2 - 2 * scores[:, 0]) / np.sqrt(2 - 2 * scores[:, 1])


def with_numba(mode: str, function):
    """``function`` run with VPR_UNCERTAINTY_NUMBA=mode ("1": the kernel at every size, "0": numpy only)."""

    def run():
        previous = os.environ.get(_fast.ENVIRONMENT_VARIABLE)
        os.environ[_fast.ENVIRONMENT_VARIABLE] = mode
        try:
            return function()
        finally:
            if previous is None:
                del os.environ[_fast.ENVIRONMENT_VARIABLE]
            else:
                os.environ[_fast.ENVIRONMENT_VARIABLE] = previous

    return run


def paired_rounds(contenders: dict, rounds: int) -> dict[str, list[float]]:
    """Seconds of every contender in every round; each round runs them all once, in turn (after one warm-up)."""
    for function in contenders.values():
        function()
    times: dict[str, list[float]] = {name: [] for name in contenders}
    for _ in range(rounds):
        for name, function in contenders.items():
            start = time.perf_counter()
            function()
            times[name].append(time.perf_counter() - start)
    return times


def print_table(title: str, times: dict[str, list[float]], n_queries: int, ratios: list[tuple]) -> None:
    """Median ns/query of each contender, then each (name, reference, target text) ratio's median over rounds."""
    print(title)
    for name, seconds in times.items():
        print(f"  {name:<36} {statistics.median(seconds) / n_queries * 1e9:8.2f} ns/query")
    for name, reference, target in ratios:
        ratio = statistics.median(a / b for a, b in zip(times[name], times[reference], strict=True))
        print(f"  {name + ' / ' + reference:<58} {ratio:7.2f}   ({target})")


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

    parser.add_argument("--rounds", type=int, default=9, help="paired rounds of the issue-22 table (median reported)")
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.uniform(0.05, 1.0, size=(args.queries, 10)).astype(np.float32), axis=1)
    kernel = _fast._load()
    print(f"numba kernel: {'available' if kernel else 'not installed (numba on = numpy path)'}")
    for dtype in (np.float32, np.float64):
        typed = scores.astype(dtype)
        name = np.dtype(dtype).name
        numba_on = with_numba("1", lambda typed=typed: statistical_uncertainty(typed))
        numba_off = with_numba("0", lambda typed=typed: statistical_uncertainty(typed))
        np.testing.assert_allclose(numba_on(), plain_formula(typed), rtol=1e-5)
        np.testing.assert_allclose(numba_off(), plain_formula(typed), rtol=1e-5)
        su = {
            "SU toolkit, numba on": numba_on,
            "SU toolkit, numba off": numba_off,
            "RS toolkit, numba off": with_numba("0", lambda typed=typed: ratio_spread(typed)),
            "SD toolkit, numba off": with_numba("0", lambda typed=typed: similarity_distribution(typed)),
            "SU plain numpy formula": lambda typed=typed: plain_formula(typed),
            "one copy S.copy()": typed.copy,
            "streaming read S.max()": lambda typed=typed: streaming_read(typed),
        }
        print_table(
            f"SU, RS and SD on {args.queries:,} x 10 {name}, median of {args.rounds} paired rounds:",
            paired_rounds(su, args.rounds),
            args.queries,
            [
                ("SU plain numpy formula", "SU toolkit, numba on", "issue 45: >= 10"),
                ("SU plain numpy formula", "SU toolkit, numba off", "issue 45: >= 10"),
                ("SU toolkit, numba on", "one copy S.copy()", "issue 45: <= 1.5"),
                ("SU toolkit, numba off", "one copy S.copy()", "issue 45: <= 1.5"),
                ("RS toolkit, numba off", "one copy S.copy()", "issue 45: <= 1.5"),
                ("SD toolkit, numba off", "one copy S.copy()", "issue 45: <= 1.5"),
                ("SU toolkit, numba on", "streaming read S.max()", "issue 22: <= 3"),
            ],
        )
        np.testing.assert_allclose(margin(typed), margin_one_line(typed))
        np.testing.assert_allclose(perceptual_aliasing(typed), perceptual_aliasing_one_line(typed), rtol=1e-6)
        baselines = {
            "margin toolkit, numba on": with_numba("1", lambda typed=typed: margin(typed)),
            "margin toolkit, numba off": with_numba("0", lambda typed=typed: margin(typed)),
            "margin one-line": lambda typed=typed: margin_one_line(typed),
            "PA toolkit, numba on": with_numba("1", lambda typed=typed: perceptual_aliasing(typed)),
            "PA toolkit, numba off": with_numba("0", lambda typed=typed: perceptual_aliasing(typed)),
            "PA one-line": lambda typed=typed: perceptual_aliasing_one_line(typed),
        }
        print_table(
            f"margin and PA on {args.queries:,} x 10 {name}, median of {args.rounds} paired rounds:",
            paired_rounds(baselines, args.rounds),
            args.queries,
            [
                ("margin toolkit, numba on", "margin one-line", "issue 45: <= 2"),
                ("margin toolkit, numba off", "margin one-line", "issue 45: <= 2"),
                ("PA toolkit, numba on", "PA one-line", "issue 45: <= 2"),
                ("PA toolkit, numba off", "PA one-line", "issue 45: <= 2"),
            ],
        )

    np.testing.assert_allclose(statistical_uncertainty(scores), plain_formula(scores), rtol=1e-5)

    ours = median_seconds(lambda: statistical_uncertainty(scores), args.repeats)
    plain = median_seconds(lambda: plain_formula(scores), args.repeats)
    print(f"throughput on {args.queries:,} x 10 float32 (median of {args.repeats}):")
    print(f"  statistical_uncertainty  {ours * 1e3:8.2f} ms  {args.queries / ours / 1e6:7.1f} M queries/s")
    print(f"  plain numpy formula      {plain * 1e3:8.2f} ms  {args.queries / plain / 1e6:7.1f} M queries/s")
    print(f"  speed-up                 {plain / ours:8.1f} x   (issue 2: >= 15 x; issue 45: >= 10 x)")

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
