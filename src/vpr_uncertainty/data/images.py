"""Image files: listing a folder without dropping one silently, and VPR-datasets-downloader's folder format."""

from __future__ import annotations

import errno
import os
import re
import warnings
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_uncertainty._files import special_file_error
from vpr_uncertainty.data.dataset import Dataset, latlon_to_utm
from vpr_uncertainty.retrieval.ground_truth import DEFAULT_RADIUS, PositionKind, positives_within_radius
from vpr_uncertainty.retrieval.result import Retrieval

#: File extensions read as images (case-insensitive).
IMAGE_EXTENSIONS: frozenset[str] = frozenset(
    {".jpg", ".jpeg", ".png", ".ppm", ".pgm", ".bmp", ".tif", ".tiff", ".webp"}
)


def is_hidden(name: str) -> bool:
    """Whether a file or folder name is hidden (starts with ``.``); hidden entries are never listed as images.

    Examples
    --------
    >>> is_hidden(".hidden.jpg"), is_hidden("0000000.jpg")
    (True, False)
    """
    return name.startswith(".")


class ImageListingError(ValueError):
    """A folder of images could not be listed completely; ``problems`` holds ``{"path": ..., "error": ...}`` of each."""

    def __init__(self, folder: str | Path, problems: list[dict[str, str]]) -> None:
        self.problems = list(problems)
        super().__init__(f"cannot list every image under {printable(folder)}: {describe_unlisted(problems)}")


def printable(text: str | Path) -> str:
    r"""``text`` with the bytes of a file name that is not valid UTF-8 written as ``\xNN`` escapes.

    Examples
    --------
    >>> printable("caf\udce9.jpg")  # the file name b"caf\xe9.jpg" (Latin-1), as Python reads it on Linux
    'caf\\xe9.jpg'
    """
    return os.fsencode(str(text)).decode("utf-8", "backslashreplace")


def _few(items: list[str], shown: int = 3, separator: str = ", ") -> str:
    more = f"{separator}and {len(items) - shown} more" if len(items) > shown else ""
    return separator.join(items[:shown]) + more


def describe_unlisted(problems: list[dict[str, str]], *, shown: int = 3) -> str:
    """The first ``shown`` listing problems, ``path (error)``, separated by semicolons."""
    return _few([f"{printable(item['path'])} ({item['error']})" for item in problems], shown, "; ")


def _link_error(path: Path) -> str:
    try:
        os.stat(path)
    except OSError as error:
        kind = "loops back on itself" if error.errno == errno.ELOOP else "whose target does not exist"
        return f"symbolic link to '{printable(os.readlink(path))}' {kind}; if it was a folder, its images are missing"
    return "cannot be read"


def scan_images(folder: str | Path) -> tuple[list[Path], list[dict[str, str]]]:
    """Image files under ``folder`` (recursively, following links to folders) and what could not be listed.

    Hidden entries (``.*``) are neither listed nor entered, as :func:`glob.glob` skips them (a stray ``._0001.jpg``
    would shift every index of a ground truth given by index). A file with an image suffix is listed even as a broken
    link (extraction reports it; the other indices stay right); links back to a folder being listed are not followed.
    A FIFO, device or socket with an image suffix (or a link to one) is refused before anything reads it: a
    ValueError names the first and how many (reading one could block for ever; leaving it out would shift indices).

    Returns
    -------
    paths : list of Path
        Files with a suffix of :data:`IMAGE_EXTENSIONS` (case-insensitive), sorted by POSIX path relative to
        ``folder``; names that are not valid UTF-8 are kept as Python decodes them.
    problems : list of dict
        ``{"path": ..., "error": ...}`` for each sub-folder that cannot be read and each broken link without an
        image suffix; images under them may be missing.
    """
    folder = Path(folder)
    images: list[Path] = []
    special: list[Path] = []
    problems: list[dict[str, str]] = []

    def visit(directory: Path, ancestors: frozenset[str]) -> None:
        try:
            with os.scandir(directory) as iterator:
                entries = list(iterator)
        except OSError as error:
            problems.append({"path": str(directory), "error": f"cannot read the folder: {error.strerror or error}"})
            return
        for entry in entries:
            if is_hidden(entry.name):
                continue
            path = Path(entry.path)
            try:
                is_dir = entry.is_dir()
                is_file = not is_dir and entry.is_file()
            except OSError:
                is_dir = is_file = False
            if is_dir:
                real = os.path.realpath(path)
                if real not in ancestors:  # a link back to a folder being listed adds no image
                    visit(path, ancestors | {real})
            elif path.suffix.lower() in IMAGE_EXTENSIONS:
                if not is_file and os.path.exists(path):  # neither a file nor a folder (nor a broken link)
                    special.append(path)
                elif is_file or entry.is_symlink():
                    images.append(path)
            elif entry.is_symlink() and not os.path.exists(path):
                problems.append({"path": str(path), "error": _link_error(path)})

    visit(folder, frozenset({os.path.realpath(folder)}))
    if special:
        first = min(special)
        error = special_file_error(first, os.stat(first).st_mode, "an image")
        raise ValueError(f"{error} ({len(special)} such file(s) under {printable(folder)}: remove or replace them)")
    return sorted(images, key=lambda path: path.relative_to(folder).as_posix()), problems


def list_images(folder: str | Path, *, problems: list[dict[str, str]] | None = None) -> list[Path]:
    """Image files under ``folder`` (recursively; see :func:`scan_images`), sorted by POSIX path relative to it.

    A listing problem raises :class:`ImageListingError` (a silently incomplete list would shift indices), unless a
    ``problems`` list is given to receive them.
    """
    paths, found = scan_images(folder)
    if found and problems is None:
        raise ImageListingError(folder, found)
    if problems is not None:
        problems.extend(found)
    return paths


def numbered_order(paths: list[Path], folder: str | Path) -> list[Path]:
    """``paths`` ordered by the number each name is (VPR-Bench: ``0000050.jpg`` is image 50 of its ground truth).

    Unchanged when no name is a number. Otherwise the numbers must be 0..N-1, once each: an image deleted and
    another added (``0000050.jpg`` gone, ``0000200.jpg`` new) would shift every index after it against the ground
    truth, so a ValueError names the files that do not fit and the numbers missing.

    Examples
    --------
    >>> numbered_order([Path("0.jpg"), Path("7.jpg")], "ref")
    Traceback (most recent call last):
    ...
    ValueError: ref: image names are their indices 0..1 in the ground truth; not fitting: 7.jpg; missing: 1; rename \
or remove the files that do not fit
    """
    numbers = [int(path.stem) if re.fullmatch("[0-9]+", path.stem) else -1 for path in paths]
    if max(numbers, default=-1) < 0:
        return paths
    count = Counter(numbers)
    misfits = [p.name for p, n in zip(paths, numbers, strict=True) if not 0 <= n < len(paths) or count[n] > 1]
    if misfits:
        missing = [str(number) for number in range(len(paths)) if number not in count]
        raise ValueError(
            f"{printable(folder)}: image names are their indices 0..{len(paths) - 1} in the ground truth; not "
            f"fitting: {_few(misfits)}; missing: {_few(missing)}; rename or remove the files that do not fit"
        )
    return [path for _, path in sorted(zip(numbers, paths, strict=True))]


#: Accepted names of the database and query folders, in order of preference.
DATABASE_FOLDERS: tuple[str, ...] = ("database", "gallery")
QUERY_FOLDERS: tuple[str, ...] = ("queries", "query")


_NAME_FORMAT = "@UTM_east@UTM_north@UTM_zone@UTM_letter@latitude@longitude@...@.jpg"
_ZONE_LETTERS = frozenset("CDEFGHJKLMNPQRSTUVWX")


class MalformedImageNameError(ValueError):
    """An image name does not follow the ``@UTM_east@UTM_north@...`` convention."""


@dataclass(frozen=True)
class ImageName:
    """The fields of an image name ``@UTM_east@UTM_north@UTM_zone@UTM_letter@latitude@longitude@...@.jpg``.

    ``utm_east`` and ``utm_north`` are metres (dummy values for some datasets); zone (1-60), letter, latitude and
    longitude (WGS84 degrees) are None when empty; ``fields`` holds every ``@``-separated field.
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
    """Read the position fields of an image name (only the file name is parsed; the path goes in error messages).

    Raises :class:`MalformedImageNameError` (a ValueError) naming the file and what is wrong with it.

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
    zone = letter = latitude = longitude = None  # the optional fields, when given
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
    return next((folder / candidate for candidate in candidates if (folder / candidate).is_dir()), None)


def has_split(folder: Path) -> bool:
    """Whether ``folder`` holds a database and a queries folder (VPR-datasets-downloader split layout)."""
    return bool(_pick(folder, DATABASE_FOLDERS) and _pick(folder, QUERY_FOLDERS))


def find_split_folder(root: str | Path, split: str = "test") -> Path:
    """The folder holding ``database/`` and ``queries/``: ``root``, ``root/split`` or ``root/images/split``.

    Raises FileNotFoundError listing the folders looked in.
    """
    root = Path(root)
    candidates = [root, root / split, root / "images" / split]
    for candidate in candidates:
        if has_split(candidate):
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
    """Read a dataset in VPR-datasets-downloader's folder format: ``<dataset>/images/<split>/{database,queries}/``.

    Images are listed recursively and sorted by path (the order of the other tools that read this format); their
    names carry the position (``@UTM_east@UTM_north@...@.jpg``); names with several UTM zones are re-projected from
    latitude/longitude into one. A sub-folder that cannot be read is kept in :attr:`Dataset.unlisted` (the extraction
    stage reports or refuses it).

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
        What the coordinates in the names are; detected by default.

    Returns
    -------
    Dataset
        Names relative to the split folder (``database/...``, ``queries/...``).

    Raises
    ------
    FileNotFoundError
        When no split folder is found, or a folder has no image.
    MalformedImageNameError
        Naming the first file whose name does not carry a position.
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


#: (queries folder, database folder) pairs a dataset folder may have: VPR-Bench, then the downloader's layout.
IMAGE_SPLIT_FOLDERS: tuple[tuple[str, str], ...] = (("query", "ref"), ("queries", "database"))


def find_split_folders(folder: str | Path) -> tuple[Path, Path]:
    """The (queries, database) image folders of a dataset: ``query/``, ``ref/`` or ``queries/``, ``database/``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"image folder not found: {folder} (argument images)")
    for queries, database in IMAGE_SPLIT_FOLDERS:
        if (folder / queries).is_dir() and (folder / database).is_dir():
            return folder / queries, folder / database
    expected = " or ".join(f"{q}/ and {d}/" for q, d in IMAGE_SPLIT_FOLDERS)
    raise FileNotFoundError(f"{folder} has no image subfolders {expected} (argument images)")


def check_image_counts(
    retrieval: Retrieval,
    n_query_images: int,
    n_database_images: int,
    *,
    queries: str,
    database: str,
    arguments: tuple[str, str] | None = None,
) -> None:
    """Refuse image lists that cannot be the retrieval's images: query i and database image j must be images i and j.

    One image too many or too few would make a method that looks at images (``GV-*``) verify a query against the
    wrong picture. ``queries`` and ``database`` name what holds the images, ``arguments`` the arguments that named
    them, for the message.

    Examples
    --------
    >>> import numpy as np
    >>> from vpr_uncertainty.retrieval import Retrieval
    >>> retrieval = Retrieval(np.array([[0.9]]), np.array([[1]]), positives=[[1]])
    >>> check_image_counts(retrieval, 1, 3, queries="q/", database="db/")
    Traceback (most recent call last):
    ...
    ValueError: db/ holds 3 images but the results have 2 database images
    """
    query_note, database_note = (f" (argument {argument})" for argument in arguments) if arguments else ("", "")
    if n_query_images != retrieval.n_queries:
        raise ValueError(
            f"{queries} holds {n_query_images} images but the results have {retrieval.n_queries} queries{query_note}"
        )
    n_database = retrieval.n_database
    largest = int(retrieval.indices.max()) if retrieval.indices.size else -1
    if (n_database is not None and n_database_images != n_database) or largest >= n_database_images:
        expected = n_database if n_database is not None else f"at least {largest + 1}"
        raise ValueError(
            f"{database} holds {n_database_images} images but the results have {expected} database "
            f"images{database_note}"
        )


def _listed(folder: Path, argument: str, numbered: bool) -> list[Path]:
    paths = list_images(folder)
    if not paths:
        raise FileNotFoundError(f"no images in {folder} (argument {argument})")
    return numbered_order(paths, folder) if numbered else paths


def _by_names(root: Path, names: object) -> list[Path] | None:
    """``root / name`` for every name when all of them exist, else None."""
    if names is None:
        return None
    paths = [root / str(name) for name in names]  # type: ignore[union-attr]
    return paths if paths and all(path.is_file() for path in paths) else None


def retrieval_image_paths(
    retrieval: Retrieval,
    *,
    images: str | Path | None = None,
    query_images: str | Path | None = None,
    database_images: str | Path | None = None,
) -> tuple[list[Path], list[Path]]:
    """Query and database image files indexed like ``retrieval`` (query i, database index j).

    Give a dataset folder ``images`` (``query/`` and ``ref/``, or ``queries/`` and ``database/``, each listed
    recursively and sorted by path) or both ``query_images`` and ``database_images``. Names the retrieval holds are
    looked up first, so an order that differs from the sorted one cannot go unnoticed; listed ``query/`` and ``ref/``
    images (VPR-Bench) are in :func:`numbered_order`. Raises ValueError when the image counts differ from the
    retrieval's (naming both), FileNotFoundError when a folder is missing or empty.
    """
    if images is not None and (query_images is not None or database_images is not None):
        raise ValueError(
            "give the dataset folder (argument images) or the two image folders (arguments query_images and "
            "database_images), not both"
        )
    if images is None and (query_images is None) != (database_images is None):
        raise ValueError("the query and database image folders go together (arguments query_images, database_images)")
    if images is None and query_images is None:
        raise ValueError("no image folder given (argument images)")
    if images is not None:
        query_folder, database_folder = find_split_folders(images)
        query_root = database_root = Path(images)
        query_argument = database_argument = "images"
    else:
        query_folder = query_root = Path(query_images)  # type: ignore[arg-type]
        database_folder = database_root = Path(database_images)  # type: ignore[arg-type]
        query_argument, database_argument = "query_images", "database_images"
    query_paths = _by_names(query_root, retrieval.query_names)
    database_paths = _by_names(database_root, retrieval.database_names)
    for folder, argument in ((query_folder, query_argument), (database_folder, database_argument)):
        if not folder.is_dir():
            raise FileNotFoundError(f"image folder not found: {folder} (argument {argument})")
    numbered = images is not None and query_folder.name == IMAGE_SPLIT_FOLDERS[0][0]  # VPR-Bench: names are indices
    query_paths = query_paths or _listed(query_folder, query_argument, numbered)
    database_paths = database_paths or _listed(database_folder, database_argument, numbered)
    check_image_counts(
        retrieval,
        len(query_paths),
        len(database_paths),
        queries=str(query_folder),
        database=str(database_folder),
        arguments=(query_argument, database_argument),
    )
    return query_paths, database_paths
