"""``vpr-uncertainty train-btl``: train the Bayesian triplet loss (BTL) uncertainty head on frozen descriptors."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from vpr_uncertainty.pipeline.options import (
    add_progress_options,
    apply_threads,
    command_wording,
    device_name,
    non_negative_float,
    output_file,
    positive_int,
)


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``train-btl`` command."""
    parser = subparsers.add_parser(
        "train-btl",
        help="train the Bayesian triplet loss (BTL) uncertainty head on frozen descriptors",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Train a head that turns each frozen global descriptor into an isotropic Gaussian embedding (an\n"
            "L2-normalised mean and one variance) with the Bayesian triplet loss (Warburg et al., ICCV 2021).\n"
            "Triplets: each anchor with its most similar positives (within --radius of its position, or from\n"
            "--gt) and its hardest negatives (most similar non-positives in descriptor space). Anchors are\n"
            "the queries when they have descriptors and ground truth, else the database images themselves.\n"
            "A random --val-fraction of the anchors is held out for early stopping; the best head is written to\n"
            "--out, the training curve beside it (OUT.curve.json and OUT.curve.png).\n\n"
            "Use the head with `vpr-uncertainty evaluate RETRIEVAL --methods BTL,SU --btl-head HEAD.pt\n"
            "--descriptors descriptors.h5` or `vpr-uncertainty run ... --methods BTL,SU --btl-head HEAD.pt`."
        ),
        epilog=(
            "examples:\n"
            "  vpr-uncertainty train-btl --descriptors train_db.npy --database-positions db_utm.npy --out head.pt\n"
            "  vpr-uncertainty train-btl --descriptors descriptors.h5 --gt ground_truth_new.npy --out head.pt\n"
            "  vpr-uncertainty train-btl --run runs/pitts30k_train --out head.pt --device cuda"
        ),
    )
    source = parser.add_argument_group("training data")
    source.add_argument(
        "--descriptors",
        type=Path,
        metavar="DESC",
        help="database descriptors: .npy (D x dim) or the HDF5 descriptor cache (its queries are used too)",
    )
    source.add_argument("--query-descriptors", type=Path, metavar="Q", help="query descriptors (.npy or .h5)")
    source.add_argument(
        "--database-positions",
        dest="positions",
        type=Path,
        metavar="POS.npy",
        help="database positions (D x 2, metres, or frame indices)",
    )
    source.add_argument("--query-positions", type=Path, metavar="POS.npy", help="query positions (Q x 2)")
    source.add_argument(
        "--gt",
        dest="positives",
        type=Path,
        metavar="GT",
        help="explicit ground truth instead of positions: VPR-Bench ground_truth_new.npy, bool .npy, .json, .txt, "
        ".npz (queries x database, or database x database without queries)",
    )
    source.add_argument(
        "--run", type=Path, metavar="DIR", help="run directory holding descriptors.h5 and retrieval.npz (positives)"
    )
    source.add_argument(
        "--radius",
        type=non_negative_float,
        default=25.0,
        help="positives: images within this distance, in the unit of the positions (default 25)",
    )
    parser.add_argument(
        "--out", type=output_file, required=True, metavar="FILE", help="head file to write (e.g. head.pt)"
    )
    model = parser.add_argument_group("model and loss")
    model.add_argument(
        "--embedding-dim", type=positive_int, help="dimension of the mean embedding (default min(dim, 2048))"
    )
    model.add_argument("--hidden-dim", type=positive_int, default=256, help="width of the variance branch (256)")
    model.add_argument("--margin", type=float, default=0.0, help="m in P(|a-p|^2 < |a-n|^2 + m) (default 0)")
    model.add_argument("--kl-weight", type=non_negative_float, default=1e-6, help="weight of the KL term (1e-6)")
    model.add_argument("--prior-variance", type=float, default=1.0, help="variance of the Gaussian prior (1)")
    training = parser.add_argument_group("training")
    training.add_argument("--negatives", type=positive_int, default=10, help="hard negatives per anchor (10)")
    training.add_argument("--max-positives", type=positive_int, default=10, help="positives per anchor (10)")
    training.add_argument("--epochs", type=positive_int, default=100, help="maximum number of epochs (100)")
    training.add_argument("--batch-size", type=positive_int, default=256, help="triplets per step (256)")
    training.add_argument("--lr", type=float, default=3e-4, help="AdamW learning rate (3e-4)")
    training.add_argument("--weight-decay", type=non_negative_float, default=1e-4, help="AdamW weight decay (1e-4)")
    training.add_argument("--val-fraction", type=float, default=0.2, help="anchors held out for validation (0.2)")
    training.add_argument("--patience", type=positive_int, default=10, help="epochs without improvement (10)")
    training.add_argument("--seed", type=int, default=0, help="random seed of the split, init and shuffling (0)")
    training.add_argument("--device", type=device_name, default="cpu", help="cpu, cuda or cuda:N (default cpu)")
    training.add_argument(
        "--threads", type=positive_int, help="CPU threads of PyTorch (default: its own choice; 1 on a busy machine)"
    )
    add_progress_options(parser)
    parser.set_defaults(handler=_handle)


_INPUTS = ("descriptors", "query_descriptors", "positions", "query_positions", "positives", "run")


def _handle(args: argparse.Namespace) -> int:
    from vpr_uncertainty.btl import BTLTrainingConfig, save_btl_head, save_training_curve, train_btl_head

    apply_threads(args.threads)
    from vpr_uncertainty.btl.method import read_training_inputs

    flags = {name: "--" + name.replace("_", "-") for name in _INPUTS}
    flags.update(positions="--database-positions", positives="--gt")
    with command_wording(**flags, learning_rate="--lr", device="--device cpu"):
        inputs = read_training_inputs(**{name: getattr(args, name) for name in _INPUTS}, radius=args.radius)
    database, queries = inputs["database"], inputs["queries"]
    # the flags named as the settings, and --negatives, --lr
    given = {f.name: getattr(args, f.name) for f in dataclasses.fields(BTLTrainingConfig) if hasattr(args, f.name)}
    config = BTLTrainingConfig(**given, n_negatives=args.negatives, learning_rate=args.lr)
    anchors = f"{len(queries)} queries" if queries is not None else f"{len(database)} database images"
    print(f"training data: {anchors} as anchors, {len(database)} database images of dimension {database.shape[1]}")
    with command_wording(learning_rate="--lr", device="--device cpu"):
        head, history = train_btl_head(
            database,
            inputs["positives"],
            query_descriptors=queries,
            config=config,
            progress=getattr(args, "progress", None),
        )
    head.metadata["source"] = inputs["source"]
    head.metadata["anchors"].update(inputs["images"])  # names and content digests: what survives re-extraction
    out = save_btl_head(head, args.out, metadata=head.metadata)
    stem = out.with_suffix("")
    curve_json, curve_png = Path(f"{stem}.curve.json"), Path(f"{stem}.curve.png")
    save_training_curve(history, curve_json, curve_png)
    summary = history.summary()
    print(
        f"{summary['n_train_anchors']} training / {summary['n_val_anchors']} validation anchors, "
        f"{summary['n_train_triplets']} / {summary['n_val_triplets']} triplets"
    )
    print(
        f"validation loss {summary['initial_val_loss']:.4f} (untrained) -> {summary['best_val_loss']:.4f} "
        f"(best epoch {summary['best_epoch']} of {summary['epochs_run']}"
        f"{', stopped early' if summary['stopped_early'] else ''})"
    )
    print(f"wrote {out}, {curve_json}, {curve_png}")
    if history.best_epoch == 0:
        print("warning: training never improved the validation loss; the head is the untrained one")
    return 0
