"""Matchers: nearest neighbours with Lowe's ratio test for any descriptor, and the interface of learned matchers.

A matcher maps two :class:`~vpr_uncertainty.geometric.local_features.LocalFeatures` (and the working resolution)
to an array of shape (M, 2): row ``(i, j)`` matches keypoint ``i`` of the first image to keypoint ``j`` of the
second.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from vpr_uncertainty.geometric.local_features import LocalFeatures

__all__ = ["Matcher", "NearestNeighborMatcher", "match_nearest_neighbors"]


class Matcher(Protocol):
    name: str
    #: whether ``match`` may run in several threads at once (numpy and torch on CPU release the GIL)
    thread_parallel: bool
    #: a torch model: parallel threads then run with one torch thread each
    uses_torch: bool

    def config(self) -> dict[str, Any]: ...

    def match(self, features0: LocalFeatures, features1: LocalFeatures, *, max_side: int) -> np.ndarray: ...


def match_nearest_neighbors(
    descriptors0: np.ndarray, descriptors1: np.ndarray, *, ratio: float | None = 0.8, mutual: bool = True
) -> np.ndarray:
    """Nearest-neighbour matches under Euclidean distance, filtered by Lowe's ratio test and a mutual check.

    Parameters
    ----------
    descriptors0, descriptors1 : ndarray of shape (N0, D) and (N1, D)
    ratio : float or None
        Keep a match when its distance is below ``ratio`` times the distance to the second-nearest neighbour
        (Lowe 2004 uses 0.8); None skips the test.
    mutual : bool
        Keep only matches that are also the nearest neighbour in the other direction.

    Returns
    -------
    ndarray of shape (M, 2), int64

    Examples
    --------
    >>> a = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    >>> b = np.array([[0.0, 0.05], [1.0, 0.1], [0.6, 0.6]])
    >>> match_nearest_neighbors(a, b, ratio=0.8)
    array([[0, 0],
           [1, 1]])
    """
    d0 = np.asarray(descriptors0, np.float32)
    d1 = np.asarray(descriptors1, np.float32)
    if d0.ndim != 2 or d1.ndim != 2 or d0.shape[1] != d1.shape[1]:
        raise ValueError(f"descriptors must be (N0, D) and (N1, D) with the same D, got {d0.shape} and {d1.shape}")
    need = 2 if ratio is not None else 1
    if len(d0) == 0 or len(d1) < need:
        return np.zeros((0, 2), np.int64)
    squared = (
        np.einsum("ij,ij->i", d0, d0)[:, None] + np.einsum("ij,ij->i", d1, d1)[None, :] - 2.0 * (d0 @ d1.T)
    ).astype(np.float64)
    np.maximum(squared, 0.0, out=squared)
    nearest = np.argmin(squared, axis=1)
    rows = np.arange(len(d0))
    keep = np.ones(len(d0), bool)
    if ratio is not None:
        best = squared[rows, nearest]
        squared[rows, nearest] = np.inf
        second = squared.min(axis=1)
        squared[rows, nearest] = best
        keep &= best < (ratio**2) * second
    if mutual:
        keep &= np.argmin(squared, axis=0)[nearest] == rows
    return np.stack([rows[keep], nearest[keep]], axis=1).astype(np.int64)


class NearestNeighborMatcher:
    """Mutual nearest neighbours with Lowe's ratio test (any float descriptor: SIFT, hloc files, DELF, ...)."""

    name = "nn-ratio"
    thread_parallel = True
    uses_torch = False

    def __init__(self, *, ratio: float | None = 0.8, mutual: bool = True) -> None:
        if ratio is not None and not 0.0 < ratio <= 1.0:
            raise ValueError(f"ratio must lie in (0, 1] or be None, got {ratio!r}")
        self.ratio = ratio
        self.mutual = bool(mutual)

    def config(self) -> dict[str, Any]:
        return {"name": self.name, "ratio": self.ratio, "mutual": self.mutual}

    def match(self, features0: LocalFeatures, features1: LocalFeatures, *, max_side: int) -> np.ndarray:
        return match_nearest_neighbors(
            features0.descriptors, features1.descriptors, ratio=self.ratio, mutual=self.mutual
        )
