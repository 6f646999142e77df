"""``vpr-uncertainty run``: images → descriptors → retrieval → uncertainties → evaluation, cached stage by stage."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from vpr_uncertainty.commands._arguments import (
    VERIFY_FRACTION_HELP,
    add_alias,
    add_image_options,
    apply_threads,
    candidate_count,
    device_name,
    fraction,
    non_negative_float,
    output_directory,
    positive_int,
)
from vpr_uncertainty.commands._bootstrap import add_bootstrap_options
from vpr_uncertainty.commands._executor import (
    DECODING_THREADS,
    add_executor_options,
    executor_from_args,
    executor_options,
    local_workers,
)
from vpr_uncertainty.commands.evaluate import METHOD_SPEC_HELP, method_list
from vpr_uncertainty.methods import default_method_names

if TYPE_CHECKING:
    from vpr_uncertainty.pipeline import RunResult

__all__ = ["add_common_run_options", "add_parser", "print_summary"]


def add_common_run_options(parser: argparse.ArgumentParser, *, default_out: Path | None = None) -> None:
    """Options shared by ``run`` and ``demo``."""
    parser.add_argument(
        "--out",
        type=output_directory,
        required=default_out is None,
        default=default_out,
        help="run directory (reused on rerun)",
    )
    parser.add_argument(
        "--methods",
        type=method_list,
        help="comma-separated uncertainty methods, each with optional options as in SUE:clip=one-sided "
        f"(default {','.join(default_method_names())}, as evaluate; plus SUE when the positions are metric)",
    )
    parser.add_argument("--k", type=candidate_count, default=10, help="candidates per query for RS/SD/SU (default 10)")
    parser.add_argument("--alpha", type=float, default=0.5, help="weight of RS in SU, in [0, 1] (default 0.5)")
    parser.add_argument(
        "--device", type=device_name, default="cpu", help="cpu, cuda, cuda:N or mps (extraction and Faiss search)"
    )
    parser.add_argument("--batch-size", type=positive_int, default=16, help="images per forward pass (default 16)")
    add_alias(parser, "--batch_size", new="--batch-size", type=positive_int)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``run`` command."""
    parser = subparsers.add_parser(
        "run",
        help="evaluate uncertainty end to end on a dataset of images with a VPR model",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Extract global descriptors of every image, retrieve the top-k database images of each query with\n"
            "Faiss, compute every requested uncertainty and evaluate it. Each stage is cached in the run directory\n"
            "(descriptors.h5, retrieval.npz), so a rerun reuses it; the run writes uncertainties.npz, results.json\n"
            "(the schema of `evaluate --json`), results.md and pr_curves.png.\n\n" + METHOD_SPEC_HELP
        ),
        epilog=(
            "examples:\n"
            "  vpr-uncertainty run --dataset data/vprbench/corridor --out runs/corridor\n"
            "  vpr-uncertainty run --dataset st_lucia --root ~/vpr-data --model cosplace --device cuda --out runs/stl"
        ),
    )
    parser.add_argument(
        "--dataset",
        required=True,
        help="dataset folder (any supported format) or a name from `vpr-uncertainty datasets`",
    )
    parser.add_argument(
        "--model",
        default="efficientnet-lite0-gem",
        help="descriptor model: a registered name (`vpr-uncertainty extract --help` lists them) or a TorchScript file "
        "(default efficientnet-lite0-gem, which works offline)",
    )
    parser.add_argument("--root", type=Path, help="data root for dataset names (default VPR_UNCERTAINTY_DATA)")
    parser.add_argument("--split", help="dataset split (default: the dataset's test split)")
    parser.add_argument("--radius", type=non_negative_float, help="positives within this many metres (default 25)")
    add_alias(parser, "--positive_dist_threshold", new="--radius", type=non_negative_float)
    parser.add_argument("--index", default="Flat", help="Faiss index-factory string (default Flat = exact search)")
    parser.add_argument("--half", action="store_true", help="store descriptors as float16")
    add_image_options(parser.add_argument_group("preprocessing and threads (as in extract)"))
    parser.add_argument(
        "--on-error",
        choices=("fail", "skip"),
        default="fail",
        help="images that cannot be used (corrupt, broken links, over PIL's decompression-bomb limit, below the "
        "model's minimum size, names not valid UTF-8) and folders that cannot be listed: stop with an error naming "
        "the first, or leave them out, counted in a warning and in results.json (default fail). The model sees at "
        "most 640 px on the longer side (larger images are shrunk), so memory per batch is bounded",
    )
    parser.add_argument("--btl-head", type=Path, metavar="HEAD.pt", help="BTL: head written by train-btl")
    parser.add_argument("--verify-fraction", type=fraction, metavar="F", help=VERIFY_FRACTION_HELP)
    parser.add_argument(
        "--rerank",
        metavar="GV-METHOD",
        help="re-rank the top k by the inliers of a geometric verification method (e.g. GV-SIFT) and report "
        "the re-ranked recall@N beside the global one",
    )
    add_common_run_options(parser)
    add_bootstrap_options(parser)
    add_executor_options(
        parser,
        local_workers=DECODING_THREADS,
        ray_workers="the descriptor actors (each loads the model once and decodes its own images) and "
        "geometric-verification tasks in flight (default: the cluster's CPUs)",
    )
    parser.set_defaults(handler=_handle)


def print_summary(result: RunResult) -> None:
    """Print the notes of the run, the table, the time per stage and where the files are."""
    from vpr_uncertainty.reports import format_table

    for note in result.notes:
        print(f"note: {note}")
    print(format_table(result.evaluation))
    stages = ", ".join(f"{stage} {seconds:.1f} s" for stage, seconds in result.stage_seconds.items())
    print(f"time per stage: {stages}")
    if result.reranking:
        from vpr_uncertainty.pipeline import format_reranking

        print(format_reranking(result.reranking))
    print(f"report: {result.paths['table']}  plot: {result.paths['plot']}  json: {result.paths['results']}")


def _handle(args: argparse.Namespace) -> int:
    from vpr_uncertainty.pipeline import RunConfig, run

    if not 0.0 <= args.alpha <= 1.0:
        raise ValueError(f"--alpha must lie in [0, 1], got {args.alpha}")
    executor_options(args)  # bad executor options fail before any work
    apply_threads(args.threads)
    config = RunConfig(
        dataset=args.dataset,
        out=args.out,
        model=args.model,
        methods=args.methods,
        k=args.k,
        alpha=args.alpha,
        index=args.index,
        device=args.device,
        batch_size=args.batch_size,
        half=args.half,
        on_error=args.on_error,
        root=args.root,
        split=args.split,
        radius=args.radius,
        image_size=args.image_size,
        max_side=args.max_side,
        num_workers=local_workers(args),
        method_options={
            key: value
            for key, value in (("btl_head", args.btl_head), ("verify_fraction", args.verify_fraction))
            if value is not None
        },
        rerank=args.rerank,
        bootstrap=args.bootstrap,
        seed=args.seed,
        reference=args.reference,
    )
    with executor_from_args(args) as executor:
        print_summary(run(config) if executor.name == "local" else run(config, executor=executor))
    return 0
