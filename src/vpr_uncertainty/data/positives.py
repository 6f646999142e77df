"""Radius ground truth: the database images within a distance of each query are its positives.

The field's convention (NetVLAD, VPR-datasets-downloader, VPR-methods-evaluation) is a 25 m radius on UTM
positions, inclusive (a database image exactly 25 m away is a positive). Sequence datasets such as Nordland use
a frame tolerance instead: frames at most ``tolerance`` apart. Both are the same radius search, in metres or in
frames, answered with a KD-tree on the database positions (``scipy.spatial.cKDTree.query_ball_point``), so the
cost grows with the number of positives, not with Q × D.
"""

from __future__ import annotations

import numbers

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

__all__ = ["DEFAULT_RADIUS", "positives_within_frames", "positives_within_radius"]

#: Default positive radius in metres.
DEFAULT_RADIUS = 25.0


def _check_positions(positions: object, name: str) -> np.ndarray:
    array = np.asarray(positions)
    if array.ndim == 1:
        array = array[:, None]
    if array.ndim != 2 or array.shape[1] not in (1, 2, 3):
        raise ValueError(f"{name} must have shape (n, 2) (or (n,) / (n, 1) / (n, 3)), got shape {array.shape}")
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise TypeError(f"{name} must be numeric, got dtype {array.dtype}")
    array = array.astype(np.float64, copy=False)
    if not np.isfinite(array).all():
        row = int(np.argwhere(~np.isfinite(array))[0, 0])
        raise ValueError(f"{name} must be finite; row {row} is {array[row].tolist()}")
    return array


def _check_radius(radius: object, name: str) -> float:
    if isinstance(radius, bool) or not isinstance(radius, numbers.Real):
        raise TypeError(f"{name} must be a non-negative number, got {radius!r}")
    value = float(radius)
    if not value >= 0.0 or not np.isfinite(value):  # also rejects NaN
        raise ValueError(f"{name} must be a finite non-negative number, got {radius!r}")
    return value


def positives_within_radius(
    query_positions: object, database_positions: object, radius: float = DEFAULT_RADIUS
) -> sparse.csr_array:
    """Positives of each query: the database images at Euclidean distance ``<= radius``.

    Parameters
    ----------
    query_positions : array-like of shape (Q, 2)
        Query positions, e.g. UTM easting and northing in metres. Shapes (Q,), (Q, 1) and (Q, 3) are also
        accepted (1-D positions along a track, or 3-D positions).
    database_positions : array-like of shape (D, 2)
        Database positions, in the same frame and unit as the queries.
    radius : float, default 25.0
        Distance threshold, inclusive, in the unit of the positions.

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool
        Row q holds the positives of query q, with sorted column indices.

    Examples
    --------
    >>> queries = np.array([[0.0, 0.0], [100.0, 0.0]])
    >>> database = np.array([[3.0, 4.0], [30.0, 0.0], [0.0, -25.0]])
    >>> positives_within_radius(queries, database, radius=25).toarray()
    array([[ True, False,  True],
           [False, False, False]])
    """
    queries = _check_positions(query_positions, "query_positions")
    database = _check_positions(database_positions, "database_positions")
    if queries.shape[1] != database.shape[1]:
        raise ValueError(
            f"query_positions and database_positions must have the same number of coordinates, got "
            f"{queries.shape[1]} and {database.shape[1]}"
        )
    radius = _check_radius(radius, "radius")
    n_queries, n_database = len(queries), len(database)
    indptr = np.zeros(n_queries + 1, dtype=np.int64)
    if n_queries == 0 or n_database == 0:
        return sparse.csr_array(
            (np.ones(0, dtype=bool), np.zeros(0, dtype=np.int64), indptr), shape=(n_queries, n_database)
        )
    tree = cKDTree(database)
    neighbours = tree.query_ball_point(queries, r=radius, return_sorted=True)
    counts = np.fromiter((len(row) for row in neighbours), dtype=np.int64, count=n_queries)
    np.cumsum(counts, out=indptr[1:])
    indices = np.fromiter((index for row in neighbours for index in row), dtype=np.int64, count=int(indptr[-1]))
    data = np.ones(indices.size, dtype=bool)
    return sparse.csr_array((data, indices, indptr), shape=(n_queries, n_database))


def positives_within_frames(
    query_frames: object, database_frames: object, tolerance: int | float = 10
) -> sparse.csr_array:
    """Positives of each query of a sequence dataset: the database frames at most ``tolerance`` frames away.

    This is the ground truth of Nordland and other datasets whose query and database traverses are aligned
    frame by frame (frame i of the query traverse shows the place of frame i of the database traverse).

    Parameters
    ----------
    query_frames : array-like of shape (Q,)
        Frame index of each query.
    database_frames : array-like of shape (D,)
        Frame index of each database image.
    tolerance : int or float, default 10
        Largest frame difference of a positive, inclusive.

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool

    Examples
    --------
    >>> positives_within_frames([0, 5], [0, 1, 2, 3, 4, 5, 6], tolerance=1).toarray().astype(int)
    array([[1, 1, 0, 0, 0, 0, 0],
           [0, 0, 0, 0, 1, 1, 1]])
    """
    queries = np.asarray(query_frames)
    database = np.asarray(database_frames)
    for name, array in (("query_frames", queries), ("database_frames", database)):
        if array.ndim != 1:
            raise ValueError(f"{name} must be 1-D (one frame index per image), got shape {array.shape}")
    tolerance = _check_radius(tolerance, "tolerance")
    return positives_within_radius(queries, database, radius=tolerance)
