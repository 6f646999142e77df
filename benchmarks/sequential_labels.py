"""How many labels sequential labelling needs to certify, against the batch gate at equal recall.

Populations: each of the ten VPR-Bench corridor matrices (111 queries, with their ground truth). Per draw, a pool of
``--pool`` queries is drawn i.i.d. with replacement from a population; the guarantee is exact with respect to that
resampled population, whose precision among the accepted answers is known.

* sequential: :class:`~vpr_uncertainty.calibration.SequentialCalibration` on the pool's scores, labelled (from the
  ground truth) in the order it asks until it says it is finished; its labels are those it asked for, its rule is
  the certified cut on the ranking. A draw violates when the population precision at that cut is < p*.
* batch: ``calibrate_arrays`` (the toolkit's defaults) on ``n`` queries drawn i.i.d. from the population, for each n
  of ``--sizes``; its rule is ``gate.accept``.

"seq labels" are all the labels it asked for until finished; "at final" those it had when its final certificate
was reached (a user who stopped there would hold the same rule). Recall = accepted-correct / answerable population
queries (0 when nothing is certified), averaged over draws. "batch labels at equal recall" is the smallest n of
``--sizes`` whose mean recall reaches the sequential mean recall, linearly interpolated between sizes ("> max" when
none does).

Usage: ``VPR_UNCERTAINTY_DATA=... python benchmarks/sequential_labels.py [--draws 100] [--pool 300]``
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from vpr_uncertainty.calibration import SequentialCalibration, calibrate_arrays
from vpr_uncertainty.calibration.calibrator import RANKINGS, feature_columns
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation import correct_at_n


def _population(folder: Path, ground_truth: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    retrieval = read_results(folder / "precomputed_data_corrected.npy", ground_truth=ground_truth)
    answerable = np.asarray(retrieval.positives.sum(axis=1)).ravel() > 0
    return np.asarray(retrieval.scores), correct_at_n(retrieval.indices, retrieval.positives, 1), answerable


def _sequential(scores, correct, answerable, rows, rankings, p_star, delta):
    session = SequentialCalibration(scores[rows], target_precision=p_star, delta=delta, rankings=rankings)
    last = (0, 0)  # (accepted, labels) when the final certificate was reached
    while (query := session.next_query()) is not None:
        status = session.add_label(query, bool(correct[rows[query]]))
        if status.accepted != last[0]:
            last = (status.accepted, status.labelled)
    status = session.status()
    if not status.certified:
        return status.labelled, 0, 0.0, False
    feature, sign = RANKINGS[status.ranking]
    accept = sign * feature_columns(scores, 10, required=(feature,))[feature] >= status.cut
    precision = correct[accept].mean() if accept.any() else 1.0
    return status.labelled, last[1], (correct & accept).sum() / answerable.sum(), precision < p_star


def _batch(scores, correct, answerable, rows, seed, p_star, delta):
    if correct[rows].all() or not correct[rows].any():
        return 0.0, False
    gate = calibrate_arrays(
        scores[rows], correct[rows], answerable=answerable[rows], target_precision=p_star, delta=delta, seed=seed
    )
    accept = gate.accept(scores[:, : gate.k])
    precision = correct[accept].mean() if accept.any() else 1.0
    return (correct & accept).sum() / answerable.sum(), precision < p_star


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=100)
    parser.add_argument("--pool", type=int, default=300, help="queries per resampled pool")
    parser.add_argument("--sizes", default="25,50,100,150,200,300", help="batch labelled sizes")
    parser.add_argument("--rankings", default="SU,margin", help="rankings of the sequential labelling")
    parser.add_argument("--target-precision", type=float, default=0.9)
    parser.add_argument("--delta", type=float, default=0.1)
    args = parser.parse_args()
    sizes = [int(size) for size in args.sizes.split(",")]
    data = Path(os.environ["VPR_UNCERTAINTY_DATA"]) / "vprbench"
    gt = data / "corridor" / "ground_truth_new.npy"
    folders = sorted(p for p in (data / "precomputed_matches" / "corridor").iterdir() if p.is_dir())
    print(f"pool {args.pool}, {args.draws} draws, p* {args.target_precision}, δ {args.delta}, rankings {args.rankings}")
    print(
        f"{'method':<14} {'seq labels':>10} {'at final':>8} {'seq recall':>10} {'seq viol':>8} "
        + " ".join(f"{'b' + str(n):>6}" for n in sizes)
        + "  batch labels at equal recall"
    )
    totals = []
    for folder in folders:
        scores, correct, answerable = _population(folder, gt)
        rng = np.random.default_rng(0)
        seq = [
            _sequential(
                scores,
                correct,
                answerable,
                rng.integers(0, correct.size, args.pool),
                args.rankings.split(","),
                args.target_precision,
                args.delta,
            )
            for _ in range(args.draws)
        ]
        labels, at_final, recall, violation = (np.mean(column) for column in zip(*seq, strict=True))
        batch = []
        for n in sizes:
            runs = [
                _batch(
                    scores,
                    correct,
                    answerable,
                    rng.integers(0, correct.size, n),
                    draw,
                    args.target_precision,
                    args.delta,
                )
                for draw in range(args.draws)
            ]
            batch.append(np.mean([run[0] for run in runs]))
        reach = np.flatnonzero(np.array(batch) >= recall)
        if recall == 0:
            equal = "-"
        elif reach.size == 0:
            equal = f"> {sizes[-1]}"
        elif reach[0] == 0:
            equal = f"<= {sizes[0]}"
        else:
            i = reach[0]
            equal = (
                f"{sizes[i - 1] + (recall - batch[i - 1]) / (batch[i] - batch[i - 1]) * (sizes[i] - sizes[i - 1]):.0f}"
            )
        totals.append((labels, at_final, recall, violation))
        print(
            f"{folder.name:<14} {labels:>10.1f} {at_final:>8.1f} {recall:>10.3f} {violation:>8.3f} "
            + " ".join(f"{b:>6.3f}" for b in batch)
            + f"  {equal}"
        )
    labels, at_final, recall, violation = np.mean(totals, axis=0)
    print(f"{'mean':<14} {labels:>10.1f} {at_final:>8.1f} {recall:>10.3f} {violation:>8.3f}")


if __name__ == "__main__":
    main()
