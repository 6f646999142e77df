"""Reproduce the study: VPR methods × datasets × uncertainty methods, then tables, figures and one HTML report.

A grid is described by a TOML file (read with :mod:`tomllib`) or a YAML file (needs ``pyyaml``)::

    out = "runs/reproduce"              # relative paths are relative to the config file
    methods = ["RS", "SD", "SU", "PA", "L2", "BM"]
    k = 10
    alpha = 0.5
    alphas = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]   # α ablation (SU); [] to skip
    ks = [2, 3, 5, 10, 15, 20, 30, 50]                                  # k ablation (RS, SD); [] to skip

    [[inputs]]                          # a VPR-Bench precomputed_matches folder: one cell per method subfolder
    precomputed_matches = "precomputed_matches/corridor"
    ground_truth = "corridor/ground_truth_new.npy"
    dataset = "corridor"                # name of the dataset column (default: the folder name)
    images = "corridor"                 # optional: VPR-Bench image folder (query/, ref/) for the qualitative figure
    vpr_methods = ["NetVLAD", "HOG"]    # optional subset of the subfolders

    [[inputs]]                          # one similarity matrix (.npy) or retrieval file (.npz)
    vpr_method = "mine"
    dataset = "corridor"
    scores = "mine.npz"
    ground_truth = "corridor/ground_truth_new.npy"   # optional for a retrieval file that holds its positives

    [[inputs]]                          # from images: pipeline.run (descriptors, retrieval, all cached)
    dataset = "corridor"                # dataset path or name (see vpr_uncertainty.data.load_dataset)
    model = "efficientnet-lite0-gem"
    root = "~/vpr-data"                 # optional options of RunConfig: root, device, batch_size, index, split

``methods`` may carry method options (``"SUE:clip=one-sided"``, see
:func:`vpr_uncertainty.methods.parse_method_spec`); ``qualitative = ["NetVLAD"]`` picks the VPR methods whose cells
get a qualitative figure (default: the first cell with images). One grid cell = one (VPR method, dataset). Each
cell is cached under ``out/cells``: a rerun skips the cells whose inputs and settings did not change
(``force=True`` recomputes them). The whole configuration is validated (every file exists, every method is known,
every need of every method is met by every cell's inputs) before any work
starts, by :mod:`vpr_uncertainty.reproduce_config`.
"""

from __future__ import annotations

import csv
import hashlib
import json
import warnings
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.evaluation import (
    RECALL_NS,
    Evaluation,
    FewerCandidatesWarning,
    MethodEvaluation,
    auc_pr,
    correct_at_n,
    evaluate,
    recall_at_full_precision,
    rejection_curve,
)
from vpr_uncertainty.methods import get_method
from vpr_uncertainty.reproduce_config import (
    DEFAULT_ALPHAS,
    DEFAULT_KS,
    VPRBENCH_FILE,
    GridConfig,
    InputEntry,
    _slug,
    load_config,
)

__all__ = [
    "DEFAULT_ALPHAS",
    "DEFAULT_KS",
    "VPRBENCH_FILE",
    "Cell",
    "GridConfig",
    "InputEntry",
    "load_config",
    "run_grid",
    "write_results",
]

#: Candidates per query whose correctness is kept for the qualitative figure.
HIT_COLUMNS = 4
CSV_FIELDS = (
    "vpr_method",
    "dataset",
    "uncertainty_method",
    "auc_pr",
    "average_precision",
    "aurc",
    "time_per_query_ms",
    "recall_at_100_precision",
    "n_queries",
)


@dataclass
class Cell:
    """Everything the reports need from one (VPR method, dataset) cell."""

    vpr_method: str
    dataset: str
    evaluation: Evaluation
    scores: np.ndarray
    indices: np.ndarray
    ablation_alpha: dict[float, float | None]
    ablation_k: dict[str, dict[int, float | None]]
    hits: np.ndarray | None = None
    query_paths: list[str] | None = None
    database_paths: list[str] | None = None
    cached: bool = False

    def rows(self) -> list[dict[str, Any]]:
        """Long-format rows, one per uncertainty method."""
        recalls = {f"recall@{n}": value for n, value in self.evaluation.recall_at_n.items()}
        rows = []
        for name, method in self.evaluation.methods.items():
            metrics = method.to_dict()
            rows.append(
                {
                    "vpr_method": self.vpr_method,
                    "dataset": self.dataset,
                    "uncertainty_method": name,
                    **{key: metrics.get(key) for key in CSV_FIELDS[3:-1]},
                    "n_queries": self.evaluation.n_queries,
                    **recalls,
                }
            )
        return rows


# --- one cell -----------------------------------------------------------------------------------------------------


def _load_cell_input(entry: InputEntry, config: GridConfig, out: Path) -> tuple[Any, Evaluation | None, Any]:
    """The cell's Retrieval, the pipeline's Evaluation when it ran one, and its image dataset (or None)."""
    if entry.model is None:
        from vpr_uncertainty.retrieval import MATRIX_TOP_K, read_results

        retrieval = read_results(
            entry.scores,
            ground_truth=entry.ground_truth,
            file_format=entry.file_format,
            top_k=max(MATRIX_TOP_K, candidates_needed(config)),
        )
        return retrieval, None, None
    from vpr_uncertainty.pipeline import RunConfig, run

    options = dict(entry.run_options)
    result = run(
        RunConfig(
            dataset=entry.dataset_source,
            out=out / "runs" / entry.key,
            model=entry.model,
            methods=config.methods,
            k=config.k,
            alpha=config.alpha,
            retrieval_k=candidates_needed(config),
            **options,
        )
    )
    from vpr_uncertainty.data import load_dataset

    dataset = load_dataset(entry.dataset_source, root=options.get("root"), split=options.get("split"))
    return result.retrieval, result.evaluation, dataset


def candidates_needed(config: GridConfig) -> int:
    """Candidates per query a cell needs: the largest k asked for (k and the k ablation) and recall@20."""
    return max([config.k, *config.ks, max(RECALL_NS)])


def _ablation_note(retrieval: Any, config: GridConfig) -> str | None:
    """A note when the k ablation leaves out ks larger than the candidates the retrieval holds."""
    left_out = [value for value in config.ks if value > retrieval.k]
    if not left_out:
        return None
    return (
        f"k ablation: k = {', '.join(map(str, left_out))} left out, the retrieval holds {retrieval.k} candidates "
        "per query"
    )


def _ablations(retrieval: Any, correct: np.ndarray, config: GridConfig) -> tuple[dict, dict]:
    both = bool(correct.any() and not correct.all())
    su, rs, sd = get_method("SU"), get_method("RS"), get_method("SD")
    k = min(config.k, retrieval.k)
    alpha_curve = {a: (auc_pr(correct, su(retrieval, k=k, alpha=a)) if both else None) for a in config.alphas}
    k_curve: dict[str, dict[int, float | None]] = {"RS": {}, "SD": {}}
    for value in config.ks:
        if value > retrieval.k:
            continue
        for name, method in (("RS", rs), ("SD", sd)):
            k_curve[name][value] = auc_pr(correct, method(retrieval, k=value)) if both else None
    return alpha_curve, k_curve


def _hits(retrieval: Any, n: int) -> np.ndarray:
    """(Q, n) bool: whether each of the first n candidates is a positive."""
    indices = retrieval.indices[:, :n]
    rows = np.repeat(np.arange(len(indices)), indices.shape[1])
    hits = np.asarray(retrieval.positives[rows, np.maximum(indices.ravel(), 0)]).reshape(indices.shape)
    return hits.astype(bool) & (indices >= 0)


def _cell_fingerprint(entry: InputEntry, config: GridConfig) -> str:
    settings = {**config.settings(), "candidates": candidates_needed(config)}
    text = json.dumps({"input": entry.fingerprint(), "settings": settings}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _save_cell(cell: Cell, json_path: Path, npz_path: Path, fingerprint: str) -> None:
    evaluation = cell.evaluation
    arrays = {
        "correct": evaluation.correct,
        "scores": cell.scores,
        "indices": cell.indices,
        "hits": cell.hits,
        **{f"uncertainty/{name}": m.uncertainty for name, m in evaluation.methods.items()},
    }
    np.savez_compressed(npz_path, **arrays)
    meta = {
        "fingerprint": fingerprint,
        "vpr_method": cell.vpr_method,
        "dataset": cell.dataset,
        "n_answerable": evaluation.n_answerable,
        "recall_at_n": {str(n): v for n, v in evaluation.recall_at_n.items()},
        "notes": evaluation.notes,
        "evaluation": evaluation.to_dict(),
        "ablation_alpha": [[a, v] for a, v in cell.ablation_alpha.items()],
        "ablation_k": {name: [[k, v] for k, v in curve.items()] for name, curve in cell.ablation_k.items()},
        "query_paths": cell.query_paths,
        "database_paths": cell.database_paths,
    }
    json_path.write_text(json.dumps(meta, indent=1) + "\n")


def _load_cell(json_path: Path, npz_path: Path, fingerprint: str) -> Cell | None:
    if not (json_path.is_file() and npz_path.is_file()):
        return None
    try:
        meta = json.loads(json_path.read_text())
        if meta.get("fingerprint") != fingerprint:
            return None
        with np.load(npz_path, allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):  # a cell cut short is recomputed
        return None
    correct = arrays["correct"].astype(bool)
    methods = {}
    for name, metrics in meta["evaluation"]["methods"].items():
        uncertainty = arrays[f"uncertainty/{name}"]
        curve = rejection_curve(correct, uncertainty, n_answerable=meta["n_answerable"])
        methods[name] = MethodEvaluation(
            name=name,
            uncertainty=uncertainty,
            auc_pr=metrics["auc_pr"],
            average_precision=metrics["average_precision"],
            aurc=metrics["aurc"],
            time_per_query_ms=metrics["time_per_query_ms"],
            curve=curve,
            recall_at_full_precision=recall_at_full_precision(curve),
            precision_at_recall={float(k): v for k, v in metrics["precision_at_recall"].items()},
            own_recall_at_1=metrics.get("own_recall@1"),
        )
    evaluation = Evaluation(
        n_queries=len(correct),
        n_answerable=meta["n_answerable"],
        correct=correct,
        recall_at_n={int(n): v for n, v in meta["recall_at_n"].items()},
        methods=methods,
        notes=list(meta["notes"]),
        k=meta["evaluation"].get("k"),
        k_requested=meta["evaluation"].get("k_requested", meta["evaluation"].get("k")),
    )
    return Cell(
        vpr_method=meta["vpr_method"],
        dataset=meta["dataset"],
        evaluation=evaluation,
        scores=arrays["scores"],
        indices=arrays["indices"],
        hits=arrays["hits"],
        ablation_alpha={float(a): v for a, v in meta["ablation_alpha"]},
        ablation_k={name: {int(k): v for k, v in curve} for name, curve in meta["ablation_k"].items()},
        query_paths=meta.get("query_paths"),
        database_paths=meta.get("database_paths"),
        cached=True,
    )


def run_cell(entry: InputEntry, config: GridConfig, *, force: bool = False) -> Cell:
    """Evaluate one (VPR method, dataset) cell, or read it from ``config.out/cells`` when it is up to date."""
    out = Path(config.out)
    cells = out / "cells"
    cells.mkdir(parents=True, exist_ok=True)
    json_path, npz_path = cells / f"{entry.key}.json", cells / f"{entry.key}.npz"
    fingerprint = _cell_fingerprint(entry, config)
    if not force:
        cached = _load_cell(json_path, npz_path, fingerprint)
        if cached is not None:
            return cached
    retrieval, evaluation, dataset = _load_cell_input(entry, config, out)
    query_paths = database_paths = None
    if dataset is None and entry.images is not None:
        from vpr_uncertainty.data import load_vprbench_dataset

        dataset = load_vprbench_dataset(entry.images)
    if dataset is not None and dataset.has_images:
        query_paths = [str(p) for p in dataset.query_paths]
        database_paths = [str(p) for p in dataset.database_paths]
        if len(query_paths) != retrieval.n_queries:
            query_paths = database_paths = None
    if evaluation is None:
        # Image-based methods (geometric verification) get the images and one local-feature cache for the grid.
        options = {} if query_paths is None else {"query_paths": query_paths, "database_paths": database_paths}
        evaluation = evaluate(
            retrieval,
            config.methods,
            k=config.k,
            alpha=config.alpha,
            cache_dir=out / "local_features",
            **options,
        )
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    alpha_curve, k_curve = _ablations(retrieval, correct, config)
    left_out = _ablation_note(retrieval, config)
    if left_out:
        evaluation.notes.append(left_out)
        warnings.warn(f"{entry.key}: {left_out}", FewerCandidatesWarning, stacklevel=2)
    cell = Cell(
        vpr_method=entry.vpr_method,
        dataset=entry.dataset,
        evaluation=evaluation,
        scores=np.asarray(retrieval.scores, dtype=np.float32),
        indices=retrieval.indices,
        ablation_alpha=alpha_curve,
        ablation_k=k_curve,
        hits=_hits(retrieval, HIT_COLUMNS),
        query_paths=query_paths,
        database_paths=database_paths,
    )
    _save_cell(cell, json_path, npz_path, fingerprint)
    return cell


def run_grid(config: GridConfig, *, force: bool = False, progress: bool | None = None) -> list[Cell]:
    """Run (or read from the cache) every cell of the grid, with a progress bar."""
    from tqdm import tqdm

    from vpr_uncertainty.data.vprbench import PickleWarning

    cells = []
    disable = None if progress is None else not progress
    with (
        warnings.catch_warnings(record=True) as caught,
        tqdm(total=len(config.inputs), desc="grid", unit="cell", disable=disable) as bar,
    ):
        warnings.simplefilter("always", PickleWarning)
        for entry in config.inputs:
            bar.set_postfix_str(f"{entry.vpr_method} / {entry.dataset}", refresh=False)
            cells.append(run_cell(entry, config, force=force))
            bar.update(1)
    others = [w for w in caught if not issubclass(w.category, PickleWarning)]
    pickled = len(caught) > len(others)
    for warning in others:
        warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    if pickled:
        warnings.warn(
            "VPR-Bench legacy files (similarity matrices, ground truth) were read with pickle; open only files "
            "you trust",
            PickleWarning,
            stacklevel=2,
        )
    return cells


def write_results(cells: Sequence[Cell], config: GridConfig) -> dict[str, Path]:
    """Write ``results.json`` (every cell's evaluation and ablations) and the long-format ``results.csv``."""
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    document = {
        "settings": config.settings(),
        "cells": [
            {
                "vpr_method": cell.vpr_method,
                "dataset": cell.dataset,
                **cell.evaluation.to_dict(),
                "ablation_alpha": {f"{a:g}": v for a, v in cell.ablation_alpha.items()},
                "ablation_k": {name: {str(k): v for k, v in c.items()} for name, c in cell.ablation_k.items()},
            }
            for cell in cells
        ],
    }
    json_path = out / "results.json"
    json_path.write_text(json.dumps(document, indent=2) + "\n")
    rows = [row for cell in cells for row in cell.rows()]
    recall_fields = sorted({key for row in rows for key in row if key.startswith("recall@")}, key=lambda s: int(s[7:]))
    csv_path = out / "results.csv"
    with csv_path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=[*CSV_FIELDS, *recall_fields])
        writer.writeheader()
        writer.writerows(rows)
    return {"results_json": json_path, "results_csv": csv_path}


# --- reports ------------------------------------------------------------------------------------------------------


def write_reports(cells: Sequence[Cell], config: GridConfig, *, html: bool = True) -> dict[str, Any]:
    """Table 1 (md, csv, tex), ΔAUC-PR heatmaps, ablations, PR curves, qualitative figures and ``report.html``."""
    from html import escape

    from vpr_uncertainty.reports import plot_rejection_curves
    from vpr_uncertainty.reports.ablations import plot_alpha_ablation, plot_k_ablation
    from vpr_uncertainty.reports.heatmaps import plot_delta_heatmaps
    from vpr_uncertainty.reports.html import Section, write_report
    from vpr_uncertainty.reports.qualitative import plot_qualitative
    from vpr_uncertainty.reports.table1 import build_table1, table1_csv, table1_html, table1_latex, table1_markdown

    out = Path(config.out)
    figures = out / "figures"
    paths: dict[str, Any] = {}
    table = build_table1(cells)
    for suffix, render in (("md", table1_markdown), ("csv", table1_csv), ("tex", table1_latex)):
        paths[f"table1_{suffix}"] = out / f"table1.{suffix}"
        paths[f"table1_{suffix}"].write_text(render(table))
    paths["heatmaps"] = plot_delta_heatmaps(cells, figures)
    paths["ablations"] = []
    if any(c.ablation_alpha for c in cells):
        paths["ablations"].append(plot_alpha_ablation(cells, figures / "ablation_alpha.png"))
    if any(curve for c in cells for curve in c.ablation_k.values()):
        paths["ablations"].append(plot_k_ablation(cells, figures / "ablation_k.png"))
    paths["pr_curves"] = [
        plot_rejection_curves(
            cell.evaluation,
            figures / "pr" / f"{_slug(cell.vpr_method)}__{_slug(cell.dataset)}.png",
            title=f"{cell.vpr_method} on {cell.dataset}",
        )
        for cell in cells
    ]
    chosen = [c for c in cells if c.query_paths and (config.qualitative is None or c.vpr_method in config.qualitative)]
    if config.qualitative is None:
        chosen = chosen[:1]
    paths["qualitative"] = [
        p
        for c in chosen
        if (
            p := plot_qualitative(
                c,
                figures / f"qualitative__{_slug(c.vpr_method)}__{_slug(c.dataset)}.png",
                k=config.k,
                alpha=config.alpha,
            )
        )
        is not None
    ]
    if html:
        settings = escape(json.dumps(config.settings()))
        sections = [
            Section(
                "Table 1: AUC-PR averaged over datasets",
                table1_html(table) + '<p class="note">Best per column in bold. ms/query: mean time per query.</p>',
            ),
            Section("ΔAUC-PR of RS, SD and SU against each baseline", figures=[(p.stem, p) for p in paths["heatmaps"]]),
            Section("Ablations", figures=[(p.stem, p) for p in paths["ablations"]]),
            Section("End-to-end precision-recall with rejection", figures=[(p.stem, p) for p in paths["pr_curves"]]),
            Section("Qualitative examples", figures=[(p.stem, p) for p in paths["qualitative"]]),
        ]
        intro = f"{len(cells)} cells (VPR method × dataset). Settings: <code>{settings}</code>"
        paths["report_html"] = write_report(
            out / "report.html", "vpr-uncertainty: reproduction report", sections, intro=intro
        )
    return paths
