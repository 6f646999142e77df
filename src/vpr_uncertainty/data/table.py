"""Datasets described by a table (CSV or TSV): one row per image, its path and its position.

A header row names the columns (case-insensitive):

* the image path: ``path``, ``image``, ``image_path``, ``file``, ``filename`` or ``name``; relative paths are
  relative to the table's folder (or to ``root``);
* the position, either in metres: ``x``/``y``, ``easting``/``northing`` or ``utm_east``/``utm_north``, or in
  WGS84 degrees: ``lat``/``lon`` (also ``latitude``, ``longitude``, ``lng``), projected to UTM metres in one
  common zone (:func:`~vpr_uncertainty.data.geo.latlon_to_utm`);
* which set the image belongs to, unless the queries come in a second table: ``role``, ``set``, ``split`` or
  ``type``, with ``database``/``db``/``reference``/``ref``/``map``/``gallery`` or ``query``/``queries``.

Example::

    path,role,lat,lon
    db/0001.jpg,database,40.44061,-79.99590
    q/0001.jpg,query,40.44063,-79.99588
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from vpr_uncertainty.data.dataset import Dataset, PositionKind
from vpr_uncertainty.data.geo import latlon_to_utm
from vpr_uncertainty.data.positives import DEFAULT_RADIUS, positives_within_radius

__all__ = ["load_table_dataset", "read_image_table"]

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
    if path.suffix.lower() == ".tsv":
        return "\t"
    if path.suffix.lower() == ".csv":
        return ","
    first = sample.splitlines()[0] if sample else ""
    return "\t" if "\t" in first else ","


def _column(header: dict[str, int], names: tuple[str, ...]) -> int | None:
    for name in names:
        if name in header:
            return header[name]
    return None


def read_image_table(
    path: str | Path, *, root: str | Path | None = None, delimiter: str | None = None
) -> tuple[list[Path], np.ndarray, str, list[str] | None]:
    """Read one table of images and positions.

    Parameters
    ----------
    path : str or Path
        The ``.csv`` / ``.tsv`` (or ``.txt``, delimiter guessed from the header) file.
    root : str or Path, optional
        Folder relative image paths are relative to; by default the folder of the table.
    delimiter : str, optional
        Column separator; by default tab for ``.tsv``, comma for ``.csv``.

    Returns
    -------
    paths : list of Path, length N
        Image paths as written, joined to ``root`` when relative.
    positions : ndarray of shape (N, 2), float64
        Metres (as written, or projected from latitude/longitude).
    unit : {"metres", "latlon"}
        What the table held.
    roles : list of {"database", "query"}, or None
        The set of each image, when the table has a role column.

    Raises
    ------
    ValueError
        Naming the file and line of the first bad row, or the columns that are missing.
    """
    path = Path(path)
    if not path.is_file():
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
    coordinate_columns: tuple[int, int] | None = None
    unit = "metres"
    for x_name, y_name in _METRIC_COLUMNS:
        if x_name in header and y_name in header:
            coordinate_columns = (header[x_name], header[y_name])
            break
    if coordinate_columns is None:
        lat, lon = _column(header, _LAT_COLUMNS), _column(header, _LON_COLUMNS)
        if lat is not None and lon is not None:
            coordinate_columns, unit = (lat, lon), "latlon"
    if coordinate_columns is None:
        raise ValueError(
            f"{path}: no position columns; expected x,y or easting,northing (metres) or lat,lon (degrees), "
            f"found {', '.join(cell.strip() for cell in rows[0])}"
        )
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
        image_path = Path(image)
        paths.append(image_path if image_path.is_absolute() else base / image_path)
        for axis, column in enumerate(coordinate_columns):
            try:
                values[row_index, axis] = float(row[column])
            except ValueError:
                raise ValueError(f"{where}: position {row[column]!r} is not a number") from None
        if roles is not None:
            role = row[role_column].strip().lower()
            if role in _DATABASE_ROLES:
                roles.append("database")
            elif role in _QUERY_ROLES:
                roles.append("query")
            else:
                raise ValueError(f"{where}: role {row[role_column]!r} is neither database nor query")
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
    """Read a dataset from a CSV/TSV of image paths and positions (see the module docstring for the columns).

    Parameters
    ----------
    path : str or Path
        The table of all images with a role column, or of the database images when ``queries`` is given.
    queries : str or Path, optional
        A second table with the query images.
    radius : float, default 25.0
        Positive radius in metres (inclusive).
    root : str or Path, optional
        Folder that relative image paths and the image names are relative to; by default the table's folder.
    name : str, optional
        Dataset name; by default the table's file name without suffix.
    delimiter : str, optional
        Column separator; by default from the suffix.
    position_kind : {"metres", "frames", "placeholder"}, optional
        What the positions are; detected by default.

    Returns
    -------
    Dataset
        In table order (database rows, then query rows, each in the order they appear).

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
