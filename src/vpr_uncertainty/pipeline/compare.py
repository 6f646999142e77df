"""``compare``: two results files of the same queries (two VPR methods) -> paired tests of every uncertainty method's
AUC-PR and AP, and McNemar's test of recall@1; or two uncertainty methods on one results file. Each file is read and
evaluated as ``evaluate`` does; nothing is cached (see docs/explanation/evaluation.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty._validation import check_resamples
from vpr_uncertainty.data import DEFAULT_TOP_K, read_results
from vpr_uncertainty.evaluation import compare
from vpr_uncertainty.pipeline.evaluate import EvaluateConf, read_inputs
from vpr_uncertainty.pipeline.evaluate import compute as evaluate_compute
from vpr_uncertainty.pipeline.options import (
    add_json_option,
    add_options,
    add_results_options,
    command_wording,
    conf_from_args,
    integer_at_least,
    option,
    write_json,
    write_output,
)


def _pair(text: str) -> tuple[str, str]:
    """``--uncertainty U1,U2``: two different method names."""
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    if len(names) != 2 or names[0] == names[1]:
        raise argparse.ArgumentTypeError(f"expected two different method names separated by a comma, got {text!r}")
    return names  # type: ignore[return-value]


@dataclass(frozen=True)
class CompareConf:
    """How the two sides are compared; each option field is also a command-line option. ``evaluate`` says which
    uncertainty methods are computed on each results file (its ``methods``, ``k`` and ``alpha`` are flags too)."""

    resamples: int = option(1000, "bootstrap resamples over queries (>= 40)", type=integer_at_least(1), metavar="N")
    seed: int = option(0, "seed of the bootstrap resamples", type=integer_at_least(0), metavar="S")
    uncertainty: tuple[str, str] | None = option(
        None,
        "compare two uncertainty methods of A (e.g. SU,BM: AUC-PR and AP of SU minus those of BM); give no B",
        type=_pair,
        metavar="U1,U2",
    )
    evaluate: EvaluateConf = field(default_factory=EvaluateConf)

    def __post_init__(self) -> None:
        check_resamples(self.resamples, "resamples")  # before any file is read


#: The configuration of the stage when none is given (hloc's ``default_conf``).
default_conf = CompareConf()


def side_labels(paths: Sequence[str | Path]) -> tuple[str, ...]:
    """Names of the compared files in the table: their stems, else (VPR-Bench's ``<METHOD>/precomputed_data*.npy``)
    their folders' names, else ``A`` and ``B``."""
    paths = [Path(path) for path in paths]
    for names in ([p.stem for p in paths], [p.parent.name for p in paths]):
        if len(set(names)) == len(names) and all(names):
            return tuple(names)
    return tuple("AB"[: len(paths)])


def compute(
    conf: CompareConf, retrieval_a: Any, retrieval_b: Any | None = None, *, labels: Sequence[str] = ("A", "B")
) -> Any:
    """The :class:`~vpr_uncertainty.evaluation.Comparison` of two retrievals of the same queries (each evaluated with
    ``conf.evaluate``), or, with ``conf.uncertainty`` and no ``retrieval_b``, of two uncertainty methods of one."""
    settings = {"n_resamples": conf.resamples, "seed": conf.seed}
    _check_sides(conf, retrieval_b is not None)
    if conf.uncertainty is not None:
        evaluate_conf = conf.evaluate
        if not evaluate_conf.methods:
            evaluate_conf = dataclasses.replace(evaluate_conf, methods=list(conf.uncertainty))
        missing = [name for name in conf.uncertainty if name not in evaluate_conf.method_names(retrieval_a)]
        if missing:
            raise ValueError(f"--uncertainty names {', '.join(missing)}, which --methods leaves out")
        evaluation = evaluate_compute(evaluate_conf, retrieval_a).evaluation
        return compare(evaluation, method_a=conf.uncertainty[0], method_b=conf.uncertainty[1], **settings)
    _check_same_ground_truth(retrieval_a, retrieval_b, labels)
    k = max(2, min(conf.evaluate.k, retrieval_a.k, retrieval_b.k))  # the uncertainties of both from as many candidates
    evaluate_conf = dataclasses.replace(conf.evaluate, k=k)
    evaluation_a, evaluation_b = (evaluate_compute(evaluate_conf, r).evaluation for r in (retrieval_a, retrieval_b))
    comparison = compare(
        evaluation_a,
        evaluation_b,
        labels=labels,
        query_names_a=retrieval_a.query_names,
        query_names_b=retrieval_b.query_names,
        **settings,
    )
    if k < conf.evaluate.k:
        comparison.notes.append(
            f"{labels[0]} holds {retrieval_a.k} candidates per query and {labels[1]} {retrieval_b.k}: both compared at "
            f"k = {k} (k = {conf.evaluate.k} asked)"
        )
    if all(np.array_equal(getattr(retrieval_a, name), getattr(retrieval_b, name)) for name in ("scores", "indices")):
        comparison.notes.append(f"{labels[0]} and {labels[1]} hold the same retrieval: every difference is 0")
    return comparison


def _check_sides(conf: CompareConf, with_b: bool) -> None:
    if conf.uncertainty is not None and with_b:
        raise ValueError("--uncertainty compares two uncertainty methods of one results file; give only A")
    if conf.uncertainty is None and not with_b:
        raise ValueError("give B (a second results file of the same queries) or --uncertainty U1,U2 (see --help)")


def _check_same_ground_truth(retrieval_a: Any, retrieval_b: Any, labels: Sequence[str]) -> None:
    """Refuse two retrievals whose queries or positives differ: their correctness labels are not comparable."""
    (a, b), (first, second) = (retrieval_a.positives, retrieval_b.positives), labels
    if a is None or b is None:
        return  # evaluate says that it needs the ground truth
    for axis, what in enumerate(("queries", "database images")):
        if a.shape[axis] != b.shape[axis]:
            raise ValueError(
                f"{first} and {second} must hold the same {what}: they have {a.shape[axis]} and {b.shape[axis]} {what}"
            )
    rows = np.unique((a != b).nonzero()[0])
    if rows.size:
        raise ValueError(
            f"{first} and {second} hold different ground truth: the positives of {rows.size} of {a.shape[0]} queries "
            f"differ (first: query {rows[0]}); compare them with the same ground truth (--gt GT)"
        )


def main(
    conf: CompareConf, inputs: Sequence[str | Path], out: str | Path, *, ground_truth: str | Path | None = None
) -> Path:
    """Compare the results files ``inputs`` (A and B, or A alone with ``conf.uncertainty``) and write the JSON
    document of the comparison to ``out``."""
    if not 1 <= len(inputs) <= 2:
        raise ValueError(f"expected one or two results files, got {len(inputs)}")
    top_k = max(DEFAULT_TOP_K, conf.evaluate.k)
    retrievals = [read_results(path, ground_truth=ground_truth, top_k=top_k) for path in inputs]
    comparison = compute(conf, *retrievals, labels=side_labels(inputs) if len(inputs) == 2 else ("A", "B"))
    out = Path(out)
    write_output(out, json.dumps(comparison.to_dict(), indent=2) + "\n")
    return out


# --- command line --------------------------------------------------------------------------------------------


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """The ``compare`` command."""
    parser = subparsers.add_parser(
        "compare",
        help="paired tests: two VPR methods on the same queries, or two uncertainty methods",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Is A better than B on the same queries?\n\n"
            "Two VPR methods: A and B are results files of the same queries in the same order (read as by\n"
            "`evaluate`: retrieval.npz, a similarity matrix .npy, VPR-Bench precomputed matches, a\n"
            "VPR-methods-evaluation log folder). For every uncertainty method evaluated on both: AUC-PR and AP of\n"
            "A and B, the difference A - B with its 95 % percentile interval, the two-sided paired p-value and the\n"
            "Holm-corrected p-value over the methods compared (paired bootstrap over queries: the same resampled\n"
            "queries for A and B, each judged by its own top-1 correctness); and recall@1 of A and B with the\n"
            "exact McNemar test (queries only A answers correctly vs only B). AUC-PR and AP rise with recall@1\n"
            "(their chance level is the share of correct answers): between VPR methods they compare the end-to-end\n"
            "quality of accepting the confident answers, not the uncertainty alone.\n\n"
            "Two uncertainty methods: give A alone and --uncertainty U1,U2: the same AUC-PR and AP differences\n"
            "U1 - U2 on A's queries (only U1 and U2 are computed unless --methods names more)."
        ),
        epilog=(
            "example:\n  vpr-uncertainty compare \\\n"
            "      precomputed_matches/corridor/NetVLAD/precomputed_data_corrected.npy \\\n"
            "      precomputed_matches/corridor/AMOSNet/precomputed_data_corrected.npy \\\n"
            "      --gt corridor/ground_truth_new.npy --json comparison.json\n"
            "  vpr-uncertainty compare NetVLAD/precomputed_data_corrected.npy --gt ground_truth_new.npy "
            "--uncertainty SU,BM"
        ),
    )
    parser.add_argument("a", type=Path, metavar="A", help="results file of the first VPR method")
    parser.add_argument(
        "b", type=Path, nargs="?", metavar="B", help="results file of the second, same queries (not with --uncertainty)"
    )
    add_results_options(parser, "A and B")
    add_options(parser, EvaluateConf, only=("methods", "k", "alpha"))
    add_options(parser, CompareConf, only=("resamples", "seed", "uncertainty"))
    add_json_option(parser, "the comparison")
    parser.set_defaults(handler=_handle)


def _read(path: Path, args: argparse.Namespace, conf: EvaluateConf) -> Any:
    """One results file, read as ``evaluate`` reads its SCORES."""
    unused = dict.fromkeys(("radius", "images", "query_images", "database_images"))
    reader_args = argparse.Namespace(scores=path, gt=args.gt, format=args.format, score_kind=args.score_kind, **unused)
    retrieval, _, _, notes = read_inputs(reader_args, conf)
    for note in notes:
        print(f"note: {path}: {note}")
    return retrieval


def _handle(args: argparse.Namespace) -> int:
    evaluate_conf = conf_from_args(EvaluateConf, args, bootstrap=0, seed=0, reference=None)
    with command_wording(resamples="--resamples"):
        conf = conf_from_args(CompareConf, args, evaluate=evaluate_conf)
    _check_sides(conf, args.b is not None)  # before reading the files
    paths = [args.a] if args.b is None else [args.a, args.b]
    with command_wording(ground_truth="--gt GT"):
        retrievals = [_read(path, args, evaluate_conf) for path in paths]
        comparison = compute(conf, *retrievals, labels=side_labels(paths) if len(paths) == 2 else ("A", "B"))
    if args.json is None or str(args.json) != "-":
        print(comparison)
    if args.json is not None:
        write_json(args.json, comparison.to_dict())
    return 0
