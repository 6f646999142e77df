"""Re-ranking the top-k of each query by RANSAC inliers, and the recall@N before and after.

>>> import numpy as np
>>> rerank_by_inliers(np.array([[4, 7, 9, -1]]), np.array([[3, 10, 3, 0]]))
array([[ 7,  4,  9, -1]])
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.evaluation import recall_at_n
from vpr_uncertainty.geometric.verify import GeometricVerifier, VerificationResult, verify_retrieval
from vpr_uncertainty.retrieval import Retrieval

__all__ = ["Reranking", "rerank", "rerank_by_inliers"]


def rerank_by_inliers(indices: object, inliers: object) -> np.ndarray:
    """Sort the first ``k`` candidates of each query by inliers, descending; the rest keep their order.

    Parameters
    ----------
    indices : array-like of shape (Q, K), int
        Database indices, best first; -1 marks a missing candidate (it stays behind the real ones).
    inliers : array-like of shape (Q, k), k <= K
        Inliers of the first k candidates. Ties keep the global ranking's order (stable sort).

    Returns
    -------
    ndarray of shape (Q, K), int64
    """
    indices = np.asarray(indices, dtype=np.int64)
    inliers = np.asarray(inliers)
    if indices.ndim != 2 or inliers.ndim != 2 or inliers.shape[0] != indices.shape[0]:
        raise ValueError(f"indices (Q, K) and inliers (Q, k) expected, got {indices.shape} and {inliers.shape}")
    k = inliers.shape[1]
    if k > indices.shape[1]:
        raise ValueError(f"inliers cover {k} candidates but indices hold only {indices.shape[1]}")
    key = np.where(indices[:, :k] >= 0, -inliers.astype(np.float64), np.inf)
    order = np.argsort(key, axis=1, kind="stable")
    result = indices.copy()
    result[:, :k] = np.take_along_axis(indices[:, :k], order, axis=1)
    return result


@dataclass
class Reranking:
    """Result of :func:`rerank`.

    Attributes
    ----------
    indices : ndarray of shape (Q, K)
        The re-ranked candidates (the first ``top_k`` sorted by inliers, the rest as before).
    inliers : ndarray of shape (Q, top_k)
        Inliers of the original first ``top_k`` candidates, in the original order.
    verification : VerificationResult
        Timings and match counts (``inliers``/``matches`` of shape (Q, top_k)).
    recall : dict
        ``{"global": {N: recall}, "reranked": {N: recall}}`` when the retrieval has positives, else empty.
    """

    indices: np.ndarray
    inliers: np.ndarray
    verification: VerificationResult
    recall: dict[str, dict[int, float]]

    @property
    def uncertainty(self) -> np.ndarray:
        """−inliers of the new top-1, shape (Q,): the GV uncertainty of the re-ranked answer."""
        return -np.max(self.inliers, axis=1, initial=0).astype(np.float64)


def rerank(
    retrieval: Retrieval,
    method: str | GeometricVerifier = "GV-SIFT",
    *,
    top_k: int = 10,
    query_paths: Sequence[str | Path] | None = None,
    database_paths: Sequence[str | Path] | None = None,
    ns: Sequence[int] = (1, 5, 10, 20),
    **options: Any,
) -> Reranking:
    """Verify each query against its first ``top_k`` candidates and re-rank them by inliers.

    Parameters
    ----------
    retrieval : Retrieval
    method : str or GeometricVerifier
        A preset name (``"GV-SIFT"``, ``"GV-DISK-LG"``, ...) or a configured verifier.
    top_k : int
        Candidates verified per query (capped at the retrieval's K).
    query_paths, database_paths : sequence of path
        Image files indexed like the retrieval.
    ns : sequence of int
        N of the recall@N reported for the global and the re-ranked lists.
    **options
        Options of :meth:`GeometricVerifier.from_preset` and :class:`GeometricVerifier` (``cache_dir``,
        ``max_side``, ``workers``, ``device``, ``seed``, ...), used when ``method`` is a name.
    """
    verifier = method if isinstance(method, GeometricVerifier) else GeometricVerifier.from_preset(method, **options)
    result = verify_retrieval(retrieval, verifier, query_paths=query_paths, database_paths=database_paths, top_k=top_k)
    indices = rerank_by_inliers(retrieval.indices, result.inliers)
    recall: dict[str, dict[int, float]] = {}
    if retrieval.positives is not None:
        recall = {
            "global": recall_at_n(retrieval.indices, retrieval.positives, ns),
            "reranked": recall_at_n(indices, retrieval.positives, ns),
        }
    return Reranking(indices=indices, inliers=result.inliers, verification=result, recall=recall)
