"""Retrieval results: the top-k database images of every query, and the retrieval file that stores them.

A :class:`Retrieval` is what every uncertainty method and the evaluation read. It is made from a full
similarity matrix (:func:`top_k_from_similarity`), from descriptors (:func:`retrieve`, a Faiss search), or read
back from a retrieval file (:func:`load_retrieval`).

Descriptor search (:func:`search_descriptors`, :func:`retrieve`)
    Descriptors are float32 arrays of shape (N, D). They are L2-normalised and compared by inner product, so the
    scores are cosine similarities in [-1, 1] and the squared L2 distances beside them are d² = 2 − 2s (clipped
    at 0). Exact search (``index="Flat"``) by default; any Faiss index-factory string (``"IVF4096,PQ64"``,
    ``"HNSW32"``, ...) builds an approximate index, trained on the database. Queries are searched in batches, so
    the memory used beyond the descriptors themselves stays bounded. Defined behaviour on hard input:

    * **Ties and duplicate descriptors**: candidates with equal scores are ordered by lower database index, and
      when a tie straddles the k-th place, the lower indices are kept, exactly as :func:`top_k_from_similarity`
      does. (Faiss alone orders them arbitrarily; the search asks for one candidate more than k to detect such a
      tie and searches that query again with a larger k to settle it.)
    * **k larger than the database** (or an approximate index that finds fewer than k candidates): the
      result still has k columns; the missing candidates have index ``-1``, score ``-inf`` and distance
      ``+inf``, at the end of the row. The uncertainty methods score such a row on the candidates it has.
      (:func:`top_k_from_similarity` instead returns min(k, D) columns.)
    * **Normalisation**: rows whose squared norm is already within 1e-5 of 1 are used as they are; other rows
      are divided by their norm, on a copy unless ``copy=False``. NaN, infinite values and all-zero rows
      (which have no direction) are rejected with the row named.

Retrieval file (``.npz``, no pickles), format version 1
    ``format_version``   int, 1
    ``scores``           (Q, K) float32, similarities sorted descending; ``-inf`` where a query has fewer than
                         K candidates
    ``indices``          (Q, K) int64, database index of each candidate; ``-1`` where missing
    ``distances``        (Q, K) float32, squared L2 distances of the candidates, ascending; ``+inf`` where
                         missing (optional)
    ``positives_indptr``, ``positives_indices``, ``n_database``
                         ground truth as a CSR matrix (optional)
    ``query_names``, ``database_names``          (Q,), (D,) unicode (optional)
    ``query_positions``, ``database_positions``  (Q, m), (D, m) float64, usually m = 2 (optional)
    ``config``           JSON text describing what produced the file (optional)

    Keys of ``config`` written by :func:`retrieve` (readers must ignore keys they do not know):
    ``"source"`` ("faiss"), ``"metric"`` ("cosine"), ``"k"``, ``"index"``, ``"device"``, ``"search_params"``,
    ``"dimension"``, ``"n_database"``, ``"n_queries"``, ``"radius"`` (when the positives come from positions),
    ``"database"`` and ``"queries"`` (descriptor files, when read from files) and ``"position_kind"``:
    ``"metres"`` (positions in a metric frame such as UTM), ``"frames"`` (frame indices of a sequence) or
    ``"placeholder"`` (ids laid out on a line that only encode which images match). Methods that work in
    metric space (SUE) warn when ``position_kind`` is present and not ``"metres"``; an absent key means metres.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse

from vpr_uncertainty.scores import squared_distances_from_similarities

__all__ = [
    "FORMAT_VERSION",
    "POSITION_KINDS",
    "Retrieval",
    "load_descriptors",
    "load_retrieval",
    "retrieve",
    "save_retrieval",
    "search_descriptors",
    "top_k_from_similarity",
]

FORMAT_VERSION = 1


@dataclass
class Retrieval:
    """Top-k retrieval of Q queries against a database of D images.

    Attributes
    ----------
    scores : ndarray of shape (Q, K), float
        Similarities, higher = more similar, sorted descending; ``-inf`` marks a missing candidate.
    indices : ndarray of shape (Q, K), int64
        Database index of each candidate; ``-1`` marks a missing candidate.
    positives : scipy.sparse.csr_array of shape (Q, D), bool, optional
        Ground truth: the database images that are correct answers for each query.
    distances : ndarray of shape (Q, K), optional
        Squared L2 distances of the candidates, ascending.
    query_names, database_names : ndarray of str, optional
    query_positions, database_positions : ndarray of shape (Q, 2) and (D, 2), optional
        Positions in metres (e.g. UTM easting, northing).
    config : dict
        What produced this retrieval (method, dataset, k, ...), stored with the file.
    """

    scores: np.ndarray
    indices: np.ndarray
    positives: sparse.csr_array | None = None
    distances: np.ndarray | None = None
    query_names: np.ndarray | None = None
    database_names: np.ndarray | None = None
    query_positions: np.ndarray | None = None
    database_positions: np.ndarray | None = None
    config: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Check every field (see :mod:`vpr_uncertainty._retrieval_checks`); a ValueError names the field."""
        from vpr_uncertainty._retrieval_checks import check_retrieval_fields

        check_retrieval_fields(self)

    @property
    def n_database(self) -> int | None:
        """Number of database images, when the positives, the database names or positions tell it."""
        if self.positives is not None:
            return int(self.positives.shape[1])
        for value in (self.database_names, self.database_positions):
            if value is not None:
                return len(value)
        return None

    @property
    def n_queries(self) -> int:
        return self.scores.shape[0]

    @property
    def k(self) -> int:
        """Number of candidates stored per query."""
        return self.scores.shape[1]


def top_k_from_similarity(similarity: object, k: int, *, chunk_size: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """The k most similar database images of each query from a full similarity matrix.

    Ties are broken by the lower database index, so the result does not depend on the sort algorithm.

    Parameters
    ----------
    similarity : array-like of shape (Q, D)
        Higher = more similar. NaN is rejected.
    k : int
        Candidates per query; ``min(k, D)`` are returned.
    chunk_size : int
        Queries processed at once, to bound memory.

    Returns
    -------
    scores : ndarray of shape (Q, min(k, D)), float32 (float64 for float64 input)
    indices : ndarray of shape (Q, min(k, D)), int64

    Examples
    --------
    >>> scores, indices = top_k_from_similarity(np.array([[0.1, 0.9, 0.9, 0.5]]), k=3)
    >>> scores, indices
    (array([[0.9, 0.9, 0.5]]), array([[1, 2, 3]]))
    """
    matrix = np.asarray(similarity)
    if matrix.ndim != 2:
        raise ValueError(f"similarity must be 2-D (n_queries, n_database), got shape {matrix.shape}")
    if not (np.issubdtype(matrix.dtype, np.floating) or np.issubdtype(matrix.dtype, np.integer)):
        raise TypeError(f"similarity must be numeric, got dtype {matrix.dtype}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"k must be a positive integer, got {k!r}")
    matrix = matrix.astype(np.result_type(matrix.dtype, np.float32), copy=False)
    n_queries, n_database = matrix.shape
    if n_database == 0:
        raise ValueError("similarity has no database columns")
    if np.isnan(matrix).any():
        row, col = np.argwhere(np.isnan(matrix))[0]
        raise ValueError(f"similarity contains NaN (first at query {row}, database image {col})")
    k = min(int(k), n_database)
    scores = np.empty((n_queries, k), dtype=matrix.dtype)
    indices = np.empty((n_queries, k), dtype=np.int64)
    for start in range(0, n_queries, chunk_size):
        block = matrix[start : start + chunk_size]
        if k < n_database:
            candidates = np.argpartition(-block, k - 1, axis=1)[:, :k]
        else:
            candidates = np.broadcast_to(np.arange(n_database), block.shape).copy()
        values = np.take_along_axis(block, candidates, axis=1)
        # Order by value descending, then index ascending (lexsort: last key is primary).
        order = np.lexsort((candidates, -values), axis=1)
        candidates = np.take_along_axis(candidates, order, axis=1)
        values = np.take_along_axis(values, order, axis=1)
        # argpartition picks an arbitrary subset of the values tied at the k-th place: redo those rows.
        kth = values[:, -1:]
        tied_rows = np.flatnonzero((block == kth).sum(axis=1) > (values == kth).sum(axis=1))
        for row in tied_rows:
            full_order = np.lexsort((np.arange(n_database), -block[row]))[:k]
            candidates[row] = full_order
            values[row] = block[row, full_order]
        scores[start : start + len(block)] = values
        indices[start : start + len(block)] = candidates
    return scores, indices


def save_retrieval(retrieval: Retrieval, path: str | Path) -> Path:
    """Write a retrieval file (see the module docstring for the layout) and return its path."""
    path = Path(path)
    arrays: dict[str, Any] = {
        "format_version": np.array(FORMAT_VERSION),
        "scores": retrieval.scores.astype(np.float32, copy=False),
        "indices": retrieval.indices,
        "config": np.array(json.dumps(retrieval.config, sort_keys=True)),
    }
    if retrieval.distances is not None:
        arrays["distances"] = retrieval.distances.astype(np.float32, copy=False)
    if retrieval.positives is not None:
        positives = retrieval.positives
        arrays["positives_indptr"] = positives.indptr.astype(np.int64)
        arrays["positives_indices"] = positives.indices.astype(np.int64)
        arrays["n_database"] = np.array(positives.shape[1])
    for name in ("query_names", "database_names"):
        value = getattr(retrieval, name)
        if value is not None:
            arrays[name] = np.asarray(value, dtype=str)
    for name in ("query_positions", "database_positions"):
        value = getattr(retrieval, name)
        if value is not None:
            arrays[name] = np.asarray(value, dtype=np.float64)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")  # written whole, then renamed: never a truncated file
    try:
        with partial.open("wb") as handle:
            np.savez_compressed(handle, **arrays)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return path


def load_retrieval(path: str | Path) -> Retrieval:
    """Read a retrieval file written by :func:`save_retrieval` (or any ``.npz`` with ``scores``, ``indices``).

    Every field is checked (dtype, range, and consistency between ``indices``, ``scores``, ``distances``, the
    positives, names and positions; see :mod:`vpr_uncertainty._retrieval_checks`).

    Raises
    ------
    FileNotFoundError
        When ``path`` is not a file.
    ValueError
        Naming the file, the field and the problem; also for an empty, truncated or non-``.npz`` file.
    """
    from vpr_uncertainty._retrieval_checks import read_retrieval_file

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"retrieval file not found: {path}")
    return read_retrieval_file(path, Retrieval, FORMAT_VERSION)


# --- descriptor search ------------------------------------------------------------------------------------------

DEVICES: tuple[str, ...] = ("cpu", "cuda")
#: Squared norms within this distance of 1 count as already L2-normalised (float32 rounding is ~1e-6).
UNIT_NORM_TOLERANCE = 1e-5
#: Queries searched at once by default (Faiss's own query block for exact search).
DEFAULT_BATCH_SIZE = 4096
#: Largest k that GPU Faiss can return.
GPU_MAX_K = 2048
#: Work (queries × database × dimension) above which the progress bar appears on a terminal.
_PROGRESS_WORK = 5e10


def faiss_gpu_available() -> bool:
    """Whether the installed Faiss has GPU support and sees at least one GPU."""
    try:
        faiss = _import_faiss()
    except ImportError:
        return False
    return hasattr(faiss, "StandardGpuResources") and faiss.get_num_gpus() > 0


def _import_faiss() -> Any:
    try:
        import faiss
    except ImportError as error:
        raise ImportError(
            "descriptor retrieval needs Faiss; install it with: pip install faiss-cpu (or faiss-gpu to search on a "
            "CUDA device)"
        ) from error
    return faiss


def _as_descriptors(values: object, name: str) -> tuple[np.ndarray, bool]:
    """(float32 C-contiguous array of shape (N, D), whether it is a new array that the caller does not hold)."""
    array = np.asarray(values)
    if array.dtype == object or not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise TypeError(f"{name} must be a numeric array of shape (n_images, dimension), got dtype {array.dtype}")
    if array.ndim != 2:
        raise ValueError(f"{name} must be 2-D with shape (n_images, dimension), got shape {array.shape}")
    if array.shape[1] == 0:
        raise ValueError(f"{name} has dimension 0; descriptors need at least one component")
    if array.dtype == np.float32 and array.flags.c_contiguous:
        return array, False
    converted = np.ascontiguousarray(array, dtype=np.float32)
    return converted, not np.shares_memory(converted, array)


def _normalised(descriptors: np.ndarray, name: str, *, owned: bool, copy: bool) -> np.ndarray:
    """L2-normalise rows that are not unit-norm already: in place when allowed, else on a copy."""
    faiss = _import_faiss()
    n_rows, dimension = descriptors.shape
    if n_rows == 0:
        return descriptors
    squared = np.empty(n_rows, dtype=np.float32)
    faiss.fvec_norms_L2sqr(faiss.swig_ptr(squared), faiss.swig_ptr(descriptors), dimension, n_rows)
    bad = ~np.isfinite(squared)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        what = "NaN" if np.isnan(descriptors[row]).any() else "an infinite or overflowing value"
        raise ValueError(f"{name} row {row} contains {what}; descriptors must be finite")
    zero = squared == 0
    if zero.any():
        rows = np.flatnonzero(zero)
        shown = ", ".join(str(r) for r in rows[:5]) + (", ..." if rows.size > 5 else "")
        raise ValueError(
            f"{name} has {rows.size} all-zero row(s) (rows {shown}); a zero vector has no direction and cannot be "
            "L2-normalised"
        )
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


class _Searcher:
    """``search(queries, k) -> (scores, indices)`` over one database, exact or through a Faiss index."""

    def __init__(self, database: np.ndarray, index: str, device: str, search_params: str | None, faiss: Any) -> None:
        self.database = database
        self.faiss = faiss
        self.max_k = GPU_MAX_K if device == "cuda" else None
        self.index = None
        self._resources = None
        exact = index.replace(" ", "").lower() == "flat"
        if device == "cpu" and exact:
            if search_params:
                raise ValueError(f"search_params {search_params!r} need an approximate index; exact search has none")
            return  # faiss.knn_inner_product on the array itself: no copy of the database into an index
        if device == "cuda":
            if not hasattr(faiss, "StandardGpuResources") or faiss.get_num_gpus() < 1:
                if hasattr(faiss, "StandardGpuResources"):
                    reason = "has GPU support but sees no GPU"
                else:
                    reason = "is built without GPU support"
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
            if not built.is_trained:
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
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Top-k cosine similarities of each query among the database descriptors, with Faiss.

    Parameters
    ----------
    database : array-like of shape (D, dim)
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
    faiss = _import_faiss()
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
    database = _normalised(database, "database", owned=database_owned, copy=copy)
    queries = _normalised(queries, "queries", owned=queries_owned, copy=copy)
    searcher = _Searcher(database, index, device, search_params, faiss)

    n_queries, n_database = len(queries), len(database)
    depth = min(k + 1, n_database)  # one more than k reveals a tie across the k-th place
    kept = min(k, n_database)
    scores = np.full((n_queries, k), -np.inf, dtype=np.float32)
    indices = np.full((n_queries, k), -1, dtype=np.int64)
    if progress is None:
        progress = float(n_queries) * n_database * database.shape[1] >= _PROGRESS_WORK
        disable = None if progress else True  # None: tqdm shows the bar on a terminal only
    else:
        disable = not progress
    from tqdm import tqdm

    with tqdm(total=n_queries, desc="retrieval", unit="query", disable=disable, leave=False) as bar:
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


# --- from descriptors to a Retrieval ------------------------------------------------------------------------------

DESCRIPTOR_SPLITS: tuple[str, ...] = ("database", "queries")
DESCRIPTOR_SUFFIXES: tuple[str, ...] = (".npy", ".h5", ".hdf5")
POSITION_KINDS: tuple[str, ...] = ("metres", "frames", "placeholder")


def load_descriptors(path: str | Path, split: str | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """Read descriptors from a ``.npy`` array (N × dim) or from the HDF5 descriptor cache.

    Parameters
    ----------
    path : str or Path
        ``.npy`` file holding one descriptor per row, or a descriptor cache ``.h5`` / ``.hdf5`` written by the
        feature extraction (:func:`vpr_uncertainty.features.cache.read_descriptors`).
    split : {"database", "queries"}, optional
        Which images to read from a descriptor cache; required for ``.h5``, ignored for ``.npy``.

    Returns
    -------
    names : ndarray of str of shape (N,), or None
        Image names (from a cache; None for ``.npy``).
    descriptors : ndarray of shape (N, dim), float32
        A new array owned by the caller (it may be normalised in place).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"descriptor file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            array = np.load(path, allow_pickle=False)
        except ValueError as error:
            raise ValueError(f"{path} is not a numeric descriptor array: {error}") from None
        names = None
    elif suffix in (".h5", ".hdf5"):
        if split not in DESCRIPTOR_SPLITS:
            raise ValueError(f"reading the descriptor cache {path} needs split in {DESCRIPTOR_SPLITS}, got {split!r}")
        try:
            from vpr_uncertainty.features.cache import read_descriptors
        except ImportError as error:
            raise ImportError(
                f"reading the descriptor cache {path} needs vpr_uncertainty.features.cache ({error}); "
                "give the descriptors as a .npy array instead"
            ) from error
        names, array = read_descriptors(path, split)
        names = None if names is None else np.asarray(names, dtype=str)
    else:
        raise ValueError(
            f"unsupported descriptor file {path}: expected one of {', '.join(DESCRIPTOR_SUFFIXES)} "
            "(a .npy array of shape (N, dim) or the HDF5 descriptor cache)"
        )
    array = np.asarray(array)
    if array.ndim != 2:
        raise ValueError(f"{path}: descriptors must be 2-D (n_images, dimension), got shape {array.shape}")
    if names is not None and len(names) != len(array):
        raise ValueError(f"{path}: {len(names)} names but {len(array)} descriptors")
    return names, np.ascontiguousarray(array, dtype=np.float32)


def _check_rows(value: object, name: str, expected: int, what: str) -> np.ndarray | None:
    if value is None:
        return None
    array = np.asarray(value)
    if len(array) != expected:
        raise ValueError(f"{name} has {len(array)} entries, expected {expected} (one per {what} descriptor)")
    return array


def _as_position_matrix(positions: np.ndarray | None) -> np.ndarray | None:
    if positions is None:
        return None
    positions = np.asarray(positions, dtype=np.float64)
    return positions[:, None] if positions.ndim == 1 else positions


def retrieve(
    database: object,
    queries: object,
    k: int = 10,
    *,
    index: str = "Flat",
    device: str = "cpu",
    batch_size: int = DEFAULT_BATCH_SIZE,
    search_params: str | None = None,
    database_positions: object = None,
    query_positions: object = None,
    radius: float = 25.0,
    positives: object = None,
    database_names: object = None,
    query_names: object = None,
    position_kind: str | None = None,
    config: dict[str, Any] | None = None,
    copy: bool = True,
    progress: bool | None = None,
) -> Retrieval:
    """Search the database descriptors for every query and return a :class:`Retrieval` with its ground truth.

    Parameters
    ----------
    database, queries : array-like of shape (D, dim) and (Q, dim)
        Descriptors (see :func:`search_descriptors`).
    k : int, default=10
        Candidates kept per query.
    index, device, batch_size, search_params, copy, progress
        Options of :func:`search_descriptors`.
    database_positions, query_positions : array-like of shape (D, 2) and (Q, 2), optional
        Camera positions (UTM easting, northing in metres). Database positions enable SUE; with both, the
        positives are the database images within ``radius`` of each query (inclusive).
    radius : float, default=25.0
        Positive radius, in the unit of the positions.
    positives : sparse or dense bool matrix of shape (Q, D), optional
        Explicit ground truth; used instead of the radius search.
    database_names, query_names : sequence of str, optional
        Image names, stored with the retrieval.
    position_kind : {"metres", "frames", "placeholder"}, optional
        What the positions are (see the module docstring); detected from the positions when not given.
    config : dict, optional
        Extra JSON-serialisable entries for ``Retrieval.config`` (e.g. the dataset and descriptor names).

    Returns
    -------
    Retrieval
        ``scores``, ``indices`` and ``distances`` of shape (Q, k); positives, positions and names as given.

    Examples
    --------
    >>> database = np.eye(3, dtype=np.float32)
    >>> result = retrieve(database, database[[2, 0]], k=2, database_positions=[[0, 0], [50, 0], [100, 0]],
    ...                   query_positions=[[95, 0], [10, 0]], position_kind="metres")
    >>> result.indices, result.positives.toarray()
    (array([[2, 0],
           [0, 1]]), array([[False, False,  True],
           [ True, False, False]]))
    """
    if position_kind is not None and position_kind not in POSITION_KINDS:
        raise ValueError(f"position_kind must be one of {POSITION_KINDS} or None, got {position_kind!r}")
    n_database, n_queries = len(np.asarray(database)), len(np.asarray(queries))
    database_positions = _check_rows(database_positions, "database_positions", n_database, "database")
    query_positions = _check_rows(query_positions, "query_positions", n_queries, "query")
    database_names = _check_rows(database_names, "database_names", n_database, "database")
    query_names = _check_rows(query_names, "query_names", n_queries, "query")
    settings: dict[str, Any] = {
        "source": "faiss",
        "metric": "cosine",
        "k": _positive_int(k, "k"),
        "index": _check_index_string(index),
        "device": device,
        "n_database": n_database,
        "n_queries": n_queries,
    }
    if search_params:
        settings["search_params"] = search_params
    if positives is not None:
        positives = sparse.csr_array(positives, dtype=bool)
        if positives.shape != (n_queries, n_database):
            raise ValueError(f"positives must have shape ({n_queries}, {n_database}), got {positives.shape}")
    elif database_positions is not None and query_positions is not None:
        from vpr_uncertainty.data.positives import positives_within_radius

        positives = positives_within_radius(query_positions, database_positions, radius)
        settings["radius"] = float(radius)
    if database_positions is not None or query_positions is not None:
        if position_kind is None:
            from vpr_uncertainty.data.dataset import detect_position_kind

            two_column = [p for p in (database_positions, query_positions) if p is not None and p.shape[1:] == (2,)]
            position_kind = detect_position_kind(*two_column) if two_column else None
        if position_kind is not None:
            settings["position_kind"] = position_kind
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
    )
    settings["dimension"] = int(np.shape(database)[1])
    settings.update(config or {})
    return Retrieval(
        scores=scores,
        indices=indices,
        positives=positives,
        distances=distances,
        query_names=query_names,
        database_names=database_names,
        query_positions=_as_position_matrix(query_positions),
        database_positions=_as_position_matrix(database_positions),
        config=settings,
    )
