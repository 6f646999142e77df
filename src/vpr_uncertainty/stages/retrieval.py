"""Stage 2, retrieval: descriptors and ground truth → ``retrieval.npz`` (top-k candidates with their ground truth).

The file stores, in its ``config``, the :func:`~vpr_uncertainty.cache.fingerprint` of the search options and of
the content of every input: both descriptor arrays with their names, and the ground truth (positives, positions,
names, radius, position kind). A rerun reuses the file only when the fingerprint is equal: new descriptors, an
edited ground truth or another ``k`` or index recompute it. A truncated or foreign file is reported in one line
and rebuilt; a file of the previous version (no fingerprint) is rebuilt with a one-line notice.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty import cache

__all__ = ["RetrievalConfig", "RetrievalResult", "ground_truth_key", "search", "search_device"]

STAGE = "retrieval"


@dataclass(frozen=True)
class RetrievalConfig:
    """How :func:`search` finds the candidates.

    Attributes
    ----------
    k : int
        Candidates kept per query.
    index : str
        Faiss index-factory string (``"Flat"`` = exact search).
    search_params : str, optional
        Parameters of an approximate index, e.g. ``"nprobe=32"``.
    device : str
        ``"cpu"`` or ``"cuda"`` (which needs GPU Faiss: see :func:`search_device`).
    batch_size : int
        Queries searched at once.
    database_block : int, optional
        Exact search reads the database in blocks of this many rows (see
        :func:`~vpr_uncertainty.retrieval.search.search_descriptors`); by default a database on disk (a
        :class:`~vpr_uncertainty.retrieval.descriptor_rows.DescriptorRows`) larger than 64 MiB is streamed, one in
        memory is searched whole. It changes the memory used, not the result, and is not part of the fingerprint
        (which hashes a database on disk in blocks of 64 MiB).
    progress : bool, optional
        Show progress bars (default: on a terminal, for long searches; see :mod:`vpr_uncertainty.progress`).
    """

    k: int = 20
    index: str = "Flat"
    search_params: str | None = None
    device: str = "cpu"
    batch_size: int = 4096
    database_block: int | None = None
    progress: bool | None = None


@dataclass
class RetrievalResult:
    """What :func:`search` produced: the file, the retrieval in memory, its fingerprint, whether it was reused."""

    path: Path
    retrieval: Any
    fingerprint: str
    reused: bool = False


def ground_truth_key(fields: Mapping[str, Any]) -> str:
    """A digest of the content of ground-truth fields (:func:`vpr_uncertainty.data.attach.ground_truth_fields`)."""
    positives = fields.get("positives")
    parts: list[Any] = []
    if positives is None:
        parts += [None, None, None]
    else:
        from scipy import sparse

        matrix = sparse.csr_array(positives, dtype=bool)
        matrix.sort_indices()
        parts += [np.asarray(matrix.shape, dtype=np.int64), matrix.indptr.astype(np.int64), matrix.indices]
    for name in ("query_names", "database_names"):
        value = fields.get(name)
        parts.append(None if value is None else np.asarray(value, dtype=str))
    for name in ("query_positions", "database_positions"):
        value = fields.get(name)
        parts.append(None if value is None else np.asarray(value, dtype=np.float64))
    return cache.fingerprint("ground_truth", dict(fields.get("config") or {}), {"arrays": cache.array_digest(*parts)})


def search(
    conf: RetrievalConfig,
    database: tuple[Any, np.ndarray],
    queries: tuple[Any, np.ndarray],
    ground_truth: Mapping[str, Any] | None,
    path: str | Path,
    *,
    describe: Mapping[str, Any] | None = None,
    copy: bool = True,
) -> RetrievalResult:
    """Top-``conf.k`` database candidates of each query, with the ground truth attached, cached in ``path``.

    Parameters
    ----------
    conf : RetrievalConfig
    database, queries : tuple of (names or None, ndarray of shape (N, D))
        Descriptors and their image names. The database may be a
        :class:`~vpr_uncertainty.retrieval.descriptor_rows.DescriptorRows` (from
        :func:`~vpr_uncertainty.retrieval.descriptor_rows.open_descriptors`): it is then hashed and searched one
        block of rows at a time, never read whole (exact search).
    ground_truth : mapping, optional
        Fields made by :func:`vpr_uncertainty.data.attach.ground_truth_fields` (None: no ground truth).
    path : str or Path
        The retrieval file (``.npz``).
    describe : mapping, optional
        Further entries of the file's ``config`` (e.g. the model, the dataset); they are part of the fingerprint.
    copy : bool
        Leave the descriptor arrays untouched (False normalises them in place).

    Returns
    -------
    RetrievalResult
    """
    from vpr_uncertainty.data.dataset import attach_ground_truth
    from vpr_uncertainty.retrieval import load_retrieval, retrieve, save_retrieval

    path = Path(path)
    (database_names, database_array), (query_names, query_array) = database, queries
    describe = dict(describe or {})
    options = {"k": conf.k, "index": conf.index, "search_params": conf.search_params}
    inputs = {
        "database": cache.array_digest(_names(database_names), database_array),
        "queries": cache.array_digest(_names(query_names), query_array),
        "ground_truth": None if ground_truth is None else ground_truth_key(ground_truth),
    }
    fingerprint = cache.fingerprint(STAGE, {**options, **describe}, inputs)
    cached = cache.read_if_fresh(path, fingerprint, load_retrieval, lambda found: found.config.get("fingerprint"))
    if cached is not None:
        return RetrievalResult(path=path, retrieval=cached, fingerprint=fingerprint, reused=True)
    retrieval = retrieve(
        database_array,
        query_array,
        conf.k,
        index=conf.index,
        device=conf.device,
        batch_size=conf.batch_size,
        search_params=conf.search_params,
        config={**describe, "fingerprint": fingerprint},
        copy=copy,
        progress=conf.progress,
        database_block=conf.database_block,
    )
    if ground_truth is not None:
        retrieval = attach_ground_truth(retrieval, ground_truth)
    save_retrieval(retrieval, path)
    return RetrievalResult(path=path, retrieval=retrieval, fingerprint=fingerprint)


def search_device(device: str) -> tuple[str, str | None]:
    """The Faiss device for descriptors computed on ``device``, and a note when it differs (no GPU Faiss).

    Examples
    --------
    >>> search_device("cpu")
    ('cpu', None)
    """
    from vpr_uncertainty.retrieval import faiss_gpu_available

    kind = device.split(":")[0]
    if kind == "cuda" and faiss_gpu_available():
        return "cuda", None
    if kind == "cpu":
        return "cpu", None
    return "cpu", f"Faiss has no GPU support here; searching on the CPU (descriptors came from {device})"


def _names(names: Any) -> np.ndarray | None:
    return None if names is None else np.asarray(names, dtype=str)
