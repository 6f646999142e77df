"""Read precomputed VPR results from files into a :class:`~vpr_uncertainty.retrieval.Retrieval`.

Accepted inputs
    * a retrieval file ``.npz`` (``scores``, ``indices`` and optionally the ground truth inside);
    * a full similarity matrix ``.npy`` of shape (queries × database), higher = more similar;
    * VPR-Bench's ``precomputed_data_corrected.npy`` (legacy object array, read without running code from it).

Ground truth comes from the retrieval file or from a separate file (any format that
:func:`vpr_uncertainty.data.load_ground_truth` reads).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vpr_uncertainty.data.ground_truth import load_ground_truth
from vpr_uncertainty.retrieval import Retrieval, load_retrieval, top_k_from_similarity

__all__ = ["INPUT_FORMATS", "load_similarity_matrix", "read_results"]

INPUT_FORMATS = ("auto", "retrieval", "matrix", "vprbench")
#: Candidates kept per query when a full matrix is read, unless a larger k asks for more (recall@20 needs 20).
MATRIX_TOP_K = 50


_MATRIX = "a numeric (queries × database) similarity matrix"


def _check_similarity(matrix: np.ndarray, path: Path) -> np.ndarray:
    """Shape, dtype and values of a similarity matrix read from ``path``; -inf (no candidate) is allowed."""
    if matrix.dtype.kind not in "iuf":
        raise ValueError(f"{path}: a similarity matrix must hold integers or floats, got dtype {matrix.dtype}")
    if matrix.ndim != 2:
        raise ValueError(f"{path}: a similarity matrix must be 2-D (queries × database), got shape {matrix.shape}")
    if matrix.shape[0] == 0 or matrix.shape[1] == 0:
        raise ValueError(f"{path}: the similarity matrix is empty (shape {matrix.shape}); expected queries × database")
    largest = matrix.max()  # NaN when any value is NaN; one pass, no temporary the size of the matrix
    if np.isnan(largest) or largest == np.inf:
        bad = np.isnan(matrix) | np.isposinf(matrix)
        row, column = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"{path}: the similarity matrix holds {matrix[row, column]} at query {row}, database image {column} "
            f"({int(bad.sum())} such values); expected finite similarities (-inf marks a database image that is "
            "no candidate)"
        )
    return matrix


def load_similarity_matrix(path: str | Path, *, file_format: str = "auto") -> np.ndarray:
    """Read a full (queries × database) similarity matrix from ``.npy`` (plain or VPR-Bench legacy).

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
    from vpr_uncertainty.data.npy import read_npy
    from vpr_uncertainty.data.vprbench import load_vprbench_similarity

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"similarity file not found: {path}")
    if file_format == "vprbench":
        return _check_similarity(load_vprbench_similarity(path), path)
    if file_format == "matrix":
        what = f"{_MATRIX} (VPR-Bench's precomputed matches are read with format 'vprbench' or 'auto')"
        return _check_similarity(read_npy(path, what=what), path)
    what = f"{_MATRIX} or VPR-Bench precomputed matches (an object array of 6 items)"
    matrix = read_npy(path, what=what, allow_objects=True)
    if matrix.dtype == object:
        if matrix.shape != (6,):
            raise ValueError(f"{path} holds Python objects (an object array of shape {matrix.shape}); expected {what}")
        return _check_similarity(load_vprbench_similarity(path), path)
    return _check_similarity(matrix, path)


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
        A retrieval ``.npz``, a similarity matrix ``.npy`` or a VPR-Bench precomputed-matches file.
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
    is_retrieval = file_format == "retrieval" or (file_format == "auto" and path.suffix.lower() == ".npz")
    if is_retrieval:
        _check_not_npy(path)
        retrieval = load_retrieval(path)
        if ground_truth is not None:
            n_database = retrieval.positives.shape[1] if retrieval.positives is not None else None
            retrieval.positives = load_ground_truth(ground_truth, n_queries=retrieval.n_queries, n_database=n_database)
            retrieval.__post_init__()
        return retrieval
    similarity = load_similarity_matrix(path, file_format=file_format)
    if ground_truth is None:
        raise ValueError(
            f"{path} is a similarity matrix without ground truth; give the ground truth (argument ground_truth)"
        )
    # Sized by the matrix: a positive beyond its columns, or a mask of another width, is an error naming the file.
    positives = load_ground_truth(ground_truth, n_queries=similarity.shape[0], n_database=similarity.shape[1])
    scores, indices = top_k_from_similarity(similarity, top_k)
    config = {"source": str(path), "ground_truth": str(ground_truth), "top_k": int(scores.shape[1])}
    return Retrieval(scores=scores, indices=indices, positives=positives, config=config)
