"""Images to answers: :func:`run` composes the stages of :mod:`vpr_uncertainty.stages` on a dataset of images.

Each stage writes one file into the run directory (atomically), and a rerun reuses what is still valid
(:mod:`vpr_uncertainty.cache`):

======================  =========================================================================================
``descriptors.h5``      global descriptors keyed by image name and content key (resumed per image; an image
                        replaced on disk is recomputed; rebuilt when the model or its preprocessing changes)
``retrieval.npz``       top-k scores, indices, distances, positives, names and positions (reused while the
                        descriptors, the ground truth, k and the index are unchanged)
``uncertainties.npz``   one (Q,) array per uncertainty method, higher = less trustworthy, ``correct`` and the
                        ``fingerprint`` of what produced them
``results.json``        the schema of ``evaluate --json``, plus the run configuration, the time of each stage
                        and, under ``dataset``, the images left out (``images_left_out``) and the folders
                        that could not be listed (``unlisted``) with ``on_error="skip"``
``results.md``          the table
``pr_curves.png``       end-to-end precision-recall of every method
======================  =========================================================================================
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.evaluation import Evaluation
from vpr_uncertainty.methods import GEOMETRIC_METHODS, default_method_names, describe_needs, get_method
from vpr_uncertainty.retrieval import Retrieval
from vpr_uncertainty.stages import (
    DescriptorsConfig,
    RetrievalConfig,
    UncertaintyConfig,
    evaluate,
    extract,
    search,
    write_reports,
)
from vpr_uncertainty.stages.reports import format_reranking
from vpr_uncertainty.stages.retrieval import search_device

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
    dataset : str, Path or Dataset
        A dataset folder in any format :func:`vpr_uncertainty.data.load_dataset` reads, a registered name, or a
        :class:`~vpr_uncertainty.data.Dataset` already loaded (``root``, ``split`` and ``radius`` then unused).
    out : Path
        The run directory.
    model : str
        A descriptor model name (:func:`vpr_uncertainty.descriptors.available_models`) or a TorchScript file.
    methods : sequence of str, optional
        Uncertainty methods; by default the registry's default entries (as ``evaluate``), plus SUE when the
        dataset has metric positions.
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
        What to do with an image that cannot be used (see :mod:`vpr_uncertainty.descriptors.images`) or a folder
        that cannot be listed: stop with an error naming it, or leave it out; the images left out are counted
        and named in a warning and in ``results.json`` (``dataset.images_left_out``).
    root, split, radius
        Passed to :func:`vpr_uncertainty.data.load_dataset`.
    image_size, max_side, num_workers : int, optional
        Overrides of the model's preprocessing and the image decoding threads (see
        :class:`~vpr_uncertainty.stages.DescriptorsConfig`).
    method_options : dict
        Further options for the uncertainty methods (e.g. ``btl_head`` or ``max_side``).
    rerank : str, optional
        A geometric verification method (``"GV-SIFT"``, ...) that re-ranks the top ``k`` of each query by
        inliers; results.json then reports the re-ranked recall@N beside the global one.
    bootstrap, seed, reference : int, int, str or None
        Paired bootstrap of the evaluation (0 resamples: none); see :func:`vpr_uncertainty.evaluate`.
    """

    dataset: Any
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
    image_size: int | None = None
    max_side: int | None = None
    num_workers: int | None = None
    method_options: dict[str, Any] = field(default_factory=dict)
    rerank: str | None = None
    bootstrap: int = 0
    seed: int = 0
    reference: str | None = None

    def to_dict(self) -> dict[str, Any]:
        dataset = self.dataset
        if not isinstance(dataset, (str, Path)):  # a loaded Dataset: its folder, else its name
            dataset = dataset.root if getattr(dataset, "root", None) is not None else dataset.name
        values = asdict(dataclasses.replace(self, dataset=None))
        values["dataset"] = dataset
        return {key: str(value) if isinstance(value, Path) else value for key, value in values.items()}


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
        Seconds spent in each stage.
    dataset : Dataset, optional
        The dataset the run read.
    reranking : dict, optional
        The re-ranking summary (with ``rerank``).
    notes : list of str
        Remarks for the user (e.g. a search moved from the GPU to the CPU).
    """

    evaluation: Evaluation
    retrieval: Retrieval
    paths: dict[str, Path]
    stage_seconds: dict[str, float]
    dataset: Any = None
    reranking: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)


def default_methods(has_metric_positions: bool) -> list[str]:
    """The registry's default methods (those ``evaluate`` runs by default), plus SUE when the positions are metric."""
    return default_method_names(metric_positions=has_metric_positions)


def _positions_of(names: Sequence[str], kept: np.ndarray) -> np.ndarray:
    """Indices into ``names`` of the names in ``kept`` (extraction leaves out images that cannot be used)."""
    position = {name: index for index, name in enumerate(names)}
    return np.array([position[name] for name in kept], dtype=np.int64)


def _left_out(dataset: Any, descriptors: Any) -> dict[str, Any] | None:
    """The images left out of the run, by split, with their reasons (None when there is none).

    Folders that could not be listed are in the dataset summary (``unlisted``): how many images they held is
    unknown.
    """
    report: dict[str, Any] = {"count": 0}
    for split, requested in (("database", dataset.database_names), ("queries", dataset.query_names)):
        reasons = {entry["name"]: entry for entry in descriptors.failed.get(split, [])}
        kept = {str(name) for name in descriptors.names[split]}
        missing = [name for name in requested if name not in kept]
        report[split] = [reasons.get(name, {"name": name, "error": "no descriptor"}) for name in missing]
        report["count"] += len(missing)
    return report if report["count"] else None


def _load_and_check(config: RunConfig, methods: list[str] | None) -> Any:
    """The dataset of ``config``, after every check that can fail before extraction (the slow part)."""
    from vpr_uncertainty.data import load_dataset

    if config.retrieval_k < config.k:
        raise ValueError(f"retrieval_k ({config.retrieval_k}) must be >= k ({config.k})")
    for name in methods or []:
        get_method(name)  # unknown names fail before any work
    if config.rerank is not None and get_method(config.rerank).name not in GEOMETRIC_METHODS:
        raise ValueError(
            f"rerank needs a geometric verification method ({', '.join(GEOMETRIC_METHODS)}), got {config.rerank!r}"
        )
    if isinstance(config.dataset, (str, Path)):
        dataset = load_dataset(config.dataset, root=config.root, split=config.split, radius=config.radius)
    else:
        dataset = config.dataset
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
    if unmet:  # every unmet need at once
        raise ValueError("; ".join(unmet))
    if dataset.unlisted:
        from vpr_uncertainty.data.images import ImageListingError, describe_unlisted

        if config.on_error == "fail":
            raise ImageListingError(dataset.root or config.dataset, dataset.unlisted)
        warnings.warn(
            f"left out the images under {len(dataset.unlisted)} path(s) of dataset {dataset.name!r} that cannot be "
            f"listed: {describe_unlisted(dataset.unlisted)}",
            stacklevel=3,
        )
    return dataset


def _ground_truth(dataset: Any, descriptors: Any) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    """The ground-truth fields of the images that have descriptors, and their indices in the dataset."""
    from vpr_uncertainty.data.dataset import ground_truth_fields

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


def run(config: RunConfig, *, executor: Any = None) -> RunResult:
    """Run the whole evaluation of ``config`` and write every stage into ``config.out``.

    Parameters
    ----------
    config : RunConfig
    executor : LocalExecutor or RayExecutor, optional
        Where descriptor extraction and the pairs of geometric verification (the GV-* methods, their cascades
        and ``rerank``) run (:func:`vpr_uncertainty.executors.get_executor`; default: this process). The results
        are those of a local run.

    Returns
    -------
    RunResult
    """
    methods = list(config.methods) if config.methods else None
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    dataset = _load_and_check(config, methods)
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    seconds["dataset"] = time.perf_counter() - start

    start = time.perf_counter()
    conf = DescriptorsConfig(
        model=config.model,
        device=config.device,
        batch_size=config.batch_size,
        half=config.half,
        on_error=config.on_error,
        image_size=config.image_size,
        max_side=config.max_side,
        num_workers=config.num_workers,
    )
    images = {
        "database": (dataset.database_paths, dataset.database_names),
        "queries": (dataset.query_paths, dataset.query_names),
    }
    descriptors = extract(conf, images, out / "descriptors.h5", executor=executor)
    seconds["extraction"] = time.perf_counter() - start

    start = time.perf_counter()
    ground_truth, kept_database, kept_queries = _ground_truth(dataset, descriptors)
    device, note = search_device(config.device)  # --device picks the model's device; Faiss may lack the GPU
    found = search(
        RetrievalConfig(k=config.retrieval_k, index=config.index, device=device),
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
        "device": config.device,
    }
    if executor is not None:
        inputs["executor"] = executor  # a stage input: the GV-* methods verify their pairs there
    uncertainty = evaluate(
        UncertaintyConfig(
            methods=methods or default_methods(dataset.has_metric_positions),
            k=config.k,
            alpha=config.alpha,
            options=dict(config.method_options),
            bootstrap=config.bootstrap,
            seed=config.seed,
            reference=config.reference,
        ),
        retrieval,
        out / "uncertainties.npz",
        inputs=inputs,
        retrieval_fingerprint=found.fingerprint,
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
            query_paths=inputs["query_paths"],
            database_paths=inputs["database_paths"],
            cache_dir=out,
            device=config.device,
            executor=executor,
        )
        reranking = {"method": config.rerank, "top_k": config.k, **result.recall}
        seconds["reranking"] = time.perf_counter() - start

    left_out = _left_out(dataset, descriptors)
    reports = write_reports(
        out,
        uncertainty.evaluation,
        dataset=dataset.summary().get("name", str(config.dataset)),
        model=config.model,
        document={
            "config": config.to_dict(),
            "dataset": {**dataset.summary(), **({"images_left_out": left_out} if left_out else {})},
        },
        stage_seconds=seconds,
        reranking=reranking,
    )
    paths = {
        **reports.paths,
        "uncertainties": uncertainty.path,
        "descriptors": descriptors.path,
        "retrieval": found.path,
    }
    return RunResult(
        evaluation=uncertainty.evaluation,
        retrieval=retrieval,
        paths=paths,
        stage_seconds=seconds,
        dataset=dataset,
        reranking=reranking,
        notes=[note] if note else [],
    )
