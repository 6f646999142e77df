"""Peak memory and time of exact descriptor retrieval from a ``.npy`` database: in-memory vs streaming.

A float32 database (200,000 × 256 = 205 MB by default, not L2-normalised) and 2,000 queries (noisy copies of
database rows) are written to a temporary folder, deleted afterwards. Each run is a fresh subprocess:

* **in-memory** — the path before streaming (what ``vpr-uncertainty retrieve`` did): ``load_descriptors`` reads
  the whole file, ``search_descriptors(..., copy=False)`` normalises it in place and searches it (Faiss exact
  inner product, 4,096 queries at a time);
* **streaming** — ``open_descriptors`` opens the file lazily (header checked through a memory map, blocks read
  at their offset) and ``search_descriptors`` streams it in its default blocks (64 MiB of rows: 65,536 rows
  here), chosen automatically for a database on disk larger than one block;
* **streaming, block B** — the same with ``database_block=B`` rows (``--block``, 16,384 rows = 16 MiB by default).

Time is wall-clock and CPU (user + system, all threads) seconds of the child; on a loaded machine the CPU time
is the steadier figure. Peak memory is the child's high-water mark (``resource.getrusage(RUSAGE_CHILDREN)
.ru_maxrss`` read by a fresh parent of each run, so the maximum is that run's alone); ``baseline`` is a child
that imports NumPy, Faiss and the package and reads the queries, which every run carries. Every run's indices
are checked equal to the in-memory run's (and the scores within float32 rounding).

    python benchmarks/bench_retrieval_memory.py                                     # 2,000 × 200,000 × 256
    python benchmarks/bench_retrieval_memory.py --database 20000 --repeats 1         # quick check
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

CHILD = """
import sys
import numpy as np
import faiss  # noqa: F401  (imported by every run: part of the baseline)
from vpr_uncertainty.data import load_descriptors, open_descriptors, search_descriptors

mode, database_path, queries_path, out = sys.argv[1:5]
queries = np.load(queries_path)
if mode == "in-memory":
    _, database = load_descriptors(database_path)
    scores, indices, _ = search_descriptors(database, queries, k=10, copy=False, progress=False)
elif mode.startswith("streaming"):
    _, database = open_descriptors(database_path)
    block = int(mode.split(":")[1]) if ":" in mode else None
    scores, indices, _ = search_descriptors(database, queries, k=10, database_block=block, progress=False)
else:  # baseline
    sys.exit(0)
np.savez(out, scores=scores, indices=indices)
"""

#: Widths of the columns of the printed table.
WIDTHS = (23, 8, 7, 13, 11, 24)

MEASURE = """
import resource, subprocess, sys, time
start = time.perf_counter()
result = subprocess.run(sys.argv[1:])
usage = resource.getrusage(resource.RUSAGE_CHILDREN)
print(time.perf_counter() - start, usage.ru_utime + usage.ru_stime, usage.ru_maxrss * 1024, result.returncode)
"""


def write_data(folder: Path, n_database: int, n_queries: int, dimension: int, seed: int = 0) -> tuple[Path, Path]:
    """A random float32 database written block by block (never whole in this process), and noisy queries."""
    rng = np.random.default_rng(seed)
    database_path, queries_path = folder / "database.npy", folder / "queries.npy"
    database = npy_format.open_memmap(database_path, mode="w+", dtype=np.float32, shape=(n_database, dimension))
    for start in range(0, n_database, 10_000):
        stop = min(start + 10_000, n_database)
        database[start:stop] = rng.standard_normal((stop - start, dimension), dtype=np.float32)
    database.flush()
    source = rng.integers(0, n_database, size=n_queries)
    queries = database[np.sort(source)] + rng.standard_normal((n_queries, dimension), dtype=np.float32)
    del database
    np.save(queries_path, queries.astype(np.float32))
    return database_path, queries_path


def measure(mode: str, database: Path, queries: Path, out: Path) -> tuple[float, float, int]:
    """(wall-clock seconds, CPU seconds, peak RSS in bytes) of one run in a fresh subprocess."""
    command = [sys.executable, "-c", CHILD, mode, str(database), str(queries), str(out)]
    result = subprocess.run([sys.executable, "-c", MEASURE, *command], capture_output=True, text=True, check=True)
    seconds, cpu, peak, returncode = result.stdout.split()
    if int(returncode) != 0:
        raise RuntimeError(f"the {mode} run failed ({returncode}): {result.stderr[-2000:]}")
    return float(seconds), float(cpu), int(peak)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--queries", type=int, default=2000)
    parser.add_argument("--database", type=int, default=200_000)
    parser.add_argument("--dimension", type=int, default=256)
    parser.add_argument("--block", type=int, default=16_384, help="rows of the explicit-block streaming run")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write the figures as JSON")
    args = parser.parse_args()
    modes = ["in-memory", "streaming", f"streaming:{args.block}"]
    runs: dict[str, list[tuple[float, float, int]]] = {mode: [] for mode in modes}
    with tempfile.TemporaryDirectory(prefix="bench_retrieval_memory_") as name:
        folder = Path(name)
        database, queries = write_data(folder, args.database, args.queries, args.dimension)
        size = database.stat().st_size
        baseline = measure("baseline", database, queries, folder / "none.npz")[2]
        for _ in range(args.repeats):  # alternate, so all see the same page cache and machine load
            for mode in modes:
                runs[mode].append(measure(mode, database, queries, folder / f"{mode.replace(':', '_')}.npz"))
        results = {mode: np.load(folder / f"{mode.replace(':', '_')}.npz") for mode in modes}
        reference = results["in-memory"]
        for mode in modes[1:]:
            np.testing.assert_array_equal(results[mode]["indices"], reference["indices"], err_msg=mode)
            np.testing.assert_allclose(results[mode]["scores"], reference["scores"], rtol=1e-5, atol=1e-6)
    figures: dict[str, object] = {"file_bytes": size, "baseline_peak_bytes": baseline}
    print(
        f"database {args.database:,} x {args.dimension} float32 = {size / 1e6:.0f} MB, {args.queries:,} queries, k=10; "
        f"baseline (imports + queries) {baseline / 1e6:.0f} MB; median of {args.repeats}"
    )
    header = ("run", "time (s)", "CPU (s)", "peak RSS (MB)", "peak / file", "(peak - baseline) / file")
    print(" | ".join(f"{text:>{width}}" for text, width in zip(header, WIDTHS, strict=True)))
    for mode in modes:
        seconds = statistics.median(value[0] for value in runs[mode])
        cpu = statistics.median(value[1] for value in runs[mode])
        peak = statistics.median(value[2] for value in runs[mode])
        label = mode if ":" not in mode else f"streaming, block {int(mode.split(':')[1]):,}"
        figures[mode] = {
            "seconds": seconds,
            "cpu_seconds": cpu,
            "peak_bytes": peak,
            "peak_over_file": peak / size,
            "above_baseline_over_file": (peak - baseline) / size,
        }
        row = (label, f"{seconds:.1f}", f"{cpu:.1f}", f"{peak / 1e6:.0f}", f"{peak / size:.2f}")
        row += (f"{(peak - baseline) / size:.2f}",)
        print(" | ".join(f"{text:>{width}}" for text, width in zip(row, WIDTHS, strict=True)))
    print("indices equal to the in-memory run in every streaming run; scores within rtol 1e-5")
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")


if __name__ == "__main__":
    main()
