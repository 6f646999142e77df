"""What users bring, read in one room: one module per external format (:mod:`.matrix`, :mod:`.hloc`,
:mod:`.vpr_methods_evaluation`, :mod:`.ground_truth`, :mod:`.per_query`), each with a cheap ``sniff(path) -> bool`` and
a ``read(path, ...)`` returning the toolkit's types, and the one dispatch of results formats (:func:`read_results`).
What each module reads, and what every reader refuses: see docs/explanation/architecture.md.
"""

from __future__ import annotations

import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.formats import matrix, per_query, vpr_methods_evaluation
from vpr_uncertainty.formats.ground_truth import load_ground_truth
from vpr_uncertainty.plugins import Registry, load_plugins, load_target
from vpr_uncertainty.retrieval.result import SCORE_KINDS, Retrieval, load_retrieval

#: Candidates kept per query when a full matrix is read, unless a larger k asks for more (recall@20 needs 20).
DEFAULT_TOP_K = 50


# --- results formats: what read_results reads ------------------------------------------------------------------


@dataclass(frozen=True)
class ResultsFormat:
    """One format of precomputed results that :func:`read_results` reads.

    Attributes
    ----------
    name, description : str
    reader : callable or str
        A format module's ``read(path, *, ground_truth, top_k) -> Retrieval`` (or ``"module:function"``); with
        ``reads_distances``, it also takes ``scores=`` (:data:`~vpr_uncertainty.retrieval.result.SCORE_KINDS`).
    detect : callable or None
        Its ``sniff(path) -> bool``: whether ``file_format="auto"`` reads ``path`` with this format (tried in
        registration order). None: only read when named.
    provides : tuple of str
        What a file of this format gives the methods (``"scores"``, ``"distances"``, ``"positives"``, ``"names"``).
    extra : str or None
        The pip extra its reader needs.
    reads_distances : bool
        Whether a file of this format may hold distances (``read_results(scores=...)``).
    """

    name: str
    description: str
    reader: Callable[..., Retrieval] | str
    detect: Callable[[Path], bool] | None = None
    provides: tuple[str, ...] = ()
    extra: str | None = None
    reads_distances: bool = False


#: The registered results formats, in detection order.
RESULTS_FORMAT_REGISTRY: Registry[ResultsFormat] = Registry("results format", label="formats")


def register_results_format(entry: ResultsFormat, *, overwrite: bool = False) -> ResultsFormat:
    """Add a results format (``file_format="auto"`` tries it after the ones registered before it)."""
    return RESULTS_FORMAT_REGISTRY.register(entry, overwrite=overwrite)


def input_formats() -> tuple[str, ...]:
    """The values of ``read_results(file_format=...)``: ``"auto"`` and every registered results format."""
    load_plugins()
    return ("auto", *RESULTS_FORMAT_REGISTRY.names())


def read_results(
    path: str | Path,
    *,
    ground_truth: str | Path | None = None,
    file_format: str = "auto",
    top_k: int = DEFAULT_TOP_K,
    scores: str = "similarity",
) -> Retrieval:
    """Read precomputed results and their ground truth into a Retrieval.

    Parameters
    ----------
    path : str or Path
        A retrieval ``.npz``, a similarity matrix ``.npy`` (higher = more similar), a VPR-Bench
        precomputed-matches file, or the log folder of VPR-methods-evaluation run with ``--save_descriptors``
        (its ground truth is derived when not given).
    ground_truth : str or Path, optional
        Ground-truth file; required unless the results hold their positives. When given, it replaces the positives
        stored in a retrieval file.
    file_format : str, default="auto"
        A name of :data:`RESULTS_FORMAT_REGISTRY` (or a plugin's); ``"auto"``: the first registered format whose
        ``detect`` accepts the path, else a similarity matrix, plain or VPR-Bench's, as the file holds.
    top_k : int
        Candidates kept per query when a full matrix is read (all of them when the database is smaller); pass at
        least the largest k the methods will use. A retrieval file keeps the candidates it holds.
    scores : str, default="similarity"
        What a matrix holds (:data:`~vpr_uncertainty.retrieval.result.SCORE_KINDS`): similarities, or distances
        whose k smallest values per query are kept and converted by
        :meth:`~vpr_uncertainty.retrieval.Retrieval.from_distances`. A retrieval file holds similarities (other
        kinds are refused); a log folder is searched by cosine similarity (``"distance"`` is refused).
    """
    path = Path(path)
    if scores not in SCORE_KINDS:
        raise ValueError(f"scores must be one of {SCORE_KINDS}, got {scores!r}")
    if file_format == "auto":  # among the formats registered so far (the CLI loads the plugins first)
        entry = next((entry for entry in RESULTS_FORMAT_REGISTRY if entry.detect and entry.detect(path)), None)
        if entry is None:  # a similarity or distance matrix, plain or VPR-Bench's, as the file holds
            return matrix.read(path, ground_truth=ground_truth, top_k=top_k, file_format="auto", scores=scores)
    else:
        try:
            entry = RESULTS_FORMAT_REGISTRY.get(file_format)  # a miss loads the plugins
        except KeyError:
            raise ValueError(f"file_format must be one of {input_formats()}, got {file_format!r}") from None
    reader = load_target(entry.reader, what=f"results format {entry.name!r}", extra=entry.extra)
    if scores == "similarity":
        return reader(path, ground_truth=ground_truth, top_k=top_k)
    if not entry.reads_distances:
        raise ValueError(
            f"{path} is read as {entry.description}, whose scores are similarities; lower-is-better scores "
            "(distances) are read from a similarity or distance matrix only (formats: "
            f"{', '.join(e.name for e in RESULTS_FORMAT_REGISTRY if e.reads_distances)})"
        )
    return reader(path, ground_truth=ground_truth, top_k=top_k, scores=scores)


def read_pool(path: str | Path, *, ground_truth: str | Path | None = None, **options: Any) -> Retrieval:
    """A pool as ``calibrate`` and ``label`` read it: :func:`read_results` (``options``: its ``file_format``, ``top_k``
    and ``scores``), but a matrix without ``ground_truth`` gives its top-k scores and indices (and
    ``config["n_database"]``); same top-k either way: same pool fingerprint."""
    path, file_format = Path(path), options.get("file_format", "auto")
    if ground_truth is None and file_format in ("auto", "matrix", "vprbench"):
        registered = (entry.detect and entry.detect(path) for entry in RESULTS_FORMAT_REGISTRY)
        if file_format != "auto" or not any(registered):
            return matrix.read(path, ground_truth=None, pool=True, **{"top_k": DEFAULT_TOP_K, **options})
    return read_results(path, ground_truth=ground_truth, **options)


def read_closures(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``edges`` (E, 2) int64 and ``scores`` (E, K) of a loop-closure score file (``.npz``, as ``loop-closures``
    reads it): each closure's two vertex ids (integers >= 0) and its VPR match's top-K similarities."""
    with np.load(path, allow_pickle=False) as file:
        if missing := {"edges", "scores"} - set(file.files):
            raise ValueError(f"{path}: no array {sorted(missing)} (expected edges (E, 2) and scores (E, K))")
        edges, rows = file["edges"], file["scores"]
    numbers = edges.dtype.kind in "iuf" and rows.dtype.kind in "iuf" and edges.ndim == rows.ndim == 2
    if not numbers or edges.shape[1] != 2 or len(edges) != len(rows):
        raise ValueError(f"{path}: expected edges (E, 2) and scores (E, K) of numbers, got {edges.shape} {rows.shape}")
    if (bad := np.flatnonzero(~(np.isfinite(edges) & (edges >= 0) & (edges == np.round(edges))).all(axis=1))).size:
        raise ValueError(f"{path}: edges, row {bad[0]}: vertex ids must be integers >= 0, got {edges[bad[0]].tolist()}")
    return edges.astype(np.int64), rows


def _read_closures_pool(path: Path, **_: Any) -> Retrieval:
    """A loop-closure score file as a pool: one query per closure (no database: every index 0), its edges in
    ``config["edges"]``."""
    edges, rows = read_closures(path)
    indices = np.zeros(rows.shape, dtype=np.int64)
    return Retrieval(rows, indices, config={"source": str(path), "edges": edges.tolist(), "n_database": 1})


def _is_closures_file(path: Path) -> bool:
    if path.suffix.lower() != ".npz" or not path.is_file():
        return False
    try:
        with np.load(path, allow_pickle=False) as file:
            return {"edges", "scores"} <= set(file.files) and "indices" not in file.files
    except (OSError, ValueError, zipfile.BadZipFile):  # not a zip of arrays: another reader says what it is
        return False


def _read_retrieval_file(path: Path, *, ground_truth: str | Path | None, **_: Any) -> Retrieval:
    retrieval = load_retrieval(path)
    if ground_truth is not None:
        n_database = retrieval.positives.shape[1] if retrieval.positives is not None else None
        retrieval.positives = load_ground_truth(ground_truth, n_queries=retrieval.n_queries, n_database=n_database)
        retrieval.config.pop("positives_vs_mean", None)  # measured against the positives replaced
        retrieval.__post_init__()
    return retrieval


for _entry in (
    ResultsFormat(
        "closures",
        "a loop-closure score file (.npz: edges (E, 2) and scores (E, K)): one query per closure",
        _read_closures_pool,
        detect=_is_closures_file,
        provides=("scores",),
    ),
    ResultsFormat(
        "vpr-methods-evaluation",
        "a VPR-methods-evaluation log folder saved with --save_descriptors (searched again with Faiss)",
        vpr_methods_evaluation.read,
        detect=vpr_methods_evaluation.sniff,
        provides=("scores", "distances", "positives", "names"),
        reads_distances=True,
    ),
    ResultsFormat(
        "retrieval",
        "a retrieval file (.npz: scores, indices and optionally the ground truth)",
        _read_retrieval_file,
        detect=lambda path: path.suffix.lower() == ".npz",
        provides=("scores", "distances", "positives", "names", "positions"),
    ),
    ResultsFormat(
        "per-query",
        "the per-query table of evaluate --per-query (.csv, .parquet: top-1, correct, s_1 ... s_K)",
        per_query.read,
        detect=per_query.sniff,
        provides=("scores", "positives", "names"),
    ),
    ResultsFormat(
        "matrix",
        "a full (queries × database) similarity or distance matrix (.npy)",
        partial(matrix.read, file_format="matrix"),
        provides=("scores",),
        reads_distances=True,
    ),
    ResultsFormat(
        "vprbench",
        "VPR-Bench's precomputed_data_corrected.npy",
        partial(matrix.read, file_format="vprbench"),
        provides=("scores",),
        reads_distances=True,
    ),
):
    register_results_format(_entry)
