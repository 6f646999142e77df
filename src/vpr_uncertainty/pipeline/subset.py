"""``vpr-uncertainty subset``: a retrieval file of some of the queries (a labelled split, an unlabelled pool)."""

import argparse
from pathlib import Path

import numpy as np

from vpr_uncertainty.data import read_results
from vpr_uncertainty.pipeline.options import add_results_options, command_wording, output_file
from vpr_uncertainty.retrieval import save_retrieval


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``subset`` command."""
    parser = subparsers.add_parser("subset", help="write the queries START:STOP of RESULTS as a retrieval file")
    parser.add_argument("results", type=Path, metavar="RESULTS", help="results, read as by evaluate")
    add_results_options(parser, "RESULTS")
    parser.add_argument("--queries", default=":", metavar="START:STOP", help="query rows, as a Python slice: 0:56, 56:")
    parser.add_argument("--out", type=output_file, required=True, metavar="FILE.npz", help="retrieval file to write")
    parser.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    if args.out.suffix.lower() != ".npz":
        raise ValueError(f"--out must name a .npz file, got {args.out}")
    with command_wording(ground_truth="--gt GT"):
        retrieval = read_results(args.results, ground_truth=args.gt, file_format=args.format, scores=args.score_kind)
    n_queries = retrieval.n_queries
    try:
        start, stop = (int(bound) if bound.strip() else None for bound in args.queries.split(":"))
    except ValueError:  # not START:STOP, or not integers
        start = stop = n_queries + 1
    if not len(rows := np.arange(n_queries)[start:stop]) or max(abs(start or 0), abs(stop or 0)) > n_queries:
        raise ValueError(f"--queries {args.queries}: expected START:STOP within the {n_queries} queries, e.g. 0:56")
    save_retrieval(retrieval.subset_queries(rows), args.out)
    print(f"wrote {args.out}: queries {args.queries} ({len(rows)} of {n_queries}), {retrieval.k} candidates each")
    return 0
