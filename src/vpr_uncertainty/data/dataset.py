"""The Dataset every reader returns: images, positions when known, the positives of each query."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse

from vpr_uncertainty.plugins import import_or_explain

# The ground truth from positions lives below data/ (retrieval.ground_truth: retrieve() attaches it); the two
# functions that build and attach it are re-exported here.
from vpr_uncertainty.retrieval.ground_truth import (
    POSITION_KINDS,
    PositionKind,
    attach_ground_truth,
    check_positions,
    detect_position_kind,
    ground_truth_fields,
)

__all__ = ["Dataset", "PlaceholderPositionsWarning", "attach_ground_truth", "ground_truth_fields", "latlon_to_utm"]


class PlaceholderPositionsWarning(UserWarning):
    """Issued when a method that needs metric positions is given frame indices or placeholder ids."""


def _relative_name(path: Path, root: Path | None) -> str:
    return (path.relative_to(root) if root is not None and path.is_relative_to(root) else path).as_posix()


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
            paths, names = getattr(self, f"{name}_paths"), getattr(self, f"{name}_names")
            paths = None if paths is None else [Path(path) for path in paths]  # an iterator is read once
            if names is None and paths is not None:
                names = [_relative_name(path, self.root) for path in paths]
            for kind, items, convert in (("paths", paths, Path), ("names", names, str)):
                if items is not None:
                    items = [convert(item) for item in items]
                    if len(items) != expected:
                        raise ValueError(f"{name}_{kind} has {len(items)} entries but positives has {expected}")
                    setattr(self, f"{name}_{kind}", items)
            positions = getattr(self, f"{name}_positions")
            if positions is not None:
                positions = check_positions(positions, f"{name}_positions", expected_rows=expected)
                setattr(self, f"{name}_positions", positions)
        if self.position_kind is None:  # stays None without positions
            self.position_kind = detect_position_kind(self.database_positions, self.query_positions)
        if self.position_kind is not None and self.position_kind not in POSITION_KINDS:
            raise ValueError(f"position_kind must be one of {POSITION_KINDS} or None, got {self.position_kind!r}")
        self.positive_radius = None if self.positive_radius is None else float(self.positive_radius)

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


def latlon_to_utm(
    latitude: object, longitude: object, *, zone_number: int | None = None, northern: bool | None = None
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
    utm = import_or_explain("utm", "converting latitude/longitude to metres needs the 'utm' package: pip install utm")
    lat = np.asarray(latitude, dtype=np.float64).reshape(-1)
    lon = np.asarray(longitude, dtype=np.float64).reshape(-1)
    if lat.shape != lon.shape:
        raise ValueError(f"latitude and longitude must have the same length, got {lat.size} and {lon.size}")
    if not (np.isfinite(lat).all() and np.isfinite(lon).all()):
        raise ValueError("latitude and longitude must be finite numbers")
    for name, values, low, high, note in (("latitude", lat, -80, 84, " (UTM)"), ("longitude", lon, -180, 180, "")):
        bad = np.flatnonzero((values < low) | (values > high))[:1]
        if bad.size:
            raise ValueError(f"{name} must lie in [{low}, {high}] degrees{note}, got {values[bad[0]]} at row {bad[0]}")
    if lat.size == 0:
        return np.empty((0, 2)), int(zone_number or 0), bool(northern if northern is not None else True)
    median_lat, median_lon = float(np.median(lat)), float(np.median(lon))
    if zone_number is None:
        zone_number = int(utm.latlon_to_zone_number(median_lat, median_lon))
    northern = median_lat >= 0 if northern is None else northern
    easting, northing, _, _ = utm.from_latlon(
        lat, lon, force_zone_number=int(zone_number), force_northern=bool(northern)
    )
    positions = np.column_stack([np.asarray(easting, np.float64), np.asarray(northing, np.float64)])
    return positions, int(zone_number), bool(northern)
