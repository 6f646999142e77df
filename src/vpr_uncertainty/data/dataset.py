"""The Dataset every reader returns: images, positions when known, the positives of each query."""

from __future__ import annotations

import dataclasses
import numbers
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy import sparse

from vpr_uncertainty.retrieval.result import Retrieval

PositionKind = Literal["metres", "frames", "placeholder"]
#: The values of :attr:`Dataset.position_kind` (besides None: no positions).
POSITION_KINDS: tuple[str, ...] = ("metres", "frames", "placeholder")


class PlaceholderPositionsWarning(UserWarning):
    """Issued when a method that needs metric positions is given frame indices or placeholder ids."""


def _check_positions(
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
    if np.all(y == y[0]):
        return x
    if np.all(x == x[0]):
        return y
    if np.array_equal(x, y):
        return x
    return None


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


def _relative_names(paths: list[Path], root: Path | None) -> list[str]:
    names = []
    for path in paths:
        if root is not None:
            try:
                names.append(Path(path).relative_to(root).as_posix())
                continue
            except ValueError:
                pass
        names.append(Path(path).as_posix())
    return names


@dataclass
class Dataset:
    """A VPR dataset: database and query images, their positions when known, and the positives of each query.

    Attributes
    ----------
    name : str
    root : Path or None
        Folder the image names are relative to (the split folder, the VPR-Bench folder, the folder of a table).
    positives : scipy.sparse.csr_array of shape (Q, D), bool
        Row q holds True at the database images that show the place of query q.
    database_paths, query_paths : list of Path (length D and Q), or None
        Image files in index order; None for a positions-only dataset.
    database_positions, query_positions : ndarray of shape (D, 2) and (Q, 2), float64, or None
    positive_radius : float or None
        Threshold of the positives, in the unit of the positions; None for explicit ground truth.
    position_kind : {"metres", "frames", "placeholder"} or None
        Metres (UTM or any metric frame); frame indices of a sequence (Nordland); or ids laid out on a line that only
        encode which images match (AmsterTime). Detected when not given (:func:`detect_position_kind`); a metric
        method (SUE) must not take the last two for metres: :meth:`metric_positions` warns.
    database_names, query_names : list of str, or None
        Unique POSIX paths relative to ``root`` (derived from the paths when not given); they key descriptor caches.
    split, source_format : str or None
        The benchmark's split; the reader (``"folder"``, ``"vprbench"``, ``"table"``, ``"poses"``).
    info : dict
        Anything else worth keeping (UTM zone, original file); JSON-serialisable.
    unlisted : list of dict
        ``{"path": ..., "error": ...}`` of each folder or broken link that could not be listed: images may be missing.
    """

    name: str
    root: Path | None
    positives: sparse.csr_array
    database_paths: list[Path] | None = None
    query_paths: list[Path] | None = None
    database_positions: np.ndarray | None = None
    query_positions: np.ndarray | None = None
    positive_radius: float | None = None
    position_kind: PositionKind | None = None
    database_names: list[str] | None = None
    query_names: list[str] | None = None
    split: str | None = None
    source_format: str | None = None
    info: dict[str, Any] = field(default_factory=dict)
    unlisted: list[dict[str, str]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.root = Path(self.root) if self.root is not None else None
        positives = sparse.csr_array(self.positives)
        if positives.ndim != 2:
            raise ValueError(f"positives must be 2-D (n_queries, n_database), got shape {positives.shape}")
        if positives.dtype != bool:
            positives = positives.astype(bool)
        positives.sort_indices()
        self.positives = positives
        n_queries, n_database = positives.shape
        for name, expected in (("database", n_database), ("query", n_queries)):
            paths = getattr(self, f"{name}_paths")
            if paths is not None:
                paths = [Path(path) for path in paths]
                if len(paths) != expected:
                    raise ValueError(f"{name}_paths has {len(paths)} entries but positives has {expected}")
                setattr(self, f"{name}_paths", paths)
            names = getattr(self, f"{name}_names")
            if names is None and paths is not None:
                names = _relative_names(paths, self.root)
            if names is not None:
                names = [str(item) for item in names]
                if len(names) != expected:
                    raise ValueError(f"{name}_names has {len(names)} entries but positives has {expected}")
                setattr(self, f"{name}_names", names)
            positions = getattr(self, f"{name}_positions")
            if positions is not None:
                positions = _check_positions(positions, f"{name}_positions", expected_rows=expected)
                setattr(self, f"{name}_positions", positions)
        has_positions = self.database_positions is not None or self.query_positions is not None
        if self.position_kind is None and has_positions:
            self.position_kind = detect_position_kind(self.database_positions, self.query_positions)
        if self.position_kind is not None and self.position_kind not in POSITION_KINDS:
            raise ValueError(f"position_kind must be one of {POSITION_KINDS} or None, got {self.position_kind!r}")
        if self.positive_radius is not None:
            self.positive_radius = float(self.positive_radius)

    # -- sizes ---------------------------------------------------------------------------------------------
    @property
    def n_queries(self) -> int:
        """Number of queries Q."""
        return int(self.positives.shape[0])

    @property
    def n_database(self) -> int:
        """Number of database images D."""
        return int(self.positives.shape[1])

    @property
    def has_images(self) -> bool:
        """Whether the image files are known (False for a positions-only dataset)."""
        return self.database_paths is not None and self.query_paths is not None

    # -- ground truth --------------------------------------------------------------------------------------
    @property
    def n_positives(self) -> np.ndarray:
        """Number of positives of each query, ndarray of shape (Q,), int64."""
        return np.diff(self.positives.indptr).astype(np.int64)

    @property
    def queries_without_positives(self) -> np.ndarray:
        """Indices of the queries with no positive in the database, ndarray of shape (M,), int64, sorted.

        No database image can be a correct answer for them: every method is wrong on them whatever it does.
        """
        return np.flatnonzero(self.n_positives == 0).astype(np.int64)

    # -- positions -----------------------------------------------------------------------------------------
    @property
    def has_metric_positions(self) -> bool:
        """Whether both position arrays are known and in metres."""
        return (
            self.database_positions is not None and self.query_positions is not None and self.position_kind == "metres"
        )

    def metric_positions(self, *, purpose: str = "a metric-space method") -> tuple[np.ndarray, np.ndarray]:
        """Database (D, 2) and query (Q, 2) positions for a method in metres (``purpose``, e.g. ``"SUE"``).

        Raises ValueError when the dataset has none; warns :class:`PlaceholderPositionsWarning` when not metres.
        """
        if self.database_positions is None or self.query_positions is None:
            raise ValueError(
                f"{purpose} needs database and query positions, but dataset {self.name!r} has none "
                f"(it was read from {self.source_format or 'explicit ground truth'})"
            )
        if self.position_kind != "metres":
            warnings.warn(
                f"dataset {self.name!r} has {self.position_kind} positions, not metres: {purpose} will treat "
                "them as metres and its output has no metric meaning",
                PlaceholderPositionsWarning,
                stacklevel=2,
            )
        return self.database_positions, self.query_positions

    # -- summaries -----------------------------------------------------------------------------------------
    def retrieval_fields(self) -> dict[str, Any]:
        """The fields of a :class:`~vpr_uncertainty.retrieval.Retrieval` that come from the dataset."""
        return {
            "positives": self.positives,
            "query_names": None if self.query_names is None else np.asarray(self.query_names, dtype=str),
            "database_names": None if self.database_names is None else np.asarray(self.database_names, dtype=str),
            "query_positions": self.query_positions,
            "database_positions": self.database_positions,
            "config": {"dataset": self.summary()},
        }

    def summary(self) -> dict[str, Any]:
        """A JSON-serialisable description: name, sizes, threshold, position kind, queries without positives."""
        return {
            "name": self.name,
            "root": None if self.root is None else str(self.root),
            "split": self.split,
            "source_format": self.source_format,
            "n_queries": self.n_queries,
            "n_database": self.n_database,
            "positive_radius": self.positive_radius,
            "position_kind": self.position_kind,
            "n_queries_without_positives": int(self.queries_without_positives.size),
            **({"info": self.info} if self.info else {}),
            **({"unlisted": list(self.unlisted)} if self.unlisted else {}),
        }

    def __repr__(self) -> str:
        radius = "" if self.positive_radius is None else f", positive_radius={self.positive_radius:g}"
        return (
            f"Dataset(name={self.name!r}, n_queries={self.n_queries}, n_database={self.n_database}"
            f"{radius}, position_kind={self.position_kind!r}, "
            f"queries_without_positives={self.queries_without_positives.size})"
        )


#: Default positive radius in metres.
DEFAULT_RADIUS = 25.0


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
    queries = _check_positions(query_positions, "query_positions", any_dimension=True)
    database = _check_positions(database_positions, "database_positions", any_dimension=True)
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
    from scipy.spatial import cKDTree  # here: scipy.spatial costs ~0.3 s of every command's start-up

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
    tolerance = _check_radius(tolerance, "tolerance")
    return positives_within_radius(queries, database, radius=tolerance)


def _import_utm():
    try:
        import utm
    except ImportError as error:  # pragma: no cover - utm is a dependency
        raise ImportError("converting latitude/longitude to metres needs the 'utm' package: pip install utm") from error
    return utm


def latlon_to_utm(
    latitude: object,
    longitude: object,
    *,
    zone_number: int | None = None,
    northern: bool | None = None,
) -> tuple[np.ndarray, int, bool]:
    """Project WGS84 latitude/longitude (N,) to UTM easting/northing (N, 2) in metres, all in one zone.

    Converting each point in its own 6° zone would put two images on either side of a boundary hundreds of km apart;
    one zone (by default that of the median point, and its hemisphere) keeps distances right at a dataset's scale.
    Returns the positions, the zone number and whether the zone is northern.

    Examples
    --------
    >>> positions, zone, northern = latlon_to_utm([40.4406, 40.4408], [-79.9959, -79.9959])
    >>> zone, northern, round(float(np.linalg.norm(positions[1] - positions[0])), 1)
    (17, True, 22.2)
    """
    utm = _import_utm()
    lat = np.asarray(latitude, dtype=np.float64).reshape(-1)
    lon = np.asarray(longitude, dtype=np.float64).reshape(-1)
    if lat.shape != lon.shape:
        raise ValueError(f"latitude and longitude must have the same length, got {lat.size} and {lon.size}")
    if not (np.isfinite(lat).all() and np.isfinite(lon).all()):
        raise ValueError("latitude and longitude must be finite numbers")
    if lat.size and not ((lat >= -80).all() and (lat <= 84).all()):
        bad = int(np.flatnonzero((lat < -80) | (lat > 84))[0])
        raise ValueError(f"latitude must lie in [-80, 84] degrees (UTM), got {lat[bad]} at row {bad}")
    if lon.size and not ((lon >= -180).all() and (lon <= 180).all()):
        bad = int(np.flatnonzero((lon < -180) | (lon > 180))[0])
        raise ValueError(f"longitude must lie in [-180, 180] degrees, got {lon[bad]} at row {bad}")
    if lat.size == 0:
        return np.empty((0, 2)), int(zone_number or 0), bool(northern if northern is not None else True)
    median_lat, median_lon = float(np.median(lat)), float(np.median(lon))
    if zone_number is None:
        zone_number = int(utm.latlon_to_zone_number(median_lat, median_lon))
    if northern is None:
        northern = median_lat >= 0
    easting, northing, _, _ = utm.from_latlon(
        lat, lon, force_zone_number=int(zone_number), force_northern=bool(northern)
    )
    positions = np.column_stack([np.asarray(easting, np.float64), np.asarray(northing, np.float64)])
    return positions, int(zone_number), bool(northern)


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
