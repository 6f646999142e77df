"""Evidence for issue 12: CAL's held-out AUC-PR against every fixed score-only method, the guarantee at p* = 0.9,
and the loop-closure example (calibrate on one part of a traversal, gate another).

    VPR_UNCERTAINTY_DATA=/path/to/data python benchmarks/calibration_evidence.py [--retrieval runs/demo/retrieval.npz]

Held-out: 30 % calibration (stratified), 20 random splits, seed 0; every method on the same held-out queries.
"""

from __future__ import annotations

import argparse
import os
import warnings
from pathlib import Path

import numpy as np

from vpr_uncertainty import calibrate
from vpr_uncertainty.calibration import evaluate_held_out
from vpr_uncertainty.calibration.plan import simulate_guarantee
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation import correct_at_n
from vpr_uncertainty.retrieval import load_retrieval

FIXED = ["RS", "SD", "SU", "PA", "L2", "BM", "margin"]


def _inputs(data: Path, extra: list[Path]) -> dict[str, object]:
    root = data / "vprbench"
    gt = root / "corridor/ground_truth_new.npy"
    found = {}
    for folder in sorted((root / "precomputed_matches/corridor").iterdir()):
        found[folder.name] = read_results(folder / "precomputed_data_corrected.npy", ground_truth=gt)
    for path in extra:
        found[f"{path.parent.name} (own run)"] = load_retrieval(path)
    return found


def held_out_table(retrievals: dict) -> None:
    print("\n## Held-out AUC-PR (30 % calibration, 20 splits, mean over splits)\n")
    print("| VPR method | " + " | ".join([*FIXED, "CAL"]) + " | best fixed | CAL − best fixed |")
    print("|---" * (len(FIXED) + 4) + "|")
    rows = []
    for name, retrieval in retrievals.items():
        methods = [m for m in FIXED if _works(m, retrieval)] + ["CAL"]
        result = evaluate_held_out(retrieval, methods, calibration_fraction=0.3, repeats=20, seed=0)
        means = {m: result.mean(m) for m in methods}
        best = max((m for m in methods if m != "CAL"), key=lambda m: means[m])
        rows.append(means)
        cells = [f"{means[m]:.3f}" if m in means else "n/a" for m in [*FIXED, "CAL"]]
        print(f"| {name} | " + " | ".join(cells) + f" | {best} {means[best]:.3f} | {means['CAL'] - means[best]:+.3f} |")
    corridor = rows[:10]
    average = {m: np.mean([r[m] for r in corridor if m in r]) for m in [*FIXED, "CAL"]}
    best = max(FIXED, key=lambda m: average[m])
    print(
        "| **corridor mean (10)** | "
        + " | ".join(f"{average[m]:.3f}" for m in [*FIXED, "CAL"])
        + f" | {best} {average[best]:.3f} | {average['CAL'] - average[best]:+.3f} |"
    )


def _works(method: str, retrieval) -> bool:
    from vpr_uncertainty.methods import get_method

    try:
        get_method(method)(retrieval, k=10)
    except ValueError:
        return False
    return True


def guarantee_table(retrievals: dict) -> None:
    print("\n## Guarantee at p* = 0.9, δ = 0.1 (200 i.i.d. calibration draws from each matrix's queries)\n")
    print("| VPR method | n cal | violations | certified | mean recall | hindsight SU recall | ratio |")
    print("|---|---|---|---|---|---|---|")
    for name, retrieval in retrievals.items():
        correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
        for n in (33, 333):
            sim = simulate_guarantee(retrieval.scores, correct, n_calibration=n, n_draws=200)
            ratio = sim.mean_recall / sim.hindsight_recall if sim.hindsight_recall else float("nan")
            print(
                f"| {name} | {n} | {sim.violation_rate:.3f} | {sim.certified.mean():.2f} | {sim.mean_recall:.3f} | "
                f"{sim.hindsight_recall:.3f} | {ratio:.2f} |"
            )


def loop_closure(retrievals: dict) -> None:
    print("\n## Loop closure: calibrate on queries 0-55, gate queries 56-110 (p* = 0.9, δ = 0.1)\n")
    print("| VPR method | certified bound | accepted | precision | recall | recall of SU at hindsight p>=0.9 |")
    print("|---|---|---|---|---|---|")
    from vpr_uncertainty.calibration.plan import hindsight_recall
    from vpr_uncertainty.scores import statistical_uncertainty

    for name, retrieval in retrievals.items():
        first, second = np.arange(56), np.arange(56, retrieval.n_queries)
        gate = calibrate(retrieval.subset_queries(first), target_precision=0.9, delta=0.1)
        other = retrieval.subset_queries(second)
        correct = correct_at_n(other.indices, other.positives, 1)
        accepted = gate.accept(other.scores[:, : gate.k])
        precision = correct[accepted].mean() if accepted.any() else float("nan")
        recall = (correct & accepted).sum() / correct.size
        su = statistical_uncertainty(other.scores, 10)
        bound = "none" if gate.precision_lower_bound is None else f"{gate.precision_lower_bound:.3f}"
        print(
            f"| {name} | {bound} | {accepted.sum()} / {correct.size} | {precision:.3f} | {recall:.3f} | "
            f"{hindsight_recall(su, correct, 0.9, correct.size):.3f} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--retrieval", type=Path, action="append", default=[], help="own retrieval.npz (repeatable)")
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    retrievals = _inputs(Path(os.environ["VPR_UNCERTAINTY_DATA"]), args.retrieval)
    held_out_table(retrievals)
    guarantee_table(retrievals)
    loop_closure(retrievals)


if __name__ == "__main__":
    main()
