"""Stage 3, ``evaluate``: a retrieval -> every uncertainty, evaluated, and ``uncertainties.npz`` (never reused: the
evaluation measures the time per query; see docs/explanation/caches.md). This module holds the one call of
:func:`vpr_uncertainty.evaluation.evaluate` that every command goes through.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty import cache
from vpr_uncertainty._repr import compact_repr
from vpr_uncertainty.data import DEFAULT_TOP_K, read_results
from vpr_uncertainty.data.images import retrieval_image_paths
from vpr_uncertainty.evaluation import evaluate as evaluate_methods
from vpr_uncertainty.evaluation.bootstrap import check_bootstrap
from vpr_uncertainty.evaluation.metrics import RECALL_NS, check_recall_ns
from vpr_uncertainty.formats.vpr_methods_evaluation import read_vpr_methods_evaluation
from vpr_uncertainty.methods import available_methods, default_method_names, get_method, split_method_list
from vpr_uncertainty.pipeline.options import (
    VERIFY_FRACTION_HELP,
    add_executor_options,
    add_figure_width_option,
    add_image_options,
    add_json_option,
    add_options,
    add_results_options,
    candidate_count,
    checked_number,
    command_wording,
    conf_from_args,
    executor_from_args,
    executor_options,
    fraction,
    integer_at_least,
    non_negative_float,
    open_fraction,
    option,
    output_file,
    positive_int,
    write_json,
    write_output,
)
from vpr_uncertainty.plugins import import_or_explain
from vpr_uncertainty.scores import check_alpha

__all__ = ["METHOD_SPEC_HELP", "EvaluateConf", "Evaluated", "add_cli", "compute", "default_conf", "main", "method_list"]

STAGE = "uncertainty"


def recall_list(text: str) -> tuple[int, ...]:
    """Comma-separated N of recall@N (``1,5,10,100``), each an int >= 1 in ASCII digits; sorted, without repeats."""
    try:
        return check_recall_ns([positive_int(part.strip()) for part in text.split(",") if part.strip()])
    except (TypeError, ValueError, argparse.ArgumentTypeError) as error:
        raise argparse.ArgumentTypeError(
            f"expected a comma-separated list of ints >= 1 such as 1,5,10,100, got {text!r}"
        ) from error


def method_list(text: str) -> list[str]:
    """Comma-separated method specs (``SU,SUE:clip=one-sided,slope=300``) checked against the registry."""
    try:
        specs = split_method_list(text)
        names = [get_method(spec).name for spec in specs]
    except (KeyError, ValueError, TypeError, ImportError) as error:
        raise argparse.ArgumentTypeError(str(error.args[0]) if error.args else str(error)) from None
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of method names, e.g. SU,PA,BM")
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise argparse.ArgumentTypeError(f"method listed more than once: {', '.join(twice)}")
    return names


METHOD_SPEC_HELP = (
    "A method can carry its own options after a colon, e.g. SUE:clip=one-sided,slope=350 (the published SUE);\n"
    "each variant is reported under its spec, so --methods SUE,SUE:clip=one-sided compares both. Options:\n"
    "SU: k, alpha; SUE: k, slope, clip (symmetric | one-sided | none), max_deviation; RS/SD/BM/L2/PA/margin: k."
)


#: Help of ``--bootstrap`` (evaluate, run, reproduce).
BOOTSTRAP_HELP = (
    "bootstrap resamples for 95 %% intervals of AUC-PR, AP and AURC, a paired test of each method's AUC-PR against "
    "the reference (Holm-corrected) and a best marked only where significant; 0 = none, else >= 40; 1000 is usual"
)


@dataclass(frozen=True)
class EvaluateConf:
    """Which uncertainties are computed and how they are evaluated; each field is also a command-line option."""

    methods: Sequence[str] | None = option(
        None,
        lambda: (
            "comma-separated uncertainty methods, each with optional options as in SUE:clip=one-sided (default: "
            f"{','.join(default_method_names())}, plus SUE when the positions are metric)"
        ),
        type=method_list,
    )
    k: int = option(10, "candidates per query for RS/SD/SU", type=candidate_count)
    alpha: float = option(0.5, "weight of RS in SU, in [0, 1]", type=checked_number(check_alpha))
    bootstrap: int = option(0, BOOTSTRAP_HELP, type=integer_at_least(0), metavar="N")
    seed: int = option(0, "seed of the bootstrap resamples (and of the held-out splits)", type=integer_at_least(0))
    reference: str | None = option(
        None,
        "the method every other one is tested against (default: SU when evaluated, else the first method)",
        metavar="NAME",
    )
    recall_at: tuple[int, ...] | None = option(
        None,
        "comma-separated N of the retrieval's recall@N, any N; a full matrix is read with enough candidates, and an "
        "N above those of a retrieval file is reported as n/a (null in --json) with a warning (default: those of "
        f"{','.join(map(str, RECALL_NS))} the retrieval holds)",
        type=recall_list,
        metavar="N,N,...",
    )
    options: Mapping[str, Any] = field(default_factory=dict)  # further method options (btl_head, verify_fraction)

    def __post_init__(self) -> None:
        check_alpha(self.alpha)  # before any work (run extracts descriptors first)
        check_bootstrap(self.bootstrap, self.seed)
        if self.recall_at is not None:
            object.__setattr__(self, "recall_at", check_recall_ns(self.recall_at))

    @property
    def candidates(self) -> int:
        """Candidates per query to read from a full matrix: enough for k, the largest recall@N and 50."""
        return max(DEFAULT_TOP_K, self.k, *(self.recall_at or ()))

    def method_names(self, retrieval: Any) -> list[str]:
        """``methods``, else the registry's defaults (with SUE when the retrieval's positions are metric), less those
        the retrieval's scores do not suit (a warning names them)."""
        if self.methods:
            return list(self.methods)
        kind = retrieval.config.get("position_kind")
        metric = retrieval.database_positions is not None and kind in (None, "metres")
        return default_method_names(metric_positions=metric, retrieval=retrieval)


#: The configuration of the stage when none is given (hloc's ``default_conf``).
default_conf = EvaluateConf()


@dataclass
class Evaluated:
    """What :func:`compute` produced: the evaluation in memory, and the file when one was written."""

    __repr__ = compact_repr

    evaluation: Any
    fingerprint: str
    path: Path | None = None


def compute(
    conf: EvaluateConf,
    retrieval: Any,
    path: str | Path | None = None,
    *,
    inputs: Mapping[str, Any] | None = None,
    retrieval_fingerprint: str | None = None,
    latency: bool = False,
) -> Evaluated:
    """Every uncertainty of ``conf`` on ``retrieval``, evaluated; the uncertainties written to ``path`` if given.

    Parameters
    ----------
    conf : EvaluateConf
    retrieval : Retrieval
        With its ground truth.
    path : str or Path, optional
        ``uncertainties.npz``.
    inputs : mapping, optional
        What image-based methods need (``query_paths``, ``database_paths``, descriptors, ``cache_dir``,
        ``device``) and where geometric verification runs (``executor``); not part of the fingerprint (the
        retrieval's fingerprint covers their content, and every executor gives the same results).
    retrieval_fingerprint : str, optional
        The fingerprint of the retrieval file.
    latency : bool
        Also measure each score-based method's latency at batch size 1.
    """
    methods = conf.method_names(retrieval)
    evaluation = evaluate_methods(
        retrieval,
        methods,
        k=conf.k,
        alpha=conf.alpha,
        recall_at=conf.recall_at,
        bootstrap=conf.bootstrap,
        seed=conf.seed,
        reference=conf.reference,
        latency=latency,
        **{**dict(inputs or {}), **dict(conf.options)},
    )
    identities = [get_method(name).identity() for name in methods]
    described = {"methods": identities, "k": conf.k, "alpha": conf.alpha, "options": dict(conf.options)}
    fingerprint = cache.fingerprint(STAGE, described, {"retrieval": retrieval_fingerprint})
    if path is not None:
        path = Path(path)
        arrays = {name: method.uncertainty for name, method in evaluation.methods.items()}
        with cache.atomic_write(path, "wb") as handle:
            np.savez_compressed(handle, correct=evaluation.correct, fingerprint=np.array(fingerprint), **arrays)
    return Evaluated(evaluation=evaluation, fingerprint=fingerprint, path=path)


def main(conf: EvaluateConf, results: str | Path, out: str | Path, *, ground_truth: str | Path | None = None) -> Path:
    """Evaluate the uncertainties of ``results`` (any file :func:`vpr_uncertainty.read_results` reads) into ``out``."""
    retrieval = read_results(results, ground_truth=ground_truth, top_k=conf.candidates)
    return compute(conf, retrieval, out).path  # type: ignore[return-value]


# --- what the command reads besides SCORES -------------------------------------------------------------------


def _verifies(name: str) -> bool:
    entry = get_method(name)
    accepted = entry.accepted_options()  # None: any option (a cascade SCORE+GV, a plugin), what it requires says
    return "images" in entry.requires if accepted is None else "query_paths" in accepted


def read_inputs(args: argparse.Namespace, conf: EvaluateConf) -> tuple[Any, list[str], dict[str, Any], list[str]]:
    """SCORES and the image folders of the command's arguments: (retrieval, methods, image options, notes)."""
    top_k = conf.candidates  # a full matrix gives as many candidates as k and the largest recall@N ask
    notes: list[str] = []
    log_paths: tuple[Any, Any] = (None, None)
    if Path(args.scores).is_dir() and args.format == "auto":
        if args.score_kind == "distance":
            raise ValueError("--scores distance: a VPR-methods-evaluation log folder is searched by similarity")
        log = read_vpr_methods_evaluation(args.scores, ground_truth=args.gt, radius=args.radius, top_k=top_k)
        retrieval, notes, log_paths = log.retrieval, log.notes, (log.query_paths, log.database_paths)
    else:
        if args.radius is not None:
            raise ValueError(
                "--radius applies to VPR-methods-evaluation log folders; a results file holds or is given (--gt) "
                "its ground truth"
            )
        retrieval = read_results(
            args.scores,
            ground_truth=args.gt,
            file_format=args.format,
            top_k=top_k,
            scores=args.score_kind,
        )
    notes += [retrieval.config["score_conversion"]] if "score_conversion" in retrieval.config else []
    methods = conf.method_names(retrieval)
    verifying = [name for name in methods if _verifies(name)]
    folders = {"images": args.images, "query_images": args.query_images, "database_images": args.database_images}
    given = any(value is not None for value in folders.values())
    if given and not verifying:
        raise ValueError(
            "--images, --query-images and --database-images feed the methods that verify images (GV-*); "
            "none is in --methods"
        )
    options: dict[str, Any] = {}
    if verifying:
        if given:
            query_paths, database_paths = retrieval_image_paths(retrieval, **folders)
        elif log_paths[0] is not None:
            query_paths, database_paths = log_paths
            notes.append("images: the folders named in the log folder's info.log")
        else:
            raise ValueError(
                f"{', '.join(verifying)} verif{'ies' if len(verifying) == 1 else 'y'} images: give --images DIR (a "
                "dataset folder with query/ and ref/, or queries/ and database/) or --query-images and "
                "--database-images"
            )
        options = {"query_paths": [str(p) for p in query_paths], "database_paths": [str(p) for p in database_paths]}
    return retrieval, methods, options, notes


# --- command line --------------------------------------------------------------------------------------------


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """The ``evaluate`` command."""
    parser = subparsers.add_parser(
        "evaluate",
        help="evaluate uncertainty methods on precomputed VPR results",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Compute each uncertainty method on precomputed results and measure how well it predicts a correct\n"
            "top-1 answer: AUC-PR (trapezoid, the convention of the VPR uncertainty tables), average precision,\n"
            "AURC, recall at 100 % precision and the time per query.\n\n"
            "SCORES is one of:\n"
            "  retrieval.npz                a retrieval file (scores, indices, optionally the ground truth)\n"
            "  matrix.npy                   a full similarity matrix, queries x database, higher = more similar\n"
            "                               (a distance matrix with --scores distance)\n"
            "  precomputed_data_*.npy       VPR-Bench precomputed matches (legacy object array, read safely)\n"
            "  LOGDIR/                      a VPR-methods-evaluation log folder saved with --save_descriptors\n"
            "                               (ground truth derived from its image names when --gt is not given)\n\n"
            "Uncertainty methods:\n"
            + "\n".join(f"  {name:<8} {get_method(name).description}" for name in available_methods())
            + "\n\n"
            + METHOD_SPEC_HELP
        ),
        epilog=(
            "example:\n  vpr-uncertainty evaluate \\\n"
            "      precomputed_matches/corridor/NetVLAD/precomputed_data_corrected.npy \\\n"
            "      --gt corridor/ground_truth_new.npy --json results.json --plot pr.png"
        ),
    )
    parser.add_argument("scores", type=Path, metavar="SCORES", help="results file (see above)")
    add_results_options(parser, "SCORES")
    add_options(parser, EvaluateConf, only=("methods", "k", "alpha", "recall_at"))
    parser.add_argument("--verify-fraction", type=fraction, metavar="F", help=VERIFY_FRACTION_HELP)
    group = parser.add_argument_group(
        "images, for the methods that verify them (GV-*): query i and database image j are the i-th and j-th "
        "images of their folder, sorted by path (VPR-Bench, VPR-datasets-downloader), or the names a retrieval "
        "file holds"
    )
    add_image_options(group)
    parser.add_argument(
        "--radius",
        type=non_negative_float,
        help="VPR-methods-evaluation log folders: positives within this many metres (default: the run's "
        "positive_dist_threshold, else 25)",
    )
    add_json_option(parser, "the results")
    parser.add_argument(
        "--plot", type=output_file, metavar="FILE", help="write the end-to-end PR curves (.png/.pdf/.svg)"
    )
    add_figure_width_option(parser)
    parser.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    parser.add_argument(
        "--csv",
        type=output_file,
        metavar="FILE",
        help="write the table as CSV to FILE: one row per method, the numbers of --json at full precision",
    )
    parser.add_argument(
        "--per-query",
        type=output_file,
        metavar="FILE",
        help="write one row per query to FILE.csv or FILE.parquet (pandas extra): query_index, query, top1_index, "
        "top1 (names, empty when SCORES has none), answerable, correct (0/1), s_1..s_k, each method's uncertainty",
    )
    parser.add_argument(
        "--latex",
        type=output_file,
        metavar="FILE",
        help="write the table as a LaTeX float to FILE (booktabs, graphicx; fits \\columnwidth, label tab:uncertainty)",
    )
    parser.add_argument(
        "--latex-intervals",
        action="store_true",
        help="--latex: show the bootstrap intervals (with --bootstrap N) beside the numbers",
    )
    parser.add_argument(
        "--latency",
        action="store_true",
        help="also measure each score-based method's latency at batch size 1 (median of 3 runs of 200 "
        "single-query calls; latency_ms_batch1 in --json)",
    )
    held_out = parser.add_argument_group(
        "held-out evaluation (no leakage): every method on the same held-out queries of random splits; "
        "CAL is fitted on the rest"
    )
    held_out.add_argument(
        "--calibration-fraction",
        type=open_fraction,
        metavar="F",
        help="share of the queries used to fit CAL in each split, in (0, 1), e.g. 0.3",
    )
    held_out.add_argument("--repeats", type=positive_int, default=20, help="random splits (default 20)")
    add_bootstrap_conf_options(parser)
    learned = parser.add_argument_group("options of methods that need more than scores")
    learned.add_argument("--btl-head", type=Path, metavar="HEAD.pt", help="BTL: the head written by train-btl")
    learned.add_argument(
        "--descriptors",
        type=Path,
        metavar="DESC.h5",
        help="BTL: descriptor cache (from extract or run) holding the queries and the database",
    )
    learned.add_argument(
        "--allow-train-queries",
        action="store_true",
        help="BTL: evaluate the head even on queries it was trained on (refused otherwise; the table marks it ‡)",
    )
    add_executor_options(
        parser,
        ray_workers="the geometric-verification tasks in flight, for the GV-* methods (default: the cluster's CPUs)",
    )
    parser.set_defaults(handler=_handle)


def add_bootstrap_conf_options(parser: argparse.ArgumentParser, **overrides: Any) -> None:
    """The ``bootstrap``, ``seed`` and ``reference`` options of :class:`EvaluateConf` in one group (evaluate, run,
    reproduce); ``overrides``: the ``help`` and ``defaults`` of :func:`~.options.add_options`."""
    group = parser.add_argument_group(
        "confidence intervals and paired tests (paired bootstrap over queries: the same resamples for every method)"
    )
    add_options(group, EvaluateConf, only=("bootstrap", "seed", "reference"), **overrides)


def method_options(args: argparse.Namespace) -> dict[str, Any]:
    """The method options the flags of ``evaluate``, ``run`` and ``reproduce`` give (only those given)."""
    options = {
        name: getattr(args, name) for name in ("btl_head", "verify_fraction") if getattr(args, name, None) is not None
    }
    if getattr(args, "descriptors", None) is not None:
        options.update(query_descriptors=args.descriptors, database_descriptors=args.descriptors)
    if getattr(args, "allow_train_queries", False):
        options["allow_train_queries"] = True
    return options


def _handle(args: argparse.Namespace) -> int:
    from vpr_uncertainty.reports import format_table, plot_rejection_curves
    from vpr_uncertainty.reports.tables import evaluation_csv, evaluation_latex, per_query_csv

    wording = {"images": "--images", "query_images": "--query-images", "database_images": "--database-images"}
    with command_wording(
        ground_truth="--gt GT", database_positions="--database-positions", bootstrap="--bootstrap", **wording
    ):
        conf = conf_from_args(EvaluateConf, args, options=method_options(args))
        executor_options(args)  # bad executor options fail before any work
        retrieval, methods, image_options, notes = read_inputs(args, conf)
        conf = dataclasses.replace(conf, methods=methods, options={**conf.options, **image_options})
        for note in notes:
            print(f"note: {note}")
        if args.calibration_fraction is not None and (args.bootstrap or args.per_query):
            raise ValueError(
                f"{'--bootstrap' if args.bootstrap else '--per-query'} and --calibration-fraction cannot be combined: "
                "the held-out evaluation reports its spread over random splits of the queries instead"
            )
        if args.per_query and args.per_query.suffix not in (".csv", ".parquet"):  # before any work
            raise ValueError(f"--per-query: expected a .csv or .parquet file name, got {args.per_query}")
        # nothing of evaluate but geometric verification would run on Ray
        if args.executor != "local" and not any(get_method(name).kind in ("geometric", "cascade") for name in methods):
            raise ValueError(
                f"--executor ray: evaluate runs only geometric verification (GV-*, SCORE+GV) on Ray, and none of the "
                f"selected methods ({', '.join(methods)}) verifies images; drop --executor or add e.g. GV-SIFT"
            )
        with executor_from_args(args) as executor:
            inputs = {} if executor.name == "local" else {"executor": executor}  # GV-* verify their pairs there
            if args.calibration_fraction is not None:
                return _held_out(args, conf, retrieval, inputs)
            evaluation = compute(conf, retrieval, inputs=inputs, latency=args.latency).evaluation
    print(format_table(evaluation, markdown=args.markdown, title=f"{args.scores}"))
    if args.latency:
        pairs = [
            f"{name} {method.timings['latency_ms_batch1']:.4f}"
            for name, method in evaluation.methods.items()
            if "latency_ms_batch1" in method.timings
        ]
        print("latency at batch size 1 (ms/query, median of 3 runs of 200 calls): " + (", ".join(pairs) or "none"))
    if args.json:
        write_json(args.json, evaluation.to_dict())
    if args.csv:
        write_output(args.csv, evaluation_csv(evaluation))
    if args.latex:
        write_output(args.latex, evaluation_latex(evaluation, intervals=args.latex_intervals))
    if args.per_query and args.per_query.suffix == ".parquet":
        import_or_explain("pyarrow", "--per-query FILE.parquet needs pyarrow: pip install 'vpr-uncertainty[pandas]'")
        args.per_query.parent.mkdir(parents=True, exist_ok=True)
        with cache.atomic_write(args.per_query, "wb") as handle:
            evaluation.per_query_frame().to_parquet(handle, index=False)
    elif args.per_query:
        write_output(args.per_query, per_query_csv(evaluation))
    for written in filter(None, (args.csv, args.latex, args.per_query)):
        print(f"wrote {written}")
    if args.plot:
        plot_rejection_curves(evaluation, args.plot, title=args.scores.parent.name or None, width=args.figure_width)
        print(f"wrote {args.plot}")
    return 0


def _held_out(args: argparse.Namespace, conf: EvaluateConf, retrieval: Any, inputs: dict[str, Any]) -> int:
    from vpr_uncertainty.calibration import evaluate_held_out

    result = evaluate_held_out(
        retrieval,
        list(conf.methods or ()),
        calibration_fraction=args.calibration_fraction,
        repeats=args.repeats,
        seed=conf.seed,
        k=conf.k,
        alpha=conf.alpha,
        **{**inputs, **dict(conf.options)},
    )
    print(
        f"{args.scores}: {result.repeats} random splits, {result.n_calibration} calibration / "
        f"{result.n_held_out} held-out queries (seed {result.seed}); mean ± std over the splits"
    )
    print(f"{'method':<10} {'AUC-PR':>16} {'AP':>16} {'AURC':>16}")

    def cell(name: str, metric: str) -> str:
        mean, std = result.mean(name, metric), result.std(name, metric)
        return "n/a" if mean is None else f"{mean:.4f} ± {std or 0.0:.4f}"

    for name in result.values:
        print(f"{name:<10} {cell(name, 'auc_pr'):>16} {cell(name, 'average_precision'):>16} {cell(name, 'aurc'):>16}")
    quality = result.quality.get("CAL", {})
    ece = f"ECE {quality.get('ece', 0.0):.3f}, mean over the {result.repeats} splits"  # JSON's ece, --plot's legend
    if quality:
        print(f"CAL calibration on held-out queries: {ece}; Brier {quality['brier']:.3f}, mean")
    if args.json:
        write_json(args.json, result.to_dict())
    if args.plot:
        if "CAL" not in result.quality:
            raise ValueError("--plot with --calibration-fraction draws CAL's reliability diagram: add CAL to --methods")
        from vpr_uncertainty.calibration.quality import Reliability
        from vpr_uncertainty.reports.display import plot_reliability

        plot_reliability(
            Reliability(**result.quality["CAL"]["reliability"]),
            args.plot,
            title="held-out reliability",
            width=args.figure_width,
            label=f"CAL ({ece})",
        )
        print(f"wrote {args.plot}")
    return 0
