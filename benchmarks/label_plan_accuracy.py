"""How far the label plan's predictions fall from what ``calibrate`` achieves: predicted vs achieved at n labels.

Populations
    Each of the ten VPR-Bench corridor matrices (its 111 queries), resampled as ``benchmarks/gate_efficiency.py``
    does: a draw takes queries i.i.d. **with replacement** from the population. ``--family`` adds (or names
    instead) the populations of ``benchmarks/random_labels.py`` built to fail (``contrasting``, ``short``,
    ``fitted``: one ranking's top clean, short, or missed by the fitted model).

Predicted
    The pool is the population's queries twice over (222 rows, the same distribution, so that 200 labels fit in
    it; ``--pool-times 6``: 666 rows, so that 200 labels are 30 % of it, the issue-43 protocol). L of them (30 or
    50, drawn without replacement; redrawn until they hold 2 correct and 2 wrong answers) are labelled, and
    ``plan_labels(labelled scores, correct, unlabelled=the other pool rows,
    answerable=..., target_precision=p*, delta=delta, sizes=(50, 100, 200), draws=--plan-draws, seed=rep)``
    predicts; ``--reps`` labelled draws per population and L (``--labelled``, default 30,50; ``--sizes``, default
    50,100,200).

Achieved
    ``calibrate_arrays(scores, correct, answerable=..., target_precision=p*, delta=delta)`` (calibrate's defaults)
    on ``--draws`` fresh draws of n queries from the same population; certified = a precision lower bound is
    returned; recall = accepted correct / answerable population queries (0 when nothing is certified). A draw
    holding one outcome counts as not certified (``calibrate`` refuses it), as in the plan.

Printed: per population, L and n the predicted P(certified) and mean recall (mean over the reps) beside the
achieved ones; then, per L and n, their means over the populations, the mean and largest |predicted - achieved|
over the populations and reps, and the share of plans within the target of +-0.15. Then a proper score: per L and n
the Brier score of the plans, mean (predicted - achieved)^2 over the populations and reps, beside that of a
no-information baseline predicting for every plan the mean achieved share over the ten populations at that n (an
oracle constant: it reads the achieved shares, so a user never has it); their means over L and n; and a reliability
summary: the plans binned by predicted P(certified) (< 1/3, 1/3 - 2/3, > 2/3), the mean predicted and achieved in each.

Usage
    VPR_UNCERTAINTY_DATA=/path/to/data python benchmarks/label_plan_accuracy.py [--reps 3] [--plan-draws 100]
        [--draws 200] [--family corridor,contrasting,short,fitted] [--jobs 2]
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from vpr_uncertainty.calibration import calibrate_arrays, plan_labels
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation.metrics import answerable_queries, correct_at_n

SIZES = (50, 100, 200)
LABELLED = (30, 50)
FAMILIES = ("corridor", "contrasting", "short", "fitted")
TOLERANCE = 0.15
BINS = (0.0, 1 / 3, 2 / 3, 1.0)


def populations(data: Path) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per corridor method: top-k scores (111, K), top-1 correct and answerable (111,)."""
    root, found = data / "vprbench", {}
    for folder in sorted((root / "precomputed_matches/corridor").iterdir()):
        retrieval = read_results(
            folder / "precomputed_data_corrected.npy", ground_truth=root / "corridor/ground_truth_new.npy"
        )
        correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
        found[folder.name] = (np.asarray(retrieval.scores), correct, answerable_queries(retrieval.positives))
    return found


def achieved(scores, correct, answerable, n, draws, rng, p_star, delta) -> tuple[float, float]:
    """Share of ``draws`` fresh draws of n that certify, and their mean recall on the population."""
    certified, recall = 0, 0.0
    for _ in range(draws):
        rows = rng.choice(correct.size, n, replace=True)
        if correct[rows].all() or not correct[rows].any():
            continue
        gate = calibrate_arrays(
            scores[rows], correct[rows], answerable=answerable[rows], target_precision=p_star, delta=delta
        )
        if gate.precision_lower_bound is not None:
            certified += 1
            recall += (gate.accept(scores[:, : gate.k]) & correct).sum() / max(int(answerable.sum()), 1)
    return certified / draws, recall / draws


def labelled_draw(correct: np.ndarray, size: int, rng: np.random.Generator, times: int = 2) -> np.ndarray:
    """Which rows of the pool (the population ``times`` over) are labelled, as a mask."""
    while True:
        rows = rng.choice(times * correct.size, size, replace=False)
        if min(int(correct[rows % correct.size].sum()), int((~correct[rows % correct.size]).sum())) >= 2:
            return np.isin(np.arange(times * correct.size), rows)


def family_populations(data: Path, wanted: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The corridor populations (``corridor``) and those of ``benchmarks/random_labels.py``'s other families."""
    found = populations(data) if "corridor" in wanted else {}
    others = [family for family in wanted if family != "corridor"]
    if others:
        sys.path.insert(0, str(Path(__file__).parent))
        from random_labels import families, load_populations

        for built in families(load_populations(data, [], 0.9), others).values():
            found.update({p.name: (p.scores, p.correct, p.answerable) for p in built})
    return found


def plan_population(task: tuple) -> tuple[list[str], dict[tuple[int, int], list[tuple[float, float, float, float]]]]:
    """Achieved and predicted figures of one population: its table rows and (L, n) -> (predicted, achieved) pairs."""
    index, name, (scores, correct, answerable), args = task
    p_star, delta = args.target_precision, args.delta
    rng = np.random.default_rng([args.seed, index])
    truth = {n: achieved(scores, correct, answerable, n, args.draws, rng, p_star, delta) for n in args.sizes}
    lines, pairs = [], {}
    for labelled in args.labelled:
        plans = []
        pool = np.tile(np.arange(correct.size), args.pool_times)
        for rep in range(args.reps):
            mask = labelled_draw(correct, labelled, rng, args.pool_times)
            rows = pool[mask]
            plans.append(
                plan_labels(
                    scores[rows],
                    correct[rows],
                    unlabelled=scores[pool[~mask]],
                    answerable=answerable[rows],
                    target_precision=p_star,
                    delta=delta,
                    sizes=args.sizes,
                    draws=args.plan_draws,
                    seed=rep,
                    progress=False,
                )
            )
        for column, n in enumerate(args.sizes):
            certified = [plan.certified[column] for plan in plans]
            recall = [plan.mean_recall[column] for plan in plans]
            pairs.setdefault((labelled, n), []).extend(
                (c, truth[n][0], r, truth[n][1]) for c, r in zip(certified, recall, strict=True)
            )
            lines.append(
                f"| {name} | {labelled} | {n} | {np.mean(certified):.2f} | {truth[n][0]:.2f} | "
                f"{np.mean(recall):.3f} | {truth[n][1]:.3f} |"
            )
    return lines, pairs


def _integers(text: str) -> list[int]:
    return sorted({int(part) for part in text.split(",") if part.strip()})


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--reps", type=int, default=3, help="labelled draws per population and L (default 3)")
    parser.add_argument("--plan-draws", type=int, default=100, help="simulations of each plan (default 100)")
    parser.add_argument("--draws", type=int, default=200, help="fresh draws per population and n (default 200)")
    parser.add_argument("--target-precision", type=float, default=0.9)
    parser.add_argument("--delta", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--family", default="corridor", help=f"comma-separated, from {', '.join(FAMILIES)}")
    parser.add_argument("--labelled", type=_integers, default=list(LABELLED), help="L, comma-separated (30,50)")
    parser.add_argument("--sizes", type=_integers, default=list(SIZES), help="n, comma-separated (50,100,200)")
    parser.add_argument("--pool-times", type=int, default=2, help="the pool: the population this many times (2)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    args = parser.parse_args(argv)
    data = os.environ.get("VPR_UNCERTAINTY_DATA")
    if not data:
        parser.error("set VPR_UNCERTAINTY_DATA to the data folder (holding vprbench/)")
    wanted = [family for family in args.family.split(",") if family]
    if unknown := set(wanted) - set(FAMILIES):
        parser.error(f"unknown families {sorted(unknown)}; valid: {', '.join(FAMILIES)}")
    started, p_star, delta = time.perf_counter(), args.target_precision, args.delta
    print(f"# Label plan: predicted vs achieved, p* = {p_star:g}, delta = {delta:g}\n")
    print(
        f"{args.reps} labelled draws per population and L, {args.plan_draws} simulations per plan; achieved on "
        f"{args.draws} fresh draws per population and n. Recall = accepted correct / answerable.\n"
    )
    print("| population | L | n | P(certified) predicted | achieved | mean recall predicted | achieved |")
    print("|---|---|---|---|---|---|---|")
    tasks = [(i, name, found, args) for i, (name, found) in enumerate(family_populations(Path(data), wanted).items())]
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        outputs = list(pool.map(plan_population, tasks))
    pairs: dict[tuple[int, int], list[tuple[float, float, float, float]]] = {}
    for lines, found in outputs:
        print("\n".join(lines))
        for key, rows in found.items():
            pairs.setdefault(key, []).extend(rows)
    print(
        "\n| L | n | P(certified) predicted / achieved (mean) | abs error: mean / largest | within +-0.15 | "
        "mean recall predicted / achieved | abs error: mean / largest |"
    )
    print("|---|---|---|---|---|---|---|")
    for (labelled, n), rows in sorted(pairs.items()):
        predicted, truth_c, recall, truth_r = np.array(rows).T
        cert, rec = np.abs(predicted - truth_c), np.abs(recall - truth_r)
        print(
            f"| {labelled} | {n} | {predicted.mean():.2f} / {truth_c.mean():.2f} | "
            f"{cert.mean():.3f} / {cert.max():.2f} | {np.mean(cert <= TOLERANCE):.2f} | "
            f"{recall.mean():.3f} / {truth_r.mean():.3f} | {rec.mean():.3f} / {rec.max():.3f} |"
        )
    scores_table(pairs)
    print(f"\n{time.perf_counter() - started:.0f} s")


def scores_table(pairs: dict[tuple[int, int], list[tuple[float, float, float, float]]]) -> None:
    """Print the Brier scores (plans vs the oracle constant) per L and n and the reliability bins per L."""
    print("\n| L | n | Brier score: plans | Brier score: oracle constant (mean achieved, unavailable to a user) |")
    print("|---|---|---|---|")
    plans, constant = [], []
    for (labelled, n), rows in sorted(pairs.items()):
        predicted, truth = np.array(rows).T[:2]
        plans.append(np.mean((predicted - truth) ** 2))
        constant.append(np.mean((truth.mean() - truth) ** 2))
        print(f"| {labelled} | {n} | {plans[-1]:.4f} | {constant[-1]:.4f} |")
    print(f"| all | all | {np.mean(plans):.4f} (mean) | {np.mean(constant):.4f} (mean) |")
    names = [f"{low:.2f}-{high:.2f}" for low, high in itertools.pairwise(BINS)]
    print(f"\n| L | {' | '.join(f'predicted {name}: plans, mean predicted / achieved' for name in names)} |")
    print(f"|---|{'---|' * len(names)}")
    for labelled in sorted({labelled for labelled, _ in pairs}):
        predicted, truth = np.concatenate(
            [np.array(rows).T[:2] for (ell, _), rows in pairs.items() if ell == labelled], 1
        )
        cells = []
        for low, high in itertools.pairwise(BINS):
            inside = (predicted >= low) & ((predicted < high) | (high == BINS[-1]))
            found = f"{predicted[inside].mean():.2f} / {truth[inside].mean():.2f}" if inside.any() else "-"
            cells.append(f"{int(inside.sum())}, {found}")
        print(f"| {labelled} | {' | '.join(cells)} |")


if __name__ == "__main__":
    main()
