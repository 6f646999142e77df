"""Peak memory of ``vpr-uncertainty evaluate`` on a full similarity matrix: streaming (memory-mapped) vs in-memory.

A ``queries × database`` float32 matrix (2,000 × 100,000 = 0.8 GB by default) is written to a temporary ``.npy``
with a ground-truth text file (one positive per query). ``evaluate`` runs on it in fresh subprocesses:

* **streaming** — today's ``read_results``: the ``.npy`` is memory-mapped and cut to its top-k one block of
  queries at a time (:func:`vpr_uncertainty.retrieval.read_similarity_top_k`);
* **in-memory** — the previous implementation, kept here as the reference: ``np.load`` of the whole matrix, a
  NaN/+inf check over it, then top-k by ``argpartition`` of the negated matrix in chunks of 4,096 queries. It
  runs the same CLI with ``read_results`` swapped for that reference.

Peak memory is the child's high-water mark (``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``, each run under its
own fresh parent so the maximum is that run's alone). Pages of a memory-mapped file that a process has touched
count in its resident memory, so the streaming run's peak includes the page-cache pages of the matrix it read.
Targets (issue 15): peak ≤ 1.3 × the file size (the in-memory path: ~3.4 ×); time within 1.5 × of in-memory.

    python benchmarks/bench_evaluate_memory.py                                  # 2,000 × 100,000, 2 runs each
    python benchmarks/bench_evaluate_memory.py --queries 200 --database 20000 --repeats 1   # quick check
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from numpy.lib import format as npy_format

IN_MEMORY = """
import sys
import numpy as np
import vpr_uncertainty.retrieval as retrieval
from vpr_uncertainty.formats.ground_truth import load_ground_truth
from vpr_uncertainty.retrieval.result import Retrieval


def old_top_k(matrix, k, chunk_size=4096):  # the implementation before streaming, verbatim in its memory use
    matrix = matrix.astype(np.result_type(matrix.dtype, np.float32), copy=False)
    n_queries, n_database = matrix.shape
    if np.isnan(matrix).any():
        raise ValueError("NaN")
    k = min(int(k), n_database)
    scores = np.empty((n_queries, k), dtype=matrix.dtype)
    indices = np.empty((n_queries, k), dtype=np.int64)
    for start in range(0, n_queries, chunk_size):
        block = matrix[start : start + chunk_size]
        candidates = np.argpartition(-block, k - 1, axis=1)[:, :k]
        values = np.take_along_axis(block, candidates, axis=1)
        order = np.lexsort((candidates, -values), axis=1)
        candidates = np.take_along_axis(candidates, order, axis=1)
        values = np.take_along_axis(values, order, axis=1)
        kth = values[:, -1:]
        tied_rows = np.flatnonzero((block == kth).sum(axis=1) > (values == kth).sum(axis=1))
        for row in tied_rows:
            full_order = np.lexsort((np.arange(n_database), -block[row]))[:k]
            candidates[row] = full_order
            values[row] = block[row, full_order]
        scores[start : start + len(block)] = values
        indices[start : start + len(block)] = candidates
    indices[scores == -np.inf] = -1
    return scores, indices


def read_results(path, *, ground_truth=None, file_format="auto", top_k=50):
    matrix = np.load(path)
    largest = matrix.max()
    if np.isnan(largest) or largest == np.inf:
        raise ValueError("bad values")
    positives = load_ground_truth(ground_truth, n_queries=matrix.shape[0], n_database=matrix.shape[1])
    scores, indices = old_top_k(matrix, top_k)
    return Retrieval(scores=scores, indices=indices, positives=positives, config={"source": str(path)})


retrieval.read_results = read_results
from vpr_uncertainty.cli import main

sys.exit(main(sys.argv[1:]))
"""

STREAMING = "import sys\nfrom vpr_uncertainty.cli import main\nsys.exit(main(sys.argv[1:]))\n"

MEASURE = """
import resource, subprocess, sys, time
start = time.perf_counter()
result = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL)
print(time.perf_counter() - start, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024, result.returncode)
"""


def write_matrix(path: Path, n_queries: int, n_database: int, seed: int = 0) -> None:
    """Random similarities in [0, 1) with query q's positive (database image q · D // Q) raised for 2/3 of them."""
    rng = np.random.default_rng(seed)
    matrix = npy_format.open_memmap(path, mode="w+", dtype=np.float32, shape=(n_queries, n_database))
    for start in range(0, n_queries, 100):
        block = rng.random((min(100, n_queries - start), n_database), dtype=np.float32)
        for row in range(len(block)):
            query = start + row
            if query % 3:
                block[row, query * n_database // n_queries] = 1.0 + rng.random(dtype=np.float32)
        matrix[start : start + len(block)] = block
    matrix.flush()
    del matrix


def measure(code: str, matrix: Path, gt: Path) -> tuple[float, int]:
    command = [sys.executable, "-c", code, "evaluate", str(matrix), "--gt", str(gt), "--methods", "BM,RS,SD,SU"]
    out = subprocess.run([sys.executable, "-c", MEASURE, *command], capture_output=True, text=True, check=True)
    seconds, peak, returncode = out.stdout.split()
    if int(returncode) != 0:
        raise RuntimeError(f"evaluate failed ({returncode}): {' '.join(command[3:])}")
    return float(seconds), int(peak)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--queries", type=int, default=2000)
    parser.add_argument("--database", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write the figures as JSON")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        matrix, gt = Path(folder) / "similarity.npy", Path(folder) / "gt.txt"
        write_matrix(matrix, args.queries, args.database)
        gt.write_text("".join(f"{q * args.database // args.queries}\n" for q in range(args.queries)))
        size = matrix.stat().st_size
        baseline = measure("pass", matrix, gt)[1]  # a bare interpreter: what every run carries anyway
        runs: dict[str, list[tuple[float, int]]] = {"streaming": [], "in-memory": []}
        for _ in range(args.repeats):  # alternate, so both see the same page cache and machine load
            runs["streaming"].append(measure(STREAMING, matrix, gt))
            runs["in-memory"].append(measure(IN_MEMORY, matrix, gt))
    figures = {"file_bytes": size, "interpreter_peak_bytes": baseline}
    for name, values in runs.items():
        seconds = statistics.median(v[0] for v in values)
        peak = statistics.median(v[1] for v in values)
        figures[name] = {"seconds": seconds, "peak_bytes": peak, "peak_over_file": peak / size}
        print(f"{name:>10}: {seconds:6.2f} s, peak RSS {peak / 2**30:.2f} GiB = {peak / size:.2f} x the file")
    ratio = figures["streaming"]["seconds"] / figures["in-memory"]["seconds"]
    figures["time_ratio"] = ratio
    print(
        f"file {size / 2**30:.2f} GiB ({args.queries} x {args.database} float32); time streaming / in-memory "
        f"{ratio:.2f} (target <= 1.5); streaming peak {figures['streaming']['peak_over_file']:.2f} x (target <= 1.3)"
    )
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")


if __name__ == "__main__":
    main()
