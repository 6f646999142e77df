"""Geometric verification on the corridor: ms per query of each GV method beside SU's, and their AUC-PR.

Every method runs through ``vpr_uncertainty.evaluate`` on NetVLAD's real retrieval, so the time per query is
measured exactly as for the cheap metrics. Each GV method is timed twice:

* cold: an empty feature cache, so the call extracts the local features of every image it needs (the models are
  loaded before, so weight loading is not counted), then matches and runs RANSAC;
* warm: the same call again, with every feature read from the HDF5 cache: matching + RANSAC only.

Images are verified at a fixed working resolution: the corridor's own 160×120 pixels by default, or, with
``--resize 640``, copies enlarged to 640×480 in a temporary folder (the size of most VPR benchmarks' images).

    python benchmarks/bench_geometric.py                          # all 111 queries at 160×120
    python benchmarks/bench_geometric.py --resize 640 --queries 20 --methods GV-SIFT,GV-XFEAT
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
import warnings
from pathlib import Path

from vpr_uncertainty import Retrieval, evaluate, read_results
from vpr_uncertainty.geometric import DEFAULT_MAX_SIDE, GeometricVerifier
from vpr_uncertainty.geometric.lightglue import WeightsUnavailableError


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--data",
        type=Path,
        default=os.environ.get("VPR_UNCERTAINTY_DATA"),
        help="the shared data folder holding vprbench/ (default: $VPR_UNCERTAINTY_DATA)",
    )
    parser.add_argument("--methods", default="GV-SIFT,GV-DISK-LG,GV-XFEAT", help="comma-separated GV methods")
    parser.add_argument("--queries", type=int, default=None, help="only the first N queries (default: all 111)")
    parser.add_argument("--resize", type=int, default=None, help="enlarge copies of the images to this width first")
    parser.add_argument("--max-side", type=int, default=DEFAULT_MAX_SIDE, help="working resolution (longer side)")
    parser.add_argument("--workers", type=int, default=os.cpu_count(), help="threads (default: all cores)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--json", type=Path, default=None, help="also write the results as JSON here")
    return parser.parse_args(argv)


def resized_copies(paths: list[Path], width: int, folder: Path) -> list[Path]:
    import cv2

    copies = []
    for path in paths:
        image = cv2.imread(str(path))
        height = round(image.shape[0] * width / image.shape[1])
        target = folder / path.parent.name / path.name
        target.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(target), cv2.resize(image, (width, height), interpolation=cv2.INTER_CUBIC))
        copies.append(target)
    return copies


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    if args.data is None:
        sys.exit("give --data or set VPR_UNCERTAINTY_DATA to the shared data folder")
    corridor = Path(args.data) / "vprbench" / "corridor"
    matrix = (
        Path(args.data) / "vprbench" / "precomputed_matches" / "corridor" / "NetVLAD" / "precomputed_data_corrected.npy"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy files are pickles and say so
        retrieval = read_results(matrix, ground_truth=corridor / "ground_truth_new.npy")
    query_paths = sorted((corridor / "query").glob("*.jpg"))
    database_paths = sorted((corridor / "ref").glob("*.jpg"))
    if args.queries is not None:
        keep = slice(0, args.queries)
        retrieval = Retrieval(
            scores=retrieval.scores[keep], indices=retrieval.indices[keep], positives=retrieval.positives[keep]
        )
        query_paths = query_paths[keep]
    methods = [name.strip() for name in args.methods.split(",") if name.strip()]
    with tempfile.TemporaryDirectory(prefix="bench_geometric_") as scratch:
        scratch = Path(scratch)
        if args.resize:
            query_paths = resized_copies(query_paths, args.resize, scratch / "images")
            database_paths = resized_copies(database_paths, args.resize, scratch / "images")
        import cv2

        size = cv2.imread(str(query_paths[0])).shape[1::-1]
        options = {
            "query_paths": query_paths,
            "database_paths": database_paths,
            "cache_dir": scratch / "cache",
            "max_side": args.max_side,
            "workers": args.workers,
            "device": args.device,
        }
        for name in list(methods):  # load the models once, outside the timings
            try:
                GeometricVerifier.from_preset(name, max_side=args.max_side, device=args.device)
            except (ImportError, WeightsUnavailableError) as error:
                print(f"skipping {name}: {error}", file=sys.stderr)
                methods.remove(name)
        # A GV method's time_per_query_ms is its cold figure; evaluate also times the call again on the filled cache
        # (timings["time_per_query_ms_warm"]). Reading time_per_query_ms of a second call gave a cold figure twice.
        evaluation = evaluate(retrieval, ["SU", *methods], timing_repeats=3, **options)
    rows = {}
    for name in ["SU", *methods]:
        method = evaluation.methods[name]
        rows[name] = {
            "auc_pr": method.auc_pr,
            "average_precision": method.average_precision,
            "cold_ms_per_query": method.timings.get("time_per_query_ms_cold", method.time_per_query_ms),
            "warm_ms_per_query": method.timings.get("time_per_query_ms_warm", method.time_per_query_ms),
        }
    report = {
        "dataset": "corridor",
        "retrieval": "NetVLAD",
        "n_queries": retrieval.n_queries,
        "recall@1": evaluation.recall_at_n.get(1),
        "image_size": list(map(int, size)),
        "max_side": args.max_side,
        "workers": args.workers,
        "device": args.device,
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "methods": rows,
    }
    print(
        f"corridor, NetVLAD top-1, {retrieval.n_queries} queries (recall@1 {report['recall@1']:.3f}), images "
        f"{size[0]}×{size[1]}, max_side {args.max_side}, {args.workers} workers on {args.device}, "
        f"{os.cpu_count()} cores"
    )
    print(f"{'method':<12}{'AUC-PR':>8}{'AP':>8}{'cold ms/q':>12}{'warm ms/q':>12}")
    for name, row in rows.items():
        print(
            f"{name:<12}{row['auc_pr']:>8.3f}{row['average_precision']:>8.3f}"
            f"{row['cold_ms_per_query']:>12.3f}{row['warm_ms_per_query']:>12.3f}"
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2))
    return report


if __name__ == "__main__":
    start = time.perf_counter()
    main()
    print(f"({time.perf_counter() - start:.0f} s)")
