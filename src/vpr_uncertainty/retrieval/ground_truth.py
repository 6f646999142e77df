"""Ground truth from positions: the positives within a radius, the kind of positions, and the ground-truth fields a
:class:`~vpr_uncertainty.retrieval.Retrieval` carries (positives, names, positions). Why it sits below
:mod:`vpr_uncertainty.data`: see docs/explanation/architecture.md.
"""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
from scipy import sparse

from vpr_uncertainty.retrieval.result import Retrieval

PositionKind = Literal["metres", "frames", "placeholder"]
#: The values of :attr:`Dataset.position_kind` (besides None: no positions).
POSITION_KINDS: tuple[str, ...] = ("metres", "frames", "placeholder")


def check_positions(
    value: object, name: str, *, expected_rows: int | None = None, any_dimension: bool = False
) -> np.ndarray:
    """Finite float64 positions of shape (n, 2); with ``any_dimension`` also (n,), (n, 1) and (n, 3)."""
    array = np.asarray(value)
    if any_dimension:
        if array.ndim == 1:
            array = array[:, None]
        if array.ndim != 2 or array.shape[1] not in (1, 2, 3):
            raise ValueError(f"{name} must have shape (n, 2) (or (n,) / (n, 1) / (n, 3)), got shape {array.shape}")
    elif array.ndim != 2 or array.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2), got shape {array.shape}")
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise TypeError(f"{name} must be numeric, got dtype {array.dtype}")
    array = np.ascontiguousarray(array, dtype=np.float64)
    if not np.isfinite(array).all():
        row = int(np.argwhere(~np.isfinite(array))[0, 0])
        raise ValueError(f"{name} must be finite; row {row} is {array[row].tolist()}")
    if expected_rows is not None and len(array) != expected_rows:
        raise ValueError(f"{name} has {len(array)} rows, expected {expected_rows} (one per image)")
    return array


def line_coordinate(positions: np.ndarray) -> np.ndarray | None:
    """The 1-D coordinate of positions that all lie on an axis-aligned line or on the diagonal x == y."""
    if len(positions) == 0:
        return None
    x, y = positions[:, 0], positions[:, 1]
    if np.all(y == y[0]) or np.array_equal(x, y):
        return x
    return y if np.all(x == x[0]) else None


def detect_position_kind(*positions: np.ndarray | None) -> PositionKind | None:
    """Guess whether positions (of one dataset, judged together) are metres, sequence frame indices or placeholder ids.

    Real 2-D camera positions never all lie on one axis-aligned line or on the diagonal x == y; benchmarks without
    positions fake them that way: ``"frames"`` when the coordinate along the line takes consecutive integers,
    ``"placeholder"`` otherwise. Fewer than three distinct positions count as metres; None when none are given. A real
    1-D track stored as (distance, 0) comes out ``"placeholder"``: pass ``position_kind="metres"`` to the reader.

    Examples
    --------
    >>> frames = np.repeat(np.arange(50.0)[:, None], 2, axis=1)     # Nordland: frame i at (i, i)
    >>> detect_position_kind(frames, frames)
    'frames'
    >>> pairs = np.column_stack([np.zeros(4), 100.0 * np.arange(4)])  # AmsterTime: pair ids 100 m apart
    >>> detect_position_kind(pairs)
    'placeholder'
    >>> detect_position_kind(np.array([[584744.9, 4476709.9], [584825.9, 4476945.6], [584800.0, 4476800.0]]))
    'metres'
    """
    arrays = [np.asarray(array, dtype=np.float64) for array in positions if array is not None]
    if not arrays:
        return None
    stacked = np.concatenate([array.reshape(-1, 2) for array in arrays])
    if len(np.unique(stacked, axis=0)) < 3:
        return "metres"
    line = line_coordinate(stacked)
    if line is None:
        return "metres"
    values = np.unique(line)
    if np.array_equal(values, np.round(values)) and np.all(np.diff(values) == 1):
        return "frames"
    return "placeholder"


#: Default positive radius in metres.
DEFAULT_RADIUS = 25.0


def check_radius(radius: object, name: str) -> float:
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
    queries = check_positions(query_positions, "query_positions", any_dimension=True)
    database = check_positions(database_positions, "database_positions", any_dimension=True)
    if queries.shape[1] != database.shape[1]:
        raise ValueError(
            f"query_positions and database_positions must have the same number of coordinates, got "
            f"{queries.shape[1]} and {database.shape[1]}"
        )
    radius = check_radius(radius, "radius")
    n_queries, n_database = len(queries), len(database)
    indptr = np.zeros(n_queries + 1, dtype=np.int64)
    if n_queries == 0 or n_database == 0:
        return sparse.csr_array(
            (np.ones(0, dtype=bool), np.zeros(0, dtype=np.int64), indptr), shape=(n_queries, n_database)
        )
    from scipy.spatial import cKDTree  # here: scipy.spatial costs ~0.3 s of every command's start-up

    tree = cKDTree(database)
    neighbours = tree.query_ball_point(queries, r=radius, return_sorted=True)
    counts = np.fromiter((len(row) for row in neighbours), dtype=np.int64, count=n_queries)
    np.cumsum(counts, out=indptr[1:])
    indices = np.fromiter((index for row in neighbours for index in row), dtype=np.int64, count=int(indptr[-1]))
    return sparse.csr_array((np.ones(indices.size, dtype=bool), indices, indptr), shape=(n_queries, n_database))


def positives_within_frames(
    query_frames: object, database_frames: object, tolerance: int | float = 10
) -> sparse.csr_array:
    """Positives of a sequence dataset: the database frames at most ``tolerance`` frames from each query (inclusive).

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
    tolerance = check_radius(tolerance, "tolerance")
    return positives_within_radius(queries, database, radius=tolerance)


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
    """The ground-truth fields of a retrieval of ``n_queries`` queries against ``n_database`` (or None) images.

    Parameters
    ----------
    n_queries : int
    n_database : int or None
    positives : sparse or dense bool matrix of shape (Q, D), optional
        Explicit ground truth; used instead of the radius search.
    database_positions, query_positions : array-like of shape (D, 2) and (Q, 2), optional
        (N,) arrays are read as (N, 1). With both and no positives, the positives are the database images within
        ``radius`` of each query (inclusive).
    radius : float, default=25.0
        Positive radius, in the unit of the positions.
    database_names, query_names : sequence of str, optional
    position_kind : {"metres", "frames", "placeholder"}, optional
        Detected from two-column positions when not given.

    Returns
    -------
    dict
        ``positives``, ``query_names``, ``database_names``, ``query_positions``, ``database_positions`` (or None)
        and ``config`` (``radius`` when the positives come from the positions, ``position_kind`` when known).
        A field of the wrong length raises a ValueError naming it.
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

    ``fields`` come from :func:`ground_truth_fields` or :meth:`Dataset.retrieval_fields`; or give the keyword options
    of :func:`ground_truth_fields` instead (sized by the retrieval, ``config["n_database"]`` as ``retrieve`` writes
    it). Each field given replaces the retrieval's; ``config`` entries are merged over its own, dropping ``radius``
    and ``position_kind`` when the positives or positions are replaced.

    Examples
    --------
    >>> from vpr_uncertainty.retrieval import retrieve
    >>> database = np.eye(3, dtype=np.float32)
    >>> result = attach_ground_truth(
    ...     retrieve(database, database[[2, 0]], top_k=2),
    ...     database_positions=[[0, 0], [50, 0], [100, 0]], query_positions=[[95, 0], [10, 0]], position_kind="metres",
    ... )
    >>> result.positives.toarray()
    array([[False, False,  True],
           [ True, False, False]])
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
