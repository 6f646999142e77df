"""Latency of the single-query gate, next to StatisticalUncertainty measured in the same run.

Target (issue 19): at most 1.5 microseconds per ``gate(row)`` call, for a gate fresh from ``calibrate()`` and the
same gate after ``Gate.save``/``Gate.load`` (they must not differ: the fresh gate once kept numpy float weights,
27 % slower). The gates are calibrated on a real corridor matrix (AMOSNet, p* = 0.9) when VPR_UNCERTAINTY_DATA is
set, else on synthetic scores. Each figure is the median over ``--repeats`` rounds, interleaved (every gate and input
timed once per round), of ``--number`` calls, per call, for a Python list and a (K,) float32 array of K = 10.

    python benchmarks/bench_gate.py [--repeats 15] [--number 20000]
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import tempfile
import timeit
from pathlib import Path

import numpy as np

from vpr_uncertainty import Gate, Retrieval, StatisticalUncertainty, calibrate


def _retrieval() -> tuple[Retrieval, str]:
    data = os.environ.get("VPR_UNCERTAINTY_DATA")
    if data:
        from vpr_uncertainty.data import read_results

        root = Path(data) / "vprbench"
        matches = root / "precomputed_matches/corridor/AMOSNet/precomputed_data_corrected.npy"
        if matches.is_file():
            return read_results(matches, ground_truth=root / "corridor/ground_truth_new.npy"), "corridor AMOSNet"
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.uniform(0.2, 0.9, size=(400, 10)), axis=1).astype(np.float32)
    positives = np.zeros((400, 10), bool)
    positives[:, 0] = rng.uniform(size=400) < scores[:, 0]
    return Retrieval(scores, np.tile(np.arange(10), (400, 1)), positives), "synthetic"


def per_call_us(functions: dict, arguments: dict, repeats: int, number: int) -> dict[tuple[str, str], float]:
    """Median µs per call of each function on each argument, timed in interleaved rounds (one timing of every pair
    per round), so that a slow spell of a shared machine falls on all of them alike."""
    timings: dict[tuple[str, str], list[float]] = {(f, a): [] for f in functions for a in arguments}
    for function, argument in timings:
        functions[function](arguments[argument])
    for _ in range(repeats):
        for function, argument in timings:
            call = functools.partial(functions[function], arguments[argument])
            timings[function, argument].append(timeit.timeit(call, number=number))
    return {pair: statistics.median(times) / number * 1e6 for pair, times in timings.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--number", type=int, default=20000)
    args = parser.parse_args()
    retrieval, source = _retrieval()
    fresh = {
        "certified (default)": calibrate(retrieval, target_precision=0.9),
        "model s1, gap, PA, SU": calibrate(retrieval, features=("s1", "gap", "PA", "SU")),
        "isotonic on SU": calibrate(retrieval, target_precision=0.9, model="isotonic"),
    }
    gates = {}
    with tempfile.TemporaryDirectory() as folder:
        for name, gate in fresh.items():
            gates[f"{name}, fresh"] = gate
            gates[f"{name}, loaded"] = Gate.load(gate.save(Path(folder) / "gate.json"))
    su = StatisticalUncertainty(k=10)
    row = retrieval.scores[0, :10].astype(np.float32)
    functions = {"StatisticalUncertainty": su, **gates}
    found = per_call_us(functions, {"list": row.tolist(), "ndarray": row}, args.repeats, args.number)
    print(f"calibrated on {source}; median of {args.repeats} interleaved rounds x {args.number} calls, µs per call")
    print(f"{'':34s} {'list':>8s} {'ndarray':>8s} {'list ÷ StatisticalUncertainty':>30s}")
    for name in functions:
        ratio = found[name, "list"] / found["StatisticalUncertainty", "list"]
        print(f"{name:34s} {found[name, 'list']:8.2f} {found[name, 'ndarray']:8.2f} {ratio:30.2f}")


if __name__ == "__main__":
    main()
