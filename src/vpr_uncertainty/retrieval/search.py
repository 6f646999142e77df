"""Descriptor search with Faiss: the top-k database images of every query, by cosine similarity.

Descriptors are float32 arrays of shape (N, D). They are L2-normalised and compared by inner product, so the
scores are cosine similarities in [-1, 1] and the squared L2 distances beside them are d² = 2 − 2s (clipped at 0,
by :func:`vpr_uncertainty.scores.squared_distances_from_similarities`, the one place this conversion is made).
Exact search (``index="Flat"``) by default; any Faiss index-factory string (``"IVF4096,PQ64"``, ``"HNSW32"``, ...)
builds an approximate index, trained on the database. Queries are searched in batches, so the memory used beyond
the descriptors themselves stays bounded; exact search can also stream the database from disk one block of rows
at a time (``database_block``; :mod:`~vpr_uncertainty.retrieval._streaming`), with the same result, for databases
larger than memory. Defined behaviour on hard input:

* **Ties and duplicate descriptors**: candidates with equal scores are ordered by lower database index, and when
  a tie straddles the k-th place, the lower indices are kept, exactly as
  :func:`~vpr_uncertainty.retrieval.readers.top_k_from_similarity` does. (Faiss alone orders them arbitrarily;
  the search asks for one candidate more than k to detect such a tie and searches that query again with a larger
  k to settle it.)
* **k larger than the database** (or an approximate index that finds fewer than k candidates): the result still
  has k columns; the missing candidates have index ``-1``, score ``-inf`` and distance ``+inf``, at the end of
  the row. The uncertainty methods score such a row on the candidates it has.
  (:func:`~vpr_uncertainty.retrieval.readers.top_k_from_similarity` instead returns min(k, D) columns.)
* **Normalisation**: rows whose squared norm is already within 1e-5 of 1 are used as they are; other rows are
  divided by their norm, on a copy unless ``copy=False``. NaN, infinite values and all-zero rows (which have no
  direction) are rejected with the row named.

:func:`search_descriptors` returns arrays; :func:`retrieve` wraps them in a
:class:`~vpr_uncertainty.retrieval.result.Retrieval` with the search settings in its ``config``. Ground truth,
names and positions are attached afterwards, by :func:`vpr_uncertainty.data.attach.attach_ground_truth`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vpr_uncertainty.retrieval._faiss import GPU_MAX_K, Searcher, faiss_gpu_available, import_faiss
from vpr_uncertainty.retrieval.descriptor_rows import DescriptorRows, default_block_rows
from vpr_uncertainty.retrieval.result import Retrieval
from vpr_uncertainty.scores import squared_distances_from_similarities

__all__ = [
    "DEFAULT_BATCH_SIZE",
    "DEVICES",
    "GPU_MAX_K",
    "faiss_gpu_available",
    "retrieve",
    "search_descriptors",
]

DEVICES: tuple[str, ...] = ("cpu", "cuda")
#: Squared norms within this distance of 1 count as already L2-normalised (float32 rounding is ~1e-6).
UNIT_NORM_TOLERANCE = 1e-5
#: Queries searched at once by default (Faiss's own query block for exact search).
DEFAULT_BATCH_SIZE = 4096
#: Work (queries × database × dimension) above which the progress bar appears on a terminal.
_PROGRESS_WORK = 5e10


def _checked_array(values: object, name: str) -> np.ndarray:
    """``values`` as an array (a memmap stays one), checked to be numeric, 2-D and of dimension ≥ 1."""
    array = values if isinstance(values, np.ndarray) else np.asarray(values)
    if array.dtype == object or not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise TypeError(f"{name} must be a numeric array of shape (n_images, dimension), got dtype {array.dtype}")
    if array.ndim != 2:
        raise ValueError(f"{name} must be 2-D with shape (n_images, dimension), got shape {array.shape}")
    if array.shape[1] == 0:
        raise ValueError(f"{name} has dimension 0; descriptors need at least one component")
    return array


def _as_descriptors(values: object, name: str) -> tuple[np.ndarray, bool]:
    """(float32 C-contiguous array of shape (N, D), whether it is a new array that the caller does not hold)."""
    if isinstance(values, DescriptorRows):
        return values.to_array(), True
    array = _checked_array(values, name)
    if array.dtype == np.float32 and array.flags.c_contiguous:
        return array, False
    converted = np.ascontiguousarray(array, dtype=np.float32)
    return converted, not np.shares_memory(converted, array)


def _check_norms(squared: np.ndarray, descriptors: np.ndarray, name: str, first_row: int = 0) -> None:
    """NaN or infinite values in rows ``first_row`` … (``squared``: their squared norms) raise, naming the row."""
    bad = ~np.isfinite(squared)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        what = "NaN" if np.isnan(descriptors[row]).any() else "an infinite or overflowing value"
        raise ValueError(f"{name} row {first_row + row} contains {what}; descriptors must be finite")


def _check_nonzero(squared: np.ndarray, name: str) -> None:
    """All-zero rows (squared norm 0) raise, naming them."""
    zero = squared == 0
    if zero.any():
        rows = np.flatnonzero(zero)
        shown = ", ".join(str(r) for r in rows[:5]) + (", ..." if rows.size > 5 else "")
        raise ValueError(
            f"{name} has {rows.size} all-zero row(s) (rows {shown}); a zero vector has no direction and cannot be "
            "L2-normalised"
        )


def _normalised(descriptors: np.ndarray, name: str, *, owned: bool, copy: bool) -> np.ndarray:
    """L2-normalise rows that are not unit-norm already: in place when allowed, else on a copy."""
    faiss = import_faiss()
    n_rows, dimension = descriptors.shape
    if n_rows == 0:
        return descriptors
    squared = np.empty(n_rows, dtype=np.float32)
    faiss.fvec_norms_L2sqr(faiss.swig_ptr(squared), faiss.swig_ptr(descriptors), dimension, n_rows)
    _check_norms(squared, descriptors, name)
    _check_nonzero(squared, name)
    if np.abs(squared - 1).max() <= UNIT_NORM_TOLERANCE:
        return descriptors
    if copy and not owned:
        descriptors = descriptors.copy()
    faiss.normalize_L2(descriptors)
    return descriptors


def _check_index_string(index: object) -> str:
    if not isinstance(index, str) or not index.strip():
        raise ValueError(f"index must be a Faiss index-factory string such as 'Flat' or 'IVF4096,PQ64', got {index!r}")
    return index.strip()


def _positive_int(value: object, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _ordered(scores: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Missing candidates as -inf / -1, rows sorted by score descending then database index ascending."""
    missing = indices < 0
    if missing.any():
        scores[missing] = -np.inf
        indices[missing] = -1
    order = np.lexsort((indices, -scores), axis=1)
    return np.take_along_axis(scores, order, axis=1), np.take_along_axis(indices, order, axis=1)


def _settle_ties(searcher: Searcher, queries: np.ndarray, k: int, n_database: int) -> tuple[np.ndarray, np.ndarray]:
    """Top-k of queries whose k-th score ties with the next one: search deeper until the tie is complete."""
    depth = min(max(4 * k, k + 16), n_database)
    while True:
        if searcher.max_k is not None:
            depth = min(depth, searcher.max_k)
        scores, indices = _ordered(*searcher.search(queries, depth))
        open_tie = (indices[:, -1] >= 0) & (scores[:, k - 1] == scores[:, -1])
        if depth >= n_database or not open_tie.any() or depth == searcher.max_k:
            return scores[:, :k], indices[:, :k]
        depth = min(4 * depth, n_database)


def _database_block(database: object, database_block: object, index: str, device: str) -> int | None:
    """Rows per block when the database is streamed (see :func:`search_descriptors`), None to search it whole."""
    exact = index.replace(" ", "").lower() == "flat"
    if database_block is not None:
        database_block = _positive_int(database_block, "database_block")
        if not exact or device != "cpu":
            raise ValueError(
                f"database_block streams the database through exact search on the CPU (index='Flat', "
                f"device='cpu'); index={index!r} on device={device!r} holds the whole database in its index: "
                "leave database_block unset"
            )
        return database_block
    if not exact or device != "cpu" or not isinstance(database, (DescriptorRows, np.memmap)):
        return None
    shape = database.shape
    if len(shape) != 2 or shape[1] == 0:
        return None  # not descriptors: rejected with the in-memory path's message
    rows = default_block_rows(shape[1])
    return rows if shape[0] > rows else None


def search_descriptors(
    database: object,
    queries: object,
    k: int = 10,
    *,
    index: str = "Flat",
    device: str = "cpu",
    batch_size: int = DEFAULT_BATCH_SIZE,
    search_params: str | None = None,
    copy: bool = True,
    progress: bool | None = None,
    database_block: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Top-k cosine similarities of each query among the database descriptors, with Faiss.

    Exact search can stream the database: read, normalise and search it one block of ``database_block`` rows at a
    time (:mod:`vpr_uncertainty.retrieval._streaming`), so that it never needs to fit in memory, with the same
    result (indices equal, scores equal up to float32 rounding). It streams when ``database_block`` is given, and
    by default when the database is on disk (a :class:`~vpr_uncertainty.retrieval.descriptor_rows.DescriptorRows`
    from :func:`~vpr_uncertainty.retrieval.descriptor_rows.open_descriptors`, or a :class:`numpy.memmap`) and
    larger than one default block (64 MiB of float32 rows). Approximate indexes and ``device="cuda"`` hold the
    whole database in their index: a database on disk is read into memory for them, as before.

    Parameters
    ----------
    database : array-like of shape (D, dim), numpy.memmap or DescriptorRows
        Database descriptors, float32 preferred (other types are converted on a copy).
    queries : array-like of shape (Q, dim)
        Query descriptors.
    k : int, default=10
        Candidates per query. May exceed D: the missing candidates are marked (see Returns).
    index : str, default="Flat"
        Faiss index-factory string: ``"Flat"`` for exact search, or an approximate index such as
        ``"IVF4096,PQ64"`` or ``"HNSW32"``, built with the inner-product metric and trained on the database.
    device : {"cpu", "cuda"}, default="cpu"
        ``"cuda"`` runs the index on GPU 0 with GPU Faiss (k < 2048; a tie that extends beyond 2048 candidates
        is cut where Faiss cuts it); a ``ValueError`` says so when Faiss has no GPU, with no fallback to the CPU.
    batch_size : int, default=4096
        Queries searched at once; bounds the memory of the intermediate results.
    search_params : str, optional
        Faiss search parameters of an approximate index, e.g. ``"nprobe=32"`` or ``"efSearch=128"``.
    copy : bool, default=True
        With ``copy=False``, float32 C-contiguous inputs that are not unit-norm are normalised in place (the
        caller's arrays change), which saves one copy of each. Unit-norm input is never copied.
    progress : bool, optional
        Show a progress bar; by default shown on a terminal for long searches.
    database_block : int, optional
        Stream the database in blocks of this many rows (exact search on the CPU only: with an approximate index
        or ``device="cuda"`` it is an error). Peak memory is then the queries, the (Q × k) result and one block;
        the database is read twice (its norms, then the search). By default: see above.

    Returns
    -------
    scores : ndarray of shape (Q, k), float32
        Cosine similarities, sorted descending; ties ordered by lower database index; ``-inf`` where missing.
    indices : ndarray of shape (Q, k), int64
        Database index of each candidate; ``-1`` where missing.
    distances : ndarray of shape (Q, k), float32
        Squared L2 distances of the normalised descriptors, ``max(2 − 2·score, 0)``; ``+inf`` where missing.

    Examples
    --------
    >>> database = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 0.0]], dtype=np.float32)
    >>> scores, indices, distances = search_descriptors(database, np.array([[3.0, 0.0]], np.float32), k=4)
    >>> scores
    array([[  1.,   1.,   0., -inf]], dtype=float32)
    >>> indices
    array([[ 0,  2,  1, -1]])
    >>> distances
    array([[ 0.,  0.,  2., inf]], dtype=float32)
    """
    k = _positive_int(k, "k")
    batch_size = _positive_int(batch_size, "batch_size")
    index = _check_index_string(index)
    if device not in DEVICES:
        raise ValueError(f"device must be one of {DEVICES}, got {device!r}")
    if search_params is not None and not isinstance(search_params, str):
        raise TypeError(f"search_params must be a string such as 'nprobe=32', got {search_params!r}")
    faiss = import_faiss()
    block = _database_block(database, database_block, index, device)
    if block is not None:
        from vpr_uncertainty.retrieval._streaming import as_rows

        database = as_rows(database)
        database_owned = False
    else:
        database, database_owned = _as_descriptors(database, "database")
    queries, queries_owned = _as_descriptors(queries, "queries")
    if database.shape[1] != queries.shape[1]:
        raise ValueError(
            f"database and queries must have the same descriptor dimension, got {database.shape[1]} and "
            f"{queries.shape[1]}"
        )
    if len(database) == 0:
        raise ValueError("the database is empty (0 descriptors)")
    if device == "cuda" and k + 1 > GPU_MAX_K:
        raise ValueError(
            f"GPU Faiss returns at most {GPU_MAX_K} candidates; k must be < {GPU_MAX_K} with device='cuda'"
        )
    queries = _normalised(queries, "queries", owned=queries_owned, copy=copy)
    n_queries, n_database = len(queries), len(database)
    kept = min(k, n_database)
    scores = np.full((n_queries, k), -np.inf, dtype=np.float32)
    indices = np.full((n_queries, k), -1, dtype=np.int64)
    from vpr_uncertainty.progress import progress_bar, progress_requested

    if progress is None and float(n_queries) * n_database * database.shape[1] < _PROGRESS_WORK:
        progress = bool(progress_requested())  # a short search gets no bar unless bars were asked for
    if block is not None:
        from vpr_uncertainty.retrieval._streaming import search_blocks

        scores[:, :kept], indices[:, :kept] = search_blocks(
            database, queries, k, block=block, batch_size=batch_size, faiss=faiss, progress=progress
        )
        return scores, indices, squared_distances_from_similarities(scores, check=False)
    database = _normalised(database, "database", owned=database_owned, copy=copy)
    searcher = Searcher(database, index, device, search_params, faiss, progress=progress)
    depth = min(k + 1, n_database)  # one more than k reveals a tie across the k-th place
    with progress_bar(total=n_queries, desc="retrieval", unit="query", enabled=progress) as bar:
        for start in range(0, n_queries, batch_size):
            batch = queries[start : start + batch_size]
            stop = start + len(batch)
            batch_scores, batch_indices = _ordered(*searcher.search(batch, depth))
            if depth > k:
                tied = np.flatnonzero((batch_indices[:, k] >= 0) & (batch_scores[:, k - 1] == batch_scores[:, k]))
                if tied.size:
                    settled_scores, settled_indices = _settle_ties(searcher, batch[tied], k, n_database)
                    batch_scores[tied, :k] = settled_scores
                    batch_indices[tied, :k] = settled_indices
            scores[start:stop, :kept] = batch_scores[:, :kept]
            indices[start:stop, :kept] = batch_indices[:, :kept]
            bar.update(len(batch))
    missing = indices < 0
    scores[missing] = -np.inf
    # Scores of normalised descriptors by construction (an approximate index may exceed 1 slightly): no range check.
    distances = squared_distances_from_similarities(scores, check=False)
    return scores, indices, distances


def retrieve(
    database: object,
    queries: object,
    k: int = 10,
    *,
    index: str = "Flat",
    device: str = "cpu",
    batch_size: int = DEFAULT_BATCH_SIZE,
    search_params: str | None = None,
    config: dict[str, Any] | None = None,
    copy: bool = True,
    progress: bool | None = None,
    database_block: int | None = None,
) -> Retrieval:
    """Search the database descriptors for every query and return the result as a :class:`Retrieval`.

    The result has no ground truth, names or positions: attach them with
    :func:`vpr_uncertainty.data.attach.attach_ground_truth`.

    Parameters
    ----------
    database, queries : array-like of shape (D, dim) and (Q, dim)
        Descriptors (see :func:`search_descriptors`); the database may be a
        :class:`~vpr_uncertainty.retrieval.descriptor_rows.DescriptorRows` or a memmap, searched block by block.
    k : int, default=10
        Candidates kept per query.
    index, device, batch_size, search_params, copy, progress, database_block
        Options of :func:`search_descriptors`.
    config : dict, optional
        Extra JSON-serialisable entries for ``Retrieval.config`` (e.g. the dataset and descriptor names); they
        take precedence over the search settings of the same name.

    Returns
    -------
    Retrieval
        ``scores``, ``indices`` and ``distances`` of shape (Q, k); ``config`` holds ``source`` ("faiss"),
        ``metric`` ("cosine"), ``k``, ``index``, ``device``, ``search_params`` (when given), ``n_database``,
        ``n_queries`` and ``dimension``.

    Examples
    --------
    >>> database = np.eye(3, dtype=np.float32)
    >>> result = retrieve(database, database[[2, 0]], k=2)
    >>> result.indices
    array([[2, 0],
           [0, 1]])
    >>> result.config["n_database"], result.config["dimension"]
    (3, 3)
    """
    k, index = _positive_int(k, "k"), _check_index_string(index)
    scores, indices, distances = search_descriptors(
        database,
        queries,
        k,
        index=index,
        device=device,
        batch_size=batch_size,
        search_params=search_params,
        copy=copy,
        progress=progress,
        database_block=database_block,
    )
    n_database, dimension = (int(size) for size in np.shape(database))  # checked; no data of a file is read
    settings: dict[str, Any] = {
        "source": "faiss",
        "metric": "cosine",
        "k": k,
        "index": index,
        "device": device,
        "n_database": n_database,
        "n_queries": int(np.shape(queries)[0]),
    }
    if search_params:
        settings["search_params"] = search_params
    settings["dimension"] = dimension
    settings.update(config or {})
    return Retrieval(scores=scores, indices=indices, distances=distances, config=settings)
