"""Random labels only: ``calibrate``'s default against the textbook, on the corridor and on populations built to fail.

Issue 43, "random labels never below the textbook". p* = 0.9 and δ = 0.1 unless given; a draw labels queries
drawn at random, the procedure certifies a rule on them, and the rule is applied to every query of the population,
whose precision and recall are then known exactly.

Families (``--family``, comma-separated; default all)
    ``corridor-30``: the ten VPR-Bench corridor matrices as they are; a draw labels 30 % of the queries (33 of 111)
    drawn without replacement, and the rule is applied to all 111 (the issue's protocol at the corridor's scale).
    ``corridor``: the ten matrices resampled: a draw takes ``--n`` queries (default 182, 30 % of the issue's 607)
    i.i.d. with replacement, so the guarantee is exact with respect to the resampled population.
    ``contrasting``: issue 29's populations (``gate_efficiency.contrasting``: one wrong answer kept among the 20 %
    most confident by SU or the margin, the other ranking clean for its 40 % most confident), resampled likewise.
    ``short``: few labels in the top, one ranking's top clean and the other's not: one wrong answer kept among the
    10 % most confident by SU (or the margin), every wrong answer dropped from the other ranking's 20 % most
    confident only (about 36 of 182 random labels land there).
    ``fitted``: a fitted ranking that fails to certify: one wrong answer kept among the 20 % most confident by the
    logistic model fitted on the whole population (CAL's model and features), every wrong answer dropped from the
    20 % most confident by SU (or the margin).
    A planted population that equals its source, or one without a qualifying wrong answer, is left out.

Procedures (the same draws for all)
    ``calibrate``: ``calibrate_arrays(scores[rows], correct[rows], answerable=answerable[rows],
    target_precision=p*, delta=δ, seed=draw)``, the body of ``calibrate()`` with its defaults; the population's
    accepted answers are ``gate.accept(scores)``.
    ``textbook, SU`` / ``textbook, margin``: the Clopper–Pearson fixed sequence on one ranking fixed before
    labelling (``gate_efficiency.fixed_sequence_cut``): every distinct labelled value, strictest first, from the
    first cut accepting ⌈log δ / log p*⌉ = 22 labelled queries, exact binomial p-values at the full δ, stopping at
    the first p-value above δ.
    ``--candidate LABEL SHARES FALLBACK DENSE``: ``calibrate_arrays`` with ``rankings=SHARES`` (``CAL=0.8,margin=0.2``
    or ``default``) and the chain's fallback share and dense part (``guarantee.cut_chain``) set to FALLBACK and DENSE.

Metrics, per family (95 % intervals from the draws' spread; populations independent)
    recall ÷ oracle: mean recall (accepted correct / answerable) over populations and draws, divided by the mean
    hindsight oracle (the most lenient SU cut whose precision on all queries is ≥ p*); ``mean ratio``: the mean of
    per-population ratios over populations whose oracle is ≥ 0.05. P(certified): share of draws that accept a query.
    Violations: share of draws whose accepted answers have precision < p* on the population, pooled and the worst
    population. ``− textbook``: the paired difference in recall ÷ oracle against each textbook on the same draws,
    and how many populations lie significantly below it (paired 95 % interval below 0).

``--save FILE`` writes every draw's recall, certification and violation; ``--compare FILE`` adds the paired
difference of ``calibrate`` against that file's ``calibrate`` (the same draws: run it at another commit).

Usage
    VPR_UNCERTAINTY_DATA=/path/to/data python benchmarks/random_labels.py [--draws 200] [--family corridor,short]
        [--candidate "CAL .8 + margin .2" CAL=0.8,margin=0.2 0.3 0] [--save run.json] [--compare before.json]
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from gate_efficiency import Population, contrasting, fixed_sequence_cut, load_populations
from vpr_uncertainty.calibration import fit
from vpr_uncertainty.calibration.calibrator import DEFAULT_FEATURES, columns, fit_model

FAMILIES = ("corridor-30", "corridor", "contrasting", "short", "fitted")
_Z = 1.959963984540054


def plant(population: Population, early: np.ndarray, late: np.ndarray, label: str, top: float, clean: float):
    """Keep one wrong answer among the ``top`` share most confident by ``early`` (outside the ``clean`` share of
    ``late``) and drop every other wrong answer from the ``clean`` share most confident by ``late``; None when no wrong
    answer qualifies or nothing changes."""
    n, wrong = population.size, ~population.correct
    rank_early = np.argsort(np.argsort(-early, kind="stable"))
    rank_late = np.argsort(np.argsort(-late, kind="stable"))
    candidates = np.flatnonzero(wrong & (rank_early < top * n) & (rank_late >= clean * n))
    if not candidates.size:
        return None
    keep = ~(wrong & (rank_late < clean * n))
    keep[candidates[np.argmin(rank_early[candidates])]] = True
    if keep.all():
        return None
    rows = np.flatnonzero(keep)
    return Population(
        f"{population.name}, {label}",
        population.scores[rows],
        population.correct[rows],
        population.answerable[rows],
        target_precision=population.target_precision,
    )


def families(corridor: list[Population], wanted: list[str]) -> dict[str, list[Population]]:
    """The populations of each wanted family."""
    found: dict[str, list[Population]] = {}
    for family in wanted:
        made: list[Population | None] = []
        if family in ("corridor-30", "corridor"):
            made = list(corridor)
        elif family == "contrasting":
            made = [contrasting(p, early) for p in corridor for early in ("SU", "margin")]
        for p in corridor if family in ("short", "fitted") else ():
            confidence = {"SU": -p.su, "margin": p.margin}
            if family == "fitted":
                names = tuple(name for name in DEFAULT_FEATURES if name in p.features)
                model = fit_model(columns(p.features, names), p.correct, names)
                confidence["CAL"] = model.confidence(columns(p.features, names))
            pairs = [("SU", "margin"), ("margin", "SU")] if family == "short" else [("CAL", "SU"), ("CAL", "margin")]
            for early, late in pairs:
                label = f"early {early}, {late} clean to 20 %"
                made.append(
                    plant(p, confidence[early], confidence[late], label, 0.2 if family == "fitted" else 0.1, 0.2)
                )
        found[family] = [p for p in made if p is not None]
    return found


def draws_of(population: Population, family: str, n: int, draws: int, seed: int, index: int) -> list[np.ndarray]:
    """Labelled rows per draw: 30 % without replacement (corridor-30) or n with replacement; both outcomes held."""
    rng = np.random.default_rng([seed, FAMILIES.index(family), index])
    size, replace = (round(0.3 * population.size), False) if family == "corridor-30" else (n, True)
    rows = []
    for _ in range(draws):
        pick = rng.choice(population.size, size, replace=replace)
        while population.correct[pick].all() or not population.correct[pick].any():
            pick = rng.choice(population.size, size, replace=replace)
        rows.append(pick)
    return rows


def calibrate_rule(population: Population, rows: np.ndarray, draw: int, p_star: float, delta: float, spec) -> Any:
    """The population's accepted answers under ``calibrate_arrays`` (``spec``: None, or shares, fallback, dense)."""
    original = fit.certify_rankings
    shares = None
    if spec is not None:
        shares, fallback, dense = spec
        fit.certify_rankings = lambda *args, **options: original(
            *args, **{**options, "fallback": fallback, "dense_from": dense}
        )
    try:
        gate = fit.calibrate_arrays(
            population.scores[rows],
            population.correct[rows],
            answerable=population.answerable[rows],
            target_precision=p_star,
            delta=delta,
            seed=draw,
            rankings=shares,
        )
    finally:
        fit.certify_rankings = original
    return np.asarray(gate.accept(population.scores[:, : gate.k]), dtype=bool)


def textbook_rule(population: Population, rows: np.ndarray, uncertainty: np.ndarray, p_star: float, delta: float):
    cut, _ = fixed_sequence_cut(uncertainty[rows], population.correct[rows], p_star, delta)
    return np.zeros(population.size, bool) if cut is None else uncertainty <= cut


def run_population(task: tuple) -> tuple[str, str, float, dict[str, dict[str, list]]]:
    """Every procedure on the same draws of one population: per draw recall, certified, violated."""
    family, index, population, n, draws, seed, p_star, delta, specs = task
    answerable = max(int(population.answerable.sum()), 1)
    procedures = {
        "calibrate": lambda rows, draw: calibrate_rule(population, rows, draw, p_star, delta, None),
        "textbook, SU": lambda rows, draw: textbook_rule(population, rows, population.su, p_star, delta),
        "textbook, margin": lambda rows, draw: textbook_rule(population, rows, -population.margin, p_star, delta),
    }
    for label, spec in specs.items():
        procedures[label] = functools.partial(
            lambda rows, draw, spec: calibrate_rule(population, rows, draw, p_star, delta, spec), spec=spec
        )
    out: dict[str, dict[str, list]] = {name: {"recall": [], "certified": [], "violated": []} for name in procedures}
    for draw, rows in enumerate(draws_of(population, family, n, draws, seed, index)):
        for name, procedure in procedures.items():
            accepted = procedure(rows, draw)
            good, total = int((accepted & population.correct).sum()), int(accepted.sum())
            out[name]["recall"].append(good / answerable)
            out[name]["certified"].append(bool(total))
            out[name]["violated"].append(bool(total) and good < p_star * total - 1e-9)
    return family, population.name, population.oracle, out


def _ratio(recalls: list[np.ndarray], oracles: np.ndarray) -> tuple[float, float]:
    """Pooled recall ÷ oracle and the half-width of its 95 % interval (draws independent, oracles fixed)."""
    mean = np.mean([r.mean() for r in recalls])
    spread = np.sqrt(sum(r.var(ddof=1) / r.size for r in recalls)) / len(recalls)
    return float(mean / oracles.mean()), float(_Z * spread / oracles.mean())


def summarise(family: str, rows: list[tuple[str, float, dict]], baseline: dict | None) -> None:
    """Print one family's table."""
    oracles = np.array([oracle for _, oracle, _ in rows])
    names = list(rows[0][2])
    print(f"\n### {family}: {len(rows)} populations, {len(rows[0][2]['calibrate']['recall'])} draws each\n")
    print(
        "| procedure | recall ÷ oracle [95 %] | mean ratio | P(certified) [95 %] | violations: pooled [95 %] / worst | "
        "− textbook SU [95 %], populations below | − textbook margin [95 %], populations below |"
    )
    print("|---|---|---|---|---|---|---|")
    table = [(name, [np.asarray(r[name]["recall"], float) for _, _, r in rows]) for name in names]
    if baseline is not None:
        old = [np.asarray(baseline[family][population]["calibrate"]["recall"], float) for population, _, _ in rows]
        table.append(("calibrate, --compare file", old))
    for name, recalls in table:
        ratio, half = _ratio(recalls, oracles)
        ratios = [r.mean() / o for r, o in zip(recalls, oracles, strict=True) if o >= 0.05]
        cells = [f"{ratio:.3f} [{ratio - half:.3f}, {ratio + half:.3f}]", f"{np.mean(ratios):.3f}"]
        if name in names:
            certified = np.array([r[name]["certified"] for _, _, r in rows], float)
            violated = np.array([r[name]["violated"] for _, _, r in rows], float)
            c_half, v_half = (
                _Z * np.sqrt((a.var(axis=1, ddof=1) / a.shape[1]).sum()) / len(a) for a in (certified, violated)
            )
            cells.append(f"{certified.mean():.2f} [{certified.mean() - c_half:.2f}, {certified.mean() + c_half:.2f}]")
            cells.append(
                f"{violated.mean():.3f} [{max(violated.mean() - v_half, 0):.3f}, {violated.mean() + v_half:.3f}]"
                f" / {violated.mean(axis=1).max():.2f}"
            )
        else:
            cells += ["", ""]
        for textbook in ("textbook, SU", "textbook, margin"):
            reference = dict(table)[textbook]
            differences = [a - b for a, b in zip(recalls, reference, strict=True)]
            mean, half = _ratio(differences, oracles)
            below = sum(d.mean() + _Z * d.std(ddof=1) / np.sqrt(d.size) < 0 for d in differences)
            cells.append("" if name == textbook else f"{mean:+.3f} [{mean - half:+.3f}, {mean + half:+.3f}], {below}")
        print(f"| {name} | " + " | ".join(cells) + " |")
    if baseline is not None:
        differences = [a - b for a, b in zip(dict(table)["calibrate"], old, strict=True)]
        mean, half = _ratio(differences, oracles)
        below = sum(d.mean() + _Z * d.std(ddof=1) / np.sqrt(d.size) < 0 for d in differences)
        print(
            f"\ncalibrate − the --compare file's calibrate: {mean:+.3f} [{mean - half:+.3f}, {mean + half:+.3f}] "
            f"of the oracle; populations significantly below: {below} of {len(rows)}"
        )


def verbose(family: str, rows: list[tuple[str, float, dict]]) -> None:
    names = list(rows[0][2])
    print(f"\n{family}, per population: oracle, then mean recall ÷ oracle of " + ", ".join(names) + "\n")
    for population, oracle, result in rows:
        cells = " ".join(f"{np.mean(result[name]['recall']) / max(oracle, 1e-9):6.2f}" for name in names)
        print(f"    {population[:48]:48s} {oracle:5.3f} {cells}")


def _shares(text: str) -> dict[str, float] | None:
    if text == "default":
        return None
    return {name: float(value) for name, value in (part.split("=") for part in text.split(","))}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--draws", type=int, default=100, help="draws per population (default 100)")
    parser.add_argument("--n", type=int, default=182, help="labels per draw of the resampled families (default 182)")
    parser.add_argument("--family", default=",".join(FAMILIES), help=f"comma-separated, from {', '.join(FAMILIES)}")
    parser.add_argument("--target-precision", type=float, default=0.9)
    parser.add_argument("--delta", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--candidate", nargs=4, action="append", default=[], metavar=("LABEL", "SHARES", "FALLBACK", "DENSE")
    )
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument("--save", type=Path, help="write every draw's outcome to this JSON file")
    parser.add_argument("--compare", type=Path, help="a --save file of another run with the same options")
    parser.add_argument("--verbose", action="store_true", help="also one line per population")
    args = parser.parse_args(argv)
    data = os.environ.get("VPR_UNCERTAINTY_DATA")
    if not data:
        parser.error("set VPR_UNCERTAINTY_DATA to the data folder (holding vprbench/)")
    wanted = [family for family in args.family.split(",") if family]
    if unknown := set(wanted) - set(FAMILIES):
        parser.error(f"unknown families {sorted(unknown)}; valid: {', '.join(FAMILIES)}")
    specs = {label: (_shares(shares), float(f), float(d)) for label, shares, f, d in args.candidate}
    started, p_star, delta = time.perf_counter(), args.target_precision, args.delta
    corridor = load_populations(Path(data), [], p_star)
    found = families(corridor, wanted)
    tasks = [
        (family, index, population, args.n, args.draws, args.seed, p_star, delta, specs)
        for family, populations in found.items()
        for index, population in enumerate(populations)
    ]
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        results = list(pool.map(run_population, tasks))
    print(f"# Random labels: calibrate's default against the textbook, p* = {p_star:g}, δ = {delta:g}")
    print(f"\nseed {args.seed}; resampled families: n = {args.n} labels with replacement; corridor-30: 30 % without.")
    baseline = json.loads(args.compare.read_text()) if args.compare else None
    saved: dict[str, dict[str, Any]] = {}
    for family in found:
        rows = [(name, oracle, out) for fam, name, oracle, out in results if fam == family]
        summarise(family, rows, baseline)
        if args.verbose:
            verbose(family, rows)
        saved[family] = {name: out for name, _, out in rows}
    print(f"\n{time.perf_counter() - started:.0f} s on {args.jobs} process(es)")
    if args.save:
        args.save.write_text(json.dumps(saved))


if __name__ == "__main__":
    main()
