"""Attach a dataset's ground truth, image names and positions to a retrieval.

The descriptor search (:func:`vpr_uncertainty.retrieval.retrieve`) knows descriptors only; what makes its
answers right or wrong comes from the dataset. :func:`ground_truth_fields` assembles those fields from what the
caller has (explicit positives, or positions and a radius; names; the kind of positions) and checks them against
the numbers of queries and database images; :func:`attach_ground_truth` puts them into a
:class:`~vpr_uncertainty.retrieval.Retrieval`. The fields have the same form as
:meth:`vpr_uncertainty.data.Dataset.retrieval_fields`.

>>> import numpy as np
>>> from vpr_uncertainty.retrieval import retrieve
>>> database = np.eye(3, dtype=np.float32)
>>> result = attach_ground_truth(
...     retrieve(database, database[[2, 0]], k=2),
...     database_positions=[[0, 0], [50, 0], [100, 0]], query_positions=[[95, 0], [10, 0]], position_kind="metres",
... )
>>> result.indices, result.positives.toarray()
(array([[2, 0],
       [0, 1]]), array([[False, False,  True],
       [ True, False, False]]))
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import sparse

from vpr_uncertainty.data.dataset import POSITION_KINDS, detect_position_kind
from vpr_uncertainty.data.positives import DEFAULT_RADIUS, positives_within_radius

if TYPE_CHECKING:
    from vpr_uncertainty.retrieval import Retrieval

__all__ = ["attach_ground_truth", "ground_truth_fields"]

#: The fields of a Retrieval that come from the dataset.
FIELDS = ("positives", "query_names", "database_names", "query_positions", "database_positions")


def _check_rows(value: object, name: str, expected: int | None, what: str) -> np.ndarray | None:
    if value is None:
        return None
    array = np.asarray(value)
    if expected is not None and len(array) != expected:
        raise ValueError(f"{name} has {len(array)} entries, expected {expected} (one per {what} descriptor)")
    return array


def _as_position_matrix(positions: np.ndarray | None) -> np.ndarray | None:
    if positions is None:
        return None
    positions = np.asarray(positions, dtype=np.float64)
    return positions[:, None] if positions.ndim == 1 else positions


def ground_truth_fields(
    n_queries: int,
    n_database: int | None,
    *,
    positives: object = None,
    database_positions: object = None,
    query_positions: object = None,
    radius: float = DEFAULT_RADIUS,
    database_names: object = None,
    query_names: object = None,
    position_kind: str | None = None,
) -> dict[str, Any]:
    """The ground-truth fields of a retrieval of ``n_queries`` queries against ``n_database`` database images.

    Parameters
    ----------
    n_queries : int
    n_database : int or None
        Number of database images; None when unknown (the lengths are then only checked against each other,
        when the fields are attached).
    positives : sparse or dense bool matrix of shape (Q, D), optional
        Explicit ground truth; used instead of the radius search.
    database_positions, query_positions : array-like of shape (D, 2) and (Q, 2), optional
        Camera positions (e.g. UTM easting, northing in metres); (N,) arrays are read as (N, 1). With both and no
        explicit positives, the positives are the database images within ``radius`` of each query (inclusive).
    radius : float, default=25.0
        Positive radius, in the unit of the positions.
    database_names, query_names : sequence of str, optional
        Image names.
    position_kind : {"metres", "frames", "placeholder"}, optional
        What the positions are (see :mod:`vpr_uncertainty.retrieval.result`); detected from two-column positions
        when not given.

    Returns
    -------
    dict
        ``positives`` (csr_array or None), ``query_names``, ``database_names``, ``query_positions``,
        ``database_positions`` (arrays or None) and ``config`` (``radius`` when the positives come from the
        positions, ``position_kind`` when known).

    Raises
    ------
    ValueError
        When a field has the wrong number of rows or ``position_kind`` is unknown, naming the field.
    """
    if position_kind is not None and position_kind not in POSITION_KINDS:
        raise ValueError(f"position_kind must be one of {POSITION_KINDS} or None, got {position_kind!r}")
    database_positions = _check_rows(database_positions, "database_positions", n_database, "database")
    query_positions = _check_rows(query_positions, "query_positions", n_queries, "query")
    database_names = _check_rows(database_names, "database_names", n_database, "database")
    query_names = _check_rows(query_names, "query_names", n_queries, "query")
    config: dict[str, Any] = {}
    if positives is not None:
        positives = sparse.csr_array(positives, dtype=bool)
        if positives.shape[0] != n_queries or (n_database is not None and positives.shape[1] != n_database):
            expected = f"({n_queries}, {'D' if n_database is None else n_database})"
            raise ValueError(f"positives must have shape {expected}, got {positives.shape}")
    elif database_positions is not None and query_positions is not None:
        positives = positives_within_radius(query_positions, database_positions, radius)
        config["radius"] = float(radius)
    if database_positions is not None or query_positions is not None:
        if position_kind is None:
            two_column = [p for p in (database_positions, query_positions) if p is not None and p.shape[1:] == (2,)]
            position_kind = detect_position_kind(*two_column) if two_column else None
        if position_kind is not None:
            config["position_kind"] = position_kind
    return {
        "positives": positives,
        "query_names": query_names,
        "database_names": database_names,
        "query_positions": _as_position_matrix(query_positions),
        "database_positions": _as_position_matrix(database_positions),
        "config": config,
    }


def attach_ground_truth(retrieval: Retrieval, fields: Mapping[str, Any] | None = None, /, **options: Any) -> Retrieval:
    """A copy of ``retrieval`` with the ground truth, names and positions of its dataset.

    Parameters
    ----------
    retrieval : Retrieval
        Typically the result of :func:`vpr_uncertainty.retrieval.retrieve`.
    fields : mapping, optional
        Fields made by :func:`ground_truth_fields` or :meth:`vpr_uncertainty.data.Dataset.retrieval_fields`.
    **options
        Or, instead of ``fields``, the keyword arguments of :func:`ground_truth_fields`; the numbers of queries and
        database images are those of ``retrieval`` (``config["n_database"]`` as written by ``retrieve``).

    Returns
    -------
    Retrieval
        The same candidates; each field given (not None) replaces the retrieval's, the others are kept. The
        ``config`` entries of ``fields`` are merged over the retrieval's; ``radius`` and ``position_kind`` left
        from earlier ground truth are dropped when the positives or positions are replaced.

    Raises
    ------
    ValueError
        When a field does not fit the retrieval (see :func:`ground_truth_fields` and
        :class:`~vpr_uncertainty.retrieval.Retrieval`).
    """
    if fields is not None and options:
        raise TypeError("attach_ground_truth takes fields or keyword options, not both")
    if fields is None:
        n_database = retrieval.n_database
        if n_database is None and isinstance(retrieval.config.get("n_database"), int):
            n_database = retrieval.config["n_database"]
        fields = ground_truth_fields(retrieval.n_queries, n_database, **options)
    unknown = set(fields) - {*FIELDS, "config"}
    if unknown:
        raise ValueError(f"unknown ground-truth fields {sorted(unknown)}; expected {', '.join(FIELDS)} and config")
    given = {name: fields[name] for name in FIELDS if fields.get(name) is not None}
    config = dict(retrieval.config)
    if "positives" in given:
        config.pop("radius", None)
    if "query_positions" in given or "database_positions" in given:
        config.pop("position_kind", None)
    config.update(fields.get("config") or {})
    return dataclasses.replace(retrieval, **given, config=config)
