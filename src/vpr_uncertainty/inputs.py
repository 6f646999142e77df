"""Read precomputed VPR results from files into a :class:`~vpr_uncertainty.retrieval.Retrieval`.

Accepted inputs
    * a retrieval file ``.npz`` (``scores``, ``indices`` and optionally the ground truth inside);
    * a full similarity matrix ``.npy`` of shape (queries × database), higher = more similar;
    * VPR-Bench's ``precomputed_data_corrected.npy`` (legacy object array, read with pickle).

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


def load_similarity_matrix(path: str | Path, *, file_format: str = "auto") -> np.ndarray:
    """Read a full (queries × database) similarity matrix from ``.npy`` (plain or VPR-Bench legacy)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"similarity file not found: {path}")
    if file_format == "vprbench":
        from vpr_uncertainty.data.vprbench import load_vprbench_similarity

        return load_vprbench_similarity(path)
    try:
        matrix = np.load(path, allow_pickle=False)
    except ValueError as error:
        if "allow_pickle" not in str(error):
            raise
        if file_format == "auto" and path.name.startswith("precomputed_data"):
            from vpr_uncertainty.data.vprbench import load_vprbench_similarity

            return load_vprbench_similarity(path)
        raise ValueError(
            f"{path} holds Python objects, not a numeric similarity matrix; if it is a VPR-Bench "
            "precomputed-matches file you trust, pass --format vprbench"
        ) from error
    if matrix.ndim != 2:
        raise ValueError(f"{path}: a similarity matrix must be 2-D (queries × database), got shape {matrix.shape}")
    return matrix


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
        retrieval = load_retrieval(path)
        if ground_truth is not None:
            n_database = retrieval.positives.shape[1] if retrieval.positives is not None else None
            retrieval.positives = load_ground_truth(ground_truth, n_queries=retrieval.n_queries, n_database=n_database)
            retrieval.__post_init__()
        return retrieval
    similarity = load_similarity_matrix(path, file_format=file_format)
    if ground_truth is None:
        raise ValueError(f"{path} is a similarity matrix without ground truth; give the ground truth (--gt)")
    positives = load_ground_truth(ground_truth, n_queries=similarity.shape[0])
    if positives.shape[1] > similarity.shape[1]:
        raise ValueError(
            f"ground truth {ground_truth} refers to database image {positives.shape[1] - 1}, but the similarity "
            f"matrix has only {similarity.shape[1]} database columns"
        )
    positives.resize((similarity.shape[0], similarity.shape[1]))
    scores, indices = top_k_from_similarity(similarity, top_k)
    config = {"source": str(path), "ground_truth": str(ground_truth), "top_k": int(scores.shape[1])}
    return Retrieval(scores=scores, indices=indices, positives=positives, config=config)
