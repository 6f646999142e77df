"""``vpr-uncertainty label``: machine labels of a pool's queries (:mod:`vpr_uncertainty.labels`) for ``calibrate``."""

from __future__ import annotations

import argparse
from pathlib import Path

from vpr_uncertainty.data import DEFAULT_TOP_K, read_pool
from vpr_uncertainty.pipeline.options import (
    add_image_options,
    add_results_options,
    candidate_count,
    command_wording,
    device_name,
    output_file,
)


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``label`` command."""
    from vpr_uncertainty.labels import LABELERS

    parser = subparsers.add_parser(
        "label",
        help="label each query's top-1 correct or not by machine (other methods' agreement, geometric verification)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Label every query of RETRIEVAL (read as calibrate reads SCORES) by a machine and write\n"
        "query,correct,confidence,source rows under a line naming the pool (its top --k scores' fingerprint, as\n"
        "calibrate computes it). Machine labels may choose a gate's cut; only a person's labels certify it. --gt\n"
        "prints the labels' precision and recall against the ground truth. gv-* cache the local features in\n"
        "local_features/ beside OUT, as verify does. Labelers (--by NAME[:option=value,...]):\n"
        + "".join(f"  {e.name}: {e.description}; options {dict(e.options)}\n" for e in LABELERS),
        epilog="example:\n  vpr-uncertainty label AMOSNet.npy --by agreement:min_agree=3 --with CALC.npy HOG.npy "
        "NetVLAD.npy --out machine.csv\n  vpr-uncertainty label retrieval.npz --by gv-sift --images DIR --out m.csv\n"
        "  vpr-uncertainty label closures.npz --by back-end --graph graph.g2o --out machine.csv",
    )
    parser.add_argument("retrieval", type=Path, metavar="RETRIEVAL", help="the pool's results")
    parser.add_argument("--by", required=True, metavar="LABELER", help=f"{', '.join(LABELERS.names())}[:option=v]")
    parser.add_argument("--with", dest="others", nargs="+", type=Path, metavar="RESULTS", help="other methods' results")
    add_image_options(parser, "dataset folder (query/ and ref/, as in verify)")
    parser.add_argument("--graph", type=Path, metavar="GRAPH", help="back-end: the pose graph of the closures")
    parser.add_argument("--device", type=device_name, default="cpu", help="cpu, cuda, cuda:N or mps (gv-*)")
    parser.add_argument("--k", type=candidate_count, default=10, help="candidates per query of the pool (default 10)")
    add_results_options(parser, "RETRIEVAL and --with", gt="ground truth: print the labels' precision and recall")
    parser.add_argument("--out", type=output_file, required=True, metavar="MACHINE.csv", help="labels to write")
    parser.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    from vpr_uncertainty.calibration.labels_file import pool_fingerprint, write_machine_labels
    from vpr_uncertainty.data.images import retrieval_image_paths
    from vpr_uncertainty.evaluation import correct_at_n
    from vpr_uncertainty.labels import LABELERS, label, label_quality

    entry, top_k = LABELERS.get(args.by.partition(":")[0].strip()), max(DEFAULT_TOP_K, args.k)
    images = {key: getattr(args, key) for key in ("images", "query_images", "database_images")}
    flags = (
        ("--with", args.others, "retrievals"),
        ("--images", any(images.values()), "images"),
        ("--graph", args.graph, "graph"),
    )
    for flag, given, need in flags:
        if bool(given) != (need in entry.requires):
            raise ValueError(f"--by {entry.name} {'needs' if need in entry.requires else 'does not read'} {flag}")
    wording = {key: f"--{key.replace('_', '-')}" for key in images}
    with command_wording(ground_truth="--gt GT", **wording):
        reading = {"file_format": args.format, "top_k": top_k, "scores": args.score_kind}
        retrieval = read_pool(args.retrieval, ground_truth=args.gt, **reading)
        inputs = {"others": {str(p): read_pool(p, **reading) for p in args.others or ()}}
        inputs["graph"] = args.graph
        if any(images.values()):
            paths = retrieval_image_paths(retrieval, **images)
            inputs.update(zip(("query_paths", "database_paths"), paths, strict=True), device=args.device)
            inputs["cache_dir"] = args.out.parent / "local_features"
        labels = label(retrieval, args.by, **{key: value for key, value in inputs.items() if value})
    about = f"{' '.join(str(args.retrieval).split())}: {retrieval.n_queries} queries, k={args.k}"
    write_machine_labels(args.out, labels, pool=pool_fingerprint(retrieval.scores, args.k), about=about)
    source = labels.sources[0] if labels.sources else entry.name
    print(f"{args.retrieval}: {labels.correct.sum()} of {retrieval.n_queries} queries labelled correct by {source}")
    if args.gt is not None:
        q = label_quality(labels.correct, correct_at_n(retrieval.indices, retrieval.positives, 1))
        print(f"against {args.gt}: precision {q['precision']:.3f}, recall {q['recall']:.3f}, wrong {q['wrong']:.1%}")
    print(f"wrote {args.out}")
    return 0
