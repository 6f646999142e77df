"""Fair evaluation protocols for the BTL head: no query is both a training anchor and a test query.

A learned head evaluated on the queries it was trained on measures memorisation, not uncertainty. The two
protocols here keep training and test queries apart, for a sequence dataset whose query and database traverses
are aligned frame by frame (query i shows the place of database image i, as in VPR-Bench's corridor):

``database``
    The head is trained on the database alone: every database image is an anchor, its positives are the other
    database images at most ``frame_tolerance`` frames away, its hard negatives the most similar of the rest.
    Every query is a test query; none is seen in training.
``query-split``
    The queries are cut at ``split_at`` into two contiguous parts of the traversal: the head is trained on queries
    ``0 .. split_at - 1`` (positives from the query ground truth) and tested on queries ``split_at .. Q - 1``.

Pure numpy at import: the training function imports torch (through :mod:`~vpr_uncertainty.btl.training`) only
when called.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import sparse

__all__ = [
    "PROTOCOLS",
    "BTLProtocol",
    "btl_protocol",
    "database_frame_positives",
    "train_for_protocol",
]

#: The protocols :func:`btl_protocol` builds.
PROTOCOLS = ("database", "query-split")


@dataclass(frozen=True)
class BTLProtocol:
    """Which images train the head and which queries test it.

    Attributes
    ----------
    name : str
        One of :data:`PROTOCOLS`.
    anchors : {"database", "queries"}
        What the training anchors are.
    train_queries : ndarray of int64
        Queries used as training anchors (training and early-stopping validation); empty when ``anchors`` is
        ``"database"``.
    test_queries : ndarray of int64
        Queries the head is evaluated on; disjoint from ``train_queries``.
    description : str
        One line for a report.
    """

    name: str
    anchors: str
    train_queries: np.ndarray
    test_queries: np.ndarray
    description: str


def _count(value: object, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def btl_protocol(name: str, n_queries: int, *, split_at: int | None = None) -> BTLProtocol:
    """The training and test queries of protocol ``name``.

    Parameters
    ----------
    name : {"database", "query-split"}
    n_queries : int
        Number of queries of the dataset (at least 2).
    split_at : int, optional
        ``query-split`` only: the first test query; queries before it train the head. Default: ``n_queries // 2``.
        Must leave at least 2 training queries (one for early stopping) and 1 test query.

    Returns
    -------
    BTLProtocol

    Examples
    --------
    >>> protocol = btl_protocol("query-split", 6, split_at=4)
    >>> protocol.train_queries.tolist(), protocol.test_queries.tolist()
    ([0, 1, 2, 3], [4, 5])
    >>> btl_protocol("database", 3).train_queries.size
    0
    """
    n_queries = _count(n_queries, "n_queries", 2)
    if name == "database":
        if split_at is not None:
            raise ValueError(
                "split_at applies to the 'query-split' protocol only; the 'database' one tests every query"
            )
        return BTLProtocol(
            name=name,
            anchors="database",
            train_queries=np.empty(0, dtype=np.int64),
            test_queries=np.arange(n_queries, dtype=np.int64),
            description=f"trained on the database images as anchors, tested on all {n_queries} queries",
        )
    if name == "query-split":
        split_at = n_queries // 2 if split_at is None else _count(split_at, "split_at", 2)
        if split_at > n_queries - 1:
            raise ValueError(
                f"split_at must leave at least one test query: got {split_at} with {n_queries} queries "
                f"(expected 2 <= split_at <= {n_queries - 1})"
            )
        return BTLProtocol(
            name=name,
            anchors="queries",
            train_queries=np.arange(split_at, dtype=np.int64),
            test_queries=np.arange(split_at, n_queries, dtype=np.int64),
            description=(
                f"trained on queries 0..{split_at - 1} as anchors, tested on queries {split_at}..{n_queries - 1}"
            ),
        )
    raise ValueError(f"unknown BTL protocol {name!r}; expected one of {', '.join(PROTOCOLS)}")


def database_frame_positives(n_database: int, frame_tolerance: int | float) -> sparse.csr_array:
    """Positives of each database image among the database: the images at most ``frame_tolerance`` frames away.

    Row i includes i itself; training with database anchors ignores that entry.

    Examples
    --------
    >>> database_frame_positives(4, 1).toarray().astype(int)
    array([[1, 1, 0, 0],
           [1, 1, 1, 0],
           [0, 1, 1, 1],
           [0, 0, 1, 1]])
    """
    from vpr_uncertainty.data import positives_within_frames

    frames = np.arange(_count(n_database, "n_database", 2))
    return positives_within_frames(frames, frames, tolerance=frame_tolerance)


def train_for_protocol(
    protocol: BTLProtocol,
    query_descriptors: object,
    database_descriptors: object,
    positives: object,
    *,
    frame_tolerance: int | float = 2,
    **settings: Any,
) -> tuple[Any, Any]:
    """Train a BTL head as ``protocol`` says, touching no test query.

    Parameters
    ----------
    protocol : BTLProtocol
    query_descriptors : array-like of shape (Q, dim)
        All queries; only ``protocol.train_queries`` are used.
    database_descriptors : array-like of shape (D, dim)
    positives : sparse or dense bool matrix of shape (Q, D)
        The query ground truth; only the rows of ``protocol.train_queries`` are used.
    frame_tolerance : int or float, default 2
        ``database`` protocol: the frame distance of database positives.
    **settings
        Passed to :func:`~vpr_uncertainty.btl.train_btl_head` (``seed``, ``epochs``, ``progress``, ...).

    Returns
    -------
    head, history
        As :func:`~vpr_uncertainty.btl.train_btl_head` returns them.
    """
    from vpr_uncertainty.btl.training import train_btl_head

    if not isinstance(protocol, BTLProtocol):
        raise TypeError(f"protocol must be a BTLProtocol (see btl_protocol), got {type(protocol).__name__}")
    overlap = np.intersect1d(protocol.train_queries, protocol.test_queries)
    if overlap.size:
        raise ValueError(
            f"protocol {protocol.name!r} trains on {overlap.size} of its test queries (first: {int(overlap[0])}); "
            "training and test queries must be disjoint"
        )
    queries = np.asarray(query_descriptors, dtype=np.float32)
    database = np.asarray(database_descriptors, dtype=np.float32)
    ground_truth = sparse.csr_array(positives, dtype=bool)
    if queries.ndim != 2 or ground_truth.shape != (len(queries), len(database)):
        raise ValueError(
            f"positives must have shape (n_queries, n_database) = ({len(queries)}, {len(database)}), "
            f"got {ground_truth.shape}"
        )
    if protocol.anchors == "database":
        return train_btl_head(database, database_frame_positives(len(database), frame_tolerance), **settings)
    rows = protocol.train_queries
    if rows.size and rows.max() >= len(queries):
        raise ValueError(f"protocol {protocol.name!r} trains on query {int(rows.max())} but there are {len(queries)}")
    return train_btl_head(database, ground_truth[rows], query_descriptors=queries[rows], **settings)
