"""``reproduce``, the grid: VPR methods x datasets x uncertainty methods, then tables, figures and report.html. One
cell = one (VPR method, dataset), cached under ``out/cells`` as ``KEY.json`` and ``KEY.npz`` and read back only when
both hold the expected fingerprint and checksum (what is keyed: see docs/explanation/caches.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
import warnings
import zipfile
from collections.abc import Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty import cache
from vpr_uncertainty.calibration import evaluate_held_out
from vpr_uncertainty.data import DEFAULT_TOP_K, load_dataset, load_vprbench_dataset, read_results
from vpr_uncertainty.evaluation import RECALL_NS, Evaluation, FewerCandidatesWarning, auc_pr, correct_at_n
from vpr_uncertainty.evaluation.metrics import candidate_hits
from vpr_uncertainty.identity import code_identity
from vpr_uncertainty.methods import get_method
from vpr_uncertainty.pipeline import evaluate
from vpr_uncertainty.pipeline.evaluate import BOOTSTRAP_HELP, EvaluateConf, add_bootstrap_conf_options
from vpr_uncertainty.pipeline.grid_config import GridConfig, InputEntry, full_query_methods, load_config
from vpr_uncertainty.pipeline.grid_report import Cell, write_reports, write_results
from vpr_uncertainty.pipeline.options import (
    VERIFY_FRACTION_HELP,
    add_executor_options,
    add_figure_width_option,
    executor_from_args,
    executor_options,
    fraction,
    output_directory,
)
from vpr_uncertainty.pipeline.retrieve import ground_truth_key
from vpr_uncertainty.plugins import registered_code
from vpr_uncertainty.progress import progress_bar
from vpr_uncertainty.retrieval import Retrieval

__all__ = [
    "Cell",
    "GridConfig",
    "add_cli",
    "held_out_evaluation",
    "load_config",
    "main",
    "run_cell",
    "run_grid",
    "write_reports",
    "write_results",
]

_EXAMPLE = """example config (TOML; relative paths are relative to the config file):
  out = "runs/reproduce"
  methods = ["RS", "SD", "SU", "PA", "L2", "BM"]   # options in the name: "SUE:clip=one-sided" (needs positions)
  k = 10
  # calibration = {fraction = 0.3, repeats = 20, seed = 0}   # held-out Table 1 (add "CAL" to methods)

  [[inputs]]
  precomputed_matches = "data/vprbench/precomputed_matches/corridor"
  ground_truth = "data/vprbench/corridor/ground_truth_new.npy"
  images = "data/vprbench/corridor"

  [[inputs]]
  dataset = "data/vprbench/corridor"
  model = "efficientnet-lite0-gem"
"""


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``reproduce`` command."""
    parser = subparsers.add_parser(
        "reproduce",
        help="run VPR methods x datasets x uncertainty methods and write tables, figures and report.html",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Run every (VPR method, dataset) cell of CONFIG with every uncertainty method, from precomputed\n"
            "similarity matrices, retrieval files or images, then write results.json, results.csv, Table 1\n"
            "(md/csv/tex), the ΔAUC-PR heatmaps, the α and k ablations, the PR curves, a qualitative figure and\n"
            "report.html into the output folder. The whole config is checked before any work; cells already\n"
            "computed with the same inputs and settings are read from out/cells (use --force to recompute)."
        ),
        epilog=_EXAMPLE,
    )
    parser.add_argument("config", type=Path, metavar="CONFIG", help="grid configuration (.toml, or .yaml with pyyaml)")
    parser.add_argument("--out", type=output_directory, help="output folder (default: `out` of the config)")
    parser.add_argument("--force", action="store_true", help="recompute every cell, ignoring the cache")
    parser.add_argument(
        "--verify",
        action="store_true",
        help="before reusing a cached cell, hash every byte of its input files over 64 MiB (a plain rerun keys "
        "them by size, modification and change times and their first and last MiB) and recompute the cell when "
        "one differs",
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="only validate the configuration: files, methods and their options, and what every method needs "
        "from every cell (positions, images, a head), all problems listed at once",
    )
    parser.add_argument("--no-report", action="store_true", help="write results.json/csv only (no tables, figures)")
    add_figure_width_option(parser)
    from_config = " (default: the config's, else 0)"  # None: the config's value applies unless given
    add_bootstrap_conf_options(
        parser,
        help={"bootstrap": BOOTSTRAP_HELP + from_config, "seed": "seed of the bootstrap resamples" + from_config},
        defaults={"bootstrap": None, "seed": None},
    )
    parser.add_argument(
        "--verify-fraction",
        type=fraction,
        metavar="F",
        help=VERIFY_FRACTION_HELP.replace("(default 0.3;", "(default: verify_fraction of CONFIG, else 0.3;"),
    )
    add_executor_options(parser, ray_workers="the grid cells run as Ray tasks at once (default: the cluster's CPUs)")
    parser.set_defaults(handler=_handle)


def main(config: GridConfig | str | Path, out: str | Path | None = None, *, report: bool = True) -> Path:
    """Run the grid of ``config`` (a :class:`GridConfig` or its file) and write its files; the path of results.json.

    ``out`` overrides the config's output folder; ``report=False`` writes results.json/csv only.
    """
    if not isinstance(config, GridConfig):
        config = load_config(config, out=out)
    elif out is not None:
        config = dataclasses.replace(config, out=Path(out))
    cells = run_grid(config)
    paths = write_results(cells, config)
    if report:
        write_reports(cells, config)
    return paths["results_json"]


def _handle(args: argparse.Namespace) -> int:
    executor_options(args)  # bad executor options fail before any work
    overrides = {key: getattr(args, key) for key in ("bootstrap", "seed", "reference", "verify_fraction")}
    config = load_config(args.config, out=args.out, **overrides)
    cells = {(e.vpr_method, e.dataset) for e in config.inputs}
    print(f"{args.config}: {len(cells)} cells x {len(config.methods)} uncertainty methods -> {config.out}")
    if args.check:
        return 0
    with executor_from_args(args) as executor:
        results = run_grid(config, force=args.force, executor=executor, verify=args.verify)
    cached = sum(cell.cached for cell in results)
    if cached:
        print(f"{cached} of {len(results)} cells read from the cache")
    paths = write_results(results, config)
    if not args.no_report:
        paths.update(write_reports(results, config, width=args.figure_width))
        if "table1_md" in paths:
            print(paths["table1_md"].read_text(), end="")
    for name in ("results_json", "results_csv", "report_html"):
        if name in paths:
            print(f"wrote {paths[name]}")
    return 0


#: Candidates per query whose correctness is kept for the qualitative figure.
HIT_COLUMNS = 4
#: Layout of the cell cache files (3: with a checksum and the fingerprint in both files; 1 and 2 are recomputed).
CACHE_VERSION = 3
STAGE = "grid cell"


def candidates_needed(config: GridConfig) -> int:
    """Candidates per query a cell needs: the largest k asked for (k and the k ablation) and recall@20."""
    return max([config.k, *config.ks, max(RECALL_NS)])


def evaluate_conf(config: GridConfig) -> EvaluateConf:
    """The evaluation every cell of ``config`` runs (CAL without a gate file only on held-out splits)."""
    return EvaluateConf(
        methods=full_query_methods(config.methods, config.calibration),
        k=config.k,
        alpha=config.alpha,
        bootstrap=config.bootstrap,
        seed=config.seed,
        reference=config.reference,
        options=config.method_options(),
    )


def _run_conf(entry: InputEntry, config: GridConfig) -> Any:
    """The :class:`~vpr_uncertainty.pipeline.run.RunConf` of a cell computed from images."""
    from vpr_uncertainty.pipeline.extract import ExtractConf
    from vpr_uncertainty.pipeline.retrieve import RetrieveConf
    from vpr_uncertainty.pipeline.run import RunConf

    options = dict(entry.run_options)
    extract_options = {key: options.pop(key) for key in ("device", "batch_size") if key in options}
    retrieve_options = {key: options.pop(key) for key in ("index",) if key in options}
    return RunConf(
        extract=ExtractConf(model=entry.model, **extract_options),
        retrieve=RetrieveConf(top_k=candidates_needed(config), **retrieve_options),
        evaluate=evaluate_conf(config),
        **options,
    )


def _load_cell_input(
    entry: InputEntry, config: GridConfig, out: Path, dataset: Any = None, seconds: dict | None = None
) -> tuple[Any, Evaluation | None]:
    """The cell's Retrieval and the pipeline's Evaluation when it ran one; the pipeline's stage times are added to
    ``seconds`` (as ``pipeline_<stage>``)."""
    if entry.model is None:
        retrieval = read_results(
            entry.scores,
            ground_truth=entry.ground_truth,
            file_format=entry.file_format,
            top_k=max(DEFAULT_TOP_K, candidates_needed(config)),
            scores=entry.score_kind,
        )
        return retrieval, None
    from vpr_uncertainty.pipeline.run import run

    result = run(_run_conf(entry, config), dataset, out / "runs" / entry.key)
    if seconds is not None:
        seconds.update({f"pipeline_{stage}": value for stage, value in result.stage_seconds.items()})
    return result.retrieval, result.evaluation


def _image_dataset(entry: InputEntry) -> Any:
    """The image dataset of a cell: its ``images`` folder, or the dataset a model runs on (None: no images)."""
    if entry.model is None:
        return None if entry.images is None else load_vprbench_dataset(entry.images)
    options = entry.run_options
    return load_dataset(entry.dataset_source, root=options.get("root"), split=options.get("split"))


def _images_key(dataset: Any) -> str | None:
    """The names and content of a dataset's images, in order, and its ground truth."""
    if dataset is None or not dataset.has_images:
        return None
    keys = {
        split: [[str(path), cache.content_key(path)] for path in paths]
        for split, paths in (("queries", dataset.query_paths), ("database", dataset.database_paths))
    }
    return cache.fingerprint("images", {}, {**keys, "ground_truth": ground_truth_key(dataset.retrieval_fields())})


def _cell_fingerprint(entry: InputEntry, config: GridConfig, dataset: Any = None) -> str | None:
    """The one key of a cell: the grid's settings, the content of its inputs (files, images by name and content),
    its model's identity, and the code of every method and of the toolkit and plugins that compute it; None when
    the model can be identified only by loading it (the cell is recomputed, its run's stage caches still apply)."""
    model = None
    if entry.model is not None:
        from vpr_uncertainty.pipeline.extract import fingerprint_of

        model = fingerprint_of(_run_conf(entry, config).extract)
        if model is None:
            return None
    # every method a cell runs: those of the evaluation and the held-out splits, and the ablations' RS, SD, SU
    methods = dict.fromkeys([*evaluate_conf(config).methods, *config.methods, "RS", "SD", "SU"])
    inputs = {
        "input": entry.fingerprint(),
        "images": _images_key(dataset),
        "model": model,
        "methods": [get_method(name).identity() for name in methods],
        "code": {"toolkit": code_identity(__name__), **registered_code()},
    }
    return cache.fingerprint(STAGE, {**config.settings(), "candidates": candidates_needed(config)}, inputs)


def save_cell(
    cell: Cell, json_path: Path, npz_path: Path, fingerprint: str, input_digests: dict[str, str] | None = None
) -> None:
    """Write a cell's cache: its arrays to ``npz_path``, then its document to ``json_path``, each atomically, both
    with ``fingerprint`` (checked by :func:`load_cell`); ``input_digests``: the
    :func:`~vpr_uncertainty.cache.file_digest` of the input files that the fingerprint hashes only in part."""
    arrays = cell.arrays()
    with cache.atomic_write(npz_path, "wb") as file:
        np.savez_compressed(file, **arrays, **{_FINGERPRINT: np.array(fingerprint)})
    content = {
        "cell": cell.to_dict(),
        "query_paths": cell.query_paths,
        "database_paths": cell.database_paths,
        "input_digests": dict(input_digests or {}),
    }
    content = json.loads(json.dumps(content))  # as it will be read back (tuples as lists)
    document = {"version": CACHE_VERSION, "fingerprint": fingerprint, **content}
    document["checksum"] = cache.payload_checksum(*_checksum_parts(content, arrays))
    cache.write_text(json_path, json.dumps(document, indent=1) + "\n")


_FINGERPRINT = "fingerprint"
_CONTENT = ("cell", "query_paths", "database_paths", "input_digests")


def load_cell(json_path: Path, npz_path: Path, fingerprint: str, verify_files: tuple[Path, ...] = ()) -> Cell | None:
    """A cell read from its cache, or None when the cache is missing, stale (another fingerprint) or unusable.

    A cell that cannot be used (cut short, foreign, of an earlier layout, changed on disk after it was written, or
    whose two files come from two different runs) is reported in one line
    (:class:`~vpr_uncertainty.cache.CacheWarning`). ``verify_files``: input files to hash whole and compare with the
    digests recorded when the cell was computed.
    """
    if not (json_path.is_file() and npz_path.is_file()):
        return None
    try:
        meta = json.loads(json_path.read_text())
        if meta.get("fingerprint") != fingerprint:
            return None
        if "checksum" not in meta:
            cache.stale_notice(json_path, "written by an earlier version (no checksum)", "recomputing the cell")
            return None
        with open(npz_path, "rb") as file, np.load(file, allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files}
        if str(arrays.pop(_FINGERPRINT, "")) != fingerprint:
            cache.stale_notice(
                npz_path, f"does not belong to {json_path.name} (another fingerprint)", "recomputing the cell"
            )
            return None
        cache.verify_checksum(json_path, meta["checksum"], *_checksum_parts(meta, arrays), what="the cell")
        recorded = meta.get("input_digests") or {}
        for path in verify_files:
            if recorded.get(str(path.resolve())) != cache.file_digest(path):
                reason = f"input {path} differs from the one it was computed from (every byte hashed)"
                cache.stale_notice(json_path, reason, "recomputing the cell")
                return None
        paths = {"query_paths": meta.get("query_paths"), "database_paths": meta.get("database_paths")}
        return Cell.from_dict(meta["cell"], arrays, **paths, cached=True)
    except cache.ChecksumError as error:
        cache.stale_notice(json_path, f"corrupted ({str(error).removeprefix(f'{json_path}: ')})", "recomputing it")
        return None
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as error:  # cut short: recompute
        cache.stale_notice(json_path, f"unreadable cell (truncated or foreign: {error or type(error).__name__})")
        return None


def _checksum_parts(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> tuple[Any, ...]:
    """What a cell's checksum covers: the canonical JSON of the document's content, then each array by name."""
    text = json.dumps({key: meta.get(key) for key in _CONTENT}, sort_keys=True, separators=(",", ":"))
    return (text, *(part for name in sorted(arrays) for part in (name, arrays[name])))


def run_cell(
    entry: InputEntry, config: GridConfig, *, force: bool = False, verify: bool = False, dataset: Any = None
) -> Cell:
    """Evaluate one (VPR method, dataset) cell, or read it from ``config.out/cells`` when it is up to date.

    Parameters
    ----------
    entry : InputEntry
        The cell's input.
    config : GridConfig
        The grid's settings (methods, k, α, ablations, output folder).
    force : bool, default=False
        Recompute the cell even when its cache is up to date.
    verify : bool, default=False
        Before reusing the cell, hash every byte of its input files larger than
        :data:`~vpr_uncertainty.cache.FULL_HASH_BYTES` (normally keyed by size, times and both ends) and recompute
        the cell when one differs from what it was computed from.
    dataset : Dataset, optional
        The cell's image dataset when already loaded (for another cell of the same images).

    Returns
    -------
    Cell
    """
    out = Path(config.out)
    cells = out / "cells"
    cells.mkdir(parents=True, exist_ok=True)
    json_path, npz_path = cells / f"{entry.key}.json", cells / f"{entry.key}.npz"
    dataset = _image_dataset(entry) if dataset is None else dataset
    fingerprint = _cell_fingerprint(entry, config, dataset)
    # the cell's input files (and those its methods' options name) that content_key hashes only in part
    large = [path for path in (entry.scores, entry.ground_truth) if path is not None]
    large += [Path(path) for name in config.methods for path in get_method(name).identity()["files"]]
    large = [path for path in large if path.is_file() and cache.is_partly_hashed(path)]
    if not force and fingerprint is not None:
        cached = load_cell(json_path, npz_path, fingerprint, large if verify else ())
        if cached is not None:
            return cached
    input_digests = {str(path.resolve()): cache.file_digest(path) for path in large}
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    retrieval, evaluation = _load_cell_input(entry, config, out, dataset, seconds)
    seconds["input"] = time.perf_counter() - start
    # Image-based methods (geometric verification) get the images and one local-feature cache for the grid.
    options: dict[str, list[str]] = {}
    if dataset is not None and dataset.has_images and len(dataset.query_paths) == retrieval.n_queries:
        options = {name: [str(p) for p in getattr(dataset, name)] for name in ("query_paths", "database_paths")}
    start = time.perf_counter()
    if evaluation is None:
        inputs = {"cache_dir": out / "local_features", **options}
        evaluation = evaluate.compute(evaluate_conf(config), retrieval, inputs=inputs).evaluation
    seconds["uncertainty_and_evaluation"] = time.perf_counter() - start
    start = time.perf_counter()
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    alpha_curve, k_curve = ablation_curves(retrieval, correct, k=config.k, alphas=config.alphas, ks=config.ks)
    left_out = [value for value in config.ks if value > retrieval.k]  # more than the candidates per query
    if left_out:
        shown = ", ".join(map(str, left_out))
        note = f"k ablation: k = {shown} left out, the retrieval holds {retrieval.k} candidates per query"
        evaluation.notes.append(note)
        warnings.warn(f"{entry.key}: {note}", FewerCandidatesWarning, stacklevel=2)
    seconds["ablations"] = time.perf_counter() - start
    cell = Cell(
        vpr_method=entry.vpr_method,
        dataset=entry.dataset,
        evaluation=evaluation,
        scores=np.asarray(retrieval.scores, dtype=np.float32),
        indices=retrieval.indices,
        ablation_alpha=alpha_curve,
        ablation_k=k_curve,
        hits=candidate_hits(retrieval.indices[:, :HIT_COLUMNS], retrieval.positives),
        query_paths=options.get("query_paths"),
        database_paths=options.get("database_paths"),
        held_out=None
        if config.calibration is None
        else held_out_evaluation(retrieval, config, cache_dir=out / "local_features", **options),
        stage_seconds=seconds,
    )
    if fingerprint is not None:
        save_cell(cell, json_path, npz_path, fingerprint, input_digests)
    return cell


def run_grid(
    config: GridConfig, *, force: bool = False, progress: bool | None = None, executor: Any = None, verify: bool = False
) -> list[Cell]:
    """Run (or read from the cache) every cell of the grid, with a progress bar.

    Parameters
    ----------
    config : GridConfig
        The validated grid (see :func:`~vpr_uncertainty.pipeline.grid_config.load_config`).
    force : bool, default=False
        Recompute every cell, ignoring the cache.
    progress : bool, optional
        Show the progress bar; by default only on a terminal.
    executor : LocalExecutor or RayExecutor, optional
        Where the cells run (:func:`vpr_uncertainty.executors.get_executor`); default: one after the other in this
        process. With Ray each cell is a task that reads and writes the cell cache under ``config.out/cells``
        itself, so that folder must be on a filesystem every worker sees; a rerun on any executor reads the cells
        already finished. The tasks only read the shared local-feature caches (``config.out/local_features``): this
        process writes what they extracted once every cell is done (a failed grid leaves them to the rerun).
    verify : bool, default=False
        Hash every byte of the large input files before reusing a cell (see :func:`run_cell`).

    Returns
    -------
    list of Cell
        In the order of ``config.inputs``.
    """
    with progress_bar(total=len(config.inputs), desc="grid", unit="cell", enabled=progress, leave=True) as bar:
        if executor is not None and executor.name != "local":
            from vpr_uncertainty.geometric.cache import deferring_writes, store_features

            task = partial(deferring_writes, partial(run_cell, config=config, force=force, verify=verify))
            results = executor.map(task, config.inputs, on_result=lambda result: bar.update(1))
            store_features(pending for _, pending in results)  # no task is running: this process is the one writer
            return [cell for cell, _ in results]
        cells, images = [], {}  # the images folder of results cells, loaded once
        for entry in config.inputs:
            bar.set_postfix_str(f"{entry.vpr_method} / {entry.dataset}", refresh=False)
            if entry.model is None and entry.images is not None and entry.images not in images:
                images[entry.images] = _image_dataset(entry)
            dataset = images.get(entry.images) if entry.model is None else None
            cells.append(run_cell(entry, config, force=force, verify=verify, dataset=dataset))
            bar.update(1)
    return cells


def ablation_curves(
    retrieval: Retrieval, correct: np.ndarray, *, k: int, alphas: Sequence[float], ks: Sequence[int]
) -> tuple[dict[float, float | None], dict[str, dict[int, float | None]]]:
    """``({α: AUC-PR of SU at k}, {"RS" or "SD": {k: AUC-PR}})`` for the cell's top-1 ``correct`` (Q,): ``k`` capped
    at the candidates per query, the ``ks`` above them left out; every AUC-PR None when every answer is correct, or
    none is."""
    both = bool(correct.any() and not correct.all())
    su, rs, sd = get_method("SU"), get_method("RS"), get_method("SD")
    k = min(k, retrieval.k)
    alpha_curve = {a: (auc_pr(correct, su(retrieval, k=k, alpha=a)) if both else None) for a in alphas}
    k_curve: dict[str, dict[int, float | None]] = {"RS": {}, "SD": {}}
    for value in ks:
        if value > retrieval.k:
            continue
        for name, method in (("RS", rs), ("SD", sd)):
            k_curve[name][value] = auc_pr(correct, method(retrieval, k=value)) if both else None
    return alpha_curve, k_curve


def held_out_evaluation(retrieval: Retrieval, config: GridConfig, **options: Any) -> dict[str, Any]:
    """Every method of the grid on the held-out queries of the grid's splits, as JSON types.

    Parameters
    ----------
    retrieval : Retrieval
        The cell's retrieval, with its ground truth.
    config : GridConfig
        Holds ``calibration`` (fraction, repeats, seed), ``methods``, ``k`` and ``alpha``.
    **options
        Further inputs of the methods (the image paths and the local-feature cache of the cell).

    Returns
    -------
    dict
        :meth:`~vpr_uncertainty.calibration.HeldOutEvaluation.to_dict`. When the splits are impossible
        (fewer than 2 correct or 2 wrong answers), every method's ``auc_pr`` is None and ``notes`` says why.
    """
    option = config.calibration
    if option is None:
        raise ValueError("the grid has no calibration option (calibration = {fraction, repeats, seed})")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the first split's notes are kept in the result
            result = evaluate_held_out(
                retrieval,
                config.methods,
                calibration_fraction=option["fraction"],
                repeats=option["repeats"],
                seed=option["seed"],
                k=config.k,
                alpha=config.alpha,
                **options,
            )
    except ValueError as error:
        if "at least 2 correct and 2 wrong" not in str(error):
            raise
        empty = {"auc_pr": None, "auc_pr_std": None, "average_precision": None, "aurc": None}
        return {
            "n_queries": retrieval.n_queries,
            "calibration": dict(option),
            "methods": {get_method(spec).name: dict(empty) for spec in config.methods},
            "notes": [f"no held-out evaluation: {error}"],
        }
    return result.to_dict()
