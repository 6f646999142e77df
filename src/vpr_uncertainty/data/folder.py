"""The folder format of VPR-datasets-downloader (gmberton), used by most deep VPR benchmarks.

Layout::

    <dataset>/images/<split>/database/...  (``gallery/`` in older Tokyo 24/7 exports)
    <dataset>/images/<split>/queries/...

with image names that carry the position::

    @UTM_east@UTM_north@UTM_zone@UTM_letter@latitude@longitude@pano_id@tile_num@heading@pitch@roll@height@timestamp@note@.jpg

Only the UTM easting and northing are required (AmsterTime and Nordland leave the zone, letter, latitude and
longitude empty and use dummy coordinates: see :mod:`vpr_uncertainty.data.dataset`). Images are listed
recursively and sorted by their path relative to the split folder, so indices match the other tools that read
this format. Positives are the database images within 25 m of the query (configurable).

Images are listed by :mod:`vpr_uncertainty.data.listing`, which never drops one silently; a sub-folder that
cannot be read is kept in :attr:`Dataset.unlisted <vpr_uncertainty.data.dataset.Dataset.unlisted>` for the
extraction stage to report or refuse.
"""

from __future__ import annotations

import warnings
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_uncertainty.data.dataset import Dataset, PositionKind
from vpr_uncertainty.data.geo import latlon_to_utm
from vpr_uncertainty.data.listing import (
    IMAGE_EXTENSIONS,
    ImageListingError,
    describe_unlisted,
    list_images,
    scan_images,
)
from vpr_uncertainty.data.positives import DEFAULT_RADIUS, positives_within_radius

__all__ = [
    "DATABASE_FOLDERS",
    "IMAGE_EXTENSIONS",
    "QUERY_FOLDERS",
    "ImageListingError",
    "ImageName",
    "MalformedImageNameError",
    "describe_unlisted",
    "find_split_folder",
    "list_images",
    "load_folder_dataset",
    "parse_image_name",
    "scan_images",
]

#: Accepted names of the database and query folders, in order of preference.
DATABASE_FOLDERS: tuple[str, ...] = ("database", "gallery")
QUERY_FOLDERS: tuple[str, ...] = ("queries", "query")

_NAME_FORMAT = "@UTM_east@UTM_north@UTM_zone@UTM_letter@latitude@longitude@...@.jpg"
_ZONE_LETTERS = frozenset("CDEFGHJKLMNPQRSTUVWX")


class MalformedImageNameError(ValueError):
    """An image name does not follow the ``@UTM_east@UTM_north@...`` convention."""


@dataclass(frozen=True)
class ImageName:
    """The fields of an image name in the VPR-datasets-downloader convention.

    Attributes
    ----------
    utm_east, utm_north : float
        UTM easting and northing in metres (dummy values for some datasets).
    utm_zone : int or None
        UTM zone number 1-60, when given.
    utm_letter : str or None
        UTM latitude band letter, when given.
    latitude, longitude : float or None
        WGS84 degrees, when given.
    fields : tuple of str
        All ``@``-separated fields after the leading ``@`` (pano_id, tile_num, heading, ... follow the six
        above; their meaning depends on the dataset).
    """

    utm_east: float
    utm_north: float
    utm_zone: int | None
    utm_letter: str | None
    latitude: float | None
    longitude: float | None
    fields: tuple[str, ...]


def _malformed(path: str | Path, problem: str) -> MalformedImageNameError:
    return MalformedImageNameError(f"malformed image name {str(path)!r}: {problem}; expected {_NAME_FORMAT}")


def _number(text: str, what: str, path: str | Path) -> float:
    try:
        value = float(text)
    except ValueError:
        raise _malformed(path, f"{what} is {text!r}, not a number") from None
    if not np.isfinite(value):
        raise _malformed(path, f"{what} is {text!r}, not a finite number")
    return value


def parse_image_name(path: str | Path) -> ImageName:
    """Read the position fields of an image name ``@UTM_east@UTM_north@UTM_zone@UTM_letter@lat@lon@...@.jpg``.

    Parameters
    ----------
    path : str or Path
        The image path or file name; only the file name is parsed, the path is used in error messages.

    Returns
    -------
    ImageName

    Raises
    ------
    MalformedImageNameError
        (a ValueError) naming the file and what is wrong with it.

    Examples
    --------
    >>> name = parse_image_name("@0584745.00@4476710.00@17@T@040.43672@-080.00082@ZHLjT7Ab@00@@@@@@@.jpg")
    >>> name.utm_east, name.utm_north, name.utm_zone, name.utm_letter, name.latitude
    (584745.0, 4476710.0, 17, 'T', 40.43672)
    >>> parse_image_name("@0@200@@@@@2@@@@@@@@.jpg").utm_zone is None   # AmsterTime: dummy positions
    True
    """
    file_name = Path(path).name
    if not file_name.startswith("@"):
        raise _malformed(path, "the name does not start with '@'")
    fields = tuple(file_name.split("@")[1:])
    if len(fields) < 3:
        raise _malformed(path, f"found {len(fields)} '@'-separated field(s), need at least UTM east and north")
    east = _number(fields[0], "UTM_east", path)
    north = _number(fields[1], "UTM_north", path)
    zone: int | None = None
    letter: str | None = None
    latitude: float | None = None
    longitude: float | None = None
    if len(fields) > 3 and fields[2]:
        try:
            zone = int(fields[2])
        except ValueError:
            raise _malformed(path, f"UTM_zone is {fields[2]!r}, not an integer") from None
        if not 1 <= zone <= 60:
            raise _malformed(path, f"UTM_zone is {zone}, not in 1..60")
    if len(fields) > 4 and fields[3]:
        letter = fields[3].upper()
        if letter not in _ZONE_LETTERS:
            raise _malformed(path, f"UTM_letter is {fields[3]!r}, not a UTM latitude band (C..X)")
    if len(fields) > 6 and (fields[4] or fields[5]):
        latitude = _number(fields[4], "latitude", path)
        longitude = _number(fields[5], "longitude", path)
        if not (-90 <= latitude <= 90 and -180 <= longitude <= 180):
            raise _malformed(path, f"latitude/longitude ({latitude}, {longitude}) out of range")
    return ImageName(east, north, zone, letter, latitude, longitude, fields)


def _pick(folder: Path, candidates: tuple[str, ...]) -> Path | None:
    for candidate in candidates:
        if (folder / candidate).is_dir():
            return folder / candidate
    return None


def find_split_folder(root: str | Path, split: str = "test") -> Path:
    """The folder holding ``database/`` and ``queries/``, from a dataset folder, its ``images/`` or the split.

    Parameters
    ----------
    root : str or Path
        ``<dataset>``, ``<dataset>/images`` or ``<dataset>/images/<split>``.
    split : str
        Split to use when ``root`` is not the split folder itself.

    Raises
    ------
    FileNotFoundError
        Listing the folders that were looked for.
    """
    root = Path(root)
    candidates = [root, root / split, root / "images" / split]
    for candidate in candidates:
        if _pick(candidate, DATABASE_FOLDERS) and _pick(candidate, QUERY_FOLDERS):
            return candidate
    looked = ", ".join(str(candidate) for candidate in candidates)
    splits = sorted(path.name for path in (root / "images").glob("*") if path.is_dir()) if root.is_dir() else []
    hint = f" (splits found under {root / 'images'}: {', '.join(splits)})" if splits else ""
    raise FileNotFoundError(
        f"no VPR-datasets-downloader split folder with database/ and queries/ found: looked in {looked}{hint}"
    )


def _positions(names: list[ImageName], paths: list[Path]) -> tuple[np.ndarray, dict[str, object]]:
    """Positions (N, 2) in one metric frame; re-projects from latitude/longitude when zones differ."""
    positions = np.array([(name.utm_east, name.utm_north) for name in names], dtype=np.float64).reshape(-1, 2)
    zones = Counter((name.utm_zone, name.utm_letter) for name in names if name.utm_zone is not None)
    info: dict[str, object] = {}
    if len(zones) == 1:
        (zone, letter), _ = zones.most_common(1)[0]
        info = {"utm_zone": zone, "utm_letter": letter}
    elif len(zones) > 1:
        missing = [path for path, name in zip(paths, names, strict=True) if name.latitude is None]
        listed = ", ".join(f"{zone}{letter or ''}" for zone, letter in sorted(zones, key=str))
        if missing:
            raise ValueError(
                f"images lie in several UTM zones ({listed}), so their UTM coordinates cannot be compared, and "
                f"{missing[0]} has no latitude/longitude to re-project it"
            )
        latitude = np.array([name.latitude for name in names])
        longitude = np.array([name.longitude for name in names])
        positions, zone, northern = latlon_to_utm(latitude, longitude)
        warnings.warn(
            f"images lie in several UTM zones ({listed}); re-projected all of them from latitude/longitude "
            f"into zone {zone}{'N' if northern else 'S'}",
            stacklevel=3,
        )
        info = {"utm_zone": zone, "utm_northern": northern, "reprojected": True}
    return positions, info


def load_folder_dataset(
    root: str | Path,
    *,
    split: str = "test",
    radius: float = DEFAULT_RADIUS,
    name: str | None = None,
    position_kind: PositionKind | None = None,
) -> Dataset:
    """Read a dataset in the VPR-datasets-downloader folder format.

    Parameters
    ----------
    root : str or Path
        ``<dataset>``, ``<dataset>/images`` or ``<dataset>/images/<split>``.
    split : str, default "test"
        Split to read when ``root`` is not the split folder itself.
    radius : float, default 25.0
        Positive radius in metres (inclusive).
    name : str, optional
        Dataset name; by default the folder name above ``images/``.
    position_kind : {"metres", "frames", "placeholder"}, optional
        What the coordinates in the names are; detected by default
        (:func:`~vpr_uncertainty.data.dataset.detect_position_kind`).

    Returns
    -------
    Dataset
        Names relative to the split folder (``database/...``, ``queries/...``), positions (D, 2) and (Q, 2) as in
        the file names, positives within ``radius``.

    Raises
    ------
    FileNotFoundError
        When no split folder is found, or a folder has no image.
    MalformedImageNameError
        Naming the first file whose name does not carry a position.

    Notes
    -----
    A sub-folder that cannot be read does not stop the reading (positions come from the names, so the other
    images keep their meaning); it is recorded in :attr:`Dataset.unlisted`, which the extraction stage reports
    (``on_error="skip"``) or refuses (``on_error="fail"``).
    """
    split_folder = find_split_folder(root, split)
    database_folder = _pick(split_folder, DATABASE_FOLDERS)
    query_folder = _pick(split_folder, QUERY_FOLDERS)
    assert database_folder is not None and query_folder is not None
    unlisted: list[dict[str, str]] = []
    database_paths = list_images(database_folder, problems=unlisted)
    query_paths = list_images(query_folder, problems=unlisted)
    for folder, paths in ((database_folder, database_paths), (query_folder, query_paths)):
        if not paths:
            if unlisted:
                raise ImageListingError(folder, unlisted)
            raise FileNotFoundError(f"no image ({', '.join(sorted(IMAGE_EXTENSIONS))}) found under {folder}")
    parsed = [parse_image_name(path) for path in database_paths + query_paths]
    positions, info = _positions(parsed, database_paths + query_paths)
    database_positions, query_positions = positions[: len(database_paths)], positions[len(database_paths) :]
    if name is None:
        name = split_folder.parent.parent.name if split_folder.parent.name == "images" else split_folder.name
    return Dataset(
        name=name,
        root=split_folder,
        positives=positives_within_radius(query_positions, database_positions, radius),
        database_paths=database_paths,
        query_paths=query_paths,
        database_positions=database_positions,
        query_positions=query_positions,
        positive_radius=radius,
        position_kind=position_kind,
        split=split_folder.name if split_folder.parent.name == "images" else None,
        source_format="folder",
        info=info,
        unlisted=unlisted,
    )
