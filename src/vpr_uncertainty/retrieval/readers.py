"""Readers of what a user brings: precomputed results, similarity matrices and descriptor files.

Accepted inputs of :func:`read_results`
    * a retrieval file ``.npz`` (``scores``, ``indices`` and optionally the ground truth inside);
    * a full similarity matrix ``.npy`` of shape (queries × database), higher = more similar, cut to its top-k by
      :func:`top_k_from_similarity`;
    * VPR-Bench's ``precomputed_data_corrected.npy`` (legacy object array, read without running code from it);
    * the log folder of VPR-methods-evaluation (``--save_descriptors``), searched again with Faiss.

Ground truth comes from the retrieval file or from a separate file (any format that
:func:`vpr_uncertainty.data.load_ground_truth` reads).

Descriptors (:func:`load_descriptors`) come from a ``.npy`` array or from the HDF5 descriptor cache, which only
:func:`vpr_uncertainty.descriptors.cache.read_descriptors` reads.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vpr_uncertainty.data.ground_truth import load_ground_truth
from vpr_uncertainty.retrieval._top_k import MappedRows, top_k_blocks
from vpr_uncertainty.retrieval.file_format import load_retrieval
from vpr_uncertainty.retrieval.result import Retrieval

__all__ = [
    "DESCRIPTOR_SPLITS",
    "DESCRIPTOR_SUFFIXES",
    "INPUT_FORMATS",
    "MATRIX_TOP_K",
    "load_descriptors",
    "load_similarity_matrix",
    "read_results",
    "read_similarity_top_k",
    "top_k_from_similarity",
]

INPUT_FORMATS = ("auto", "retrieval", "matrix", "vprbench")
#: Candidates kept per query when a full matrix is read, unless a larger k asks for more (recall@20 needs 20).
MATRIX_TOP_K = 50
DESCRIPTOR_SPLITS: tuple[str, ...] = ("database", "queries")
DESCRIPTOR_SUFFIXES: tuple[str, ...] = (".npy", ".h5", ".hdf5")


def top_k_from_similarity(
    similarity: object, k: int, *, chunk_size: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The k most similar database images of each query from a full similarity matrix.

    Ties are broken by the lower database index, so the result does not depend on the sort algorithm. The matrix
    is processed in blocks of query rows (a :class:`numpy.memmap` is read block by block), so the work memory is
    one block plus the (Q × k) result.

    Parameters
    ----------
    similarity : array-like of shape (Q, D)
        Higher = more similar. NaN is rejected; ``-inf`` marks a database image that is no candidate for that
        query, and comes back with index -1.
    k : int
        Candidates per query; ``min(k, D)`` are returned.
    chunk_size : int, optional
        Queries processed at once, to bound memory; by default as many as hold about 4 M values.

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
    matrix = similarity if isinstance(similarity, np.ndarray) else np.asarray(similarity)
    if matrix.ndim != 2:
        raise ValueError(f"similarity must be 2-D (n_queries, n_database), got shape {matrix.shape}")
    if not (np.issubdtype(matrix.dtype, np.floating) or np.issubdtype(matrix.dtype, np.integer)):
        raise TypeError(f"similarity must be numeric, got dtype {matrix.dtype}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"k must be a positive integer, got {k!r}")
    if chunk_size is not None and (isinstance(chunk_size, bool) or chunk_size < 1):
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    if matrix.shape[1] == 0:
        raise ValueError("similarity has no database columns")

    def check_block(block: np.ndarray, first_row: int) -> None:
        if np.isnan(block.max()):  # one pass, no temporary the size of the block unless there is a NaN
            row, col = np.argwhere(np.isnan(block))[0]
            raise ValueError(f"similarity contains NaN (first at query {first_row + row}, database image {col})")

    return top_k_blocks(matrix, k, block_rows=chunk_size, check_block=check_block)


_MATRIX = "a numeric (queries × database) similarity matrix"


def _check_similarity_shape(matrix: np.ndarray, path: Path) -> np.ndarray:
    """Dtype and shape of a similarity matrix read (or memory-mapped) from ``path``."""
    if matrix.dtype.kind not in "iuf":
        raise ValueError(f"{path}: a similarity matrix must hold integers or floats, got dtype {matrix.dtype}")
    if matrix.ndim != 2:
        raise ValueError(f"{path}: a similarity matrix must be 2-D (queries × database), got shape {matrix.shape}")
    if matrix.shape[0] == 0 or matrix.shape[1] == 0:
        raise ValueError(f"{path}: the similarity matrix is empty (shape {matrix.shape}); expected queries × database")
    return matrix


def _check_similarity_values(block: np.ndarray, path: Path, first_row: int = 0) -> None:
    """No NaN or +inf in rows ``first_row`` … of a similarity matrix; -inf (no candidate) is allowed."""
    largest = block.max()  # NaN when any value is NaN; one pass, no temporary the size of the block
    if np.isnan(largest) or largest == np.inf:
        bad = np.isnan(block) | np.isposinf(block)
        row, column = (int(i) for i in np.argwhere(bad)[0])
        last = first_row + len(block) - 1
        raise ValueError(
            f"{path}: the similarity matrix holds {block[row, column]} at query {first_row + row}, database image "
            f"{column} ({int(bad.sum())} such values in queries {first_row}–{last}); expected finite "
            "similarities (-inf marks a database image that is no candidate)"
        )


def _open_similarity(path: str | Path, file_format: str, *, mmap: bool) -> np.ndarray:
    """The matrix of ``path`` with dtype and shape checked (values not yet); memory-mapped when ``mmap``."""
    from vpr_uncertainty.data.npy import read_npy
    from vpr_uncertainty.data.vprbench import load_vprbench_similarity

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"similarity file not found: {path}")
    if file_format == "vprbench":
        return _check_similarity_shape(load_vprbench_similarity(path), path)
    if file_format == "matrix":
        what = f"{_MATRIX} (VPR-Bench's precomputed matches are read with format 'vprbench' or 'auto')"
        return _check_similarity_shape(read_npy(path, what=what, mmap=mmap), path)
    what = f"{_MATRIX} or VPR-Bench precomputed matches (an object array of 6 items)"
    matrix = read_npy(path, what=what, allow_objects=True, mmap=mmap)
    if matrix.dtype == object:
        if matrix.shape != (6,):
            raise ValueError(f"{path} holds Python objects (an object array of shape {matrix.shape}); expected {what}")
        return _check_similarity_shape(load_vprbench_similarity(path), path)
    return _check_similarity_shape(matrix, path)


def load_similarity_matrix(path: str | Path, *, file_format: str = "auto") -> np.ndarray:
    """Read a full (queries × database) similarity matrix from ``.npy`` (plain or VPR-Bench legacy).

    The whole matrix is read into memory; :func:`read_results` instead memory-maps a plain ``.npy`` matrix and
    keeps only the top-k of each block of queries.

    Parameters
    ----------
    path : str or Path
        The ``.npy`` file.
    file_format : {"auto", "matrix", "vprbench"}
        "matrix": a numeric array; "vprbench": VPR-Bench's precomputed matches; "auto": whichever the file is
        (VPR-Bench's object arrays are read without running code from the file).

    Returns
    -------
    ndarray of shape (Q, D), Q, D ≥ 1
        Integers or floats; no NaN or +inf (-inf marks a database image that is no candidate for a query).

    Raises
    ------
    FileNotFoundError
        When the file does not exist.
    ValueError
        When the file is empty, truncated, not a ``.npy`` file, not of the requested format, or holds a
        non-numeric, non-2-D or empty array, NaN or +inf; the message names the file (and the query).
    """
    path = Path(path)
    matrix = _open_similarity(path, file_format, mmap=False)
    _check_similarity_values(matrix, path)
    return matrix


def read_similarity_top_k(
    path: str | Path, top_k: int, *, file_format: str = "auto", block_rows: int | None = None
) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """The top-k of every query of a similarity matrix file, read memory-mapped one block of queries at a time.

    Peak memory is the (Q × k) result plus one block (about 4 M values by default), not a multiple of the
    matrix; the values are checked block by block with the same errors as :func:`load_similarity_matrix`.
    VPR-Bench's legacy files are read whole.

    Parameters
    ----------
    path : str or Path
        The ``.npy`` file.
    top_k : int
        Candidates kept per query (all of them when the database is smaller).
    file_format : {"auto", "matrix", "vprbench"}
        As in :func:`load_similarity_matrix`.
    block_rows : int, optional
        Queries read at once.

    Returns
    -------
    scores, indices : ndarray of shape (Q, min(top_k, D))
        As :func:`top_k_from_similarity` returns them (ties to the lower index, -inf with index -1).
    shape : tuple of int
        (Q, D) of the matrix.
    """
    path = Path(path)
    matrix = _open_similarity(path, file_format, mmap=True)
    if isinstance(top_k, bool) or not isinstance(top_k, (int, np.integer)) or top_k < 1:
        raise ValueError(f"top_k must be a positive integer, got {top_k!r}")

    def check_block(block: np.ndarray, first_row: int) -> None:
        _check_similarity_values(block, path, first_row)

    shape = (int(matrix.shape[0]), int(matrix.shape[1]))
    if isinstance(matrix, np.memmap) and matrix.flags.c_contiguous:
        matrix = MappedRows(matrix)  # one mapping per block: read pages do not pile up in resident memory
    scores, indices = top_k_blocks(matrix, top_k, block_rows=block_rows, check_block=check_block)
    return scores, indices, shape


def _check_not_npy(path: Path) -> None:
    """A ``.npy`` read as a retrieval file: say what it is instead of failing inside the ``.npz`` reader."""
    if path.is_file():
        with path.open("rb") as handle:
            if handle.read(6) == b"\x93NUMPY":
                raise ValueError(
                    f"{path} is a .npy array, not a retrieval file (a .npz archive with scores and indices); "
                    "read it as a similarity matrix (format 'matrix' or 'auto')"
                )


def read_results(
    path: str | Path,
    *,
    ground_truth: str | Path | None = None,
    file_format: str = "auto",
    top_k: int = MATRIX_TOP_K,
) -> Retrieval:
    """Read precomputed results and their ground truth into a Retrieval.

    Parameters
    ----------
    path : str or Path
        A retrieval ``.npz``, a similarity matrix ``.npy``, a VPR-Bench precomputed-matches file, or the log
        folder of VPR-methods-evaluation run with ``--save_descriptors`` (see
        :mod:`vpr_uncertainty.retrieval.vpr_methods_evaluation`; its ground truth is derived when not given).
    ground_truth : str or Path, optional
        Ground-truth file; required unless the retrieval file holds its positives. When given, it replaces
        the positives stored in a retrieval file.
    file_format : {"auto", "retrieval", "matrix", "vprbench"}
        How to read ``path``; "auto" decides from the suffix and the file name.
    top_k : int
        Candidates kept per query when a full matrix is read (all of them when the database is smaller); pass at
        least the largest k the methods will use. A retrieval file keeps the candidates it holds.
    """
    if file_format not in INPUT_FORMATS:
        raise ValueError(f"file_format must be one of {INPUT_FORMATS}, got {file_format!r}")
    path = Path(path)
    if file_format == "auto" and path.is_dir():  # a VPR-methods-evaluation log folder (--save_descriptors)
        from vpr_uncertainty.retrieval.vpr_methods_evaluation import read_vpr_methods_evaluation

        return read_vpr_methods_evaluation(path, ground_truth=ground_truth, top_k=top_k).retrieval
    is_retrieval = file_format == "retrieval" or (file_format == "auto" and path.suffix.lower() == ".npz")
    if is_retrieval:
        _check_not_npy(path)
        retrieval = load_retrieval(path)
        if ground_truth is not None:
            n_database = retrieval.positives.shape[1] if retrieval.positives is not None else None
            retrieval.positives = load_ground_truth(ground_truth, n_queries=retrieval.n_queries, n_database=n_database)
            retrieval.__post_init__()
        return retrieval
    # Memory-mapped and cut to its top-k one block of queries at a time: never the whole matrix in memory.
    scores, indices, (n_queries, n_database) = read_similarity_top_k(path, top_k, file_format=file_format)
    if ground_truth is None:
        raise ValueError(
            f"{path} is a similarity matrix without ground truth; give the ground truth (argument ground_truth)"
        )
    # Sized by the matrix: a positive beyond its columns, or a mask of another width, is an error naming the file.
    positives = load_ground_truth(ground_truth, n_queries=n_queries, n_database=n_database)
    config = {"source": str(path), "ground_truth": str(ground_truth), "top_k": int(scores.shape[1])}
    return Retrieval(scores=scores, indices=indices, positives=positives, config=config)


def load_descriptors(path: str | Path, split: str | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """Read descriptors from a ``.npy`` array (N × dim) or from the HDF5 descriptor cache.

    A dispatcher on the suffix: ``.npy`` files are read by :func:`vpr_uncertainty.data.npy.read_npy` (which never
    runs code from the file), descriptor caches by :func:`vpr_uncertainty.descriptors.cache.read_descriptors`.

    Parameters
    ----------
    path : str or Path
        ``.npy`` file holding one descriptor per row, a descriptor cache ``.h5`` / ``.hdf5`` written by the
        feature extraction, or hloc's global features (:mod:`vpr_uncertainty.descriptors.hloc`).
    split : {"database", "queries"}, optional
        Which images to read from a descriptor cache; required for ``.h5``, ignored for ``.npy``. An hloc file
        whose names carry no split prefix (``query/``, ``db/``, ...) is read whole.

    Returns
    -------
    names : ndarray of str of shape (N,), or None
        Image names (from a cache; None for ``.npy``).
    descriptors : ndarray of shape (N, dim), float32
        A new array owned by the caller (it may be normalised in place).

    Raises
    ------
    FileNotFoundError
        When ``path`` is not a file.
    ValueError
        For another suffix, a ``.h5`` without a valid ``split``, an unreadable file or an array that is not 2-D.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"descriptor file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        from vpr_uncertainty.data.npy import read_npy

        array, names = read_npy(path, what="a descriptor array of shape (n_images, dimension)"), None
        if array.dtype.kind not in "biuf":
            raise ValueError(f"{path} is not a numeric descriptor array (it holds dtype {array.dtype})")
    elif suffix in (".h5", ".hdf5"):
        if split not in DESCRIPTOR_SPLITS:
            raise ValueError(f"reading the descriptor cache {path} needs split in {DESCRIPTOR_SPLITS}, got {split!r}")
        from vpr_uncertainty.descriptors.cache import read_descriptors  # imported here: h5py only when needed
        from vpr_uncertainty.descriptors.hloc import is_hloc_file, read_hloc_descriptors

        if is_hloc_file(path):  # hloc's global features: one group per image with a global_descriptor
            names, array = read_hloc_descriptors(path, split)
        else:
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
