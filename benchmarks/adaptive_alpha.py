"""Adaptive α (``SU-adaptive``) against fixed α on every corridor matrix, and on any retrieval file given.

For each retrieval: AUC-PR and AP of SU with the paper's α = 0.5, of SU with the best fixed α of the grid 0, 0.1,
..., 1 chosen in hindsight on that retrieval (an upper bound no fixed rule can reach without labels), of
``SU-adaptive`` (α_q = 1 − |mean − median| / std of the runners-up, :mod:`vpr_uncertainty.scores`), and of the
reversed rule (α_q = |mean − median| / std) as a check of the rule's direction. Prints a Markdown table.

    python benchmarks/adaptive_alpha.py                                   # the ten corridor matrices
    python benchmarks/adaptive_alpha.py --retrieval /tmp/demo/retrieval.npz --label demo
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation import auc_pr, average_precision, correct_at_n
from vpr_uncertainty.methods import get_method
from vpr_uncertainty.scores import adaptive_alpha, ratio_spread, similarity_distribution

ALPHAS = tuple(round(0.1 * i, 1) for i in range(11))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=os.environ.get("VPR_UNCERTAINTY_DATA"), help="shared data folder")
    parser.add_argument("--retrieval", type=Path, action="append", default=[], help="a retrieval file with positives")
    parser.add_argument("--label", action="append", default=[], help="the name of each --retrieval in the table")
    parser.add_argument("--k", type=int, default=10)
    return parser.parse_args(argv)


def retrievals(args: argparse.Namespace):
    """(name, Retrieval) of every corridor matrix, then of every --retrieval."""
    if args.data is not None:
        corridor = Path(args.data) / "vprbench"
        ground_truth = corridor / "corridor" / "ground_truth_new.npy"
        for matrix in sorted((corridor / "precomputed_matches" / "corridor").glob("*/precomputed_data_corrected.npy")):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the legacy files are pickles and say so
                yield f"corridor · {matrix.parent.name}", read_results(matrix, ground_truth=ground_truth)
    labels = [*args.label, *(path.stem for path in args.retrieval[len(args.label) :])]
    for label, path in zip(labels, args.retrieval, strict=False):
        yield label, read_results(path)


def compare(retrieval, k: int = 10) -> dict[str, float]:
    """AUC-PR and AP of SU (α = 0.5), at the best fixed α in hindsight and at the adaptive rule's mean α (a control:
    is the gain the per-query choice, or only a shift of the average weight?), of SU-adaptive and of the reversed
    rule."""
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    su = get_method("SU")
    fixed = {a: auc_pr(correct, su(retrieval, k=k, alpha=a)) for a in ALPHAS}
    best = max(fixed, key=lambda a: (fixed[a], -a))
    adaptive = get_method("SU-adaptive")(retrieval, k=k)
    alpha = adaptive_alpha(retrieval.scores, k)
    reversed_rule = (1 - alpha) * ratio_spread(retrieval.scores, k) + alpha * similarity_distribution(
        retrieval.scores, k
    )
    return {
        "auc_pr_0.5": fixed[0.5],
        "best_alpha": best,
        "auc_pr_best": fixed[best],
        "auc_pr_adaptive": auc_pr(correct, adaptive),
        "auc_pr_reversed": auc_pr(correct, reversed_rule),
        "auc_pr_mean_alpha": auc_pr(correct, su(retrieval, k=k, alpha=float(alpha.mean()))),
        "ap_0.5": average_precision(correct, su(retrieval, k=k, alpha=0.5)),
        "ap_best": average_precision(correct, su(retrieval, k=k, alpha=best)),
        "ap_adaptive": average_precision(correct, adaptive),
        "mean_alpha": float(alpha.mean()),
    }


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    args = parse_args(argv)
    rows = {name: compare(retrieval, args.k) for name, retrieval in retrievals(args)}
    if not rows:
        sys.exit("no retrieval: give --data (or set VPR_UNCERTAINTY_DATA) or --retrieval FILE")
    print(
        "| retrieval | AUC-PR α=0.5 | best fixed α (hindsight) | AUC-PR | SU-adaptive | reversed rule | "
        "fixed α = mean α_q | AP α=0.5 | AP best α | AP adaptive | mean α_q |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, row in rows.items():
        print(
            f"| {name} | {row['auc_pr_0.5']:.4f} | {row['best_alpha']:g} | {row['auc_pr_best']:.4f} | "
            f"{row['auc_pr_adaptive']:.4f} | {row['auc_pr_reversed']:.4f} | {row['auc_pr_mean_alpha']:.4f} | "
            f"{row['ap_0.5']:.4f} | "
            f"{row['ap_best']:.4f} | {row['ap_adaptive']:.4f} | {row['mean_alpha']:.2f} |"
        )
    keys = ["auc_pr_0.5", "auc_pr_best", "auc_pr_adaptive", "auc_pr_reversed", "auc_pr_mean_alpha"]
    keys += ["ap_0.5", "ap_best", "ap_adaptive"]
    mean = {key: float(np.mean([row[key] for row in rows.values()])) for key in keys}
    wins = sum(row["auc_pr_adaptive"] > row["auc_pr_0.5"] for row in rows.values())
    print(
        f"| **mean of {len(rows)}** | {mean['auc_pr_0.5']:.4f} | | {mean['auc_pr_best']:.4f} | "
        f"{mean['auc_pr_adaptive']:.4f} | {mean['auc_pr_reversed']:.4f} | {mean['auc_pr_mean_alpha']:.4f} | "
        f"{mean['ap_0.5']:.4f} | "
        f"{mean['ap_best']:.4f} | {mean['ap_adaptive']:.4f} | |"
    )
    control = sum(row["auc_pr_adaptive"] > row["auc_pr_mean_alpha"] for row in rows.values())
    print(f"SU-adaptive above α = 0.5 (AUC-PR) on {wins} of {len(rows)} retrievals, above α = mean α_q on {control}")
    return rows


if __name__ == "__main__":
    main()
