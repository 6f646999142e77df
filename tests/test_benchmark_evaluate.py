"""``benchmarks/bench_evaluate.py``: its numpy + scikit-learn reference computes what ``evaluate`` computes, to the
tie groups of SU's curves (issue 45: it still summed SU with the float32 product of issue 22, so the run stopped at
Q = 10,000 with 9983 thresholds against 9987 before it timed anything)."""

from __future__ import annotations

from conftest import load_benchmark


def test_the_reference_agrees_with_evaluate():
    bench = load_benchmark("bench_evaluate")
    retrieval = bench.synthetic_retrieval(10_000)
    evaluation, table = bench.toolkit(retrieval)
    bench.check_agree(evaluation, bench.reference(retrieval))  # raises where a number or a tie group differs
    assert "SU" in table
