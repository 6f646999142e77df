"""Ground truth: which database images are correct answers (positives) for each query.

Inside the toolkit the positives are one sparse boolean matrix of shape (n_queries, n_database), a
``scipy.sparse.csr_array``: row q holds True at the database indices that show the place of query q. It is
built from any of the formats users have:

* a boolean (Q × D) ``.npy`` mask (0/1 numbers are accepted as booleans, nothing else);
* per-query lists of database indices (Python lists, a ``.json`` list of lists, or a text file with one line of
  whitespace- or comma-separated indices per query, an empty line for a query with no positive);
* a ``.npz`` with ``positives_indptr`` and ``positives_indices`` (the layout of retrieval files);
* VPR-Bench's ``ground_truth_new.npy`` (legacy object array, read without running any code from the file: see
  :func:`vpr_uncertainty.data.vprbench.load_vprbench_ground_truth`).

Every database index must be an integer (not a float, not a boolean) in [0, n_database); a mask must have
exactly one column per database image. Anything else is an error that names the file, the query and the value.
"""

from __future__ import annotations

import json
import re
import zipfile
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
from scipy import sparse

__all__ = [
    "load_ground_truth",
    "positives_from_lists",
    "positives_from_mask",
    "positives_from_vprbench_rows",
    "positives_to_lists",
]

_INTEGER_FIELD = re.compile(r"[+-]?[0-9]+")
#: What VPR-Bench's ``ground_truth_new.npy`` holds, for error messages.
VPRBENCH_GROUND_TRUTH = (
    "VPR-Bench ground truth (an object array of rows [query index, list of positive database indices])"
)


def _is_index(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _index_row(item: object, query: int, n_database: int | None, source: str) -> np.ndarray:
    """Validate the positives of one query; return them as a sorted, duplicate-free int64 array."""
    expected = f"an integer in [0, {n_database})" if n_database is not None else "a non-negative integer"
    if isinstance(item, np.ndarray) and item.dtype.kind in "iu":
        values = item.reshape(-1)
        if values.dtype.kind == "u" and values.size and values.max() > np.iinfo(np.int64).max:
            raise ValueError(
                f"{source}positives of query {query} must be database indices ({expected}), got {values.max()}"
            )
    else:
        if isinstance(item, (str, bytes, dict)) or not isinstance(item, (Iterable, np.ndarray)):
            raise ValueError(f"{source}positives of query {query} must be a list of database indices, got {item!r}")
        values = list(np.asarray(item, dtype=object).reshape(-1)) if isinstance(item, np.ndarray) else list(item)
        for value in values:
            if not _is_index(value):
                raise ValueError(
                    f"{source}positives of query {query}: {value!r} is not a database index (expected {expected})"
                )
        values = [int(value) for value in values]
        if values and (min(values) < 0 or max(values) > np.iinfo(np.int64).max):
            bad = min(values) if min(values) < 0 else max(values)
            raise ValueError(f"{source}positives of query {query} must be database indices ({expected}), got {bad}")
        values = np.asarray(values, dtype=np.int64)
    row = np.unique(values.astype(np.int64))
    if row.size and (row[0] < 0 or (n_database is not None and row[-1] >= n_database)):
        bad = row[0] if row[0] < 0 else row[-1]
        raise ValueError(f"{source}positives of query {query} must be database indices ({expected}), got {bad}")
    return row


def _csr_from_rows(rows: Sequence[np.ndarray], n_database: int) -> sparse.csr_array:
    indptr = np.zeros(len(rows) + 1, dtype=np.int64)
    np.cumsum([row.size for row in rows], out=indptr[1:])
    indices = np.concatenate(rows) if rows else np.empty(0, np.int64)
    data = np.ones(indices.size, dtype=bool)
    return sparse.csr_array((data, indices, indptr), shape=(len(rows), n_database))


def _check_n_database(n_database: object) -> int:
    if not _is_index(n_database) or n_database < 0:
        raise ValueError(f"n_database must be a non-negative integer, got {n_database!r}")
    return int(n_database)


def positives_from_lists(lists: Sequence[Iterable[int]], n_database: int | None = None) -> sparse.csr_array:
    """Build the positives matrix from one list of database indices per query.

    Parameters
    ----------
    lists : sequence of iterables of int, length Q
        Positive database indices of each query (may be empty; duplicates are merged). Floats and booleans are
        rejected, not converted.
    n_database : int, optional
        Number of database images D; every index must be below it. By default the largest index + 1 (pass it
        whenever you know it: the last database images may be nobody's positive).

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool

    Raises
    ------
    ValueError
        When an entry is not an integer database index in range; the message names the query and the value.

    Examples
    --------
    >>> positives_from_lists([[0, 2], []], n_database=3).toarray()
    array([[ True, False,  True],
           [False, False, False]])
    >>> positives_from_lists([[1], [0, 1]]).shape
    (2, 2)
    """
    if n_database is not None:
        n_database = _check_n_database(n_database)
    return _lists_to_positives(lists, n_database, "")


def _lists_to_positives(lists: Sequence[object], n_database: int | None, source: str) -> sparse.csr_array:
    """Validated lists → positives; the database size defaults to the largest index + 1."""
    rows = [_index_row(item, query, n_database, source) for query, item in enumerate(lists)]
    if n_database is None:
        n_database = max((int(row[-1]) for row in rows if row.size), default=-1) + 1
    return _csr_from_rows(rows, n_database)


def positives_from_mask(mask: object, *, source: str | Path | None = None) -> sparse.csr_array:
    """Build the positives matrix from a boolean (Q × D) mask.

    Numeric masks are accepted when every value is exactly 0 or 1; ``source`` (a file name) prefixes errors.

    Examples
    --------
    >>> positives_from_mask(np.array([[True, False], [False, False]])).nnz
    1
    """
    prefix = f"{source}: " if source is not None else ""
    array = np.asarray(mask)
    if array.ndim != 2:
        raise ValueError(f"{prefix}a ground-truth mask must be 2-D (n_queries, n_database), got shape {array.shape}")
    if array.dtype != bool:
        numeric = array.dtype.kind in "iuf"
        valid = np.isin(array, (0, 1)) if numeric else np.zeros(array.shape, dtype=bool)
        if not valid.all():
            query, column = (int(i) for i in np.argwhere(~valid)[0])
            raise ValueError(
                f"{prefix}a ground-truth mask must be boolean (or 0/1), got dtype {array.dtype} with "
                f"{array[query, column].item()!r} at query {query}, database image {column}"
            )
        array = array.astype(bool)
    return sparse.csr_array(array)


def positives_from_vprbench_rows(rows: np.ndarray, path: str | Path, *, n_database: int | None) -> sparse.csr_array:
    """Positives from VPR-Bench's ground-truth rows [query index, positives], validated; errors name ``path``.

    Parameters
    ----------
    rows : ndarray of shape (Q, 2), dtype object
        Row i = [query index, list (or array, or single int) of positive database indices]; the query indices
        are a permutation of 0..Q-1.
    path : str or Path
        The file the rows come from, for error messages.
    n_database : int, optional
        Number of database images; by default the largest positive index + 1.

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool
    """
    if not isinstance(rows, np.ndarray) or rows.dtype != object or rows.ndim != 2 or rows.shape[1] != 2:
        found = f"a {rows.dtype} array of shape {rows.shape}" if isinstance(rows, np.ndarray) else type(rows).__name__
        raise ValueError(f"{path}: expected {VPRBENCH_GROUND_TRUTH} of shape (n_queries, 2), got {found}")
    n_queries = len(rows)
    lists: list[object | None] = [None] * n_queries
    for row, (query, positives) in enumerate(rows):
        if not _is_index(query) or not 0 <= query < n_queries:
            raise ValueError(
                f"{path}: row {row}: the query index must be an integer in [0, {n_queries}), got {query!r}"
            )
        if lists[query] is not None:
            raise ValueError(
                f"{path}: row {row}: query {query} appears twice; expected each of 0..{n_queries - 1} once"
            )
        lists[query] = [positives] if _is_index(positives) else positives
    return _lists_to_positives(lists, n_database, f"{path}: ")  # errors name the file, the query and the value


def positives_to_lists(positives: sparse.csr_array) -> list[np.ndarray]:
    """One sorted int64 array of positive database indices per query."""
    positives = sparse.csr_array(positives)
    positives.sort_indices()
    return [
        positives.indices[positives.indptr[q] : positives.indptr[q + 1]].astype(np.int64)
        for q in range(positives.shape[0])
    ]


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path} is not a UTF-8 text file; expected ground truth as text") from None


def _from_text(path: Path, n_database: int | None) -> sparse.csr_array:
    lists = []
    for line_number, line in enumerate(_read_text(path).splitlines(), start=1):
        fields = line.replace(",", " ").split()
        bad = next((field for field in fields if not _INTEGER_FIELD.fullmatch(field)), None)
        if bad is not None:
            raise ValueError(
                f"{path}:{line_number}: expected integer database indices (line {line_number} = query "
                f"{line_number - 1}), got {bad!r} in {line!r}"
            )
        lists.append([int(field) for field in fields])
    return _lists_to_positives(lists, n_database, f"{path}: ")


def _from_json(path: Path, n_database: int | None) -> sparse.csr_array:
    try:
        content = json.loads(_read_text(path))
    except json.JSONDecodeError as error:
        raise ValueError(f"{path} is not valid JSON ({error}); expected a list of lists of database indices") from None
    except RecursionError:
        raise ValueError(
            f"{path}: the JSON is nested too deeply to read; expected a list of lists of database indices"
        ) from None
    lists = content.get("positives") if isinstance(content, dict) else content
    if not isinstance(lists, list) or not all(isinstance(item, list) for item in lists):
        raise ValueError(f"{path}: expected a JSON list of lists of database indices (one list per query)")
    return _lists_to_positives(lists, n_database, f"{path}: ")


def _integer_array(contents: dict[str, np.ndarray], key: str, path: Path, ndim: int) -> np.ndarray:
    array = contents[key]
    if array.ndim != ndim or array.dtype.kind not in "iu":
        shape = "a scalar" if ndim == 0 else "a 1-D array"
        raise ValueError(f"{path}: '{key}' must be {shape} of integers, got dtype {array.dtype}, shape {array.shape}")
    if array.dtype.kind == "u" and array.size and array.max() > np.iinfo(np.int64).max:
        raise ValueError(f"{path}: '{key}' holds {array.max()}, beyond any database size")
    return array.astype(np.int64)


_NPZ_KEYS = ("positives_indptr", "positives_indices", "n_database")


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    with path.open("rb") as handle:
        head = handle.read(4)
    if head not in (b"PK\x03\x04", b"PK\x05\x06"):
        kind = "empty (0 bytes)" if not head else "a .npy array" if head == b"\x93NUM" else "not a zip archive"
        raise ValueError(f"{path} is {kind}; expected ground truth in a .npz archive")
    try:
        with np.load(path, allow_pickle=False) as archive:
            found = sorted(archive.files)
            contents = {key: archive[key] for key in _NPZ_KEYS if key in archive}
    except (OSError, EOFError, zipfile.BadZipFile, ValueError) as error:
        raise ValueError(f"{path} is not a readable .npz archive ({error}); expected ground truth arrays") from None
    if "positives_indptr" not in contents or "positives_indices" not in contents:
        raise ValueError(
            f"{path} has no ground truth: expected arrays 'positives_indptr' and 'positives_indices', found {found}"
        )
    return contents


def _from_npz(path: Path, n_database: int | None) -> sparse.csr_array:
    contents = _read_npz(path)
    indptr = _integer_array(contents, "positives_indptr", path, 1)
    indices = _integer_array(contents, "positives_indices", path, 1)
    stored = int(_integer_array(contents, "n_database", path, 0)) if "n_database" in contents else None
    if indptr.size == 0 or indptr[0] != 0 or np.any(np.diff(indptr) < 0) or indptr[-1] != indices.size:
        raise ValueError(
            f"{path}: 'positives_indptr' must start at 0, never decrease and end at the number of "
            f"'positives_indices' ({indices.size}); got {indptr[:3].tolist()}...{indptr[-1:].tolist()}"
        )
    if stored is not None and stored < 0:
        raise ValueError(f"{path}: 'n_database' must be non-negative, got {stored}")
    if stored is not None and n_database is not None and stored != n_database:
        raise ValueError(f"ground truth {path} covers {stored} database images, expected {n_database}")
    size = stored if stored is not None else n_database
    lists = [indices[indptr[q] : indptr[q + 1]] for q in range(indptr.size - 1)]
    return _lists_to_positives(lists, size, f"{path}: ")


def _from_npy(path: Path, n_database: int | None) -> sparse.csr_array:
    from vpr_uncertainty.data.npy import read_npy

    array = read_npy(
        path, what="ground truth (a boolean mask or VPR-Bench's object array of positives)", allow_objects=True
    )
    if array.dtype == object:
        return positives_from_vprbench_rows(array, path, n_database=n_database)
    return positives_from_mask(array, source=path)


def load_ground_truth(
    path: str | Path, *, n_queries: int | None = None, n_database: int | None = None
) -> sparse.csr_array:
    """Read ground truth from a file in any supported format (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The file.
    n_queries, n_database : int, optional
        Expected shape. Required to size the matrix exactly for list formats; checked against the file.

    Returns
    -------
    scipy.sparse.csr_array of shape (Q, D), dtype bool

    Raises
    ------
    FileNotFoundError
        When the file does not exist.
    ValueError
        When the file cannot be read, holds something other than integer database indices in range (or a 0/1
        mask), or does not match the expected shape; the message names the file, and the query and value when
        one is at fault.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ground truth file not found: {path}")
    if n_database is not None:
        n_database = _check_n_database(n_database)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        positives = _from_npy(path, n_database)
    elif suffix == ".npz":
        positives = _from_npz(path, n_database)
    elif suffix == ".json":
        positives = _from_json(path, n_database)
    elif suffix in {".txt", ".csv", ".tsv"}:
        positives = _from_text(path, n_database)
    else:
        raise ValueError(
            f"unknown ground truth format {suffix!r} for {path}; expected .npy (boolean mask or VPR-Bench), "
            ".npz, .json or .txt/.csv"
        )
    if n_queries is not None and positives.shape[0] != n_queries:
        raise ValueError(f"ground truth {path} has {positives.shape[0]} queries, expected {n_queries}")
    if n_database is not None and positives.shape[1] != n_database:
        raise ValueError(
            f"ground truth {path} covers {positives.shape[1]} database images, expected {n_database} "
            "(a mask needs one column per database image)"
        )
    return positives
