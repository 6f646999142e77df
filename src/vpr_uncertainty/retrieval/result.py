"""The Retrieval type: the top-k database images of every query, with its ground truth, every field checked; and its
file, a :class:`~vpr_uncertainty.retrieval.Retrieval` in one ``.npz`` archive (format version 1, no pickles, written
atomically, checksummed). The file's fields and ``config`` keys: see docs/reference/file-formats.md.
"""

from __future__ import annotations

import dataclasses
import json
import zipfile
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty.cache import ChecksumError, atomic_write, payload_checksum

#: What the scores given to :meth:`Retrieval.from_distances` (and ``--scores``) are; all but ``"distance"`` become
#: exact similarities.
SCORE_KINDS = ("similarity", "cosine-distance", "l2-distance", "l2-distance:squared", "l2-distance:plain", "distance")
_UNIT_TOLERANCE = 1e-3  # rounding of distances between unit-norm descriptors (Faiss: -1e-7 for an exact match)


def distance_kind_hint(values: np.ndarray) -> str:
    """``"KIND (why)"``, the ``--scores`` kind that scores ``values`` (Q, K) read as similarities (a matrix's largest
    values) would be if they are distances, from their range as :meth:`Retrieval.from_distances` reads the kinds."""
    finite = np.asarray(values, dtype=np.float64)[np.isfinite(values)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    if low < -_UNIT_TOLERANCE or high > 4 + _UNIT_TOLERANCE:
        kind = f"distance (values in [{low:.4g}, {high:.4g}]: no distances between unit-norm descriptors)"
    elif high > 2:
        kind = f"l2-distance (values up to {high:.4g}, above 2: squared L2 distances of unit-norm descriptors)"
    else:  # squared and plain L2 distances, and cosine distances, all lie in [0, 2] here
        kind = "l2-distance (of unit-norm descriptors; values in [0, 2] do not tell squared, as Faiss returns them, "
        kind += "from plain: say l2-distance:plain), cosine-distance (1 - cos) or distance (any other)"
    return kind


@dataclass(repr=False)
class Retrieval:
    """Top-k retrieval of Q queries against a database of D images.

    Attributes
    ----------
    scores : ndarray of shape (Q, K), float
        Similarities, higher = more similar, sorted descending; ``-inf`` marks a missing candidate (at the row's end).
    indices : ndarray of shape (Q, K), int64
        Database index of each candidate; ``-1`` marks a missing candidate.
    positives : scipy.sparse.csr_array of shape (Q, D), bool, optional
        Ground truth: the correct database images of each query. Given as lists of indices per query
        (``[[0, 4], [], [7]]``), a boolean (Q, D) mask or a sparse matrix. From lists, D is what ``database_names`` or
        ``database_positions`` give, else the smallest that holds every index (:func:`positives_from_lists` fixes D).
    distances : ndarray of shape (Q, K), optional
        Squared L2 distances of the candidates, ascending; ``+inf`` where missing.
    query_names, database_names : ndarray of str, optional
    query_positions, database_positions : ndarray of shape (Q, 2) and (D, 2), optional
        Positions, in metres unless ``config["position_kind"]`` is ``"frames"`` or ``"placeholder"``.
    config : dict
        What produced this retrieval (method, dataset, k, ...), stored with the file. ``config["scores"] ==
        "distance"`` marks scores that are negated distances (:meth:`from_distances`; see :attr:`score_kind`).
    """

    scores: np.ndarray
    indices: np.ndarray
    positives: sparse.csr_array | None = None
    distances: np.ndarray | None = None
    query_names: np.ndarray | None = None
    database_names: np.ndarray | None = None
    query_positions: np.ndarray | None = None
    database_positions: np.ndarray | None = None
    config: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Check every field; a ValueError names the field."""
        check_retrieval_fields(self)

    @classmethod
    def from_distances(
        cls, distances: object, indices: object, *, kind: str = "distance", largest: float | None = None, **fields: Any
    ) -> Retrieval:
        """A retrieval from distances sorted ascending: the one place lower-is-better scores are converted.

        ``kind`` says what they are (:data:`SCORE_KINDS`):

        - ``"cosine-distance"`` (d = 1 − cos): the scores are the exact cosine similarities 1 − d;
        - ``"l2-distance"`` between unit-norm descriptors: the exact cosine similarities, s = 1 − d/2 of squared
          distances (what Faiss ``IndexFlatL2`` returns), s = 1 − d²/2 of plain ones; ``"l2-distance:squared"`` and
          ``"l2-distance:plain"`` say which, ``"l2-distance"`` detects it (a value above 2 is a squared distance,
          otherwise squared is assumed) and says so in ``config["score_conversion"]``; :attr:`distances` keeps the
          squared distances. Every uncertainty method then runs as on the similarities;
        - ``"distance"``: any other lower-is-better score, negated as :attr:`scores` (kept as :attr:`distances` when
          none is below 0), with ``config["scores"] = "distance"``, so that the methods that need similarities (RS,
          SD, SU divide by s_1) are left out of the default list.

        Parameters
        ----------
        distances : array-like of shape (Q, K)
            Ascending per row; ``+inf`` marks a missing candidate.
        indices : array-like of shape (Q, K), int
        kind : str, default="distance"
        largest : float, optional
            The largest distance of the whole matrix when ``distances`` hold only the nearest (detects squared L2).
        **fields
            The other fields of :class:`Retrieval` (``positives``, names, positions, ``config``).

        Examples
        --------
        >>> retrieval = Retrieval.from_distances([[0.2, 0.5, 0.9]], [[4, 0, 7]])
        >>> retrieval.scores, retrieval.score_kind
        (array([[-0.2, -0.5, -0.9]]), 'distance')
        >>> Retrieval.from_distances([[0.2, 0.5]], [[4, 0]], kind="cosine-distance").scores
        array([[0.8, 0.5]])
        """
        distances = _check_real("distances", distances)
        if kind not in SCORE_KINDS[1:]:
            raise ValueError(f"kind must be one of {SCORE_KINDS[1:]}, got {kind!r}")
        config = fields.pop("config", {})
        if kind == "distance":
            kept = None if (distances < 0).any() else distances  # below 0: no squared L2 distances
            config = {**config, "scores": "distance"}
            return cls(scores=-distances, indices=indices, distances=kept, config=config, **fields)
        finite = distances[np.isfinite(distances)]
        low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
        high = max(high, largest if largest is not None else high)
        note = "cosine distances d = 1 - cos: scores are the cosine similarities 1 - d"
        if kind == "l2-distance":
            kind = "l2-distance:squared"
            how = "a value above 2" if high > 2 else "assumed, as Faiss IndexFlatL2 returns; else l2-distance:plain"
            note = f"squared L2 distances of unit-norm descriptors ({how}): scores are the cosine similarities 1 - d/2"
        elif kind != "cosine-distance":
            note = f"{kind.split(':')[1]} L2 distances of unit-norm descriptors: scores are the cosine similarities"
        bound = 2.0 if kind != "l2-distance:squared" else 4.0
        if low < -_UNIT_TOLERANCE or high > bound + _UNIT_TOLERANCE:
            raise ValueError(
                f"distances lie in [{low:.4g}, {high:.4g}]; {kind} between unit-norm descriptors lie in "
                f"[0, {bound:g}]: these are other distances (read them as kind 'distance')"
            )
        squared = distances if kind == "l2-distance:squared" else distances**2 if kind == "l2-distance:plain" else None
        scores = 1 - distances if squared is None else 1 - squared / 2
        config = {**config, "scores": "similarity", "score_conversion": note}
        squared = None if squared is None else np.maximum(squared, 0)  # Faiss rounds an exact match to -1e-7
        return cls(scores=scores, indices=indices, distances=squared, config=config, **fields)

    @property
    def score_kind(self) -> str:
        """``"distance"`` when the scores are negated distances (:meth:`from_distances`), else ``"similarity"``."""
        return "distance" if self.config.get("scores") == "distance" else "similarity"

    @property
    def n_database(self) -> int | None:
        """Number of database images, when the positives, the database names or positions tell it."""
        return int(self.positives.shape[1]) if self.positives is not None else _known_database_size(self)

    def subset_queries(self, rows: np.ndarray) -> Retrieval:
        """The retrieval of the queries ``rows`` only (an index array or a boolean mask), same database."""
        rows = np.asarray(rows)
        taken = {
            name: None if (value := getattr(self, name)) is None else value[rows]
            for name in ("scores", "indices", "positives", "distances", "query_names", "query_positions")
        }
        return dataclasses.replace(self, **taken)

    @property
    def n_queries(self) -> int:
        return self.scores.shape[0]

    @property
    def k(self) -> int:
        """Number of candidates stored per query."""
        return self.scores.shape[1]

    def __repr__(self) -> str:
        optional = ("positives", "distances", "query_names", "database_names", "query_positions", "database_positions")
        given = [name for name in optional if getattr(self, name) is not None]
        return (
            f"Retrieval(n_queries={self.n_queries}, k={self.k}, n_database={self.n_database}, "
            f"scores={self.scores.dtype}, fields={given}, config={sorted(self.config)})"
        )


_INT64_MAX = np.iinfo(np.int64).max


def _first(mask: np.ndarray) -> tuple[int, ...]:
    return tuple(int(i) for i in np.argwhere(mask)[0])


def _where(position: tuple[int, ...]) -> str:
    return f"row {position[0]}, column {position[1]}" if len(position) == 2 else f"entry {position[0]}"


def _check_real(name: str, value: object) -> np.ndarray:
    array = np.asarray(value)
    if array.dtype == bool or not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"{name} must hold real numbers, got dtype {array.dtype}")
    return array


def check_integers(name: str, value: object) -> np.ndarray:
    """An integer array (any integer dtype) converted to int64 without wrapping."""
    array = np.asarray(value)
    if array.dtype == bool or not np.issubdtype(array.dtype, np.integer):
        raise ValueError(f"{name} must hold integers, got dtype {array.dtype}")
    if array.size and np.issubdtype(array.dtype, np.unsignedinteger) and array.max() > _INT64_MAX:
        position = _first(array > _INT64_MAX)
        raise ValueError(
            f"{name} holds {int(array[position])} at {_where(position)}, beyond the int64 range (a negative "
            "index wrapped into an unsigned type?)"
        )
    return array.astype(np.int64, copy=False)


def check_scores(scores: object) -> np.ndarray:
    scores = _check_real("scores", scores)
    if scores.ndim != 2 or scores.shape[1] < 1:
        raise ValueError(f"scores must have shape (n_queries, k) with k >= 1, got shape {scores.shape}")
    if np.issubdtype(scores.dtype, np.floating) and scores.size:
        nan = np.isnan(scores)
        if nan.any():
            raise ValueError(f"scores contains NaN (first at {_where(_first(nan))}); expected finite similarities")
        if (scores == np.inf).any():
            raise ValueError(f"scores contains +inf (first at {_where(_first(scores == np.inf))})")
    _check_sorted("scores", scores, descending=True)
    return scores


def _check_sorted(name: str, array: np.ndarray, *, descending: bool) -> None:
    unsorted = array[:, 1:] > array[:, :-1] if descending else array[:, 1:] < array[:, :-1]
    if unsorted.any():
        row, column = _first(unsorted)
        order = "descending order along each row" if descending else "ascending order along each row (nearest first)"
        raise ValueError(
            f"{name} must be sorted in {order}, but row {row} has {array[row, column]} before {array[row, column + 1]}"
        )


def check_indices(indices: object, scores: np.ndarray) -> np.ndarray:
    indices = check_integers("indices", indices)
    if indices.shape != scores.shape:
        raise ValueError(f"indices has shape {indices.shape} but scores has shape {scores.shape}; they must agree")
    if indices.size and indices.min() < -1:
        position = _first(indices < -1)
        raise ValueError(
            f"indices holds {int(indices[position])} at {_where(position)}; expected a database index >= 0, or -1 "
            "for a missing candidate"
        )
    missing_score = scores == -np.inf
    mismatch = (indices == -1) != missing_score
    if mismatch.any():
        position = _first(mismatch)
        raise ValueError(
            f"indices holds {int(indices[position])} beside the score {scores[position]} at {_where(position)}; a "
            "missing candidate must have index -1 and score -inf, and only a missing one"
        )
    return indices


def check_distinct(indices: np.ndarray, names: dict[str, object]) -> None:
    """Refuse a database image twice among one query's candidates (``-1`` may repeat), and a name given twice."""
    if indices.ndim == 2 and indices.shape[1] > 1:
        ordered = np.sort(indices, axis=1)
        repeated = (ordered[:, 1:] == ordered[:, :-1]) & (ordered[:, 1:] >= 0)
        if repeated.any():
            row, column = _first(repeated)
            raise ValueError(
                f"indices: query {row} lists database image {int(ordered[row, column + 1])} twice among its "
                "candidates; expected each database image at most once per query"
            )
    for key, value in names.items():
        if value is None:
            continue
        array = np.asarray(value)
        unique, counts = np.unique(array, return_counts=True)
        if (counts > 1).any():
            name = unique[np.argmax(counts > 1)]
            rows = np.flatnonzero(array == name)[:2].tolist()
            raise ValueError(
                f"{key} holds {str(name)!r} twice (entries {rows[0]} and {rows[1]}); expected one distinct name "
                "per image"
            )


def _check_distances(distances: object, indices: np.ndarray) -> np.ndarray:
    distances = _check_real("distances", distances)
    if distances.shape != indices.shape:
        raise ValueError(
            f"distances has shape {distances.shape} but scores and indices have shape {indices.shape}; they must agree"
        )
    if not distances.size:
        return distances
    with np.errstate(invalid="ignore"):
        missing = indices == -1
        bad = np.isnan(distances) | (distances < 0) | (np.isinf(distances) != missing)
    if bad.any():
        position = _first(bad)
        raise ValueError(
            f"distances holds {distances[position]} at {_where(position)}; expected finite squared L2 distances "
            ">= 0, and +inf where a candidate is missing (index -1)"
        )
    _check_sorted("distances", distances, descending=False)
    return distances


def _check_rows(name: str, value: object, expected: int | None, what: str) -> np.ndarray | None:
    """Names (1-D strings) or positions (2-D finite real numbers), one row per ``what``; None stays None."""
    if value is None:
        return None
    positions = name.endswith("_positions")
    array = _check_real(name, value) if positions else np.asarray(value)
    if positions and (array.ndim != 2 or array.shape[1] < 1):
        raise ValueError(f"{name} must have shape (n_images, 2) (one row per {what}), got shape {array.shape}")
    if not positions and (array.ndim != 1 or array.dtype.kind not in "USO"):
        raise ValueError(
            f"{name} must be a 1-D array of strings (one per {what}), got dtype {array.dtype} and shape {array.shape}"
        )
    if expected is not None and len(array) != expected:
        raise ValueError(f"{name} has {len(array)} entries, expected {expected} (one per {what})")
    if positions and not np.isfinite(array).all():
        raise ValueError(f"{name} holds a non-finite value (first at {_where(_first(~np.isfinite(array)))})")
    return array


def _known_database_size(retrieval: Any) -> int | None:
    """The database size the names or positions tell (the first 1-D / 2-D one); None when neither is given."""
    for value, ndim in ((retrieval.database_names, 1), (retrieval.database_positions, 2)):
        if value is not None and np.ndim(value) == ndim:
            return len(value)
    return None


def check_retrieval_fields(retrieval: Any) -> None:
    """Check every field of a Retrieval, converting in place (indices to int64); a ValueError names the field."""
    retrieval.scores = check_scores(retrieval.scores)
    retrieval.indices = check_indices(retrieval.indices, retrieval.scores)
    n_queries = retrieval.scores.shape[0]
    if retrieval.distances is not None:
        retrieval.distances = _check_distances(retrieval.distances, retrieval.indices)
    if retrieval.positives is not None:
        retrieval.positives = coerce_positives(
            retrieval.positives, n_database=_known_database_size(retrieval), indices=retrieval.indices
        )
        if retrieval.positives.shape[0] != n_queries:
            raise ValueError(
                f"positives has {retrieval.positives.shape[0]} rows but there are {n_queries} queries (scores rows)"
            )
    retrieval.query_names = _check_rows("query_names", retrieval.query_names, n_queries, "query")
    retrieval.database_names = _check_rows("database_names", retrieval.database_names, None, "database image")
    retrieval.query_positions = _check_rows("query_positions", retrieval.query_positions, n_queries, "query")
    retrieval.database_positions = _check_rows(
        "database_positions", retrieval.database_positions, None, "database image"
    )
    if retrieval.query_positions is not None and retrieval.database_positions is not None:
        if retrieval.query_positions.shape[1] != retrieval.database_positions.shape[1]:
            raise ValueError(
                f"query_positions has {retrieval.query_positions.shape[1]} columns but database_positions has "
                f"{retrieval.database_positions.shape[1]}; they must agree"
            )
    sizes = {
        name: value.shape[1] if name == "positives" else len(value)
        for name in ("positives", "database_names", "database_positions")
        if (value := getattr(retrieval, name)) is not None
    }
    if len(set(sizes.values())) > 1:
        described = ", ".join(f"{name}: {length}" for name, length in sizes.items())
        raise ValueError(f"the database sizes disagree ({described})")
    if sizes and retrieval.indices.size and retrieval.indices.max() >= max(sizes.values()):
        name, length = next(iter(sizes.items()))
        position = _first(retrieval.indices >= length)
        raise ValueError(
            f"indices refer to database image {int(retrieval.indices[position])} (at {_where(position)}) but "
            f"{name} covers only {length} database images"
        )


_EXPECTED = (
    "a list of positive database indices per query (e.g. [[0, 4], [], [7]]), a boolean (n_queries, n_database) "
    "mask or a scipy sparse matrix"
)


def _from_sparse(value: object) -> sparse.csr_array:
    matrix = sparse.csr_array(value)
    if matrix.ndim != 2:
        raise ValueError(f"positives must be 2-D (n_queries, n_database), got shape {matrix.shape}")
    if matrix.dtype != bool:
        if matrix.dtype.kind not in "iuf" or not np.isin(matrix.data, (0, 1)).all():
            raise ValueError(
                f"positives is a sparse matrix of dtype {matrix.dtype}; expected booleans (or 0/1), got values "
                f"{np.unique(matrix.data)[:5].tolist()}"
            )
        matrix = matrix.astype(bool)
        matrix.eliminate_zeros()
    return matrix


def coerce_positives(value: object, *, n_database: int | None, indices: np.ndarray) -> sparse.csr_array:
    """``positives`` as lists per query, a boolean (Q, D) mask or a sparse matrix, as a boolean ``csr_array``.

    Lists without a known ``n_database`` cover every positive and every retrieved index (``indices``).
    """
    if sparse.issparse(value):
        return _from_sparse(value)
    if isinstance(value, np.ndarray) and value.dtype != object:
        if value.ndim != 2:
            raise ValueError(f"positives must be {_EXPECTED}; got an array of shape {value.shape}")
        return positives_from_mask(value, source="positives")
    if isinstance(value, (str, bytes, dict)) or not isinstance(value, Iterable):
        raise ValueError(f"positives must be {_EXPECTED}; got {type(value).__name__}")
    rows = list(value)
    if rows and all(  # non-empty lists of booleans: a mask written as Python lists
        isinstance(row, (list, tuple)) and len(row) > 0 and all(isinstance(x, (bool, np.bool_)) for x in row)
        for row in rows
    ):
        widths = {len(row) for row in rows}
        if len(widths) > 1:
            raise ValueError(f"positives as a boolean mask needs rows of one length, got lengths {sorted(widths)}")
        return positives_from_mask(np.array(rows, dtype=bool), source="positives")
    try:
        lists = positives_from_lists(rows, n_database=n_database)
    except ValueError as error:
        raise ValueError(f"{error} (positives must be {_EXPECTED})") from None
    if n_database is None:  # the lists cover their largest positive already
        n_database = max(lists.shape[1], int(indices.max()) + 1 if indices.size else 0)
        lists = sparse.csr_array((lists.data, lists.indices, lists.indptr), shape=(lists.shape[0], n_database))
    return lists


def is_index(value: object) -> bool:
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
            if not is_index(value):
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


def check_positive_int(value: object, name: str) -> int:
    """``value`` as an int when it is an integer >= 1 (not a bool); otherwise a ValueError naming ``name``."""
    if not is_index(value) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def check_n_database(n_database: object) -> int:
    if not is_index(n_database) or n_database < 0:
        raise ValueError(f"n_database must be a non-negative integer, got {n_database!r}")
    return int(n_database)


def positives_from_lists(
    lists: Sequence[Iterable[int]], n_database: int | None = None, *, source: str | Path | None = None
) -> sparse.csr_array:
    """Build the positives matrix from one list of database indices per query.

    Parameters
    ----------
    lists : sequence of iterables of int, length Q
        Positive database indices of each query (may be empty; duplicates are merged). Floats and booleans are
        rejected, not converted.
    n_database : int, optional
        Number of database images D; every index must be below it. By default the largest index + 1 (pass it
        whenever you know it: the last database images may be nobody's positive).
    source : str or Path, optional
        What the lists come from (a file name), prefixed to error messages.

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
    n_database = None if n_database is None else check_n_database(n_database)
    prefix = f"{source}: " if source is not None else ""
    rows = [_index_row(item, query, n_database, prefix) for query, item in enumerate(lists)]
    if n_database is None:
        n_database = max((int(row[-1]) for row in rows if row.size), default=-1) + 1
    indptr = np.zeros(len(rows) + 1, dtype=np.int64)
    np.cumsum([row.size for row in rows], out=indptr[1:])
    indices = np.concatenate(rows) if rows else np.empty(0, np.int64)
    return sparse.csr_array((np.ones(indices.size, dtype=bool), indices, indptr), shape=(len(rows), n_database))


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


# --- the retrieval file ---------------------------------------------------------------------------------------

FORMAT_VERSION = 1


def save_retrieval(retrieval: Retrieval, path: str | Path) -> Path:
    """Write a retrieval file (layout: docs/reference/file-formats.md) and return its path."""
    if not isinstance(retrieval, Retrieval):  # numpy.save's order, (path, array), given by habit
        raise TypeError(f"save_retrieval(retrieval, path): the Retrieval comes first, got {type(retrieval).__name__}")
    path = Path(path)
    arrays: dict[str, Any] = {
        "format_version": np.array(FORMAT_VERSION),
        "scores": retrieval.scores.astype(np.float32, copy=False),
        "indices": retrieval.indices,
        "config": np.array(json.dumps(retrieval.config, sort_keys=True)),
    }
    if retrieval.distances is not None:
        arrays["distances"] = retrieval.distances.astype(np.float32, copy=False)
    if retrieval.positives is not None:
        arrays["positives_indptr"] = retrieval.positives.indptr.astype(np.int64)
        arrays["positives_indices"] = retrieval.positives.indices.astype(np.int64)
        arrays["n_database"] = np.array(retrieval.positives.shape[1])
    for name in ("query_names", "database_names", "query_positions", "database_positions"):
        value = getattr(retrieval, name)
        if value is not None:
            arrays[name] = np.asarray(value, dtype=str if name.endswith("_names") else np.float64)
    arrays["checksum"] = np.array(_checksum(arrays))
    with atomic_write(path, "wb") as handle:  # written whole, then renamed: never a truncated file
        np.savez_compressed(handle, **arrays)
    return path


def _checksum(arrays: dict[str, np.ndarray]) -> str:
    """The payload checksum of a retrieval file's fields (every field but ``checksum``, in name order)."""
    names = sorted(name for name in arrays if name != "checksum")
    return payload_checksum(*(part for name in names for part in (name, arrays[name])))


def load_retrieval(path: str | Path) -> Retrieval:
    """Read a retrieval file written by :func:`save_retrieval` (or any ``.npz`` with ``scores``, ``indices``).

    Raises
    ------
    FileNotFoundError
        When ``path`` is not a file.
    ValueError
        Naming the file, the field and the problem; also for an empty, truncated or non-``.npz`` file.
    """
    path = Path(path)
    if not is_regular_file(path, "a retrieval file"):
        raise FileNotFoundError(f"retrieval file not found: {path}")
    arrays = read_npz(path, _RETRIEVAL_FILE)
    missing = {"scores", "indices"} - set(arrays)
    if missing:
        raise ValueError(f"{path} is not a retrieval file: missing {sorted(missing)} (found {sorted(arrays)})")
    try:
        _format_version(arrays)
        scores = check_scores(arrays["scores"])  # first, so that the positives are checked against them
        check_indices(arrays["indices"], scores)
        positives = positives_from_csr(arrays, scores.shape[0])
        optional = ("distances", "query_names", "database_names", "query_positions", "database_positions")
        retrieval = Retrieval(
            scores=scores,
            indices=arrays["indices"],
            positives=positives,
            config=_config(arrays),
            **{name: arrays.get(name) for name in optional},
        )
        names = {"query_names": retrieval.query_names, "database_names": retrieval.database_names}
        check_distinct(retrieval.indices, names)
    except ValueError as error:
        raise ValueError(f"retrieval file {path}: {error}") from None
    if "checksum" in arrays:  # last: a field that is wrong in itself is named first
        stored = arrays["checksum"]
        if stored.ndim != 0 or stored.dtype.kind != "U" or str(stored) != _checksum(arrays):
            raise ChecksumError(
                f"retrieval file {path}: its content does not match the checksum stored with it (changed on disk "
                "after it was written); write it again (a run or retrieve rebuilds it)"
            )
    return retrieval


# --- reading, field by field ----------------------------------------------------------------------------------

_READ_ERRORS = (EOFError, OSError, ValueError, zipfile.BadZipFile, zlib.error, KeyError)
_RETRIEVAL_FILE = "a retrieval file (a .npz archive with scores and indices; a .npy is read as a similarity matrix)"


def read_npz(path: Path, what: str) -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` archive ``path`` (no pickles); a ValueError naming it and ``what`` it should be
    for an empty, truncated or foreign file (a ``.npy`` array included)."""
    with path.open("rb") as handle:
        head = handle.read(6)
    if head[:4] not in (b"PK\x03\x04", b"PK\x05\x06"):
        kind = "empty (0 bytes)" if not head else "a .npy array" if head == b"\x93NUMPY" else "no zip archive"
        raise ValueError(f"{path} is {kind}, not {what}")
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {key: archive[key] for key in archive.files}
    except PermissionError:
        raise
    except _READ_ERRORS as error:
        detail = str(error) or type(error).__name__
        raise ValueError(f"{path} is not a readable .npz archive (truncated?): {detail}; expected {what}") from None


def _scalar_int(name: str, value: np.ndarray) -> int:
    if value.ndim != 0 or value.dtype == bool or not np.issubdtype(value.dtype, np.integer):
        raise ValueError(f"{name} must be a single integer, got {value!r}")
    return int(value)


def _format_version(arrays: dict[str, np.ndarray]) -> int:
    maximum = FORMAT_VERSION
    if "format_version" not in arrays:
        return maximum  # written by another tool: read as the current version
    value = arrays["format_version"]
    if value.ndim != 0 or value.dtype == bool or not np.issubdtype(value.dtype, np.integer) or value < 1:
        raise ValueError(f"format_version must be an integer between 1 and {maximum}, got {value.tolist()!r}")
    if value > maximum:
        raise ValueError(f"format_version is {value}; this toolkit reads up to {maximum}. Upgrade vpr-uncertainty")
    return int(value)


def positives_from_csr(
    arrays: dict[str, np.ndarray], n_queries: int | None = None, n_database: int | None = None
) -> sparse.csr_array | None:
    """The ground truth stored as ``positives_indptr``, ``positives_indices`` and optionally ``n_database`` (retrieval
    files, ground-truth ``.npz``), every array checked; None when neither is stored. ``n_queries``, ``n_database``:
    the sizes expected (a stored ``n_database`` must agree)."""
    present = [key for key in ("positives_indptr", "positives_indices") if key in arrays]
    stored = check_n_database(_scalar_int("n_database", arrays["n_database"])) if "n_database" in arrays else None
    if not present:
        return None
    if len(present) == 1:
        other = ({"positives_indptr", "positives_indices"} - set(present)).pop()
        raise ValueError(f"{present[0]} is present without {other}; the ground truth needs both")
    indptr = check_integers("positives_indptr", arrays["positives_indptr"])
    indices = check_integers("positives_indices", arrays["positives_indices"])
    if indptr.ndim != 1 or indices.ndim != 1:
        raise ValueError(
            f"positives_indptr and positives_indices must be 1-D, got shapes {indptr.shape} and {indices.shape}"
        )
    if n_queries is not None and len(indptr) != n_queries + 1:
        raise ValueError(f"positives_indptr has {len(indptr)} entries, expected {n_queries + 1} (queries + 1)")
    decreases = (np.diff(indptr) < 0).any()
    if not len(indptr) or indptr[0] != 0 or indptr[-1] != len(indices) or decreases:
        raise ValueError(
            f"positives_indptr must rise from 0 to the {len(indices)} entries of positives_indices without "
            f"decreasing, got {indptr[:1].tolist()} ... {indptr[-1:].tolist()}" + (" (it decreases)" * bool(decreases))
        )
    if stored is not None and n_database is not None and stored != n_database:
        raise ValueError(f"the ground truth covers {stored} database images, expected {n_database}")
    size = stored if stored is not None else n_database
    size = size if size is not None else int(indices.max(initial=-1)) + 1
    if indices.size and (indices.min() < 0 or indices.max() >= size):
        bad = int(indices[(indices < 0) | (indices >= size)][0])
        raise ValueError(f"positives_indices holds {bad}, outside the database of n_database = {size} images")
    return sparse.csr_array((np.ones(indices.size, dtype=bool), indices, indptr), shape=(len(indptr) - 1, size))


def _config(arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    if "config" not in arrays:
        return {}
    value = arrays["config"]
    if value.ndim != 0 or value.dtype.kind != "U":
        raise ValueError(f"config must be JSON text, got dtype {value.dtype} and shape {value.shape}")
    try:
        config = json.loads(str(value))
    except json.JSONDecodeError as error:
        raise ValueError(f"config is not valid JSON ({error})") from None
    if not isinstance(config, dict):
        raise ValueError(f"config must be a JSON object, got {type(config).__name__}")
    return config
