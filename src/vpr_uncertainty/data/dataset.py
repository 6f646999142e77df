"""The interface every dataset reader returns: images, their positions when known, and the positives of each query.

A :class:`Dataset` is what the feature-extraction stage reads (image paths and names) and what the retrieval file
inherits (names, positions, positives). Every reader in :mod:`vpr_uncertainty.data` returns one:

* :func:`~vpr_uncertainty.data.folder.load_folder_dataset`: VPR-datasets-downloader folders, image names
  ``@east@north@zone@letter@lat@lon@...@.jpg``;
* :func:`~vpr_uncertainty.data.vprbench.load_vprbench_dataset`: VPR-Bench ``query/``, ``ref/``,
  ``ground_truth_new.npy``;
* :func:`~vpr_uncertainty.data.table.load_table_dataset`: CSV/TSV of image paths with x, y in metres or
  latitude/longitude;
* :func:`~vpr_uncertainty.data.poses.load_poses_dataset`: ``.npz`` with ``utmQ``, ``utmDb``, ``posDistThr``
  (positions only);
* :func:`~vpr_uncertainty.data.named_datasets.load_dataset`: any of the above, detected from the path, or a named
  dataset of the paper.

Positions and their kind
    Positions are float64 arrays of shape (N, 2), in metres (UTM easting, northing, or any metric frame) when
    ``position_kind == "metres"``. Some benchmarks store stand-ins instead, and a method that works in metric
    space (SUE, spatial spread of the retrieved places) must not take them for metres:

    * ``"frames"``: the position encodes a frame index of a sequence (Nordland: Patch-NetVLAD's ground-truth file
      stores frame i as (i, i)); neighbouring frames are neighbouring places but the unit is not a metre;
    * ``"placeholder"``: ids laid out on a line (AmsterTime's pair ids 100 m apart on a dummy axis,
      VPR-datasets-downloader's Nordland at 25/10.5 m per frame, which the named dataset ``"nordland"`` turns
      back into frame indices); they only encode which images match.

    :func:`detect_position_kind` recognises these layouts from the numbers alone; named datasets set the kind
    explicitly; :meth:`Dataset.metric_positions` returns the positions for a metric method and warns with
    :class:`PlaceholderPositionsWarning` when they are not metres.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy import sparse

__all__ = [
    "POSITION_KINDS",
    "Dataset",
    "PlaceholderPositionsWarning",
    "PositionKind",
    "detect_position_kind",
]

PositionKind = Literal["metres", "frames", "placeholder"]
#: The values of :attr:`Dataset.position_kind` (besides None: no positions).
POSITION_KINDS: tuple[str, ...] = ("metres", "frames", "placeholder")


class PlaceholderPositionsWarning(UserWarning):
    """Issued when a method that needs metric positions is given frame indices or placeholder ids."""


def _as_positions(value: object, name: str, expected_rows: int | None) -> np.ndarray | None:
    if value is None:
        return None
    array = np.asarray(value)
    if array.ndim != 2 or array.shape[1] != 2:
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


def _line_coordinate(positions: np.ndarray) -> np.ndarray | None:
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
    """Guess whether positions are metres, sequence frame indices or placeholder ids.

    Camera positions of a real 2-D dataset never all lie exactly on one axis-aligned line or on the diagonal
    x == y; benchmarks that have no positions fake them that way. Such positions are ``"frames"`` when the
    coordinate along the line takes consecutive integer values (frame indices), ``"placeholder"`` otherwise.
    At least three distinct positions are needed to tell; fewer are taken as metres.

    A genuine 1-D metric track stored as (distance, 0) is classified ``"placeholder"``; pass
    ``position_kind="metres"`` to the reader to say otherwise.

    Parameters
    ----------
    *positions : ndarray of shape (N_i, 2) or None
        Position arrays of the same dataset (typically database and queries), judged together.

    Returns
    -------
    {"metres", "frames", "placeholder"} or None
        None when no positions are given.

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
    line = _line_coordinate(stacked)
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
        Short name, e.g. ``"st_lucia"`` or the folder name.
    root : Path or None
        Folder the image names are relative to (the split folder holding ``database/`` and ``queries/``, the
        VPR-Bench dataset folder, the folder of a CSV), or None.
    positives : scipy.sparse.csr_array of shape (Q, D), bool
        Row q holds True at the database images that show the place of query q.
    database_paths, query_paths : list of Path (length D and Q), or None
        Image files, in index order. None when only positions are known (a ``.npz`` of positions).
    database_positions : ndarray of shape (D, 2), float64, or None
    query_positions : ndarray of shape (Q, 2), float64, or None
        Positions; in metres when ``position_kind == "metres"`` (see the module docstring).
    positive_radius : float or None
        Threshold the positives were computed with, in the unit of the positions (metres, or frames when
        ``position_kind == "frames"``). None for explicit ground truth.
    position_kind : {"metres", "frames", "placeholder"} or None
        What the positions are; None when there are none.
    database_names, query_names : list of str (length D and Q), or None
        Image names, unique within the dataset: POSIX paths relative to ``root``. Derived from the paths when
        not given. They key descriptor caches and are stored in retrieval files.
    split : str or None
        Split of the benchmark (``"test"``, ``"val"``, ...), when it has splits.
    source_format : str or None
        Reader that produced the dataset: ``"folder"``, ``"vprbench"``, ``"table"`` or ``"poses"``.
    info : dict
        Anything else worth keeping (UTM zone, original file, notes); JSON-serialisable.
    unlisted : list of dict
        What could not be listed when the images were discovered, ``{"path": ..., "error": ...}`` per folder
        that cannot be read or broken link without an image suffix: images under them are missing from the
        dataset. The extraction stage reports them (``on_error="skip"``) or refuses to go on (``"fail"``).
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
            positions = _as_positions(getattr(self, f"{name}_positions"), f"{name}_positions", expected)
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
        """Database and query positions for a method that works in metres, e.g. SUE.

        Parameters
        ----------
        purpose : str
            Who asks, for the messages (e.g. ``"SUE"``).

        Returns
        -------
        database_positions : ndarray of shape (D, 2)
        query_positions : ndarray of shape (Q, 2)

        Raises
        ------
        ValueError
            When the dataset has no positions.

        Warns
        -----
        PlaceholderPositionsWarning
            When the positions are frame indices or placeholder ids: distances between them are not metres.
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
        """The fields of a :class:`~vpr_uncertainty.retrieval.Retrieval` that come from the dataset.

        Returns
        -------
        dict
            ``positives``, ``query_names`` and ``database_names`` (ndarray of str or None),
            ``query_positions`` and ``database_positions`` (or None) and ``config`` (a dict with the dataset
            name, split, positive radius and position kind).
        """
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
