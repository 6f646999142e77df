"""``vpr-uncertainty train-btl``: train the Bayesian triplet loss (BTL) uncertainty head on frozen descriptors."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.commands._arguments import device_name, non_negative_float, output_file, positive_int

__all__ = ["add_parser", "read_training_inputs"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``train-btl`` command."""
    parser = subparsers.add_parser(
        "train-btl",
        help="train the Bayesian triplet loss (BTL) uncertainty head on frozen descriptors",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Train a head that turns each frozen global descriptor into an isotropic Gaussian embedding (an\n"
            "L2-normalised mean and one variance) with the Bayesian triplet loss (Warburg et al., ICCV 2021).\n"
            "Triplets: each anchor with its most similar positives (within --radius of its position, or from\n"
            "--positives) and its hardest negatives (most similar non-positives in descriptor space). Anchors are\n"
            "the queries when they have descriptors and ground truth, else the database images themselves.\n"
            "A random --val-fraction of the anchors is held out for early stopping; the best head is written to\n"
            "--out, the training curve beside it (OUT.curve.json and OUT.curve.png).\n\n"
            "Use the head with `vpr-uncertainty evaluate RETRIEVAL --methods BTL,SU --btl-head HEAD.pt\n"
            "--descriptors descriptors.h5` or `vpr-uncertainty run ... --methods BTL,SU --btl-head HEAD.pt`."
        ),
        epilog=(
            "examples:\n"
            "  vpr-uncertainty train-btl --descriptors train_db.npy --positions train_db_utm.npy --out head.pt\n"
            "  vpr-uncertainty train-btl --descriptors descriptors.h5 --positives ground_truth_new.npy --out head.pt\n"
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
        "--positions", type=Path, metavar="POS.npy", help="database positions (D x 2, metres, or frame indices)"
    )
    source.add_argument("--query-positions", type=Path, metavar="POS.npy", help="query positions (Q x 2)")
    source.add_argument(
        "--positives",
        type=Path,
        metavar="GT",
        help="explicit positives instead of positions: VPR-Bench ground_truth_new.npy, bool .npy, .json, .txt, "
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
    training.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=_run_train_btl)


def _load_positions(path: Path, name: str) -> np.ndarray:
    if not path.is_file():
        raise FileNotFoundError(f"{name} file not found: {path}")
    try:
        array = np.load(path, allow_pickle=False)
    except ValueError as error:
        raise ValueError(f"{path}: {name} must be a numeric .npy array: {error}") from None
    if array.ndim not in (1, 2) or not np.issubdtype(array.dtype, np.number):
        raise ValueError(f"{path}: {name} must be a numeric array of shape (n, 2) or (n,), got {array.shape}")
    return array


def _h5_has_queries(path: Path) -> bool:
    from vpr_uncertainty.features.cache import cache_info

    return bool(cache_info(path).get("queries", {}).get("count", 0))


def read_training_inputs(args: argparse.Namespace) -> dict[str, Any]:
    """Descriptors and positives for :func:`~vpr_uncertainty.learned.train_btl_head` from the command line.

    Returns a dict with ``database``, ``queries`` (or None: the database trains on itself), ``positives`` and
    ``source`` (JSON-compatible description for the head file).
    """
    from vpr_uncertainty.data import load_ground_truth, positives_within_radius
    from vpr_uncertainty.retrieval import load_descriptors, load_retrieval

    if args.run is not None:
        exclusive = ("descriptors", "query_descriptors", "positions", "query_positions", "positives")
        given = ["--" + name.replace("_", "-") for name in exclusive if getattr(args, name) is not None]
        if given:
            raise ValueError(f"--run reads descriptors.h5 and retrieval.npz; do not combine it with {', '.join(given)}")
        if not args.run.is_dir():
            raise FileNotFoundError(f"run directory not found: {args.run}")
        args.descriptors = args.run / "descriptors.h5"
        retrieval_path = args.run / "retrieval.npz"
        if not args.descriptors.is_file() or not retrieval_path.is_file():
            raise FileNotFoundError(f"{args.run} must hold descriptors.h5 and retrieval.npz (from extract + retrieve)")
    elif args.descriptors is None:
        raise ValueError("give the training data: --descriptors DESC (with --positions or --positives) or --run DIR")
    else:
        retrieval_path = None

    database_names, database = load_descriptors(args.descriptors, "database")
    query_path = args.query_descriptors
    if query_path is None and args.descriptors.suffix.lower() in (".h5", ".hdf5") and _h5_has_queries(args.descriptors):
        query_path = args.descriptors
    query_names, queries = load_descriptors(query_path, "queries") if query_path is not None else (None, None)
    source: dict[str, Any] = {"descriptors": str(args.descriptors), "query_descriptors": str(query_path or "")}

    positives = None
    if retrieval_path is not None:
        retrieval = load_retrieval(retrieval_path)
        if retrieval.positives is None:
            raise ValueError(f"{retrieval_path} holds no ground truth (positives); retrieve with positions")
        if queries is None:
            raise ValueError(f"{args.descriptors} holds no query descriptors")
        for split, names, stored in (
            ("query", query_names, retrieval.query_names),
            ("database", database_names, retrieval.database_names),
        ):
            if names is not None and stored is not None and list(names) != [str(name) for name in stored]:
                raise ValueError(f"the {split} names of {args.descriptors} and {retrieval_path} differ")
        positives = retrieval.positives
        source["positives"] = str(retrieval_path)
    elif args.positives is not None:
        positives = load_ground_truth(args.positives, n_database=len(database))
        if queries is None or positives.shape[0] != len(queries):
            if positives.shape[0] != len(database):
                expected = f"{len(queries)} (queries) or {len(database)}" if queries is not None else f"{len(database)}"
                raise ValueError(
                    f"{args.positives} has positives for {positives.shape[0]} images; expected {expected} (database)"
                )
            queries = None  # database × database ground truth: the database trains on itself
        source["positives"] = str(args.positives)
    elif args.positions is not None:
        database_positions = _load_positions(args.positions, "--positions")
        if len(database_positions) != len(database):
            raise ValueError(f"--positions has {len(database_positions)} rows but there are {len(database)} images")
        if args.query_positions is not None and queries is not None:
            query_positions = _load_positions(args.query_positions, "--query-positions")
            if len(query_positions) != len(queries):
                raise ValueError(
                    f"--query-positions has {len(query_positions)} rows but there are {len(queries)} queries"
                )
            positives = positives_within_radius(query_positions, database_positions, args.radius)
        else:
            queries = None  # no query ground truth: the database trains on itself
            positives = positives_within_radius(database_positions, database_positions, args.radius)
        source.update(positions=str(args.positions), radius=args.radius)
    else:
        raise ValueError("give the ground truth: --positions POS.npy (with --radius) or --positives GT")
    if queries is None:
        source["query_descriptors"] = ""
    source["anchors"] = "queries" if queries is not None else "database"
    return {"database": database, "queries": queries, "positives": positives, "source": source}


def _run_train_btl(args: argparse.Namespace) -> int:
    from vpr_uncertainty.learned import BTLTrainingConfig, save_btl_head, save_training_curve, train_btl_head

    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    inputs = read_training_inputs(args)
    database, queries = inputs["database"], inputs["queries"]
    config = BTLTrainingConfig(
        embedding_dim=args.embedding_dim,
        hidden_dim=args.hidden_dim,
        margin=args.margin,
        kl_weight=args.kl_weight,
        prior_variance=args.prior_variance,
        n_negatives=args.negatives,
        max_positives=args.max_positives,
        epochs=args.epochs,
        batch_size=args.batch_size,
        learning_rate=args.lr,
        weight_decay=args.weight_decay,
        val_fraction=args.val_fraction,
        patience=args.patience,
        seed=args.seed,
        device=args.device,
    )
    anchors = f"{len(queries)} queries" if queries is not None else f"{len(database)} database images"
    print(f"training data: {anchors} as anchors, {len(database)} database images of dimension {database.shape[1]}")
    head, history = train_btl_head(
        database, inputs["positives"], query_descriptors=queries, config=config, progress=not args.no_progress
    )
    head.metadata["source"] = inputs["source"]
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
