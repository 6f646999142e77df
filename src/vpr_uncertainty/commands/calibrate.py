"""``vpr-uncertainty calibrate``: fit P(correct) and a gate with a precision guarantee on labelled queries."""

from __future__ import annotations

import argparse
from pathlib import Path

from vpr_uncertainty.commands._arguments import candidate_count, command_wording, output_file
from vpr_uncertainty.retrieval import INPUT_FORMATS, MATRIX_TOP_K, read_results

__all__ = ["add_parser"]


def _probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}") from None
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must lie strictly between 0 and 1, got {text}")
    return value


def add_parser(subparsers: argparse._SubParsersAction) -> None:
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
            "SCORES is read as by `evaluate` (retrieval.npz, a similarity matrix .npy, VPR-Bench matches)."
        ),
        epilog=(
            "example:\n  vpr-uncertainty calibrate \\\n"
            "      precomputed_matches/corridor/AMOSNet/precomputed_data_corrected.npy \\\n"
            "      --gt corridor/ground_truth_new.npy --out gate.json --target-precision 0.9 --plot reliability.png"
        ),
    )
    parser.add_argument("scores", type=Path, metavar="SCORES", help="labelled calibration results")
    parser.add_argument("--gt", type=Path, help="ground truth (as in evaluate); required unless SCORES holds it")
    parser.add_argument("--format", choices=INPUT_FORMATS, default="auto", help="how to read SCORES")
    parser.add_argument("--out", type=output_file, required=True, metavar="GATE.json", help="gate file to write")
    parser.add_argument("--target-precision", type=_probability, metavar="P", help="precision to certify, in (0, 1)")
    parser.add_argument("--delta", type=_probability, default=0.1, help="risk of the guarantee (default 0.1)")
    parser.add_argument("--k", type=candidate_count, default=10, help="candidates per query (default 10)")
    parser.add_argument("--model", choices=("logistic", "isotonic"), default="logistic", help="calibrator")
    parser.add_argument("--seed", type=int, default=0, help="seed of the fit/test split (default 0)")
    parser.add_argument("--plot", type=output_file, metavar="FILE", help="write the reliability diagram")
    parser.set_defaults(handler=_run_calibrate)


def _run_calibrate(args: argparse.Namespace) -> int:
    from vpr_uncertainty.calibration import calibrate
    from vpr_uncertainty.calibration.quality import brier_score, expected_calibration_error, reliability_diagram
    from vpr_uncertainty.evaluation import correct_at_n

    with command_wording(ground_truth="--gt GT"):
        retrieval = read_results(
            args.scores, ground_truth=args.gt, file_format=args.format, top_k=max(MATRIX_TOP_K, args.k)
        )
        gate = calibrate(
            retrieval,
            target_precision=args.target_precision,
            delta=args.delta,
            k=args.k,
            seed=args.seed,
            model=args.model,
        )
    gate.save(args.out)
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    probability = gate.probability_correct(retrieval.scores)
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
        print(f"threshold P >= {gate.threshold:.3f} (no target precision: nothing certified)")
    else:
        print(gate.info["certificate"]["message"])
        if gate.precision_lower_bound is not None:
            print(
                f"threshold P >= {gate.threshold:.4f}; certified precision lower bound "
                f"{gate.precision_lower_bound:.3f}; expected recall {gate.expected_recall:.3f}, "
                f"coverage {gate.expected_coverage:.3f} (on the test part)"
            )
        else:
            print("the gate accepts nothing")
    print(f"wrote {args.out}")
    if args.plot:
        from vpr_uncertainty.reports.reliability import plot_reliability

        plot_reliability(reliability_diagram(probability, correct), args.plot, title="in-sample reliability")
        print(f"wrote {args.plot}")
    return 0
