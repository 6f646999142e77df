"""Certify by audit (issue 43): machine labels choose the rule, a random audit of at most 40 human labels certifies it.

Tables (p* = 0.9, δ = 0.1, audit size 40 unless said; every audit label is read from the ground truth):

* ``corridor``: the ten VPR-Bench corridor methods (111 queries each), one audit per seed, with machine labels by
  agreement: the top-1 is labelled correct when at least 3 of the 9 other methods return the same database image (as
  the ``agreement`` labeler does without positions), or one within ±2 frames (the positives' tolerance; as it does
  with positions). Columns: the labeler against the ground truth (false-correct = wrong answers among those it
  labels correct; recall; wrong = labels that differ from the truth), the ranking and lenient cut M the machine
  chose, P(certified), recall ÷ the hindsight SU oracle (accepted-correct of the most lenient SU cut whose precision
  on the pool is ≥ p*; 0 when nothing is certified), violations (a certified cut whose precision on the pool is
  < p*), labels used, and the design the issue first proposed on the same selection (draws with replacement, exact
  binomial test: :func:`binomial_audit`).
* ``populations``: pools of ``--pool`` queries drawn i.i.d. from each corridor method, with labelers that are wrong
  10–30 % of the time (``flip r``: each label flipped with probability r; ``optimist r``: each wrong answer labelled
  correct with probability r) or the same-image agreement labels carried with the queries, and a person who labels
  until the tool stops, stops at a random time (uniform in 0..40 labels) or stops at the first certificate.
  Violations are counted against the pool (what is guaranteed) and against the method's 111 queries (the
  distribution the pool was drawn from: not guaranteed).
* ``needed``: how many labels the audit uses and how often it certifies as the true precision of the machine's
  lenient cut varies from 0.92 to 1.0, by audit size: pools of 600 (and 111) queries with random scores, machine
  labels that make the lenient cut accept about 400 (75) of them, and wrong answers placed at random among those,
  uniformly or with a density rising linearly with the rank.

Usage: ``VPR_UNCERTAINTY_DATA=... python benchmarks/audit_evidence.py [--table all] [--seeds 100]``
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from vpr_uncertainty.calibration.audit import AuditCalibration
from vpr_uncertainty.calibration.calibrator import RANKINGS, feature_columns
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation import correct_at_n

P_STAR, DELTA = 0.9, 0.1


def corridor() -> dict[str, dict[str, np.ndarray]]:
    """Per method: scores (111, K), correct (111,), answerable (111,), machine (111,): 3-of-9 agreement."""
    root = Path(os.environ["VPR_UNCERTAINTY_DATA"]) / "vprbench"
    found = {}
    for folder in sorted(p for p in (root / "precomputed_matches" / "corridor").iterdir() if p.is_dir()):
        retrieval = read_results(
            folder / "precomputed_data_corrected.npy", ground_truth=root / "corridor/ground_truth_new.npy"
        )
        found[folder.name] = {
            "scores": np.asarray(retrieval.scores),
            "top": np.asarray(retrieval.indices)[:, 0],
            "correct": correct_at_n(retrieval.indices, retrieval.positives, 1),
            "answerable": np.asarray(retrieval.positives.sum(axis=1)).ravel() > 0,
        }
    for name, method in found.items():
        others = np.stack([other["top"] for key, other in found.items() if key != name])
        method["machine"] = (others == method["top"]).sum(axis=0) >= 3
        method["frames"] = (np.abs(others - method["top"]) <= 2).sum(axis=0) >= 3  # the positives' ±2 frames
    return found


def oracle(scores: np.ndarray, correct: np.ndarray) -> int:
    """Accepted-correct of the most lenient SU cut (between distinct values) whose precision is ≥ p*."""
    su = RANKINGS["SU"][1] * feature_columns(scores, 10, required=("SU",))["SU"]
    order = np.argsort(-su, kind="stable")
    ends = np.flatnonzero(np.append(su[order][:-1] > su[order][1:], True))
    hits = np.cumsum(correct[order])[ends]
    good = hits / (ends + 1) >= P_STAR
    return int(hits[good].max()) if good.any() else 0


def audit(scores, machine, truth, *, seed, size=40, stop=None):
    """One audit labelled from ``truth`` until the tool stops or the person does (``stop``: "first" or a label
    count). Returns (certified, accepted (N,) bool, labels used, the gate or None)."""
    session = AuditCalibration(scores, machine, target_precision=P_STAR, delta=DELTA, seed=seed, audit_size=size)
    status = session.status()
    while (query := session.next_query()) is not None:
        if (stop == "first" and status.certified) or (isinstance(stop, int) and status.labelled >= stop):
            break
        status = session.add_label(query, bool(truth[query]))
    if not status.certified:
        return False, np.zeros(len(truth), bool), status.labelled, None
    gate = session.gate()
    return True, gate.accept(np.asarray(scores)[:, : gate.k]), status.labelled, gate


def binomial_audit(session: AuditCalibration, truth: np.ndarray, seed: int, size: int = 40) -> tuple[int, int]:
    """The design the issue first proposed, on the same selection: ``size`` draws *with* replacement from the lenient
    cut, the exact binomial test of each candidate from the strictest that receives min_accepted draws with
    probability ≥ START, every draw labelled (a query drawn twice is labelled once). Returns (certified size,
    labels used until the sequence ends)."""
    from scipy import stats

    from vpr_uncertainty.calibration.audit import START
    from vpr_uncertainty.calibration.guarantee import min_accepted

    if session.ranking is None:
        return 0, 0
    ranked, lenient = session._confidence[session._order], session.lenient
    cuts = np.flatnonzero(np.append(ranked[:-1] > ranked[1:], True))[:lenient] + 1
    cuts = cuts[cuts <= lenient]
    first = min_accepted(P_STAR, DELTA)
    cuts = cuts[stats.binom.sf(first - 1, size, cuts / lenient) >= START]
    draws = np.sort(np.random.default_rng(seed).integers(0, lenient, size))
    inside = np.searchsorted(draws, cuts)
    wrong = np.concatenate([[0], np.cumsum(~truth[session._order[draws]])])[inside]
    allowed = np.where(inside > 0, inside - (stats.binom.isf(DELTA, np.maximum(inside, 1), P_STAR) + 1), -1)
    failed = np.flatnonzero(wrong > allowed)
    passed = failed[0] if failed.size else cuts.size
    read = inside[failed[0]] if failed.size else size
    return (int(cuts[passed - 1]) if passed else 0), int(np.unique(draws[:read]).size)


def quality(machine: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    """(false-correct share of the labels "correct", recall of the correct answers, share of labels that differ)."""
    return (
        float((machine & ~truth).sum() / max(machine.sum(), 1)),
        float((machine & truth).sum() / max(truth.sum(), 1)),
        float((machine != truth).mean()),
    )


def corridor_table(data, seeds: int, key: str) -> None:
    what = {"machine": "the same image", "frames": "an image within the positives' ±2 frames"}[key]
    print(f"\n## Corridor, agreement labels (3 of the 9 others return {what}), audit 40, {seeds} seeds\n")
    print(
        "| method | false-correct | labeler recall | labels wrong | ranking | M | SU oracle (correct) | P(certified) "
        "| recall ÷ oracle | violations | labels used (mean, max) | with replacement, binomial: P, recall, labels |"
    )
    print("|---" * 12 + "|")
    rows = []
    for name, m in data.items():
        best = oracle(m["scores"], m["correct"])
        runs = [audit(m["scores"], m[key], m["correct"], seed=s) for s in range(seeds)]
        first = AuditCalibration(m["scores"], m[key], target_precision=P_STAR, delta=DELTA)
        certified = np.array([r[0] for r in runs])
        recall = np.array([(r[1] & m["correct"]).sum() / max(best, 1) for r in runs])
        violation = np.array([r[0] and m["correct"][r[1]].mean() < P_STAR for r in runs])
        labels = np.array([r[2] for r in runs])
        fc, rec, wrong = quality(m[key], m["correct"])
        rows.append(
            (wrong, certified.mean(), recall.mean(), violation.mean(), labels.mean(), recall.mean() * best, best)
        )
        binomial = np.array([binomial_audit(first, m["correct"], s) for s in range(seeds)])
        order = first._order if first.ranking else np.arange(0)
        binomial_recall = np.mean([m["correct"][order[:c]].sum() / max(best, 1) for c in binomial[:, 0]])
        print(
            f"| {name} | {fc:.3f} | {rec:.2f} | {wrong:.2f} | {first.ranking} | {first.lenient} | {best} | "
            f"{certified.mean():.2f} | {recall.mean():.2f} | {violation.mean():.3f} | {labels.mean():.1f}, "
            f"{labels.max()} | {(binomial[:, 0] > 0).mean():.2f}, {binomial_recall:.2f}, {binomial[:, 1].mean():.1f} |"
        )
    rows = np.array(rows)
    good = rows[:, 0] <= 0.05
    for label, pick in (("all ten", rows[:, 0] >= 0), (f"labels wrong ≤ 5 % ({good.sum()})", good)):
        if pick.any():
            mean, ratio = rows[pick].mean(axis=0), rows[pick, 5].sum() / rows[pick, 6].sum()
            print(
                f"| **mean, {label}** | | | | | | | {mean[1]:.2f} | {mean[2]:.2f} (ratio of means {ratio:.2f}) | "
                f"{mean[3]:.3f} | {mean[4]:.1f} |"
            )


def _labeler(kind: str, truth: np.ndarray, carried: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    name, _, rate = kind.partition(" ")
    if name == "agreement":
        return carried
    if name == "flip":
        return truth ^ (rng.random(truth.size) < float(rate))
    return truth | (rng.random(truth.size) < float(rate))  # optimist: wrong answers labelled correct


def populations_table(data, pools: int, pool: int) -> None:
    labelers = ["agreement", "flip 0.05", "flip 0.1", "flip 0.2", "flip 0.3", "optimist 0.1", "optimist 0.3"]
    stops = [None, "random", "first"]
    print(f"\n## Resampled populations: {pools} pools of {pool} queries per method and labeler, audit 40\n")
    print(
        "| labeler | person | labels wrong | P(certified) | recall ÷ oracle (mean of methods) | ratio of means | "
        "violations (pool) | max over methods | violations (distribution) | labels used | with replacement, "
        "binomial: P(certified), ratio of means |"
    )
    print("|---" * 11 + "|")
    pooled = []
    for kind in labelers:
        for stop in stops:
            rows = []
            for index, m in enumerate(data.values()):
                rng = np.random.default_rng([index, labelers.index(kind)])
                runs = []
                for draw in range(pools):
                    rows_ = rng.integers(0, len(m["correct"]), pool)
                    scores, truth = m["scores"][rows_], m["correct"][rows_]
                    machine = _labeler(kind, truth, m["machine"][rows_], rng)
                    when = int(rng.integers(0, 41)) if stop == "random" else stop
                    certified, accepted, used, gate = audit(scores, machine, truth, seed=draw, stop=when)
                    everywhere = gate.accept(m["scores"][:, : gate.k]) if certified else accepted[:0]
                    best, binomial = oracle(scores, truth), (0, 0)
                    if stop is None:  # the first design on the same selection, for comparison
                        session = AuditCalibration(scores, machine, target_precision=P_STAR, delta=DELTA, seed=draw)
                        size, _ = binomial_audit(session, truth, draw)
                        binomial = (size > 0, truth[session._order[:size]].sum() if size else 0)
                    runs.append(
                        (
                            certified,
                            (accepted & truth).sum() / max(best, 1),
                            certified and truth[accepted].mean() < P_STAR,
                            certified and m["correct"][everywhere].mean() < P_STAR,
                            used,
                            (machine != truth).mean(),
                            (accepted & truth).sum(),
                            best,
                            *binomial,
                        )
                    )
                rows.append(np.mean(runs, axis=0))
            rows = np.array(rows)
            pooled.append(rows[:, 2])
            mean = rows.mean(axis=0)
            print(
                f"| {kind} | {stop or 'until done'} | {mean[5]:.2f} | {mean[0]:.2f} | {mean[1]:.2f} | "
                f"{mean[6] / mean[7]:.2f} | {mean[2]:.3f} | {rows[:, 2].max():.3f} | {mean[3]:.3f} | {mean[4]:.1f} | "
                + (f"{mean[8]:.2f}, {mean[9] / mean[7]:.2f} |" if stop is None else " |")
            )
    print(f"\npooled violation rate (pool): {np.mean(pooled):.4f} over {len(pooled) * len(data) * pools} audits")


def needed_table(seeds: int) -> None:
    print(f"\n## Labels needed as the lenient cut's true precision varies ({seeds} draws per cell)\n")
    sizes = [20, 40, 60, 80, 120]
    print("| pool, M | wrong answers | true precision | " + " | ".join(f"n = {n}" for n in sizes) + " |")
    print("|---" * (3 + len(sizes)) + "|")
    rng = np.random.default_rng(0)
    for pool, lenient in ((600, 400), (111, 75)):
        scores = -np.sort(-rng.uniform(0.2, 0.9, size=(pool, 10)), axis=1)
        su = -feature_columns(scores, 10, required=("SU",))["SU"]
        order = np.argsort(-su, kind="stable")
        machine = np.zeros(pool, bool)
        machine[order[: int(lenient * 0.95)]] = True  # the machine's estimate reaches p* + slack at `lenient`
        chosen = AuditCalibration(scores, machine, target_precision=P_STAR, delta=DELTA, rankings=["SU"]).lenient
        for spread in ("uniform", "rising"):
            for precision in (0.92, 0.94, 0.96, 0.98, 1.0):
                cells = []
                for n in sizes:
                    runs = []
                    for seed in range(seeds):
                        truth = np.ones(pool, bool)
                        weight = np.ones(chosen) if spread == "uniform" else np.arange(1, chosen + 1.0)
                        wrong = rng.choice(
                            chosen, round((1 - precision) * chosen), replace=False, p=weight / weight.sum()
                        )
                        truth[order[wrong]] = False
                        truth[order[chosen:]] = rng.random(pool - chosen) < 0.5
                        certified, accepted, used, _ = audit(scores, machine, truth, seed=seed, size=n)
                        runs.append(
                            (
                                certified,
                                used,
                                (accepted & truth).sum() / truth[order[:chosen]].sum(),
                                certified and truth[accepted].mean() < P_STAR,
                            )
                        )
                    c, used, recall, violation = np.mean(runs, axis=0)
                    cells.append(
                        f"{c:.2f} / {used:.0f} / {recall:.2f}" + (f" (viol {violation:.2f})" if violation else "")
                    )
                print(f"| {pool}, {chosen} | {spread} | {precision:.2f} | " + " | ".join(cells) + " |")
    print("\ncells: P(certified) / labels used / certified correct ÷ correct in the lenient cut")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--table", choices=("corridor", "populations", "needed", "all"), default="all")
    parser.add_argument("--seeds", type=int, default=100, help="audit seeds on the corridor; draws per cell")
    parser.add_argument("--pools", type=int, default=20, help="resampled pools per method and labeler")
    parser.add_argument("--pool", type=int, default=600, help="queries per resampled pool")
    args = parser.parse_args()
    if args.table in ("corridor", "populations", "all"):
        data = corridor()
    if args.table in ("corridor", "all"):
        corridor_table(data, args.seeds, "machine")
        corridor_table(data, args.seeds, "frames")
    if args.table in ("populations", "all"):
        populations_table(data, args.pools, args.pool)
    if args.table in ("needed", "all"):
        needed_table(args.seeds)


if __name__ == "__main__":
    main()
