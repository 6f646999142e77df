"""Dataset formats: how load_dataset recognises and reads a path (folders, VPR-Bench, tables, position files)."""

from __future__ import annotations

import csv
import io
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty.data.dataset import Dataset, latlon_to_utm
from vpr_uncertainty.data.images import has_split, list_images, load_folder_dataset, numbered_order
from vpr_uncertainty.formats.ground_truth import load_vprbench_ground_truth
from vpr_uncertainty.plugins import Registry
from vpr_uncertainty.retrieval.ground_truth import (
    DEFAULT_RADIUS,
    PositionKind,
    detect_position_kind,
    line_coordinate,
    positives_within_frames,
    positives_within_radius,
)


@dataclass(frozen=True)
class DatasetFormat:
    """One dataset format of :data:`DATASET_FORMAT_REGISTRY`.

    Attributes
    ----------
    name, description : str
    expects : str
        What a path of this format holds, in words (for the error of an unrecognised path).
    reader : callable or str
        ``reader(path, *, split, radius, queries, name, position_kind) -> Dataset`` or its dotted path.
    suffixes : tuple of str
        File suffixes (lower case) of a file format; empty for a folder format.
    detect : callable or None
        ``detect(folder) -> bool`` of a folder format.
    provides : tuple of str
        What the format gives the stages (``"images"``, ``"positions"``, ``"positives"``).
    extra : str or None
        The pip extra its reader needs.
    """

    name: str
    description: str
    expects: str
    reader: Callable[..., Dataset] | str
    suffixes: tuple[str, ...] = ()
    detect: Callable[[Path], bool] | None = None
    provides: tuple[str, ...] = ()
    extra: str | None = None


#: The registered dataset formats, in detection order.
DATASET_FORMAT_REGISTRY: Registry[DatasetFormat] = Registry("dataset format", label="formats")


def register_format(entry: DatasetFormat, *, overwrite: bool = False) -> DatasetFormat:
    """Add a dataset format (tried after the ones registered before it)."""
    if bool(entry.suffixes) == (entry.detect is not None):
        raise ValueError(f"dataset format {entry.name!r}: give either suffixes (a file format) or detect (a folder)")
    return DATASET_FORMAT_REGISTRY.register(entry, overwrite=overwrite)


def detect_format(path: str | Path) -> str:
    """The name of the registered format of a dataset path (file formats by suffix, folder formats by ``detect``).

    Raises FileNotFoundError for a missing path, ValueError when no format matches (listing what each expects).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no such file or folder: {path}")
    if is_regular_file(path, "a dataset file"):
        suffix = path.suffix.lower()
        files = DATASET_FORMAT_REGISTRY.entries()
        for entry in files:
            if suffix in entry.suffixes:
                return entry.name
        expected = " or ".join(entry.expects for entry in files if entry.suffixes)
        raise ValueError(f"{path}: unknown dataset file type {suffix!r}; expected {expected}")
    for entry in DATASET_FORMAT_REGISTRY:
        if entry.detect is not None and entry.detect(path):
            return entry.name
    expected = " or ".join(entry.expects for entry in DATASET_FORMAT_REGISTRY if entry.detect is not None)
    raise ValueError(f"{path} is not a dataset folder: expected {expected}")


def is_vprbench_folder(path: Path) -> bool:
    return (path / "ground_truth_new.npy").is_file() or ((path / "query").is_dir() and (path / "ref").is_dir())


def _is_downloader_folder(path: Path) -> bool:
    return any(
        candidate.is_dir() and has_split(candidate)
        for candidate in (path, *(path / "images").glob("*"), *path.glob("*"))
    )


def read_poses(path: Path, *, radius: float | None, name: str | None, position_kind: PositionKind | None, **_: Any):
    return load_poses_dataset(path, radius=radius, name=name, position_kind=position_kind)


def read_table(path: Path, *, queries: Any, radius: float | None, name: str | None, position_kind: Any, **_: Any):
    radius = DEFAULT_RADIUS if radius is None else radius
    return load_table_dataset(path, queries=queries, radius=radius, name=name, position_kind=position_kind)


def read_vprbench(path: Path, *, radius: float | None, name: str | None, **_: Any) -> Dataset:
    if radius is not None:
        raise ValueError(f"{path} is a VPR-Bench dataset with explicit ground truth: radius does not apply")
    return load_vprbench_dataset(path, name=name)


def read_folder(path: Path, *, split: str | None, radius: float | None, name: str | None, position_kind: Any, **_: Any):
    radius = DEFAULT_RADIUS if radius is None else radius
    return load_folder_dataset(path, split=split or "test", radius=radius, name=name, position_kind=position_kind)


for _entry in (
    DatasetFormat(
        "poses",
        "positions of database and queries (utmQ, utmDb, posDistThr), as in the published .npz files",
        ".npz (utmQ, utmDb, posDistThr)",
        read_poses,
        suffixes=(".npz",),
        provides=("positions",),
    ),
    DatasetFormat(
        "table",
        "a CSV/TSV table of image paths with positions (and an optional second table of queries)",
        ".csv/.tsv (image paths with positions)",
        read_table,
        suffixes=(".csv", ".tsv", ".txt"),
        provides=("images", "positions"),
    ),
    DatasetFormat(
        "vprbench",
        "a VPR-Bench folder: query/, ref/ and ground_truth_new.npy (explicit positives)",
        "query/, ref/ and ground_truth_new.npy (VPR-Bench)",
        read_vprbench,
        detect=is_vprbench_folder,
        provides=("images", "positives"),
    ),
    DatasetFormat(
        "folder",
        "a VPR-datasets-downloader folder: images/<split>/database/ and queries/, positions in the image names",
        "images/<split>/database/ and queries/ (VPR-datasets-downloader)",
        read_folder,
        detect=_is_downloader_folder,
        provides=("images", "positions"),
    ),
):
    register_format(_entry)

_PATH_COLUMNS = ("path", "image", "image_path", "file", "filename", "name")
_ROLE_COLUMNS = ("role", "set", "split", "type")
_METRIC_COLUMNS = (("x", "y"), ("easting", "northing"), ("utm_east", "utm_north"))
_LAT_COLUMNS = ("lat", "latitude")
_LON_COLUMNS = ("lon", "lng", "long", "longitude")
_DATABASE_ROLES = frozenset({"database", "db", "reference", "ref", "map", "gallery"})
_QUERY_ROLES = frozenset({"query", "queries", "q"})


def _delimiter(path: Path, sample: str, delimiter: str | None) -> str:
    if delimiter is not None:
        return delimiter
    suffix = path.suffix.lower()
    if suffix in (".csv", ".tsv"):
        return "," if suffix == ".csv" else "\t"
    return "\t" if "\t" in (sample.splitlines()[0] if sample else "") else ","


def _column(header: dict[str, int], names: tuple[str, ...]) -> int | None:
    return next((header[name] for name in names if name in header), None)


def read_image_table(
    path: str | Path, *, root: str | Path | None = None, delimiter: str | None = None
) -> tuple[list[Path], np.ndarray, str, list[str] | None]:
    """Read one table of images and positions: (paths, positions (N, 2), "metres" or "latlon", roles or None).

    Errors name the file and line of the first bad row, or the columns that are missing.
    """
    path = Path(path)
    if not is_regular_file(path, "an image table"):
        raise FileNotFoundError(f"image table not found: {path}")
    text = path.read_text(encoding="utf-8-sig")
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=_delimiter(path, text, delimiter))
    rows, line_numbers = [], []
    for row in reader:
        if row and any(cell.strip() for cell in row):
            rows.append(row)
            line_numbers.append(reader.line_num)
    if not rows:
        raise ValueError(f"{path} is empty; expected a header row and one row per image")
    header = {cell.strip().lower(): index for index, cell in enumerate(rows[0])}
    path_column = _column(header, _PATH_COLUMNS)
    if path_column is None:
        raise ValueError(f"{path}: no image path column; expected one of {', '.join(_PATH_COLUMNS)} in the header")
    lat, lon = _column(header, _LAT_COLUMNS), _column(header, _LON_COLUMNS)
    pairs = [((header[x], header[y]), "metres") for x, y in _METRIC_COLUMNS if x in header and y in header]
    pairs += [((lat, lon), "latlon")] if lat is not None and lon is not None else []
    if not pairs:
        raise ValueError(
            f"{path}: no position columns; expected x,y or easting,northing (metres) or lat,lon (degrees), "
            f"found {', '.join(cell.strip() for cell in rows[0])}"
        )
    coordinate_columns, unit = pairs[0]
    role_column = _column(header, _ROLE_COLUMNS)
    base = Path(root) if root is not None else path.parent
    paths: list[Path] = []
    values = np.empty((len(rows) - 1, 2), dtype=np.float64)
    roles: list[str] | None = [] if role_column is not None else None
    width = max(path_column, *coordinate_columns, role_column if role_column is not None else 0) + 1
    for row_index, (line, row) in enumerate(zip(line_numbers[1:], rows[1:], strict=True)):
        where = f"{path}:{line}"
        if len(row) < width:
            raise ValueError(f"{where}: expected at least {width} columns, got {len(row)}: {row}")
        image = row[path_column].strip()
        if not image:
            raise ValueError(f"{where}: empty image path")
        paths.append(base / image)  # an absolute image path stays as it is
        for axis, column in enumerate(coordinate_columns):
            try:
                values[row_index, axis] = float(row[column])
            except ValueError:
                raise ValueError(f"{where}: position {row[column]!r} is not a number") from None
        if roles is not None:
            role = row[role_column].strip().lower()
            if role not in _DATABASE_ROLES and role not in _QUERY_ROLES:
                raise ValueError(f"{where}: role {row[role_column]!r} is neither database nor query")
            roles.append("database" if role in _DATABASE_ROLES else "query")
    if not np.isfinite(values).all():
        line = line_numbers[1 + int(np.argwhere(~np.isfinite(values))[0, 0])]
        raise ValueError(f"{path}:{line}: position is not finite")
    return paths, values, unit, roles


def load_table_dataset(
    path: str | Path,
    *,
    queries: str | Path | None = None,
    radius: float = DEFAULT_RADIUS,
    root: str | Path | None = None,
    name: str | None = None,
    delimiter: str | None = None,
    position_kind: PositionKind | None = None,
) -> Dataset:
    """Read a dataset from a CSV/TSV table: one row per image, its path and its position.

    The header names the columns (case-insensitive): the image path (``path``, ``image``, ``image_path``, ``file``,
    ``filename`` or ``name``; relative to ``root``, by default the table's folder); the position in metres (``x``/``y``,
    ``easting``/``northing``, ``utm_east``/``utm_north``) or in degrees (``lat``/``lon``, projected to UTM in one zone);
    and, unless the queries come in a second table ``queries``, the set (``role``, ``set``, ``split`` or ``type``:
    ``database``/``db``/``reference``/``ref``/``map``/``gallery`` or ``query``/``queries``). Positives lie within
    ``radius`` metres; ``delimiter`` is by default from the suffix.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = (folder / "images.csv").write_text("path,role,x,y\\ndb/a.jpg,database,0,0\\ndb/b.jpg,database,100,0\\n"
    ...                                        "q/a.jpg,query,10,0\\n")
    >>> dataset = load_table_dataset(folder / "images.csv")
    >>> dataset.database_names, dataset.query_names, dataset.positives.toarray()
    (['db/a.jpg', 'db/b.jpg'], ['q/a.jpg'], array([[ True, False]]))
    """
    path = Path(path)
    base = Path(root) if root is not None else path.parent
    paths, positions, unit, roles = read_image_table(path, root=base, delimiter=delimiter)
    if queries is not None:
        query_paths, query_positions, query_unit, _ = read_image_table(queries, root=base, delimiter=delimiter)
        if query_unit != unit:
            raise ValueError(
                f"{path} gives positions as {unit} but {queries} as {query_unit}; use the same kind in both tables"
            )
        database_paths, database_positions = paths, positions
        origin = {"database_table": str(path), "query_table": str(queries)}
    else:
        if roles is None:
            raise ValueError(
                f"{path}: no role column to tell database from query images; add one of "
                f"{', '.join(_ROLE_COLUMNS)} (database/query) or pass the queries as a second table"
            )
        is_query = np.array([role == "query" for role in roles], dtype=bool)
        database_paths = [item for item, query in zip(paths, is_query, strict=True) if not query]
        query_paths = [item for item, query in zip(paths, is_query, strict=True) if query]
        database_positions, query_positions = positions[~is_query], positions[is_query]
        origin = {"table": str(path)}
    for what, items in (("database", database_paths), ("query", query_paths)):
        if not items:
            raise ValueError(f"{path}: no {what} image")
    info: dict[str, object] = {**origin, "unit": unit}
    if unit == "latlon":
        both = np.concatenate([database_positions, query_positions])
        projected, zone, northern = latlon_to_utm(both[:, 0], both[:, 1])
        database_positions, query_positions = projected[: len(database_paths)], projected[len(database_paths) :]
        info.update(utm_zone=zone, utm_northern=northern)
    return Dataset(
        name=name or path.stem,
        root=base,
        positives=positives_within_radius(query_positions, database_positions, radius),
        database_paths=database_paths,
        query_paths=query_paths,
        database_positions=database_positions,
        query_positions=query_positions,
        positive_radius=radius,
        position_kind=position_kind,
        source_format="table",
        info=info,
    )


def load_poses_dataset(
    path: str | Path,
    *,
    radius: float | None = None,
    name: str | None = None,
    position_kind: PositionKind | None = None,
) -> Dataset:
    """Read positions from an ``.npz`` with ``utmQ`` (Q, 2), ``utmDb`` (D, 2) and ``posDistThr`` (Patch-NetVLAD).

    The dataset has positions and positives but no images. ``radius`` defaults to ``posDistThr`` (25 when absent).
    Frame positions (Nordland stores frame i as (i, i) with ``posDistThr = 10``) take as positives the frames at most
    ``radius`` apart (±10, VPR-datasets-downloader's convention); ``position_kind="metres"`` applies it as a Euclidean
    radius instead (Patch-NetVLAD's ±7 frames).
    """
    path = Path(path)
    if not is_regular_file(path, "a position file"):
        raise FileNotFoundError(f"position file not found: {path}")
    with np.load(path, allow_pickle=False) as archive:
        missing = [key for key in ("utmQ", "utmDb") if key not in archive.files]
        if missing:
            raise ValueError(
                f"{path}: expected arrays utmQ (queries × 2) and utmDb (database × 2) and optionally posDistThr, "
                f"missing {', '.join(missing)} (found {', '.join(sorted(archive.files))})"
            )
        query_positions, database_positions = archive["utmQ"], archive["utmDb"]
        threshold = float(archive["posDistThr"]) if "posDistThr" in archive.files else None
    for key, array in (("utmQ", query_positions), ("utmDb", database_positions)):
        if array.ndim != 2 or array.shape[1] != 2:
            raise ValueError(f"{path}: {key} must have shape (n, 2), got {array.shape}")
    if radius is None:
        radius = threshold if threshold is not None else DEFAULT_RADIUS
    if position_kind is None:
        position_kind = detect_position_kind(database_positions, query_positions)
    if position_kind == "frames":
        frames = line_coordinate(np.concatenate([database_positions, query_positions]).astype(np.float64))
        if frames is None:
            raise ValueError(f"{path}: position_kind='frames' needs positions on a line, e.g. frame i at (i, i)")
        n_database = len(database_positions)
        positives = positives_within_frames(frames[n_database:], frames[:n_database], radius)
    else:
        positives = positives_within_radius(query_positions, database_positions, radius)
    return Dataset(
        name=name or path.stem,
        root=path.parent,
        positives=positives,
        database_positions=database_positions,
        query_positions=query_positions,
        positive_radius=radius,
        position_kind=position_kind,
        source_format="poses",
        info={"file": path.name, **({"posDistThr": threshold} if threshold is not None else {})},
    )


def load_vprbench_dataset(root: str | Path, *, name: str | None = None, n_database: int | None = None) -> Dataset:
    """Read a VPR-Bench image dataset: ``query/``, ``ref/`` and ``ground_truth_new.npy`` (explicit positives).

    Images are sorted by name (numbers: :func:`~vpr_uncertainty.data.images.numbered_order`), hidden files left out,
    names relative to ``root``. ``n_database`` defaults to the ground truth's own count (largest positive + 1), which
    ``ref/`` must match: give it only when the last reference images are no query's positive. Raises FileNotFoundError
    for a missing folder or ground truth, ValueError when an image count or name disagrees with the ground truth.
    """
    root = Path(root)
    paths = {}
    for folder in ("query", "ref"):
        if not (root / folder).is_dir():
            raise FileNotFoundError(f"{root} is not a VPR-Bench dataset: no {folder}/ folder (expected query/, ref/)")
        paths[folder] = list_images(root / folder)
        if not paths[folder]:
            raise FileNotFoundError(f"no image found under {root / folder}")
    ground_truth = root / "ground_truth_new.npy"
    if not is_regular_file(ground_truth, "ground truth"):
        raise FileNotFoundError(f"{root} is not a VPR-Bench dataset: no ground_truth_new.npy")
    positives = load_vprbench_ground_truth(ground_truth, n_database=n_database)
    if positives.shape[1] != len(paths["ref"]):
        covered = (
            f"is about {positives.shape[1]} database images (n_database)"
            if n_database is not None
            else f"covers {positives.shape[1]} database images (its largest positive index is {positives.shape[1] - 1})"
        )
        raise ValueError(
            f"{root / 'ref'} holds {len(paths['ref'])} images but the ground truth {ground_truth} {covered}: a stray "
            "or missing image would shift every index after it; remove the extra file (or, when the last reference "
            "images are no query's positive, give n_database)"
        )
    if positives.shape[0] != len(paths["query"]):
        raise ValueError(
            f"{ground_truth} has ground truth for {positives.shape[0]} queries but {root / 'query'} holds "
            f"{len(paths['query'])} images"
        )
    return Dataset(
        name=name or root.name,
        root=root,
        positives=positives,
        database_paths=numbered_order(paths["ref"], root / "ref"),
        query_paths=numbered_order(paths["query"], root / "query"),
        source_format="vprbench",
        info={"ground_truth": ground_truth.name},
    )
