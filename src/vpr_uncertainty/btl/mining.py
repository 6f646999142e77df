"""Triplet mining for the BTL head: positives from the ground truth, hard negatives from descriptor space.

For every anchor (a training query, or a database image when the database trains on itself), the triplets are
every pair of

* a **positive**: one of its ``max_positives`` most similar positives (database images within the positive
  radius, 25 m by default, or in the dataset's explicit positive lists), and
* a **hard negative**: one of its ``n_negatives`` most similar database images that are not positives,

with similarity the cosine of the frozen descriptors. Mining happens once, before training, so the triplets do
not depend on the head being trained. Anchors without a positive or without a negative give no triplet.
Pure numpy: importing this module does not import torch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

__all__ = ["Triplets", "mine_triplets"]


@dataclass(frozen=True)
class Triplets:
    """Index triplets: ``anchor`` indexes the anchor descriptors, ``positive`` and ``negative`` the database.

    Attributes
    ----------
    anchor, positive, negative : ndarray of shape (T,), int64
    """

    anchor: np.ndarray
    positive: np.ndarray
    negative: np.ndarray

    def __len__(self) -> int:
        return int(self.anchor.size)

    @property
    def n_anchors(self) -> int:
        """Number of distinct anchors with at least one triplet."""
        return int(np.unique(self.anchor).size)


def _unit_rows(values: object, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float32)
    if array.ndim != 2:
        raise ValueError(f"{name} must be 2-D (n_images, dimension), got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} contain NaN or inf")
    norms = np.linalg.norm(array, axis=1, keepdims=True)
    if (norms == 0).any():
        raise ValueError(f"{name} row {int(np.flatnonzero(norms[:, 0] == 0)[0])} is all zeros")
    return array / norms


def mine_triplets(
    anchor_descriptors: object,
    database_descriptors: object,
    positives: object,
    *,
    anchors: object = None,
    n_negatives: int = 10,
    max_positives: int = 10,
    same_set: bool = False,
    block_size: int = 1024,
) -> Triplets:
    """Triplets of (anchor, positive, hard negative) indices.

    Parameters
    ----------
    anchor_descriptors : array-like of shape (Q, dim)
        Descriptors of the anchors (queries).
    database_descriptors : array-like of shape (D, dim)
        Descriptors of the images positives and negatives are taken from.
    positives : sparse or dense bool matrix of shape (Q, D)
        Ground truth of each anchor.
    anchors : array-like of int, optional
        Rows of ``anchor_descriptors`` to mine for (e.g. the training split); default all.
    n_negatives : int, default 10
        Hard negatives per anchor: its most similar non-positive database images.
    max_positives : int, default 10
        Positives per anchor: its most similar positives.
    same_set : bool, default False
        The anchors are the database images themselves (Q == D, row i is database image i): an image is never
        its own positive or negative.
    block_size : int, default 1024
        Anchors whose similarities are computed at once (bounds memory to block_size × D floats).

    Returns
    -------
    Triplets
        Ordered by anchor, then positive (most similar first), then negative (most similar first).

    Examples
    --------
    >>> database = np.array([[1.0, 0.0], [0.0, 1.0], [0.7, 0.7], [-1.0, 0.0]])
    >>> query = np.array([[0.9, 0.1]])
    >>> t = mine_triplets(query, database, np.array([[True, False, False, False]]), n_negatives=2)
    >>> t.anchor.tolist(), t.positive.tolist(), t.negative.tolist()
    ([0, 0], [0, 0], [2, 1])
    """
    queries = _unit_rows(anchor_descriptors, "anchor descriptors")
    database = _unit_rows(database_descriptors, "database descriptors")
    if queries.shape[1] != database.shape[1]:
        raise ValueError(
            f"anchor and database descriptors must have the same dimension, got {queries.shape[1]} and "
            f"{database.shape[1]}"
        )
    positives = sparse.csr_array(positives, dtype=bool)
    if positives.shape != (len(queries), len(database)):
        raise ValueError(
            f"positives must have shape ({len(queries)}, {len(database)}) (anchors × database), got {positives.shape}"
        )
    if same_set and len(queries) != len(database):
        raise ValueError("same_set=True needs the anchors to be the database images (as many rows)")
    for name, value in (("n_negatives", n_negatives), ("max_positives", max_positives), ("block_size", block_size)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    rows = np.arange(len(queries)) if anchors is None else np.asarray(anchors, dtype=np.int64).ravel()
    if rows.size and (rows.min() < 0 or rows.max() >= len(queries)):
        raise ValueError(f"anchors must index the {len(queries)} anchor descriptors")

    parts: tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]] = ([], [], [])
    for start in range(0, rows.size, block_size):
        block = rows[start : start + block_size]
        similarity = queries[block] @ database.T  # (B, D)
        for row, anchor in zip(similarity, block, strict=True):
            own = positives.indices[positives.indptr[anchor] : positives.indptr[anchor + 1]]
            if same_set:
                own = own[own != anchor]
            if own.size == 0:
                continue
            positive = own[np.lexsort((own, -row[own]))[:max_positives]]
            candidates = row.copy()
            candidates[own] = -np.inf
            if same_set:
                candidates[anchor] = -np.inf
            available = int(np.isfinite(candidates).sum())
            count = min(n_negatives, available)
            if count == 0:
                continue
            nearest = np.argpartition(-candidates, count - 1)[:count]
            negative = nearest[np.lexsort((nearest, -candidates[nearest]))]
            parts[0].append(np.full(positive.size * negative.size, anchor, dtype=np.int64))
            parts[1].append(np.repeat(positive, negative.size).astype(np.int64))
            parts[2].append(np.tile(negative, positive.size).astype(np.int64))
    if not parts[0]:
        empty = np.empty(0, dtype=np.int64)
        return Triplets(empty, empty.copy(), empty.copy())
    return Triplets(*(np.concatenate(part) for part in parts))
