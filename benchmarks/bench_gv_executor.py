"""Geometric verification throughput with the local executor and with Ray at 1 and 2 workers, and Ray's start-up.

GV-SIFT (the ``GV-SIFT`` preset, MAGSAC++ homography, 640 px) on the first ``--pairs`` corridor queries and their
top-1 database image in NetVLAD's precomputed similarity matrix. The local features are extracted once before the
timings, in this process, as every executor does (their cost per image is printed), so each row times a call that
reads them from the cache (in this process) and then matches and counts RANSAC inliers of the pairs: the step that
``--executor ray`` distributes (geometric/distributed.py: chunks of pairs as Ray tasks, one thread each).

Rows: ``local`` with the verifier's threads (``--local-threads``, default 1 and the toolkit's default), and once
with numpy's BLAS limited to 1 thread (threadpoolctl), which is what a Ray task gets (Ray sets OMP_NUM_THREADS to
its CPUs); ``ray N`` on a local cluster of N CPUs, with ``ray.init`` and the first call (worker processes starting
and importing the package) reported apart from the median of the warm repeats. On a machine with C cores expect
near-linear scaling only up to C workers, and only where the pairs step dominates.

    python benchmarks/bench_gv_executor.py              # VPR_UNCERTAINTY_DATA must point at the shared data
    python benchmarks/bench_gv_executor.py --pairs 111 --workers 1 2 4 --repeats 5
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.executors import get_executor
from vpr_uncertainty.geometric import GeometricVerifier
from vpr_uncertainty.geometric.cache import image_names
from vpr_uncertainty.geometric.local_features import default_workers


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=os.environ.get("VPR_UNCERTAINTY_DATA"), help="shared data folder")
    parser.add_argument("--pairs", type=int, default=60, help="queries verified against their top-1 (default 60)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="Ray worker counts (default 1 2)")
    parser.add_argument("--local-threads", type=int, nargs="+", help="threads of the local rows (default 1 and auto)")
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats per row; the median is reported")
    return parser.parse_args(argv)


def corridor_pairs(data: Path, count: int) -> tuple[dict[str, Path], list[tuple[str, str]]]:
    """Image paths by name and the (query, top-1) pairs of the first ``count`` queries (NetVLAD's matrix)."""
    from vpr_uncertainty.retrieval import read_results

    root = data / "vprbench" / "corridor"
    matrix = data / "vprbench" / "precomputed_matches" / "corridor" / "NetVLAD" / "precomputed_data_corrected.npy"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy VPR-Bench file is a pickle, read safely, and says so
        retrieval = read_results(matrix, ground_truth=root / "ground_truth_new.npy")
    queries, database = sorted((root / "query").glob("*.jpg")), sorted((root / "ref").glob("*.jpg"))
    names = image_names([*queries, *database])
    paths = dict(zip(names, [*queries, *database], strict=True))
    query_names, database_names = names[: len(queries)], names[len(queries) :]
    top1 = retrieval.indices[: min(count, len(queries)), 0]
    return paths, [(query_names[q], database_names[int(d)]) for q, d in enumerate(top1)]


def timed(verifier: GeometricVerifier, pairs: list, paths: dict, repeats: int) -> tuple[dict[str, float], np.ndarray]:
    """Median seconds of verifying ``pairs`` (``total``; ``read``: the features from the cache, in this process;
    ``pairs``: matching and RANSAC, the step an executor distributes) and the inliers of the last repeat."""
    runs, inliers = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = verifier.verify_names(pairs, paths)
        total = time.perf_counter() - start
        runs.append((total, result.extraction.seconds, result.matching_seconds + result.ransac_seconds))
        inliers = result.inliers
    return {key: statistics.median(run[i] for run in runs) for i, key in enumerate(("total", "read", "pairs"))}, inliers


def blas_threads(limit: int | None) -> Any:
    """A context limiting numpy's BLAS to ``limit`` threads (threadpoolctl), or nothing for None."""
    if limit is None:
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=limit, user_api="blas")


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.data is None:
        raise SystemExit("set VPR_UNCERTAINTY_DATA or pass --data")
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    import ray

    paths, pairs = corridor_pairs(args.data, args.pairs)
    threads = args.local_threads or sorted({1, default_workers()})
    local_rows = [(count, None) for count in threads] + [(1, 1)]
    rows, reference = [], None
    with tempfile.TemporaryDirectory() as cache_dir:
        start = time.perf_counter()
        extraction = GeometricVerifier.from_preset("GV-SIFT", cache_dir=cache_dir).verify_names(pairs, paths).extraction
        first_seconds = time.perf_counter() - start
        for count, blas in local_rows:
            verifier = GeometricVerifier.from_preset("GV-SIFT", cache_dir=cache_dir, workers=count)
            with blas_threads(blas):
                figures, inliers = timed(verifier, pairs, paths, args.repeats)
            reference = inliers if reference is None else reference
            assert np.array_equal(inliers, reference), "local runs disagree"
            name = f"local, {count} thread{'s' if count > 1 else ''}" + (", BLAS 1 thread" if blas else "")
            rows.append((name, figures, None, None))
        for workers in args.workers:
            start = time.perf_counter()
            ray.init(address="local", num_cpus=workers, include_dashboard=False, log_to_driver=False)
            init = time.perf_counter() - start
            with get_executor("ray", workers=workers) as executor:
                verifier = GeometricVerifier.from_preset("GV-SIFT", cache_dir=cache_dir, workers=1, executor=executor)
                first, _ = timed(verifier, pairs, paths, 1)  # worker processes start and import the package
                figures, inliers = timed(verifier, pairs, paths, args.repeats)
            ray.shutdown()
            assert np.array_equal(inliers, reference), f"ray {workers} gave other inliers than the local run"
            rows.append((f"ray, {workers} worker{'s' if workers > 1 else ''}", figures, init, first["total"]))
    base = rows[0][1]["total"]
    print(
        f"GV-SIFT on {len(pairs)} corridor pairs (query, NetVLAD top-1), {os.cpu_count()} CPUs (load average "
        f"{os.getloadavg()[0]:.1f} at the end), median of "
        f"{args.repeats} repeats. Local features of {extraction.extracted + extraction.cached} images extracted once "
        f"beforehand in this process, as every executor does ({extraction.seconds:.2f} s, "
        f"{extraction.seconds / max(extraction.extracted, 1) * 1e3:.0f} ms/image; first call with extraction "
        f"{first_seconds:.2f} s). Inliers identical on every row.\n"
    )
    columns = ["executor", "s per run", "of which: read features", "pairs step", "pairs/s", "vs first row"]
    print("| " + " | ".join([*columns, "ray.init s", "first call s"]) + " |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, figures, init, first in rows:
        extra = "– | – |" if init is None else f"{init:.2f} | {first:.2f} |"
        print(
            f"| {name} | {figures['total']:.3f} | {figures['read']:.3f} | {figures['pairs']:.3f} | "
            f"{len(pairs) / figures['total']:.0f} | {base / figures['total']:.2f}x | {extra}"
        )


if __name__ == "__main__":
    main()
