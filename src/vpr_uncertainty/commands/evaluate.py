"""``vpr-uncertainty evaluate``: uncertainty methods on precomputed VPR results."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from vpr_uncertainty.commands._arguments import (
    VERIFY_FRACTION_HELP,
    candidate_count,
    command_wording,
    fraction,
    output_file,
    positive_int,
    write_output,
)
from vpr_uncertainty.commands._bootstrap import add_bootstrap_options
from vpr_uncertainty.commands._evaluate_inputs import add_input_options, read_inputs
from vpr_uncertainty.commands._executor import add_executor_options, executor_from_args, executor_options
from vpr_uncertainty.data import DEFAULT_TOP_K, input_formats
from vpr_uncertainty.evaluation import evaluate
from vpr_uncertainty.methods import available_methods, default_method_names, get_method, split_method_list
from vpr_uncertainty.reports import format_table, plot_rejection_curves

__all__ = ["METHOD_SPEC_HELP", "add_parser", "method_list"]


def method_list(text: str) -> list[str]:
    """Comma-separated method specs (``SU,SUE:clip=one-sided,slope=300``) checked against the registry."""
    try:
        specs = split_method_list(text)
        names = [get_method(spec).name for spec in specs]
    except (KeyError, ValueError, TypeError, ImportError) as error:
        raise argparse.ArgumentTypeError(str(error.args[0]) if error.args else str(error)) from None
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of method names, e.g. SU,PA,BM")
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise argparse.ArgumentTypeError(f"method listed more than once: {', '.join(twice)}")
    return names


METHOD_SPEC_HELP = (
    "A method can carry its own options after a colon, e.g. SUE:clip=one-sided,slope=350 (the published SUE);\n"
    "each variant is reported under its spec, so --methods SUE,SUE:clip=one-sided compares both. Options:\n"
    "SU: k, alpha; SUE: k, slope, clip (symmetric | one-sided | none), max_deviation; RS/SD/BM/L2/PA/margin: k."
)


def _method_help() -> str:
    return "\n".join(f"  {name:<8} {get_method(name).description}" for name in available_methods())


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``evaluate`` command."""
    parser = subparsers.add_parser(
        "evaluate",
        help="evaluate uncertainty methods on precomputed VPR results",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Compute each uncertainty method on precomputed results and measure how well it predicts a correct\n"
            "top-1 answer: AUC-PR (trapezoid, the convention of the VPR uncertainty tables), average precision,\n"
            "AURC, recall at 100 % precision and the time per query.\n\n"
            "SCORES is one of:\n"
            "  retrieval.npz                a retrieval file (scores, indices, optionally the ground truth)\n"
            "  matrix.npy                   a full similarity matrix, queries x database, higher = more similar\n"
            "  precomputed_data_*.npy       VPR-Bench precomputed matches (legacy object array, read safely)\n"
            "  LOGDIR/                      a VPR-methods-evaluation log folder saved with --save_descriptors\n"
            "                               (ground truth derived from its image names when --gt is not given)\n\n"
            "Uncertainty methods:\n" + _method_help() + "\n\n" + METHOD_SPEC_HELP
        ),
        epilog=(
            "example:\n  vpr-uncertainty evaluate \\\n"
            "      precomputed_matches/corridor/NetVLAD/precomputed_data_corrected.npy \\\n"
            "      --gt corridor/ground_truth_new.npy --json results.json --plot pr.png"
        ),
    )
    parser.add_argument("scores", type=Path, metavar="SCORES", help="results file (see above)")
    parser.add_argument(
        "--gt",
        type=Path,
        help="ground truth: VPR-Bench ground_truth_new.npy, boolean (Q x D) .npy, .json list of lists, "
        ".txt with one line of positive indices per query, or .npz; required unless SCORES holds it",
    )
    parser.add_argument(
        "--format", choices=input_formats(), default="auto", help="how to read SCORES (default: from its name)"
    )
    parser.add_argument("--k", type=candidate_count, default=10, help="candidates per query for RS/SD/SU (default 10)")
    parser.add_argument("--alpha", type=float, default=0.5, help="weight of RS in SU, in [0, 1] (default 0.5)")
    parser.add_argument(
        "--methods",
        type=method_list,
        help=f"comma-separated uncertainty methods, each with optional options as in SUE:clip=one-sided "
        f"(default {','.join(default_method_names())}, plus SUE when SCORES holds metric positions; as run and demo)",
    )
    parser.add_argument("--verify-fraction", type=fraction, metavar="F", help=VERIFY_FRACTION_HELP)
    add_input_options(parser)
    parser.add_argument("--json", type=output_file, metavar="FILE", help="write the results as JSON")
    parser.add_argument(
        "--plot", type=output_file, metavar="FILE", help="write the end-to-end PR curves (.png/.pdf/.svg)"
    )
    parser.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    parser.add_argument(
        "--latency",
        action="store_true",
        help="also measure each score-based method's latency at batch size 1 (median of 3 runs of 200 "
        "single-query calls; latency_ms_batch1 in --json)",
    )
    held_out = parser.add_argument_group(
        "held-out evaluation (no leakage): every method on the same held-out queries of random splits; "
        "CAL is fitted on the rest"
    )
    held_out.add_argument(
        "--calibration-fraction",
        type=_fraction,
        metavar="F",
        help="share of the queries used to fit CAL in each split, in (0, 1), e.g. 0.3",
    )
    held_out.add_argument("--repeats", type=positive_int, default=20, help="random splits (default 20)")
    held_out.add_argument(
        "--seed", type=int, default=0, help="seed of the splits, and of the bootstrap resamples (default 0)"
    )
    add_bootstrap_options(parser, seed=False)
    learned = parser.add_argument_group("options of methods that need more than scores")
    learned.add_argument("--btl-head", type=Path, metavar="HEAD.pt", help="BTL: the head written by train-btl")
    learned.add_argument(
        "--descriptors",
        type=Path,
        metavar="DESC.h5",
        help="BTL: descriptor cache (from extract or run) holding the queries and the database",
    )
    learned.add_argument(
        "--allow-train-queries",
        action="store_true",
        help="BTL: evaluate the head even on queries it was trained on (refused otherwise; the table marks it ‡)",
    )
    add_executor_options(
        parser,
        ray_workers="the geometric-verification tasks in flight, for the GV-* methods (default: the cluster's CPUs)",
    )
    parser.set_defaults(handler=_run_evaluate)


def _run_evaluate(args: argparse.Namespace) -> int:
    if not 0.0 <= args.alpha <= 1.0:
        raise ValueError(f"--alpha must lie in [0, 1], got {args.alpha}")
    # A full matrix gives as many candidates as k asks (and at least DEFAULT_TOP_K, enough for recall@20).
    top_k = max(DEFAULT_TOP_K, args.k)
    options = {}
    if args.btl_head is not None:
        options["btl_head"] = args.btl_head
    if args.descriptors is not None:
        options.update(query_descriptors=args.descriptors, database_descriptors=args.descriptors)
    if args.allow_train_queries:
        options["allow_train_queries"] = True
    if args.verify_fraction is not None:
        options["verify_fraction"] = args.verify_fraction
    executor_options(args)  # bad executor options fail before any work
    wording = {"images": "--images", "query_images": "--query-images", "database_images": "--database-images"}
    with command_wording(ground_truth="--gt GT", database_positions="--database-positions", **wording):
        retrieval, args.methods, image_options, notes = read_inputs(args, top_k=top_k)
        options.update(image_options)
        for note in notes:
            print(f"note: {note}")
        if args.calibration_fraction is not None and args.bootstrap:
            raise ValueError(
                "--bootstrap and --calibration-fraction cannot be combined: the held-out evaluation reports its "
                "spread over the random splits instead"
            )
        if args.executor != "local":
            _check_verifies(args.methods)
        with executor_from_args(args) as executor:
            if executor.name != "local":
                options["executor"] = executor  # the GV-* methods verify their pairs there
            if args.calibration_fraction is not None:
                return _run_held_out(args, retrieval, options)
            evaluation = evaluate(
                retrieval,
                args.methods,
                k=args.k,
                alpha=args.alpha,
                bootstrap=args.bootstrap,
                seed=args.seed,
                reference=args.reference,
                latency=args.latency,
                **options,
            )
    print(format_table(evaluation, markdown=args.markdown, title=f"{args.scores}"))
    if args.latency:
        print(_latency_line(evaluation))
    if args.json:
        write_output(args.json, json.dumps(evaluation.to_dict(), indent=2) + "\n")
        print(f"wrote {args.json}")
    if args.plot:
        plot_rejection_curves(evaluation, args.plot, title=args.scores.parent.name or None)
        print(f"wrote {args.plot}")
    return 0


def _check_verifies(methods: list[str]) -> None:
    """Refuse ``--executor ray`` when no selected method verifies images (nothing of evaluate would run there)."""
    if not any(get_method(name).kind in ("geometric", "cascade") for name in methods):
        raise ValueError(
            f"--executor ray: evaluate runs only geometric verification (GV-*, SCORE+GV) on Ray, and none of the "
            f"selected methods ({', '.join(methods)}) verifies images; drop --executor or add e.g. GV-SIFT"
        )


def _latency_line(evaluation) -> str:
    """``latency at batch size 1 (ms/query): RS 0.0123, ...`` beside the batched figures of the table."""
    pairs = [
        f"{name} {method.timings['latency_ms_batch1']:.4f}"
        for name, method in evaluation.methods.items()
        if "latency_ms_batch1" in method.timings
    ]
    return "latency at batch size 1 (ms/query, median of 3 runs of 200 calls): " + (", ".join(pairs) or "none")


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}") from None
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must lie strictly between 0 and 1, got {text}")
    return value


def _run_held_out(args: argparse.Namespace, retrieval, options: dict) -> int:
    from vpr_uncertainty.calibration.heldout import evaluate_held_out

    result = evaluate_held_out(
        retrieval,
        args.methods,
        calibration_fraction=args.calibration_fraction,
        repeats=args.repeats,
        seed=args.seed,
        k=args.k,
        alpha=args.alpha,
        **options,
    )
    print(
        f"{args.scores}: {result.repeats} random splits, {result.n_calibration} calibration / "
        f"{result.n_held_out} held-out queries (seed {result.seed}); mean ± std over the splits"
    )
    print(f"{'method':<10} {'AUC-PR':>16} {'AP':>16} {'AURC':>16}")

    def cell(name: str, metric: str) -> str:
        mean, std = result.mean(name, metric), result.std(name, metric)
        return "n/a" if mean is None else f"{mean:.4f} ± {std or 0.0:.4f}"

    for name in result.values:
        print(f"{name:<10} {cell(name, 'auc_pr'):>16} {cell(name, 'average_precision'):>16} {cell(name, 'aurc'):>16}")
    if "CAL" in result.quality:
        quality = result.quality["CAL"]
        print(f"CAL calibration on held-out queries: ECE {quality['ece']:.3f}, Brier {quality['brier']:.3f}")
    if args.json:
        write_output(args.json, json.dumps(result.to_dict(), indent=2) + "\n")
        print(f"wrote {args.json}")
    if args.plot:
        if "CAL" not in result.quality:
            raise ValueError("--plot with --calibration-fraction draws CAL's reliability diagram: add CAL to --methods")
        from vpr_uncertainty.calibration.quality import Reliability
        from vpr_uncertainty.reports.reliability import plot_reliability

        plot_reliability(Reliability(**result.quality["CAL"]["reliability"]), args.plot, title="held-out reliability")
        print(f"wrote {args.plot}")
    return 0
