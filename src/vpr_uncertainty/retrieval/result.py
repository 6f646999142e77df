"""The result type of a retrieval: the top-k database images of every query, with its ground truth.

A :class:`Retrieval` is what every uncertainty method and the evaluation read. It is made from a full similarity
matrix (:func:`~vpr_uncertainty.retrieval.readers.read_results`), from descriptors
(:func:`~vpr_uncertainty.retrieval.search.retrieve`, a Faiss search), or read back from a retrieval file
(:func:`~vpr_uncertainty.retrieval.file_format.load_retrieval`); the ground truth, names and positions of a
dataset are attached by :func:`vpr_uncertainty.data.attach.attach_ground_truth`.

Conventions: scores are similarities, higher = more similar, sorted descending along each row; a missing
candidate (k larger than the database, or an approximate index that found fewer) has index ``-1``, score
``-inf`` and distance ``+inf``, at the end of its row. ``config["position_kind"]`` says what the positions are:
``"metres"`` (a metric frame such as UTM), ``"frames"`` (frame indices of a sequence) or ``"placeholder"`` (ids
laid out on a line that only encode which images match); an absent key means metres.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import sparse

from vpr_uncertainty.retrieval._checks import check_retrieval_fields

__all__ = ["Retrieval"]


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
        Ground truth: the database images that are correct answers for each query. Given as a list of positive
        database indices per query (``[[0, 4], [], [7]]``), a boolean (Q, D) mask or a sparse matrix; stored as a
        boolean ``csr_array``. From lists, D is the size that ``database_names`` or ``database_positions`` give,
        else the smallest that holds every positive and retrieved index (see
        :func:`vpr_uncertainty.positives_from_lists` to fix D yourself).
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
        """Check every field (see :mod:`vpr_uncertainty.retrieval._checks`); a ValueError names the field."""
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

    def subset_queries(self, rows: np.ndarray) -> Retrieval:
        """The retrieval of the queries ``rows`` only (an index array or a boolean mask), same database."""
        rows = np.asarray(rows)

        def take(value: Any) -> Any:
            return None if value is None else value[rows]

        return dataclasses.replace(
            self,
            scores=self.scores[rows],
            indices=self.indices[rows],
            positives=take(self.positives),
            distances=take(self.distances),
            query_names=take(self.query_names),
            query_positions=take(self.query_positions),
        )

    @property
    def n_queries(self) -> int:
        return self.scores.shape[0]

    @property
    def k(self) -> int:
        """Number of candidates stored per query."""
        return self.scores.shape[1]
