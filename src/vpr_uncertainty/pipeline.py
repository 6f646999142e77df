"""Images to answers: dataset → descriptors → retrieval → uncertainties → evaluation → report files.

Each stage writes one file into the run directory, and a rerun reuses what is there:

======================  =========================================================================================
``descriptors.h5``      global descriptors keyed by image name (resumable; invalidated when the model or its
                        preprocessing changes)
``retrieval.npz``       top-k scores, indices, distances, positives, names and positions (reused while the
                        descriptors, k and index are unchanged)
``uncertainties.npz``   one (Q,) array per uncertainty method, higher = less trustworthy, and ``correct``
``results.json``        the schema of ``evaluate --json``, plus the run configuration, the time of each stage
                        and, under ``dataset``, the images left out (``images_left_out``) and the folders
                        that could not be listed (``unlisted``) with ``on_error="skip"``
``results.md``          the table
``pr_curves.png``       end-to-end precision-recall of every method
======================  =========================================================================================
"""

from __future__ import annotations

import hashlib
import json
import time
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.evaluation import Evaluation, evaluate
from vpr_uncertainty.methods import GEOMETRIC_METHODS, SCORE_ONLY_METHODS, describe_needs, get_method
from vpr_uncertainty.reports import format_table, plot_rejection_curves
from vpr_uncertainty.retrieval import Retrieval, load_retrieval, save_retrieval

__all__ = ["RunConfig", "RunResult", "default_methods", "format_reranking", "run"]

#: Candidates kept per query: enough for k = 10 and recall@20.
RETRIEVAL_K = 20
#: Options the pipeline gives every uncertainty method (images, descriptors, a cache folder, the device).
PIPELINE_OPTIONS: tuple[str, ...] = (
    "query_paths",
    "database_paths",
    "query_descriptors",
    "database_descriptors",
    "cache_dir",
    "device",
)


@dataclass
class RunConfig:
    """What :func:`run` does.

    Attributes
    ----------
    dataset : str or Path
        A dataset folder in any format :func:`vpr_uncertainty.data.load_dataset` reads, or a registered name.
    out : Path
        The run directory.
    model : str
        A descriptor model name (:func:`vpr_uncertainty.features.available_models`) or a TorchScript file.
    methods : sequence of str, optional
        Uncertainty methods; by default every score-only method, plus SUE when the dataset has metric positions.
    k, alpha : int, float
        Options of RS, SD and SU.
    retrieval_k : int
        Candidates stored per query (at least k).
    index : str
        Faiss index-factory string (``"Flat"`` = exact search).
    device : str
        ``"cpu"`` or ``"cuda"`` for extraction and search.
    batch_size : int
        Images per forward pass.
    half : bool
        Store descriptors as float16.
    on_error : {"fail", "skip"}
        What to do with an image that cannot be used (see :mod:`vpr_uncertainty.features.images`) or a folder
        that cannot be listed: stop with an error naming it, or leave it out; the images left out are counted
        and named in a warning and in ``results.json`` (``dataset.images_left_out``).
    root, split, radius
        Passed to :func:`vpr_uncertainty.data.load_dataset`.
    method_options : dict
        Further options for the uncertainty methods (e.g. ``btl_head`` or ``max_side``).
    rerank : str, optional
        A geometric verification method (``"GV-SIFT"``, ...) that re-ranks the top ``k`` of each query by
        inliers; results.json then reports the re-ranked recall@N beside the global one.
    bootstrap, seed, reference : int, int, str or None
        Paired bootstrap of the evaluation (0 resamples: none); see :func:`vpr_uncertainty.evaluate`.
    """

    dataset: str | Path
    out: Path
    model: str = "efficientnet-lite0-gem"
    methods: Sequence[str] | None = None
    k: int = 10
    alpha: float = 0.5
    retrieval_k: int = RETRIEVAL_K
    index: str = "Flat"
    device: str = "cpu"
    batch_size: int = 16
    half: bool = False
    on_error: str = "fail"
    root: str | Path | None = None
    split: str | None = None
    radius: float | None = None
    method_options: dict[str, Any] = field(default_factory=dict)
    rerank: str | None = None
    bootstrap: int = 0
    seed: int = 0
    reference: str | None = None

    def to_dict(self) -> dict[str, Any]:
        values = asdict(self)
        return {key: str(value) if isinstance(value, Path) else value for key, value in values.items()}


@dataclass
class RunResult:
    """What :func:`run` produced: the evaluation, the files it wrote and the seconds spent in each stage."""

    evaluation: Evaluation
    retrieval: Retrieval
    paths: dict[str, Path]
    stage_seconds: dict[str, float]


def default_methods(has_metric_positions: bool) -> list[str]:
    """Every score-only method, plus SUE when the database positions are metric."""
    return [*SCORE_ONLY_METHODS, *(["SUE"] if has_metric_positions else [])]


def _subset(names: Sequence[str], kept: np.ndarray) -> np.ndarray:
    """Indices into ``names`` of the names in ``kept`` (extraction leaves out images that failed to decode)."""
    position = {name: index for index, name in enumerate(names)}
    return np.array([position[name] for name in kept], dtype=np.int64)


def _left_out(dataset: Any, descriptors_path: Path, extracted: dict[str, Any]) -> dict[str, Any] | None:
    """The images left out of the run, by split, with their reasons (None when there is none).

    Folders that could not be listed are in the dataset summary (``unlisted``): how many images they held is
    unknown.
    """
    from vpr_uncertainty.features.cache import cache_info

    info = cache_info(descriptors_path) if descriptors_path.is_file() else {}
    report: dict[str, Any] = {"count": 0}
    for split, requested in (("database", dataset.database_names), ("queries", dataset.query_names)):
        reasons = {entry["name"]: entry for entry in info.get(split, {}).get("failed", [])}
        kept = {str(name) for name in extracted[split][0]}
        missing = [name for name in requested if name not in kept]
        report[split] = [reasons.get(name, {"name": name, "error": "no descriptor"}) for name in missing]
        report["count"] += len(missing)
    return report if report["count"] else None


def _digest(*arrays: np.ndarray) -> str:
    hasher = hashlib.sha256()
    for array in arrays:
        hasher.update(np.ascontiguousarray(array).tobytes())
    return hasher.hexdigest()[:16]


def run(config: RunConfig) -> RunResult:
    """Run the whole evaluation of ``config`` and write every stage into ``config.out``.

    Returns
    -------
    RunResult
    """
    from vpr_uncertainty.data import load_dataset
    from vpr_uncertainty.data.attach import attach_ground_truth
    from vpr_uncertainty.features import extract_descriptors, load_model
    from vpr_uncertainty.retrieval import faiss_gpu_available, retrieve

    if config.retrieval_k < config.k:
        raise ValueError(f"retrieval_k ({config.retrieval_k}) must be >= k ({config.k})")
    methods = list(config.methods) if config.methods else None
    for name in methods or []:
        get_method(name)  # unknown names fail before any work
    if config.rerank is not None and get_method(config.rerank).name not in GEOMETRIC_METHODS:
        raise ValueError(
            f"rerank needs a geometric verification method ({', '.join(GEOMETRIC_METHODS)}), got {config.rerank!r}"
        )
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    seconds: dict[str, float] = {}

    start = time.perf_counter()
    dataset = load_dataset(config.dataset, root=config.root, split=config.split, radius=config.radius)
    if not dataset.has_images:
        raise ValueError(f"dataset {dataset.name!r} has no image paths; `run` needs images to extract descriptors")
    fields = dataset.retrieval_fields()
    available = {key for key, value in {**fields, **config.method_options}.items() if value is not None}
    available |= set(PIPELINE_OPTIONS)
    unmet = [
        f"uncertainty method {name!r} needs {describe_needs(need)}, which dataset {dataset.name!r} lacks"
        for name in methods or []
        if (need := get_method(name).unmet_needs(available))
    ]
    if unmet:  # every unmet need at once, before extraction (the slow part)
        raise ValueError("; ".join(unmet))
    if dataset.unlisted:
        from vpr_uncertainty.data.folder import ImageListingError, describe_unlisted

        if config.on_error == "fail":
            raise ImageListingError(dataset.root or config.dataset, dataset.unlisted)
        warnings.warn(
            f"left out the images under {len(dataset.unlisted)} path(s) of dataset {dataset.name!r} that cannot be "
            f"listed: {describe_unlisted(dataset.unlisted)}",
            stacklevel=2,
        )
    seconds["dataset"] = time.perf_counter() - start

    start = time.perf_counter()
    model = load_model(config.model, device=config.device)
    descriptors_path = out / "descriptors.h5"
    extracted = {}
    for split, paths, names in (
        ("database", dataset.database_paths, dataset.database_names),
        ("queries", dataset.query_paths, dataset.query_names),
    ):
        extracted[split] = extract_descriptors(
            model,
            paths,
            names,
            descriptors_path,
            split,
            batch_size=config.batch_size,
            device=config.device,
            half=config.half,
            on_error=config.on_error,
        )
    seconds["extraction"] = time.perf_counter() - start
    left_out = _left_out(dataset, descriptors_path, extracted)

    start = time.perf_counter()
    database_names, database = extracted["database"]
    query_names, queries = extracted["queries"]
    kept_database = _subset(dataset.database_names, database_names)
    kept_queries = _subset(dataset.query_names, query_names)
    positives = fields["positives"][kept_queries][:, kept_database]
    positions = {
        name: None if fields[name] is None else np.asarray(fields[name])[kept]
        for name, kept in (("query_positions", kept_queries), ("database_positions", kept_database))
    }
    retrieval_config = {
        **fields["config"],
        "model": model.name,
        "k": config.retrieval_k,
        "index": config.index,
        "descriptors": _digest(database, queries),
    }
    retrieval_path = out / "retrieval.npz"
    retrieval = None
    if retrieval_path.is_file():
        cached = load_retrieval(retrieval_path)
        # The stored config holds what we asked for plus what the search added (dimension, metric, ...).
        wanted = json.loads(json.dumps(retrieval_config, default=str))
        if all(cached.config.get(key) == value for key, value in wanted.items()):
            retrieval = cached
    if retrieval is None:
        # --device picks the device of the model; Faiss searches on the GPU only where GPU Faiss is installed.
        search_device = "cuda" if config.device.startswith("cuda") and faiss_gpu_available() else "cpu"
        if search_device != config.device.split(":")[0]:
            print(f"note: Faiss has no GPU support here; searching on the CPU (descriptors came from {config.device})")
        retrieval = attach_ground_truth(
            retrieve(
                database,
                queries,
                config.retrieval_k,
                index=config.index,
                device=search_device,
                config=retrieval_config,
            ),
            positives=positives,
            database_names=database_names,
            query_names=query_names,
            position_kind=dataset.position_kind,
            **positions,
        )
        save_retrieval(retrieval, retrieval_path)
    seconds["retrieval"] = time.perf_counter() - start

    start = time.perf_counter()
    if methods is None:
        methods = default_methods(dataset.has_metric_positions)
    options = {
        "query_paths": [dataset.query_paths[i] for i in kept_queries],
        "database_paths": [dataset.database_paths[i] for i in kept_database],
        "query_descriptors": queries,
        "database_descriptors": database,
        "cache_dir": out,
        "device": config.device,
        **config.method_options,
    }
    evaluation = evaluate(
        retrieval,
        methods,
        k=config.k,
        alpha=config.alpha,
        bootstrap=config.bootstrap,
        seed=config.seed,
        reference=config.reference,
        **options,
    )
    seconds["uncertainty_and_evaluation"] = time.perf_counter() - start

    reranking = None
    if config.rerank:
        from vpr_uncertainty.geometric import rerank

        start = time.perf_counter()
        result = rerank(
            retrieval,
            config.rerank,
            top_k=config.k,
            query_paths=options["query_paths"],
            database_paths=options["database_paths"],
            cache_dir=out,
            device=config.device,
        )
        reranking = {"method": config.rerank, "top_k": config.k, **result.recall}
        seconds["reranking"] = time.perf_counter() - start

    start = time.perf_counter()
    summary = {**dataset.summary(), **({"images_left_out": left_out} if left_out else {})}
    paths = _write_outputs(out, evaluation, config, summary, seconds, reranking)
    seconds["reports"] = time.perf_counter() - start
    _rewrite_seconds(paths["results"], seconds)
    paths.update(descriptors=descriptors_path, retrieval=retrieval_path)
    return RunResult(evaluation=evaluation, retrieval=retrieval, paths=paths, stage_seconds=seconds)


def _write_outputs(
    out: Path,
    evaluation: Evaluation,
    config: RunConfig,
    dataset_summary: dict[str, Any],
    seconds: dict[str, float],
    reranking: dict[str, Any] | None = None,
) -> dict[str, Path]:
    uncertainties = out / "uncertainties.npz"
    np.savez_compressed(
        uncertainties,
        correct=evaluation.correct,
        **{name: method.uncertainty for name, method in evaluation.methods.items()},
    )
    results = out / "results.json"
    content = {
        **evaluation.to_dict(),
        "config": config.to_dict(),
        "dataset": dataset_summary,
        "stage_seconds": seconds,
        **({"reranking": reranking} if reranking else {}),
    }
    results.write_text(json.dumps(content, indent=2, default=str) + "\n")
    table = out / "results.md"
    title = f"# {dataset_summary.get('name', config.dataset)} with {config.model}\n"
    text = title + "\n" + format_table(evaluation, markdown=True) + "\n"
    if reranking:
        text += "\n" + format_reranking(reranking) + "\n"
    table.write_text(text)
    plot = plot_rejection_curves(
        evaluation, out / "pr_curves.png", title=f"{dataset_summary.get('name')} · {config.model}"
    )
    return {"uncertainties": uncertainties, "results": results, "table": table, "plot": plot}


def format_reranking(reranking: dict[str, Any]) -> str:
    """recall@N of the global retrieval and after re-ranking its top-k by inliers, in one line."""
    pairs = ", ".join(
        f"R@{n} {reranking['global'][n]:.3f} → {reranking['reranked'][n]:.3f}" for n in reranking["reranked"]
    )
    return f"re-ranking the top {reranking['top_k']} by {reranking['method']} inliers: {pairs}"


def _rewrite_seconds(results: Path, seconds: dict[str, float]) -> None:
    content = json.loads(results.read_text())
    content["stage_seconds"] = seconds
    results.write_text(json.dumps(content, indent=2, default=str) + "\n")
