"""How good the machine labelers are: precision and recall against the ground truth on the VPR-Bench corridor.

For each of the corridor's ten VPR methods (111 queries each), the labels of its top-1 by

* ``agreement``: the other nine methods' matrices as ``others``, ``min_agree`` 3 (``--min-agree``): the same database
  image (the matrices carry no positions);
* ``agreement`` with positions: the same, each reference image placed at its frame index (``database_positions`` =
  (i, 0), ``config["radius"]`` = 2 frames, about the ground truth's tolerance), so a neighbouring frame agrees too;
* the geometric labelers of ``--presets`` (default ``gv-sift``; ``gv-disk-lg,gv-xfeat`` take about two minutes each on
  two CPU cores) on the real 160×120 images, at their default ``min_inliers``.

Precision = correct among the labels "correct" (the false-correct rate is 1 − precision), recall = share of the
correct top-1 labelled correct, wrong = share of labels that differ from the ground truth. Then, pooled over the ten
methods (1,110 labels), each geometric labeler's sweep of ``min_inliers``: the default is the one with the fewest
wrong labels (the strictest such).

Usage: ``VPR_UNCERTAINTY_DATA=... python benchmarks/machine_labels.py [--presets gv-sift,gv-disk-lg,gv-xfeat]``
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

from vpr_uncertainty.data import read_results
from vpr_uncertainty.data.images import retrieval_image_paths
from vpr_uncertainty.evaluation import correct_at_n
from vpr_uncertainty.labels import LABELERS, label, label_quality

METHODS = ("AMOSNet", "AlexNet_VPR", "CALC", "CoHOG", "HOG", "HybridNet", "NetVLAD", "RegionVLAD", "ap-gem-r101",
           "denseVLAD")  # fmt: skip


def _cell(quality: dict) -> str:
    return f"{quality['precision']:.3f} / {quality['recall']:.3f} / {quality['wrong']:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--presets", default="gv-sift", help="geometric labelers, comma-separated ('' for none)")
    parser.add_argument("--min-agree", type=int, default=3)
    parser.add_argument("--cache", type=Path, help="local-feature cache folder (default: a temporary one)")
    args = parser.parse_args()
    data = Path(os.environ["VPR_UNCERTAINTY_DATA"]) / "vprbench"
    corridor, gt = data / "corridor", data / "corridor" / "ground_truth_new.npy"
    matches = {m: data / "precomputed_matches/corridor" / m / "precomputed_data_corrected.npy" for m in METHODS}
    retrievals = {m: read_results(path, ground_truth=gt) for m, path in matches.items()}
    presets = [name for name in args.presets.split(",") if name]
    cache = args.cache or Path(tempfile.mkdtemp(prefix="machine-labels-"))
    spec = f"agreement:min_agree={args.min_agree}"
    columns = ["agreement", "agreement, frames ±2", *presets]
    print(
        f"precision / recall / wrong of each labeler against the ground truth ({spec}; geometric: default min_inliers)"
    )
    print(f"| method | top-1 correct | {' | '.join(columns)} |\n|---|---|{'---|' * len(columns)}")
    pooled: dict[str, list] = {name: [[], []] for name in columns}
    for method, retrieval in retrievals.items():
        truth = correct_at_n(retrieval.indices, retrieval.positives, 1)
        others = {m: r for m, r in retrievals.items() if m != method}
        framed = read_results(matches[method], ground_truth=gt)
        framed.database_positions = np.column_stack([np.arange(111.0), np.zeros(111)])
        framed.config["radius"] = 2.0
        labels = {
            "agreement": label(retrieval, spec, others=others),
            "agreement, frames ±2": label(framed, spec, others=others),
        }
        if presets:
            query_paths, database_paths = retrieval_image_paths(retrieval, images=corridor)
            for name in presets:
                labels[name] = label(retrieval, name, query_paths=query_paths, database_paths=database_paths,
                                     cache_dir=cache)  # fmt: skip
        for name, machine in labels.items():
            pooled[name][0].append(machine)
            pooled[name][1].append(truth)
        cells = [_cell(label_quality(labels[name].correct, truth)) for name in columns]
        print(f"| {method} | {truth.mean():.3f} | {' | '.join(cells)} |")
    pooled_cells = []
    for name in columns:
        correct = np.concatenate([machine.correct for machine in pooled[name][0]])
        pooled_cells.append(_cell(label_quality(correct, np.concatenate(pooled[name][1]))))
    print(
        f"| pooled (1,110 labels) | {np.concatenate(pooled['agreement'][1]).mean():.3f} | {' | '.join(pooled_cells)} |"
    )
    for name in presets:
        inliers, truth = (np.concatenate([m.confidence for m in pooled[name][0]]), np.concatenate(pooled[name][1]))
        default = LABELERS.get(name).options["min_inliers"]
        print(f"\n{name}, pooled: min_inliers -> precision / recall / wrong (default {default})")
        best = min(range(int(inliers.max()) + 2), key=lambda t: (((inliers >= t) != truth).mean(), -t))
        for threshold in sorted({0, 2, 4, 6, 8, 10, 12, 15, 20, 25, 30, best, default}):
            marker = " (fewest wrong)" if threshold == best else ""
            print(f"  {threshold:>3}: {_cell(label_quality(inliers >= threshold, truth))}{marker}")


if __name__ == "__main__":
    main()
