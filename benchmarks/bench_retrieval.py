"""Retrieval on a Pittsburgh250k-sized problem, next to a bare ``faiss.IndexFlatIP`` search in the same run.

Synthetic unit descriptors (83,952 database x 8,280 queries, 512-d and 4,096-d by default); each query is a noisy
copy of one database descriptor taken near its position, so that some top-1 answers are right and some wrong.
Targets (issue 3):

* retrieval time: ``search_descriptors`` at most 10 % slower than ``IndexFlatIP.add`` + ``search``;
* peak memory: at most 1.5 x the descriptor arrays;
* the uncertainty + evaluation stage on the resulting retrieval file (every score-only method and SUE, through
  ``vpr_uncertainty.evaluate``): at most 1 s.

How it is measured. Every retrieval run is a fresh subprocess that loads the arrays from ``.npy`` files and
searches them once; the two kinds of run alternate, and medians are reported. Peak memory is the kernel's
high-water mark of that process (``resource.getrusage(RUSAGE_SELF).ru_maxrss``, which counts Faiss's C++ and BLAS
allocations that tracemalloc cannot see; it is what ``RUSAGE_CHILDREN`` reports for a single child). The ratio
shown is (peak − the process's resident memory before loading the arrays) / bytes of the two descriptor arrays.

    python benchmarks/bench_retrieval.py                       # full size, both dimensions (~25 min on 2 cores)
    python benchmarks/bench_retrieval.py --database 20000 --queries 2000 --dims 256 --repeats 1   # quick check
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

K = 10


def _peak_kib() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux


def _cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _current_kib() -> int:
    """Resident memory now (VmRSS), or the peak so far where /proc is not available."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return _peak_kib()


# --- the two kinds of retrieval run, each in its own process -------------------------------------------------


def child(kind: str, folder: Path, batch_size: int) -> None:
    import faiss

    if kind == "ours":
        from vpr_uncertainty.data import positives_within_radius
        from vpr_uncertainty.retrieval import Retrieval, save_retrieval, search_descriptors
    before = _current_kib()
    database = np.load(folder / "database.npy")
    queries = np.load(folder / "queries.npy")
    array_bytes = database.nbytes + queries.nbytes
    report: dict[str, float] = {"before_kib": before, "array_bytes": array_bytes}
    cpu, start = _cpu_seconds(), time.perf_counter()
    if kind == "bare":
        index = faiss.IndexFlatIP(database.shape[1])
        index.add(database)
        _, indices = index.search(queries, K)
        report["seconds"], report["cpu_seconds"] = time.perf_counter() - start, _cpu_seconds() - cpu
        report["peak_kib"] = _peak_kib()
        np.save(folder / "bare_indices.npy", indices)
    else:
        scores, indices, distances = search_descriptors(database, queries, K, batch_size=batch_size, progress=False)
        report["seconds"], report["cpu_seconds"] = time.perf_counter() - start, _cpu_seconds() - cpu
        report["peak_kib"] = _peak_kib()
        start = time.perf_counter()
        database_positions = np.load(folder / "database_positions.npy")
        query_positions = np.load(folder / "query_positions.npy")
        positives = positives_within_radius(query_positions, database_positions, 25.0)
        report["ground_truth_seconds"] = time.perf_counter() - start
        retrieval = Retrieval(
            scores=scores,
            indices=indices,
            distances=distances,
            positives=positives,
            database_positions=database_positions,
            query_positions=query_positions,
            config={"k": K, "index": "Flat", "position_kind": "metres", "source": "bench_retrieval"},
        )
        save_retrieval(retrieval, folder / "retrieval.npz")
        report["wrapper_cpu_seconds"] = wrapper_cpu_seconds(database, queries, scores, indices, batch_size)
    print(json.dumps(report))


def wrapper_cpu_seconds(database, queries, scores, indices, batch_size: int) -> float:
    """CPU time of search_descriptors besides the Faiss call: the Faiss call replaced by handing back results.

    Wall-clock comparisons are at the mercy of other load on the machine; this isolates the work our code adds
    (input checks, normalisation checks, ordering, tie detection, distances), which does not depend on it.
    """
    from vpr_uncertainty.retrieval import _faiss, search

    extra_column = np.concatenate([scores, scores[:, -1:] - 1e-3], axis=1)
    extra_index = np.concatenate([indices, (indices[:, -1:] + 1) % len(database)], axis=1)
    offset = 0

    def handed_back(self, batch, k):
        nonlocal offset
        rows = slice(offset, offset + len(batch))
        offset += len(batch)
        return extra_column[rows, :k].copy(), extra_index[rows, :k].copy()

    original = _faiss.Searcher.search
    _faiss.Searcher.search = handed_back
    try:
        durations = []
        for _ in range(3):
            offset = 0
            cpu = _cpu_seconds()
            search.search_descriptors(database, queries, K, batch_size=batch_size, progress=False)
            durations.append(_cpu_seconds() - cpu)
    finally:
        _faiss.Searcher.search = original
    return min(durations)


def run_child(kind: str, folder: Path, batch_size: int) -> dict[str, float]:
    command = [sys.executable, __file__, "--child", kind, "--folder", str(folder), "--batch-size", str(batch_size)]
    completed = subprocess.run(command, capture_output=True, text=True, check=False)
    if completed.returncode != 0:
        raise RuntimeError(f"{kind} run failed:\n{completed.stderr}")
    return json.loads(completed.stdout.strip().splitlines()[-1])


# --- data ----------------------------------------------------------------------------------------------------


def make_problem(folder: Path, n_database: int, n_queries: int, dim: int, seed: int = 0) -> None:
    """Unit descriptors; queries are noisy copies of a database descriptor taken a few metres away."""
    import faiss

    rng = np.random.default_rng(seed)
    side = 5000.0 * np.sqrt(n_database / 83952)  # about 3 database images per 25 m disc at full size
    database_positions = rng.uniform(0, side, size=(n_database, 2)) + np.array([584000.0, 4477000.0])
    source = rng.integers(0, n_database, size=n_queries)
    query_positions = database_positions[source] + rng.normal(scale=5.0, size=(n_queries, 2))
    database = rng.standard_normal((n_database, dim), dtype=np.float32)
    faiss.normalize_L2(database)
    # Noise of norm sigma: cosine to the source about 1/sqrt(1 + sigma²), from 0.7 down to 0.05.
    sigma = rng.uniform(1.0, 20.0, size=(n_queries, 1)).astype(np.float32)
    queries = rng.standard_normal((n_queries, dim), dtype=np.float32) * (sigma / float(np.sqrt(dim)))
    queries += database[source]
    faiss.normalize_L2(queries)
    np.save(folder / "database.npy", database)
    np.save(folder / "queries.npy", queries)
    np.save(folder / "database_positions.npy", database_positions)
    np.save(folder / "query_positions.npy", query_positions)


# --- the uncertainty + evaluation stage ------------------------------------------------------------------------


def time_evaluation(folder: Path, repeats: int) -> dict[str, float]:
    import warnings

    from vpr_uncertainty import evaluate, load_retrieval
    from vpr_uncertainty.methods import available_methods

    methods = [*available_methods(kind="score"), "SUE"]
    results: dict[str, float] = {}
    start = time.perf_counter()
    retrieval = load_retrieval(folder / "retrieval.npz")
    results["load_seconds"] = time.perf_counter() - start
    for label, options in (("default", {}), ("timing_repeats=1", {"timing_repeats": 1})):
        durations = []
        for _ in range(repeats):
            start = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                evaluation = evaluate(retrieval, methods, **options)
            durations.append(time.perf_counter() - start)
        results[label] = statistics.median(durations)
    results["recall@1"] = evaluation.recall_at_n[1]
    results["auc_pr"] = {name: round(m.auc_pr, 3) for name, m in evaluation.methods.items() if m.auc_pr is not None}
    results["methods"] = methods
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--database", type=int, default=83952, help="database descriptors (default 83,952)")
    parser.add_argument("--queries", type=int, default=8280, help="query descriptors (default 8,280)")
    parser.add_argument("--dims", type=int, nargs="+", default=[512, 4096], help="dimensions (default 512 4096)")
    parser.add_argument("--repeats", type=int, default=5, help="runs of each kind per dimension (default 5)")
    parser.add_argument("--batch-size", type=int, default=4096, help="query batch of search_descriptors")
    parser.add_argument("--skip-evaluation", action="store_true", help="time the retrieval only")
    parser.add_argument("--child", choices=("bare", "ours"), help=argparse.SUPPRESS)
    parser.add_argument("--folder", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.folder, args.batch_size)
        return

    import faiss

    print(
        f"retrieval benchmark: {args.database:,} database x {args.queries:,} queries, k = {K}, "
        f"faiss {faiss.__version__}, {os.cpu_count()} CPUs, {faiss.omp_get_max_threads()} OpenMP threads"
    )
    for dim in args.dims:
        with tempfile.TemporaryDirectory(prefix="bench_retrieval_") as name:
            folder = Path(name)
            make_problem(folder, args.database, args.queries, dim)
            runs: dict[str, list[dict[str, float]]] = {"bare": [], "ours": []}
            for _ in range(args.repeats):
                for kind in ("bare", "ours"):
                    runs[kind].append(run_child(kind, folder, args.batch_size))
            agree = (np.load(folder / "bare_indices.npy") == np.load(folder / "retrieval.npz")["indices"]).mean()
            array_mib = runs["ours"][0]["array_bytes"] / 2**20
            print(f"\n{dim}-d: descriptor arrays {array_mib:,.0f} MiB; top-{K} indices identical: {agree:.4%}")
            summary = {}
            for kind, label in (("bare", "faiss.IndexFlatIP add+search"), ("ours", "search_descriptors")):
                wall = [run["seconds"] for run in runs[kind]]
                cpu = [run["cpu_seconds"] for run in runs[kind]]
                extra = statistics.median(
                    (run["peak_kib"] - run["before_kib"]) * 1024 / run["array_bytes"] for run in runs[kind]
                )
                peak = statistics.median(run["peak_kib"] for run in runs[kind]) / 1024
                summary[kind] = {"wall": wall, "cpu": cpu, "memory": extra}
                print(
                    f"  {label:<30} wall median {statistics.median(wall):7.2f} s, min {min(wall):7.2f} s; "
                    f"CPU median {statistics.median(cpu):7.2f} s; peak RSS {peak:6,.0f} MiB = {extra:.2f} x arrays"
                )
                print(f"  {'':<30} wall of each run: {', '.join(f'{value:.2f}' for value in wall)}")
            ours, bare = summary["ours"], summary["bare"]
            print(
                "  overhead (target <= +10 %): wall median "
                f"{statistics.median(ours['wall']) / statistics.median(bare['wall']) - 1:+.1%}, wall min "
                f"{min(ours['wall']) / min(bare['wall']) - 1:+.1%}, CPU median "
                f"{statistics.median(ours['cpu']) / statistics.median(bare['cpu']) - 1:+.1%}"
            )
            wrapper = statistics.median(run["wrapper_cpu_seconds"] for run in runs["ours"])
            print(
                f"  work of search_descriptors besides the Faiss call: {wrapper:.3f} CPU s = "
                f"{wrapper / statistics.median(bare['cpu']):.2%} of the bare search's CPU time"
            )
            print(
                f"  peak memory above the process's start (target <= 1.5 x arrays): ours {ours['memory']:.2f} x, "
                f"bare Faiss {bare['memory']:.2f} x (IndexFlatIP.add copies the database)"
            )
            gt = statistics.median(run["ground_truth_seconds"] for run in runs["ours"])
            print(f"  radius ground truth (25 m, KD-tree): {gt:.2f} s")
            if not args.skip_evaluation:
                result = time_evaluation(folder, repeats=5)
                print(
                    f"  uncertainty + evaluation of {', '.join(result['methods'])} on {args.queries:,} queries: "
                    f"{result['default']:.3f} s with evaluate()'s defaults (5 timing calls per method), "
                    f"{result['timing_repeats=1']:.3f} s with timing_repeats=1 (target <= 1 s); "
                    f"loading the file {result['load_seconds']:.3f} s"
                )
                print(f"  recall@1 {result['recall@1']:.3f}; AUC-PR {result['auc_pr']}")


if __name__ == "__main__":
    main()
