"""Descriptor search with Faiss: the top-k database images of every query, by cosine similarity."""

from __future__ import annotations

from typing import Any

import numpy as np

from vpr_uncertainty.plugins import import_or_explain
from vpr_uncertainty.progress import progress_bar, progress_requested, progress_status
from vpr_uncertainty.retrieval.blocks import DescriptorRows, default_block_rows
from vpr_uncertainty.retrieval.ground_truth import DEFAULT_RADIUS, attach_ground_truth, ground_truth_fields
from vpr_uncertainty.retrieval.result import Retrieval, check_positive_int
from vpr_uncertainty.scores import squared_distances_from_similarities

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
    rows = np.flatnonzero(squared == 0)
    if rows.size:
        shown = ", ".join(str(r) for r in rows[:5]) + (", ..." if rows.size > 5 else "")
        raise ValueError(
            f"{name} has {rows.size} all-zero row(s) (rows {shown}); a zero vector has no direction and cannot be "
            "L2-normalised"
        )


def _normalised(descriptors: np.ndarray, name: str, *, owned: bool, copy: bool) -> np.ndarray:
    """L2-normalise rows that are not unit-norm already: in place when allowed, else on a copy."""
    faiss = _import_faiss()
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


def _ordered(scores: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Missing candidates as -inf / -1, rows sorted by score descending then database index ascending."""
    missing = indices < 0
    if missing.any():
        scores[missing] = -np.inf
        indices[missing] = -1
    order = np.lexsort((indices, -scores), axis=1)
    return np.take_along_axis(scores, order, axis=1), np.take_along_axis(indices, order, axis=1)


def _settle_ties(searcher: _Searcher, queries: np.ndarray, k: int, n_database: int) -> tuple[np.ndarray, np.ndarray]:
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


def _is_exact(index: str) -> bool:
    """Whether a Faiss index-factory string is exact search (``"Flat"``, in any case and spacing)."""
    return index.replace(" ", "").lower() == "flat"


def _database_block(database: object, database_block: object, index: str, device: str) -> int | None:
    """Rows per block when the database is streamed (see :func:`search_descriptors`), None to search it whole."""
    exact = _is_exact(index)
    if database_block is not None:
        database_block = check_positive_int(database_block, "database_block")
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
    top_k: int = 10,
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

    Descriptors are L2-normalised (rows within 1e-5 of unit norm are used as they are; NaN, infinite and all-zero rows
    are rejected, naming the row) and compared by inner product. Ties are ordered by lower database index, also across
    the k-th place (Faiss alone orders them arbitrarily: a tied query is searched again deeper). Exact search streams
    the database one block of rows at a time, with the same result, when ``database_block`` is given, and by default
    for a database on disk (:class:`DescriptorRows`, :class:`numpy.memmap`) larger than one 64 MiB block.

    Parameters
    ----------
    database : array-like of shape (D, dim), numpy.memmap or DescriptorRows
        Database descriptors, float32 preferred (other types are converted on a copy).
    queries : array-like of shape (Q, dim)
        Query descriptors.
    top_k : int, default=10
        Candidates per query. May exceed D: the missing candidates are marked (see Returns).
    index : str, default="Flat"
        Faiss index-factory string: ``"Flat"`` for exact search, or an approximate index such as
        ``"IVF4096,PQ64"`` or ``"HNSW32"``, built with the inner-product metric and trained on the database.
    device : {"cpu", "cuda"}, default="cpu"
        ``"cuda"``: GPU 0 with GPU Faiss (top_k < 2048); a ``ValueError`` when Faiss has no GPU (no CPU fallback).
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
        Stream the database in blocks of this many rows (exact search on the CPU only). Peak memory is then the
        queries, the (Q × k) result and one block; the database is read twice (its norms, then the search).

    Returns
    -------
    scores : ndarray of shape (Q, top_k), float32
        Cosine similarities, sorted descending; ties ordered by lower database index; ``-inf`` where missing.
    indices : ndarray of shape (Q, top_k), int64
        Database index of each candidate; ``-1`` where missing.
    distances : ndarray of shape (Q, top_k), float32
        Squared L2 distances of the normalised descriptors, ``max(2 − 2·score, 0)``; ``+inf`` where missing.

    Examples
    --------
    >>> database = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 0.0]], dtype=np.float32)
    >>> scores, indices, distances = search_descriptors(database, np.array([[3.0, 0.0]], np.float32), top_k=4)
    >>> scores
    array([[  1.,   1.,   0., -inf]], dtype=float32)
    >>> indices
    array([[ 0,  2,  1, -1]])
    >>> distances
    array([[ 0.,  0.,  2., inf]], dtype=float32)
    """
    k = check_positive_int(top_k, "top_k")
    batch_size = check_positive_int(batch_size, "batch_size")
    index = _check_index_string(index)
    if device not in DEVICES:
        raise ValueError(f"device must be one of {DEVICES}, got {device!r}")
    if search_params is not None and not isinstance(search_params, str):
        raise TypeError(f"search_params must be a string such as 'nprobe=32', got {search_params!r}")
    faiss = _import_faiss()
    block = _database_block(database, database_block, index, device)
    if block is not None:
        database, database_owned = _as_rows(database), False
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
            f"GPU Faiss returns at most {GPU_MAX_K} candidates; top_k must be < {GPU_MAX_K} with device='cuda'"
        )
    queries = _normalised(queries, "queries", owned=queries_owned, copy=copy)
    n_queries, n_database = len(queries), len(database)
    kept = min(k, n_database)
    scores = np.full((n_queries, k), -np.inf, dtype=np.float32)
    indices = np.full((n_queries, k), -1, dtype=np.int64)
    if progress is None and float(n_queries) * n_database * database.shape[1] < _PROGRESS_WORK:
        progress = bool(progress_requested())  # a short search gets no bar unless bars were asked for
    if block is not None:
        scores[:, :kept], indices[:, :kept] = search_blocks(
            database, queries, k, block=block, batch_size=batch_size, faiss=faiss, progress=progress
        )
        return scores, indices, squared_distances_from_similarities(scores, check=False)
    database = _normalised(database, "database", owned=database_owned, copy=copy)
    searcher = _Searcher(database, index, device, search_params, faiss, progress=progress)
    with progress_bar(total=n_queries, desc="retrieval", unit="query", enabled=progress) as bar:
        for start in range(0, n_queries, batch_size):
            batch = queries[start : start + batch_size]
            stop = start + len(batch)
            scores[start:stop, :kept], indices[start:stop, :kept] = _block_top_k(searcher, batch, k, n_database)
            bar.update(len(batch))
    # Scores of normalised descriptors by construction (an approximate index may exceed 1 slightly): no range check.
    return scores, indices, squared_distances_from_similarities(scores, check=False)


def retrieve(
    database: object,
    queries: object,
    top_k: int = 10,
    *,
    index: str = "Flat",
    device: str = "cpu",
    batch_size: int = DEFAULT_BATCH_SIZE,
    search_params: str | None = None,
    config: dict[str, Any] | None = None,
    copy: bool = True,
    progress: bool | None = None,
    database_block: int | None = None,
    database_positions: object = None,
    query_positions: object = None,
    radius: float = DEFAULT_RADIUS,
    positives: object = None,
    position_kind: str | None = None,
) -> Retrieval:
    """Search the database descriptors for every query and return the result as a :class:`Retrieval`.

    With positions (or explicit ``positives``) the result carries its ground truth, ready for
    :func:`vpr_uncertainty.evaluate`: the same fields as the ``retrieve`` command writes with ``--database-positions``,
    ``--query-positions`` and ``--radius`` (one implementation:
    :func:`~vpr_uncertainty.retrieval.ground_truth.ground_truth_fields`, checked before the search). Without them it
    has no ground truth; :func:`~vpr_uncertainty.retrieval.ground_truth.attach_ground_truth` adds it later.

    Parameters
    ----------
    database, queries : array-like of shape (D, dim) and (Q, dim)
        Descriptors (see :func:`search_descriptors`).
    top_k : int, default=10
        Candidates kept per query.
    index, device, batch_size, search_params, copy, progress, database_block
        Options of :func:`search_descriptors`.
    config : dict, optional
        Extra JSON-serialisable entries for ``Retrieval.config``; they take precedence over the search settings.
    database_positions, query_positions, radius, positives, position_kind
        The ground truth, as :func:`~vpr_uncertainty.retrieval.ground_truth.ground_truth_fields` takes it: positions
        (D, 2) and (Q, 2), kept (SUE reads them), whose positives lie within ``radius`` (default 25.0, inclusive),
        or explicit ``positives`` (Q, D).

    Returns
    -------
    Retrieval
        ``scores``, ``indices`` and ``distances`` of shape (Q, top_k); ``config`` holds ``source`` ("faiss"),
        ``metric`` ("cosine"), ``k``, ``index``, ``device``, ``search_params`` (when given), ``n_database``,
        ``n_queries`` and ``dimension`` (and ``radius``, ``position_kind`` with positions). ``positives``,
        ``query_positions`` and ``database_positions`` are set when given (or derived), else None.

    Examples
    --------
    >>> database = np.eye(3, dtype=np.float32)
    >>> result = retrieve(database, database[[2, 0]], top_k=2)
    >>> result.indices
    array([[2, 0],
           [0, 1]])
    >>> result.config["n_database"], result.config["dimension"]
    (3, 3)
    >>> located = retrieve(database, database[[2, 0]], top_k=2, database_positions=[[0, 0], [50, 0], [100, 0]],
    ...                    query_positions=[[95, 0], [10, 0]], radius=25)
    >>> located.positives.toarray()
    array([[False, False,  True],
           [ True, False, False]])
    """
    k, index = check_positive_int(top_k, "top_k"), _check_index_string(index)
    ground_truth = None
    if positives is not None or database_positions is not None or query_positions is not None:
        ground_truth = ground_truth_fields(  # checked before the search, the slow part
            int(np.shape(queries)[0]),
            int(np.shape(database)[0]),
            positives=positives,
            database_positions=database_positions,
            query_positions=query_positions,
            radius=radius,
            position_kind=position_kind,
        )
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
        **({"search_params": search_params} if search_params else {}),
        "dimension": dimension,
        **(config or {}),
    }
    result = Retrieval(scores=scores, indices=indices, distances=distances, config=settings)
    return result if ground_truth is None else attach_ground_truth(result, ground_truth)


def _as_rows(database: object) -> DescriptorRows:
    """A DescriptorRows of the database: itself, or a checked numeric 2-D array (a memmap read block by block)."""
    if isinstance(database, DescriptorRows):
        rows = database
    else:
        rows = DescriptorRows.from_array(_checked_array(database, "database"), source="database")
    if rows.shape[1] == 0:
        raise ValueError("database has dimension 0; descriptors need at least one component")
    return rows


def _database_norms(rows: DescriptorRows, block: int, faiss: Any) -> np.ndarray:
    """Squared norms (float32) of every row, read block by block; bad rows raise as in the in-memory search."""
    squared = np.empty(len(rows), dtype=np.float32)
    for start in range(0, len(rows), block):
        data = rows.read(start, start + block)
        part = squared[start : start + len(data)]
        faiss.fvec_norms_L2sqr(faiss.swig_ptr(part), faiss.swig_ptr(data), data.shape[1], len(data))
        _check_norms(part, data, "database", first_row=start)
        del data  # before the next block is read: one block in memory at a time
    _check_nonzero(squared, "database")
    return squared


def _merge(
    scores: np.ndarray, indices: np.ndarray, new_scores: np.ndarray, new_indices: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The first ``scores.shape[1]`` of two candidate lists by score descending, then database index ascending."""
    kept = scores.shape[1]
    both_scores = np.concatenate([scores, new_scores], axis=1)
    both_indices = np.concatenate([indices, new_indices], axis=1)
    missing = both_indices < 0
    order = np.lexsort((np.where(missing, np.iinfo(np.int64).max, both_indices), -both_scores), axis=1)[:, :kept]
    return np.take_along_axis(both_scores, order, axis=1), np.take_along_axis(both_indices, order, axis=1)


def _block_top_k(searcher: _Searcher, batch: np.ndarray, kept: int, n_block: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact top-``min(kept, n_block)`` of a batch of queries in one searcher, ties to the lower index."""
    depth = min(kept + 1, n_block)  # one more than kept reveals a tie across the kept-th place
    scores, indices = _ordered(*searcher.search(batch, depth))
    if depth > kept:
        tied = np.flatnonzero((indices[:, kept] >= 0) & (scores[:, kept - 1] == scores[:, kept]))
        if tied.size:
            scores[tied, :kept], indices[tied, :kept] = _settle_ties(searcher, batch[tied], kept, n_block)
    width = min(kept, n_block)
    return scores[:, :width], indices[:, :width]


def search_blocks(
    rows: DescriptorRows,
    queries: np.ndarray,
    k: int,
    *,
    block: int,
    batch_size: int,
    faiss: Any,
    progress: bool | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact top-min(k, D) (cosine, ties to the lower index) of L2-normalised queries, reading ``block`` rows at once.

    Each block's top-k is made exact under the order (score descending, index ascending) and merged into the running
    top-k: the result equals the in-memory search in indices, and in scores up to float32 rounding.
    """
    n_database = len(rows)
    squared = _database_norms(rows, block, faiss)
    normalise = bool(np.abs(squared - 1).max() > UNIT_NORM_TOLERANCE)
    del squared
    kept = min(k, n_database)
    scores = np.full((len(queries), kept), -np.inf, dtype=np.float32)
    indices = np.full((len(queries), kept), -1, dtype=np.int64)
    with progress_bar(total=n_database, desc="retrieval", unit="descriptor", enabled=progress) as bar:
        for start in range(0, n_database, block):
            data = rows.read(start, start + block)
            if normalise:
                faiss.normalize_L2(data)
            searcher = _Searcher(data, "Flat", "cpu", None, faiss)
            for first in range(0, len(queries), batch_size):
                batch = queries[first : first + batch_size]
                block_scores, block_indices = _block_top_k(searcher, batch, kept, len(data))
                block_indices = np.where(block_indices >= 0, block_indices + start, -1)  # database numbering
                stop = first + len(batch)
                scores[first:stop], indices[first:stop] = _merge(
                    scores[first:stop], indices[first:stop], block_scores, block_indices
                )
            bar.update(len(data))
            del data, searcher
    return scores, indices


#: Largest k that GPU Faiss can return.
GPU_MAX_K = 2048


def faiss_gpu_available() -> bool:
    """Whether the installed Faiss has GPU support and sees at least one GPU."""
    try:
        faiss = _import_faiss()
    except ImportError:
        return False
    return hasattr(faiss, "StandardGpuResources") and faiss.get_num_gpus() > 0


def _import_faiss() -> Any:
    return import_or_explain(
        "faiss",
        "descriptor retrieval needs Faiss; install it with: pip install faiss-cpu (or faiss-gpu to search on a CUDA "
        "device)",
    )


class _Searcher:
    """``search(queries, k) -> (scores, indices)`` over one database, exact or through a Faiss index."""

    def __init__(
        self,
        database: np.ndarray,
        index: str,
        device: str,
        search_params: str | None,
        faiss: Any,
        *,
        progress: bool | None = None,
    ) -> None:
        self.database = database
        self.faiss = faiss
        self.max_k = GPU_MAX_K if device == "cuda" else None
        self.index = None
        self._resources = None
        if device == "cpu" and _is_exact(index):
            if search_params:
                raise ValueError(f"search_params {search_params!r} need an approximate index; exact search has none")
            return  # faiss.knn_inner_product on the array itself: no copy of the database into an index
        gpu_faiss = hasattr(faiss, "StandardGpuResources")
        if device == "cuda" and not (gpu_faiss and faiss.get_num_gpus() > 0):
            reason = "has GPU support but sees no GPU" if gpu_faiss else "is built without GPU support"
            raise ValueError(
                f"device='cuda' needs GPU Faiss and a visible GPU, but this Faiss ({faiss.__version__}) {reason}; "
                "install faiss-gpu and check CUDA_VISIBLE_DEVICES, or use device='cpu'"
            )
        dimension = database.shape[1]
        try:
            built = faiss.index_factory(dimension, index, faiss.METRIC_INNER_PRODUCT)
        except RuntimeError as error:
            raise ValueError(f"invalid Faiss index-factory string {index!r}: {_faiss_message(error)}") from None
        if device == "cuda":
            self._resources = faiss.StandardGpuResources()
            try:
                built = faiss.index_cpu_to_gpu(self._resources, 0, built)
            except RuntimeError as error:
                raise ValueError(f"Faiss index {index!r} cannot run on the GPU: {_faiss_message(error)}") from None
        try:
            if not built.is_trained:  # IVF/PQ training can take minutes: say so while it runs
                with progress_status(f"train Faiss {index} on {len(database):,} vectors", enabled=progress):
                    built.train(database)
            built.add(database)
        except RuntimeError as error:
            raise ValueError(f"cannot build the Faiss index {index!r}: {_faiss_message(error)}") from None
        if search_params:
            space = faiss.GpuParameterSpace() if device == "cuda" else faiss.ParameterSpace()
            try:
                space.set_index_parameters(built, search_params)
            except RuntimeError as error:
                raise ValueError(
                    f"invalid search_params {search_params!r} for index {index!r}: {_faiss_message(error)}"
                ) from None
        self.index = built

    def search(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        scores = np.empty((len(queries), k), dtype=np.float32)
        indices = np.empty((len(queries), k), dtype=np.int64)
        if len(queries) == 0:
            return scores, indices
        faiss = self.faiss
        if self.index is None:
            faiss.knn_inner_product(
                faiss.swig_ptr(queries),
                faiss.swig_ptr(self.database),
                self.database.shape[1],
                len(queries),
                len(self.database),
                k,
                faiss.swig_ptr(scores),
                faiss.swig_ptr(indices),
            )
        else:
            self.index.search(queries, k, D=scores, I=indices)
        return scores, indices


def _faiss_message(error: BaseException) -> str:
    """The useful last part of a Faiss C++ error message."""
    text = str(error).strip()
    return text.rsplit(": ", 1)[-1] if ": " in text else text
