"""BTL on the corridor with no overlap between training and test queries; SU and BM on the same test queries.

    VPR_UNCERTAINTY_DATA=/path/to/data python benchmarks/btl_protocol.py [--seeds 0 1 2] [--split-at 56]

Descriptors: the offline model ``efficientnet-lite0-gem`` (default preprocessing), extracted by the descriptor
stage into ``--work``/descriptors.h5 (reused on the next run when images and model are unchanged). Retrieval: exact
cosine top-10. Protocols (:mod:`vpr_uncertainty.btl.method`):

* ``database``: the head is trained on the 111 database images as anchors (positives: database images within
  ±``--frame-tolerance`` frames, the tolerance of the corridor's ground truth; hard negatives: the most similar of
  the rest), tested on all 111 queries;
* ``query-split``: trained on queries 0..split_at-1 (one part of the traversal), tested on queries
  split_at..110.

BTL is judged by its own top-1 (its own retrieval with the head's means), SU and BM by the descriptors' top-1,
all on the same test queries. Training settings: :class:`~vpr_uncertainty.btl.BTLTrainingConfig` defaults (embedding
as wide as the descriptor, so the untrained head retrieves like the descriptors; margin, KL weight, learning rate,
batch 256) except the options below (a smaller variance branch, 5 hard negatives, at most 30 epochs, patience 3),
which keep the six trainings within a few minutes on 2 CPU cores; 20 % of the training anchors (drawn with the
seed) are held out for early stopping.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from vpr_uncertainty.btl.method import PROTOCOLS, btl_protocol, train_for_protocol
from vpr_uncertainty.data.dataset import attach_ground_truth
from vpr_uncertainty.evaluation import evaluate
from vpr_uncertainty.formats.ground_truth import load_vprbench_ground_truth
from vpr_uncertainty.pipeline.extract import ExtractConf
from vpr_uncertainty.pipeline.extract import compute as extract
from vpr_uncertainty.retrieval import retrieve

MODEL = "efficientnet-lite0-gem"
BASELINES = ["SU", "BM"]


def corridor_inputs(corridor: Path, work: Path) -> dict:
    """Descriptors (extracted or read back from the cache), retrieval with ground truth, and the positives."""
    images = {}
    for split, folder in (("database", "ref"), ("queries", "query")):
        paths = sorted((corridor / folder).glob("*.jpg"))
        images[split] = (paths, [path.name for path in paths])
    result = extract(ExtractConf(model=MODEL, batch_size=32, progress=False), images, work / "descriptors.h5")
    positives = load_vprbench_ground_truth(corridor / "ground_truth_new.npy", n_database=len(images["database"][0]))
    retrieval = attach_ground_truth(
        retrieve(result.descriptors["database"], result.descriptors["queries"], k=10),
        positives=positives,
        database_names=result.names["database"],
        query_names=result.names["queries"],
    )
    return {
        "queries": result.descriptors["queries"],
        "database": result.descriptors["database"],
        "positives": positives,
        "retrieval": retrieval,
    }


def _metrics(method) -> dict:
    found = {"auc_pr": method.auc_pr, "average_precision": method.average_precision}
    if method.own_recall_at_1 is not None:
        found["own_recall@1"] = method.own_recall_at_1
    return found


def run_protocol(
    name: str, inputs: dict, seeds: list[int], *, split_at: int, frame_tolerance: int, settings: dict
) -> dict:
    """Train one head per seed under protocol ``name``; BTL, SU and BM on the protocol's test queries."""
    n_queries = len(inputs["queries"])
    protocol = btl_protocol(name, n_queries, split_at=split_at if name == "query-split" else None)
    test = protocol.test_queries
    retrieval = inputs["retrieval"].subset_queries(test)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        baseline = evaluate(retrieval, BASELINES)
    report = {
        "protocol": name,
        "description": protocol.description,
        "train_queries": protocol.train_queries.tolist(),
        "test_queries": test.tolist(),
        "recall@1": float(baseline.recall_at_n[1]),
        "baselines": {method: _metrics(baseline.methods[method]) for method in BASELINES},
        "settings": settings,
        "seeds": {},
    }
    for seed in seeds:
        start = time.perf_counter()
        head, history = train_for_protocol(
            protocol,
            inputs["queries"],
            inputs["database"],
            inputs["positives"],
            frame_tolerance=frame_tolerance,
            seed=seed,
            progress=False,
            **settings,
        )
        seconds = time.perf_counter() - start
        options = {
            "btl_head": head,
            "query_descriptors": inputs["queries"][test],
            "database_descriptors": inputs["database"],
        }
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            btl = evaluate(retrieval, ["BTL"], **options).methods["BTL"]
        report["seeds"][seed] = {
            **_metrics(btl),
            "best_epoch": history.best_epoch,
            "epochs_run": history.epoch[-1],
            "n_train_anchors": history.n_train_anchors,
            "n_val_anchors": history.n_val_anchors,
            "training_s": seconds,
        }
    for metric in ("auc_pr", "average_precision", "own_recall@1"):
        report[f"mean_{metric}"] = float(np.mean([entry[metric] for entry in report["seeds"].values()]))
    return report


def print_report(reports: list[dict]) -> None:
    print("\n| protocol | test queries | BTL AUC-PR mean (per seed) | BTL AP mean (per seed) | BTL own R@1 | "
          "SU AUC-PR / AP | BM AUC-PR / AP | R@1 |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for report in reports:
        seeds = report["seeds"].values()
        auc = " / ".join(f"{entry['auc_pr']:.3f}" for entry in seeds)
        ap = " / ".join(f"{entry['average_precision']:.3f}" for entry in seeds)
        su, bm = report["baselines"]["SU"], report["baselines"]["BM"]
        test = report["test_queries"]
        print(
            f"| {report['description']} | {len(test)} ({test[0]}..{test[-1]}) | {report['mean_auc_pr']:.3f} ({auc}) | "
            f"{report['mean_average_precision']:.3f} ({ap}) | {report['mean_own_recall@1']:.3f} | "
            f"{su['auc_pr']:.3f} / {su['average_precision']:.3f} | "
            f"{bm['auc_pr']:.3f} / {bm['average_precision']:.3f} | {report['recall@1']:.3f} |"
        )
    for report in reports:
        for seed, entry in report["seeds"].items():
            print(
                f"{report['protocol']} seed {seed}: anchors {entry['n_train_anchors']} train + "
                f"{entry['n_val_anchors']} validation, best epoch {entry['best_epoch']} of {entry['epochs_run']}, "
                f"{entry['training_s']:.1f} s"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default_data = Path(os.environ.get("VPR_UNCERTAINTY_DATA", "data"))
    parser.add_argument("--corridor", type=Path, default=default_data / "vprbench" / "corridor")
    parser.add_argument("--work", type=Path, default=Path("runs/btl_protocol"), help="descriptor cache and JSON")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--split-at", type=int, default=56, help="query-split: first test query (56)")
    parser.add_argument("--frame-tolerance", type=int, default=2, help="database protocol: positives within ±N frames")
    parser.add_argument("--protocols", nargs="+", choices=PROTOCOLS, default=list(PROTOCOLS))
    parser.add_argument("--threads", type=int, default=2, help="torch threads (2)")
    parser.add_argument("--hidden-dim", type=int, default=64, help="variance branch width (64)")
    parser.add_argument("--negatives", type=int, default=5, help="hard negatives per anchor (5)")
    parser.add_argument("--epochs", type=int, default=30, help="most epochs (30)")
    parser.add_argument("--patience", type=int, default=3, help="early-stopping patience (3)")
    args = parser.parse_args()
    settings = {"hidden_dim": args.hidden_dim, "n_negatives": args.negatives, "epochs": args.epochs}
    settings["patience"] = args.patience
    torch.set_num_threads(args.threads)
    args.work.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    inputs = corridor_inputs(args.corridor, args.work)
    reports = [
        run_protocol(
            name, inputs, args.seeds, split_at=args.split_at, frame_tolerance=args.frame_tolerance, settings=settings
        )
        for name in args.protocols
    ]
    print_report(reports)
    (args.work / "btl_protocol.json").write_text(json.dumps(reports, indent=2) + "\n")
    print(f"\nwritten {args.work / 'btl_protocol.json'}; total {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
