"""``vpr-uncertainty retrieve``: descriptors in, retrieval file out (the retrieval stage, Faiss top-k search)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from vpr_uncertainty.commands._arguments import (
    add_alias,
    add_progress_options,
    non_negative_float,
    output_file,
    positive_int,
)

__all__ = ["add_parser"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``retrieve`` command."""
    parser = subparsers.add_parser(
        "retrieve",
        help="search database descriptors for each query and write a retrieval file",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "L2-normalise the descriptors, find the k most similar database images of each query by inner\n"
            "product (cosine similarity) with Faiss, and write a retrieval file (.npz) with the scores, indices\n"
            "and squared L2 distances. With positions, the file also holds the positives (database images within\n"
            "--radius of each query) and the database positions that SUE needs, so that\n"
            "`vpr-uncertainty evaluate retrieval.npz` runs with no other argument.\n\n"
            "DB and Q are .npy arrays (one descriptor per row) or the HDF5 descriptor cache (.h5) of the feature\n"
            "extraction. Candidates with equal scores are ordered by lower database index; with k larger than the\n"
            "database, the missing candidates have index -1."
        ),
        epilog=(
            "examples:\n"
            "  vpr-uncertainty retrieve --database db.npy --queries q.npy --out runs/retrieval.npz \\\n"
            "      --database-positions db_utm.npy --query-positions q_utm.npy --radius 25\n"
            "  vpr-uncertainty retrieve --database descriptors.h5 --queries descriptors.h5 --out r.npz \\\n"
            '      --index "IVF4096,PQ64" --search-params nprobe=32'
        ),
    )
    parser.add_argument("--database", type=Path, required=True, metavar="DB", help="database descriptors (.npy, .h5)")
    parser.add_argument("--queries", type=Path, required=True, metavar="Q", help="query descriptors (.npy, .h5)")
    parser.add_argument("--out", type=output_file, required=True, metavar="FILE", help="retrieval file to write (.npz)")
    parser.add_argument("--k", type=positive_int, default=10, help="candidates kept per query (default 10)")
    parser.add_argument(
        "--index",
        default="Flat",
        help='Faiss index-factory string: "Flat" (exact, default), "IVF4096,PQ64", "HNSW32", ...',
    )
    parser.add_argument(
        "--search-params", metavar="PARAMS", help='search parameters of an approximate index, e.g. "nprobe=32"'
    )
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="cuda needs GPU Faiss (default cpu)")
    parser.add_argument("--batch-size", type=positive_int, default=4096, help="queries searched at once (default 4096)")
    parser.add_argument(
        "--database-block",
        type=positive_int,
        metavar="ROWS",
        help="exact search: read the database in blocks of ROWS rows, never whole (default: a database file larger "
        "than 64 MiB is read in blocks of 64 MiB; approximate indexes and cuda read it whole)",
    )
    parser.add_argument("--database-positions", type=Path, metavar="P.npy", help="database positions (D x 2, metres)")
    parser.add_argument("--query-positions", type=Path, metavar="P.npy", help="query positions (Q x 2, metres)")
    parser.add_argument(
        "--radius",
        type=non_negative_float,
        default=25.0,
        help="positives: database images within this distance of the query, inclusive (default 25)",
    )
    add_alias(parser, "--positive_dist_threshold", new="--radius", type=non_negative_float)
    parser.add_argument(
        "--position-kind",
        choices=("metres", "frames", "placeholder"),
        help="what the positions are (default: detected; frame indices and placeholder ids make SUE warn)",
    )
    parser.add_argument(
        "--gt",
        type=Path,
        help="explicit ground truth instead of the radius (any format that `evaluate --gt` reads)",
    )
    add_progress_options(parser)
    parser.set_defaults(handler=_run_retrieve)


def _load_positions(path: Path | None, expected: int, what: str):
    import numpy as np

    if path is None:
        return None
    if not path.is_file():
        raise FileNotFoundError(f"{what} positions file not found: {path}")
    if path.suffix.lower() != ".npy":
        raise ValueError(f"{path}: positions must be a .npy array of shape ({expected}, 2)")
    positions = np.load(path, allow_pickle=False)
    if positions.ndim != 2 or len(positions) != expected:
        raise ValueError(
            f"{path}: {what} positions must have shape ({expected}, 2), one row per {what} descriptor; "
            f"got shape {positions.shape}"
        )
    return positions


def _run_retrieve(args: argparse.Namespace) -> int:
    from vpr_uncertainty.data import load_descriptors, open_descriptors
    from vpr_uncertainty.data.dataset import ground_truth_fields
    from vpr_uncertainty.evaluation import recall_at_n
    from vpr_uncertainty.stages.retrieval import RetrievalConfig, search

    if args.out.suffix.lower() != ".npz":
        raise ValueError(f"--out must name a .npz file, got {args.out}")
    # The database stays on disk: exact search reads it block by block (approximate indexes read it whole).
    database_names, database = open_descriptors(args.database, "database")
    query_names, queries = load_descriptors(args.queries, "queries")
    database_positions = _load_positions(args.database_positions, len(database), "database")
    query_positions = _load_positions(args.query_positions, len(queries), "query")
    positives = None
    if args.gt is not None:
        from vpr_uncertainty.data.ground_truth import load_ground_truth

        positives = load_ground_truth(args.gt, n_queries=len(queries), n_database=len(database))
    ground_truth = ground_truth_fields(  # checked before the search, the slow part
        len(queries),
        len(database),
        database_positions=database_positions,
        query_positions=query_positions,
        radius=args.radius,
        positives=positives,
        database_names=database_names,
        query_names=query_names,
        position_kind=args.position_kind,
    )
    describe = {"database": str(args.database), "queries": str(args.queries)}
    if args.gt is not None:
        describe["ground_truth"] = str(args.gt)
    conf = RetrievalConfig(
        k=args.k,
        index=args.index,
        search_params=args.search_params,
        device=args.device,
        batch_size=args.batch_size,
        database_block=args.database_block,
        progress=getattr(args, "progress", None),
    )
    start = time.perf_counter()
    found = search(
        conf,
        (database_names, database),
        (query_names, queries),
        ground_truth,
        args.out,
        describe=describe,
        copy=False,  # the arrays were just read from disk: normalise them in place
    )
    seconds = time.perf_counter() - start
    result = found.retrieval
    done = "kept" if found.reused else "wrote"
    why = " (same descriptors, ground truth and options)" if found.reused else f" ({args.index}, {args.device}"
    print(
        f"{done} {args.out}: {result.n_queries} queries x {result.k} candidates among {len(database)} database "
        f"images{why}" + ("" if found.reused else f", {seconds:.1f} s)")
    )
    if result.positives is not None:
        answerable = int((result.positives.sum(axis=1) > 0).sum())
        if answerable:
            recalls = recall_at_n(result.indices, result.positives, ns=(1, 5, 10))
            shown = ", ".join(f"recall@{n} {value:.3f}" for n, value in recalls.items())
            print(f"{shown} ({result.n_queries - answerable} queries without a positive)")
        else:
            print("no query has a positive in the database: check the positions and --radius")
    return 0
