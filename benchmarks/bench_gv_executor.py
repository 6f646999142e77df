"""Geometric verification throughput with the local executor and with Ray at 1 and 2 workers, and Ray's start-up.

GV-SIFT (the ``GV-SIFT`` preset, MAGSAC++ homography) on the first ``--pairs`` corridor queries and their top-1
database image in NetVLAD's precomputed similarity matrix, on copies enlarged to ``--resize`` pixels wide (640 by
default, the size of most VPR benchmarks' images). Each row times two calls: cold, with an empty feature cache (the
local features of every image are extracted, then the pairs matched and RANSAC run), and warm, with every feature
read from the cache. With ``--executor ray`` both steps run as Ray tasks in chunks, one thread each
(geometric/cache.py and verify.py); this process reads and writes the cache.

Rows: ``local`` with the verifier's threads (``--local-threads``, default 1 and the toolkit's default); ``ray N`` on a
local cluster of N CPUs, with ``ray.init`` and the first call (worker processes starting and importing the package)
reported apart from the medians. On a machine with C cores expect near-linear scaling only up to C workers.

    python benchmarks/bench_gv_executor.py              # VPR_UNCERTAINTY_DATA must point at the shared data
    python benchmarks/bench_gv_executor.py --pairs 111 --workers 1 2 4 --repeats 5
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from bench_geometric import resized_copies
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
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats per row; the median is reported")
    parser.add_argument("--resize", type=int, default=640, help="verify copies this wide (0: the 160x120 originals)")
    return parser.parse_args(argv)


def corridor_pairs(data: Path, count: int) -> tuple[dict[str, Path], list[tuple[str, str]]]:
    """Image paths by name and the (query, top-1) pairs of the first ``count`` queries (NetVLAD's matrix)."""
    from vpr_uncertainty.data import read_results

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


def timed(make_verifier: Any, pairs: list, paths: dict, repeats: int, folder: Path) -> tuple[dict, np.ndarray]:
    """Median seconds of verifying ``pairs`` cold (an empty feature cache: features extracted, then pairs matched)
    and warm (every feature read from the cache), and the inliers of the last run."""
    cold, warm, inliers = [], [], None
    for repeat in range(repeats):
        verifier = make_verifier(folder / f"cache{repeat}")
        start = time.perf_counter()
        result = verifier.verify_names(pairs, paths)
        cold.append(time.perf_counter() - start)
        start = time.perf_counter()
        inliers = verifier.verify_names(pairs, paths).inliers
        warm.append(time.perf_counter() - start)
        assert result.extraction.extracted and np.array_equal(result.inliers, inliers)
    return {"cold": statistics.median(cold), "warm": statistics.median(warm)}, inliers


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.data is None:
        raise SystemExit("set VPR_UNCERTAINTY_DATA or pass --data")
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    import ray

    paths, pairs = corridor_pairs(args.data, args.pairs)
    rows, reference = [], None
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        if args.resize:
            copies = resized_copies(list(paths.values()), args.resize, folder / "images")
            paths = dict(zip(paths, copies, strict=True))
        images = len({name for pair in pairs for name in pair})
        for count in args.local_threads or sorted({1, default_workers()}):

            def local(cache: Path, count: int = count) -> GeometricVerifier:
                return GeometricVerifier.from_preset("GV-SIFT", cache_dir=cache, workers=count)

            figures, reference = timed(local, pairs, paths, args.repeats, folder / f"local{count}")
            rows.append((f"local, {count} thread{'s' if count > 1 else ''}", figures, None, None))
        for workers in args.workers:
            start = time.perf_counter()
            ray.init(address="local", num_cpus=workers, include_dashboard=False, log_to_driver=False)
            init = time.perf_counter() - start
            with get_executor("ray", workers=workers) as executor:

                def on_ray(cache: Path, executor: Any = executor) -> GeometricVerifier:
                    return GeometricVerifier.from_preset("GV-SIFT", cache_dir=cache, workers=1, executor=executor)

                first, _ = timed(on_ray, pairs, paths, 1, folder / f"first{workers}")  # workers start, import
                figures, inliers = timed(on_ray, pairs, paths, args.repeats, folder / f"ray{workers}")
            ray.shutdown()
            assert np.array_equal(inliers, reference), f"ray {workers} gave other inliers than the local run"
            rows.append((f"ray, {workers} worker{'s' if workers > 1 else ''}", figures, init, first["cold"]))
    base = rows[0][1]
    side = f"{args.resize} px wide" if args.resize else "160x120"
    print(
        f"GV-SIFT on {len(pairs)} corridor pairs (query, NetVLAD top-1; {images} images, {side}), "
        f"{os.cpu_count()} CPUs (load average {os.getloadavg()[0]:.1f} at the end), median of {args.repeats} "
        "repeats; cold: empty feature cache (features extracted, then pairs); warm: features cached. Inliers "
        "identical on every row.\n"
    )
    print("| executor | cold s | cold pairs/s | vs first row | warm s | warm pairs/s | ray.init s | first call s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, figures, init, first in rows:
        extra = "– | – |" if init is None else f"{init:.2f} | {first:.2f} |"
        print(
            f"| {name} | {figures['cold']:.2f} | {len(pairs) / figures['cold']:.0f} | "
            f"{base['cold'] / figures['cold']:.2f}x | {figures['warm']:.3f} | {len(pairs) / figures['warm']:.0f} | "
            f"{extra}"
        )


if __name__ == "__main__":
    main()
