"""The image files behind a retrieval's indices, for the methods that look at images (``GV-*``).

A retrieval read from precomputed results knows its queries and database images by index (and sometimes by
name). :func:`retrieval_image_paths` maps them to files:

* a dataset folder with ``query/`` and ``ref/`` (VPR-Bench) or ``queries/`` and ``database/`` (VPR-datasets-
  downloader, VPR-methods-evaluation) subfolders: query ``i`` is the i-th image of the queries folder and database
  image ``j`` the j-th of the database folder, each listed recursively and sorted by path (the order of both
  tools);
* or the two folders given separately.

When the retrieval holds image names (a retrieval file written by ``retrieve`` or ``run``), names are looked up
under the dataset folder first, so an order that differs from the sorted one cannot go unnoticed.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from vpr_uncertainty.retrieval import Retrieval

__all__ = ["IMAGE_SPLIT_FOLDERS", "check_image_counts", "find_split_folders", "retrieval_image_paths"]

#: (queries folder, database folder) pairs a dataset folder may have: VPR-Bench, then the downloader's layout.
IMAGE_SPLIT_FOLDERS: tuple[tuple[str, str], ...] = (("query", "ref"), ("queries", "database"))


def find_split_folders(folder: str | Path, *, argument: str = "images") -> tuple[Path, Path]:
    """The (queries, database) image folders of a dataset folder.

    Raises
    ------
    FileNotFoundError
        When ``folder`` is missing or has none of the layouts of :data:`IMAGE_SPLIT_FOLDERS` (the message names
        ``argument``).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"image folder not found: {folder} (argument {argument})")
    for queries, database in IMAGE_SPLIT_FOLDERS:
        if (folder / queries).is_dir() and (folder / database).is_dir():
            return folder / queries, folder / database
    expected = " or ".join(f"{q}/ and {d}/" for q, d in IMAGE_SPLIT_FOLDERS)
    raise FileNotFoundError(f"{folder} has no image subfolders {expected} (argument {argument})")


def check_image_counts(
    retrieval: Retrieval,
    n_query_images: int,
    n_database_images: int,
    *,
    queries: str,
    database: str,
    arguments: tuple[str, str] | None = None,
) -> None:
    """Refuse image lists that cannot be the retrieval's images: query i and database image j must be images i, j.

    One image too many or too few would make a method that looks at images (``GV-*``) verify a query against
    the wrong picture, silently. ``evaluate --images``, ``reproduce`` (a config's ``images``) and the ``GV-*``
    methods all check their images here.

    Parameters
    ----------
    retrieval : Retrieval
    n_query_images, n_database_images : int
        How many query and database images were found.
    queries, database : str
        What holds them, for the message (e.g. the folder ``"corridor/ref"``).
    arguments : (str, str), optional
        The arguments that named the query and the database images, for the message (``("images", "images")``).

    Raises
    ------
    ValueError
        When there are not exactly ``retrieval.n_queries`` query images, or not exactly ``retrieval.n_database``
        database images (at least the largest candidate index + 1 when the retrieval does not know its database
        size); the message gives both counts.

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


def _listed(folder: Path, argument: str) -> list[Path]:
    from vpr_uncertainty.data.listing import list_images

    paths = list_images(folder)
    if not paths:
        raise FileNotFoundError(f"no images in {folder} (argument {argument})")
    return paths


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

    Parameters
    ----------
    retrieval : Retrieval
    images : str or Path, optional
        A dataset folder with ``query/`` and ``ref/`` or ``queries/`` and ``database/`` subfolders.
    query_images, database_images : str or Path, optional
        The two image folders, instead of ``images`` (both together).

    Returns
    -------
    query_paths, database_paths : list of Path

    Raises
    ------
    ValueError
        When both ways are given, only one of the two folders, or when the number of images does not match the
        retrieval (the message gives both counts).
    FileNotFoundError
        When a folder is missing or holds no images.
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
        root = Path(images)
        query_folder, database_folder = find_split_folders(root)
        query_paths = _by_names(root, retrieval.query_names)
        database_paths = _by_names(root, retrieval.database_names)
        query_argument = database_argument = "images"
    else:
        query_folder, database_folder = Path(query_images), Path(database_images)  # type: ignore[arg-type]
        query_paths = _by_names(query_folder, retrieval.query_names)
        database_paths = _by_names(database_folder, retrieval.database_names)
        query_argument, database_argument = "query_images", "database_images"
    for folder, argument in ((query_folder, query_argument), (database_folder, database_argument)):
        if not folder.is_dir():
            raise FileNotFoundError(f"image folder not found: {folder} (argument {argument})")
    if query_paths is None:
        query_paths = _listed(query_folder, query_argument)
    if database_paths is None:
        database_paths = _listed(database_folder, database_argument)
    check_image_counts(
        retrieval,
        len(query_paths),
        len(database_paths),
        queries=str(query_folder),
        database=str(database_folder),
        arguments=(query_argument, database_argument),
    )
    return query_paths, database_paths
