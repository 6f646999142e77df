"""``vpr-uncertainty calibrate``: fit P(correct) and a gate with a precision guarantee on labelled queries."""

from __future__ import annotations

import argparse
import copy
import os
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.cache import array_digest
from vpr_uncertainty.calibration.labels_file import pool_fingerprint
from vpr_uncertainty.data import DEFAULT_TOP_K, read_pool, read_results
from vpr_uncertainty.pipeline.options import (
    add_figure_width_option,
    add_results_options,
    candidate_count,
    command_wording,
    open_fraction,
    output_file,
)
from vpr_uncertainty.retrieval import Retrieval


def _rankings(text: str) -> tuple[str, ...] | dict[str, float]:
    """``SU,CAL`` (δ shared evenly) or ``CAL=0.9,margin=0.1`` (each name's share of δ)."""
    parts = [part.strip() for part in text.split(",") if part.strip()]
    if not parts:
        raise argparse.ArgumentTypeError(f"expected comma-separated names, got {text!r}")
    if not any("=" in part for part in parts):
        return tuple(parts)
    try:
        pairs = [(name.strip(), float(share)) for name, share in (part.split("=") for part in parts)]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected NAME,NAME,... or NAME=SHARE,NAME=SHARE,... (every name with its share), got {text!r}"
        ) from None
    if len(shares := dict(pairs)) < len(pairs):
        raise argparse.ArgumentTypeError(f"a ranking is named twice in {text!r}; give each name one share")
    return shares


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``calibrate`` command."""
    parser = subparsers.add_parser(
        "calibrate",
        help="fit P(correct top-1) and an acceptance threshold with a precision guarantee (a gate file)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Fit a calibrated probability that the top-1 answer is correct on labelled calibration queries, and,\n"
            "with --target-precision p*, choose the acceptance threshold by Learn-then-Test: with probability at\n"
            "least 1 - delta over the draw of the calibration queries, the precision of accepted answers on new\n"
            "queries from the same distribution is at least p*. The gate is written as JSON (no pickle); use it\n"
            "with Gate.load in Python, or as the uncertainty method CAL:gate=GATE.json in evaluate.\n\n"
            "Every label is used: each candidate ranking (--rankings; by default, by the number n of labelled\n"
            "queries: SU alone at the whole delta below 132 (6 x the 22 that p* 0.9, delta 0.1 need at least),\n"
            "SU and the cross-fitted model CAL at delta/2 each below 176, then CAL at 0.9 delta and the margin at\n"
            "0.1 delta) is tested on all labelled queries, at cuts fixed from the scores alone\n"
            "(quantiles over the labelled and --unlabelled queries), by a chain that one early wrong answer cannot\n"
            "end. Without --target-precision the gate accepts P >= 0.5 and certifies nothing.\n\n"
            "--plan answers, before more labelling, how many labelled queries would certify the target: SCORES holds\n"
            "the few labelled queries so far (at least 2 correct and 2 wrong), --unlabelled the queries not yet\n"
            "labelled. The pool (labelled + unlabelled queries) is the population: each of 100 simulations labels\n"
            "every unlabelled query like its 3 nearest labelled ones (their rates drawn from a posterior), draws n\n"
            "queries from the pool (the same draws for every n) and runs this command's defaults on them. Per n\n"
            "it prints the share of simulations that certify p* and the mean recall (accepted correct /\n"
            "answerable), each with a 95% interval; n never exceeds the pool, and the answer says so when the\n"
            "pool is too small.\n\n"
            "SCORES is read as by `evaluate` (retrieval.npz, a similarity matrix .npy, VPR-Bench matches)."
        ),
        epilog=(
            "example:\n  vpr-uncertainty calibrate \\\n"
            "      precomputed_matches/corridor/AMOSNet/precomputed_data_corrected.npy \\\n"
            "      --gt corridor/ground_truth_new.npy --out gate.json --target-precision 0.9 --plot reliability.png\n"
            "  vpr-uncertainty calibrate few_labelled.npz --unlabelled all_queries.npz --target-precision 0.9 --plan"
        ),
    )
    parser.add_argument("scores", type=Path, metavar="SCORES", help="labelled calibration results")
    add_results_options(parser, "SCORES (and --unlabelled)")
    parser.add_argument(
        "--out", type=output_file, metavar="GATE.json", help="gate file to write (required unless --plan)"
    )
    parser.add_argument("--target-precision", type=open_fraction, metavar="P", help="precision to certify, in (0, 1)")
    parser.add_argument("--delta", type=open_fraction, default=0.1, help="risk of the guarantee (default 0.1)")
    parser.add_argument("--k", type=candidate_count, default=10, help="candidates per query (default 10)")
    parser.add_argument("--model", choices=("logistic", "isotonic"), default="logistic", help="calibrator")
    parser.add_argument("--seed", type=int, default=0, help="seed of the cross-fitting folds (default 0)")
    parser.add_argument(
        "--unlabelled",
        type=Path,
        metavar="RESULTS",
        help="queries without labels (read like SCORES, ground truth not needed): the cuts are quantiles over them "
        "and the labelled ones; with --plan, the queries that could be labelled next",
    )
    parser.add_argument(
        "--rankings",
        type=_rankings,
        metavar="NAMES",
        help="candidate rankings of the certified threshold, comma-separated, from SU, RS, SD, BM, margin, PA, CAL: "
        "names share delta evenly, NAME=SHARE,... gives each its share (default: by the number of labels, see above; "
        "--sequential: SU, margin at delta/2)",
    )
    parser.add_argument(
        "--plan",
        action="store_true",
        help="simulate how often 25, 50, 100, ... labelled queries (up to the pool) certify --target-precision, "
        "and at what recall; writes no gate",
    )
    parser.add_argument(
        "--sequential",
        type=Path,
        metavar="LABELS.csv",
        help="label one query at a time: SCORES is the unlabelled pool, LABELS.csv (query,correct rows; created "
        "when missing; its first line names the pool's fingerprint, and labels of another pool are refused) the "
        "labels so far; prints whether --target-precision is certified and the query to label "
        "next (append its row and rerun), and writes --out once certified. With --gt the queries asked for are "
        "labelled from the ground truth (a simulation of how many labels it takes)",
    )
    parser.add_argument("--machine-labels", type=Path, metavar="MACHINE.csv", help="see --audit (written by label)")
    parser.add_argument(
        "--audit",
        type=Path,
        metavar="AUDIT.csv",
        help="certify by audit: the --machine-labels of SCORES choose the ranking and cuts; AUDIT.csv (query,correct "
        "rows, created when missing) holds a person's labels of --audit-size queries drawn at random (--seed) from "
        "the most lenient cut; prints the status and the query to label next (append its row and rerun); --out "
        "writes the certified gate, or a machine-labelled one before. --gt: labelled from the ground truth",
    )
    parser.add_argument("--audit-size", type=candidate_count, default=40, help="draws of the audit (default 40)")
    parser.add_argument(
        "--images",
        type=Path,
        metavar="DIR",
        help="--sequential, --audit: the dataset folder (query/ "
        "and ref/, as in verify): the query to label next is named by its image pair",
    )
    parser.add_argument(
        "--contact-sheet",
        type=output_file,
        metavar="FILE.png",
        help="--sequential, --audit with --images: draw the next --sheet-size queries to label, each beside its top-1",
    )
    parser.add_argument("--sheet-size", type=candidate_count, default=8, help="pairs of --contact-sheet (default 8)")
    parser.add_argument("--plot", type=output_file, metavar="FILE", help="write the reliability diagram")
    add_figure_width_option(parser)
    parser.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    from vpr_uncertainty.calibration import calibrate
    from vpr_uncertainty.calibration.quality import brier_score, expected_calibration_error, reliability_diagram
    from vpr_uncertainty.evaluation import correct_at_n

    if args.plan and (args.sequential or args.audit or args.machine_labels):
        raise ValueError("--plan simulates labelling before it starts; --sequential and --audit label: use one")
    if (args.contact_sheet and not args.images) or (args.images and not (args.sequential or args.audit)):
        raise ValueError(
            "--images DIR and --contact-sheet FILE show the queries to label (--sequential, --audit); "
            "--contact-sheet needs --images"
        )
    if args.sequential is not None and args.audit is None:
        return _run_sequential(args)
    if args.audit is not None or args.machine_labels is not None:
        return _run_audit(args)
    if args.plan and args.target_precision is None:
        raise ValueError("--plan needs --target-precision P: the plan says how many labels certify that precision")
    if not args.plan and args.out is None:
        raise ValueError("--out GATE.json is required (unless --plan)")
    with command_wording(ground_truth="--gt GT"):
        retrieval = read_results(args.scores, ground_truth=args.gt, **_reading(args))
        _explain_no_correct_answer(args.scores, retrieval)
        unlabelled = None if args.unlabelled is None else read_pool(args.unlabelled, **_reading(args)).scores
        if args.plan:
            return _run_plan(args, retrieval, unlabelled)
        gate = calibrate(
            retrieval,
            target_precision=args.target_precision,
            delta=args.delta,
            k=args.k,
            seed=args.seed,
            model=args.model,
            rankings=args.rankings,
            unlabelled=unlabelled,
        )
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    probability = gate.probability_correct(retrieval.scores[:, : gate.k])
    if args.plot:  # first: a plot that fails leaves an existing gate file as it was
        from vpr_uncertainty.reports.display import plot_reliability

        plot_reliability(
            reliability_diagram(probability, correct),
            args.plot,
            title="in-sample reliability",
            width=args.figure_width,
            threshold=gate.threshold,
        )
    gate.save(args.out)
    calibration = gate.info["calibration"]
    print(
        f"{args.scores}: {calibration['n_queries']} calibration queries, {calibration['n_correct']} correct; "
        f"calibrator {gate.calibrator.model} on {', '.join(gate.calibrator.features)} (k={gate.k})"
    )
    print(
        f"in-sample calibration: ECE {expected_calibration_error(probability, correct):.3f}, "
        f"Brier {brier_score(probability, correct):.3f} (held-out figures: evaluate --calibration-fraction)"
    )
    if args.target_precision is None:
        print(f"{gate.acceptance} (no target precision: nothing certified)")
    else:
        print(gate.info["certificate"]["message"])
        if gate.precision_lower_bound is not None:
            print(
                f"{gate.acceptance}; certified precision lower bound "
                f"{gate.precision_lower_bound:.3f}; expected recall {gate.expected_recall:.3f}, "
                f"coverage {gate.expected_coverage:.3f} (on the labelled queries)"
            )
        else:
            print("the gate accepts nothing")
    print(f"wrote {args.out}")
    if args.plot:
        print(f"wrote {args.plot}")
    return 0


def _reading(args: argparse.Namespace) -> dict[str, Any]:
    """How SCORES (and --unlabelled) are read: --format, --scores and the candidates --k needs."""
    return {"file_format": args.format, "top_k": max(DEFAULT_TOP_K, args.k), "scores": args.score_kind}


def _explain_no_correct_answer(path: Path, retrieval: Retrieval) -> None:
    """When no labelled top-1 answer is correct, a ValueError with the evaluation's notes on why (distances read as
    similarities: the scores rank the ground truth backwards, and the kind such distances would be)."""
    from vpr_uncertainty.evaluation import correct_at_n, evaluate

    correct = None if retrieval.positives is None else correct_at_n(retrieval.indices, retrieval.positives)
    if correct is None or not correct.size or correct.any():
        return
    with warnings.catch_warnings(record=True) as caught:  # the notes go in the error, not in warnings as well
        warnings.simplefilter("always")
        notes = evaluate(retrieval, methods=["BM"], k=2).notes
    undefined = {str(warning.message) for warning in caught if issubclass(warning.category, RuntimeWarning)}
    if reasons := [note for note in notes if note not in undefined]:  # not "AUC-PR is undefined": none is computed
        raise ValueError(f"{path}: no calibration query's top-1 answer is correct: {'; '.join(reasons)}")


def _pool(args: argparse.Namespace) -> tuple[Retrieval, np.ndarray | None, str, tuple[list[Path], list[Path]] | None]:
    """SCORES as a pool (read as `label` reads it), with --gt whether each top-1 is correct, its description and,
    with --images, its image files (query i, database image j); an output that is an input is refused first."""
    from vpr_uncertainty._files import refuse_shared_files
    from vpr_uncertainty.data.images import retrieval_image_paths
    from vpr_uncertainty.evaluation import correct_at_n

    inputs = {"SCORES": args.scores, "--machine-labels": args.machine_labels, "--gt": args.gt}
    refuse_shared_files(
        inputs,
        {
            "--sequential": args.sequential,
            "--audit": args.audit,
            "--out": args.out,
            "--contact-sheet": args.contact_sheet,
        },
    )
    with command_wording(ground_truth="--gt GT"):
        pool = read_pool(args.scores, ground_truth=args.gt, **_reading(args))
    truth = None if args.gt is None else correct_at_n(pool.indices, pool.positives, 1)
    images = None if args.images is None else retrieval_image_paths(pool, images=args.images)
    return pool, truth, f"{' '.join(str(args.scores).split())}: {pool.n_queries} queries, k={args.k}", images


def _run_plan(args: argparse.Namespace, retrieval: Retrieval, unlabelled: np.ndarray | None) -> int:
    from vpr_uncertainty.calibration.plan import plan_labels
    from vpr_uncertainty.evaluation.metrics import answerable_queries, correct_at_n

    if retrieval.positives is None:
        raise ValueError("--plan needs the labels of the few labelled queries in SCORES (--gt GT)")
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    plan = plan_labels(
        retrieval.scores,
        correct,
        target_precision=args.target_precision,
        unlabelled=unlabelled,
        answerable=answerable_queries(retrieval.positives),
        delta=args.delta,
        k=args.k,
        seed=args.seed,
    )
    print(
        f"{args.scores}: {plan.n_labelled} labelled queries ({int(correct.sum())} correct); a pool of "
        f"{plan.pool_size} queries to label from; p* = {args.target_precision:g}, delta = {args.delta:g}"
    )
    print(plan.table())
    print(plan.message)
    for note in plan.notes:
        print(f"note: {note}")
    if unlabelled is None:
        print("note: the pool is SCORES alone; pass the queries not yet labelled with --unlabelled RESULTS")
    return 0


def _run_sequential(args: argparse.Namespace) -> int:
    from vpr_uncertainty.calibration import SequentialCalibration
    from vpr_uncertainty.calibration.labels_file import read_labels, write_labels

    if args.target_precision is None:
        raise ValueError("--sequential needs --target-precision P: it labels until that precision is certified")
    retrieval, truth, about, images = _pool(args)
    scores, rankings = retrieval.scores, args.rankings or ("SU", "margin")
    session = SequentialCalibration(
        scores, target_precision=args.target_precision, delta=args.delta, k=args.k, rankings=rankings
    )
    pool = session.fingerprint
    read = read_labels(args.sequential, n_queries=len(scores), pool=pool, about=about)
    for query, correct in read.labels:
        session.add_label(query, correct)
    new: list[tuple[int, bool]] = []
    while truth is not None and (query := session.next_query()) is not None:
        session.add_label(query, bool(truth[query]))
        new.append((query, bool(truth[query])))
    if truth is not None or read.pool is None:  # a new or adopted file gets its pool line; --gt appends the labels
        write_labels(args.sequential, read, new, pool=pool, about=about)
    if read.text and read.pool is None:
        print(
            f"note: {args.sequential} carried no pool fingerprint: adopted for pool {pool} ({about}), on its first line"
        )
    if truth is not None:
        print(
            f"labelled {len(read.labels) + len(new)} of {len(scores)} queries from {args.gt} in the order asked; "
            f"wrote {args.sequential}"
        )
    status = session.status()
    print(f"{args.scores}: {status.labelled} of {len(scores)} queries labelled; {status.message}")
    _ask(args, session, retrieval, images, args.sequential)
    if status.certified and args.out is not None:
        (gate := session.gate()).save(args.out)
        print(f"{gate.acceptance}; wrote {args.out}")
    return 0


def _run_audit(args: argparse.Namespace) -> int:
    from vpr_uncertainty.calibration.audit import AuditCalibration
    from vpr_uncertainty.calibration.labels_file import read_labels, read_machine_labels, write_labels

    if None in (args.machine_labels, args.audit, args.target_precision) or args.sequential or args.plan:
        raise ValueError("certify by audit: --machine-labels MACHINE.csv --audit AUDIT.csv --target-precision P")
    retrieval, truth, about, images = _pool(args)
    n, pool = retrieval.n_queries, pool_fingerprint(retrieval.scores, args.k)
    machine = read_machine_labels(args.machine_labels, n_queries=n, pool=pool, about=about)
    options = dict(delta=args.delta, k=args.k, seed=args.seed, audit_size=args.audit_size)
    options |= {"rankings": args.rankings} if args.rankings else {}
    session = AuditCalibration(retrieval.scores, machine, target_precision=args.target_precision, **options)
    read = read_labels(args.audit, n_queries=n, pool=pool, about=about)
    design = f"seed {args.seed}, {args.audit_size} draws, p* {args.target_precision:g}, delta {args.delta:g}, "
    named = args.rankings.items() if isinstance(args.rankings, dict) else ()
    shown = [f"{name}={share:g}" for name, share in named] or args.rankings or ["default"]
    design += f"rankings {','.join(shown)}, machine labels {array_digest(machine.correct)[:16]}"
    if (found := re.search(r"^# vpr-uncertainty audit: (.*)$", read.text, re.MULTILINE)) and found[1] != design:
        why = "its draws were fixed before its first label, and drawing again after labelling voids the guarantee"
        raise ValueError(f"{args.audit} is the audit of {found[1]}, not of {design}: {why}; start another audit file")
    if not found:  # the design, on a line of its own, before the first label
        text = read.text + ("\n" if read.text[-1:] not in ("", "\n") else "") + f"# vpr-uncertainty audit: {design}\n"
        read = read._replace(text=text + ("" if read.text.strip() else "query,correct\n"))
    for query, correct in [*read.labels, *(new := [])]:
        session.add_label(query, correct)
    while truth is not None and (query := session.next_query()) is not None:
        new.append((query, bool(truth[query])))
        session.add_label(*new[-1])
    if new or not found:
        write_labels(args.audit, read, new, pool=pool, about=about)
    status, gt = session.status(), f" (labelled from {args.gt}: a simulation)" if truth is not None else ""
    print(f"{args.scores}: {status.labelled} of the audit's {args.audit_size} draws labelled{gt}; {status.message}")
    _ask(args, session, retrieval, images, args.audit)
    if args.out is not None:
        (gate := session.gate()).save(args.out)
        certificate = "" if status.certified else gate.info["certificate"]["message"] + "; "
        print(f"{certificate}{gate.acceptance}; wrote {args.out}")
    return 0


def _ask(args: argparse.Namespace, session: Any, retrieval: Retrieval, images: Any, labels: Path) -> None:
    """Print the query to label next, named by its image pair where known (the files of --images, else the
    results' image names), and draw --contact-sheet: the next --sheet-size pairs (query | top-1), in that order."""
    probe, queries = copy.deepcopy(session), []  # the next ones if each is labelled correct
    while len(queries) < (args.sheet_size if args.contact_sheet else 1) and (query := probe.next_query()) is not None:
        queries.append(query)
        probe.add_label(query, True)
    if not queries:
        return print(f"no query is left to label: {args.contact_sheet} not written") if args.contact_sheet else None
    shown = [[os.path.relpath(path, args.images) for path in side] for side in images] if images else None
    names = shown or (retrieval.query_names, retrieval.database_names)
    query, top = queries[0], retrieval.indices[queries[0], 0]
    pair = "" if names[0] is None or names[1] is None else f" ({names[0][query]} -> {names[1][top]})"
    answer = f"append '{query},1' if its top-1 answer is correct, else '{query},0', to {labels}, and rerun"
    print(f"label next: query {query}{pair} ({answer})")
    if not pair:
        print("note: the results name no image files: --images DIR (the dataset folder) shows the pair to label")
    if not args.contact_sheet:
        return None
    from vpr_uncertainty.cache import write_figure
    from vpr_uncertainty.reports.style import pyplot

    plt = pyplot()
    figure, axes = plt.subplots(len(queries), 2, figsize=(6, 2.4 * len(queries)), squeeze=False, layout="constrained")
    for row, query, top in zip(axes, queries, retrieval.indices[queries, 0], strict=True):
        row[0].set_title(f"query {query}\n{names[0][query]}")
        row[1].set_title(f"its top-1, similarity {retrieval.scores[query, 0]:.3f}\n{names[1][top]}")
        for axis, file in zip(row, (images[0][query], images[1][top]), strict=True):
            axis.imshow(plt.imread(file), cmap="gray")
            axis.set(xticks=[], yticks=[])
    figure.suptitle(f"the next {len(queries)} queries to label, in order (a wrong answer may change it)")
    write_figure(figure, args.contact_sheet, dpi=150)
    plt.close(figure)
    return print(f"wrote {args.contact_sheet}: the next {len(queries)} queries to label, each beside its top-1")
