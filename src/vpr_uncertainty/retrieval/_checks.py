"""Checks of every field of a :class:`~vpr_uncertainty.retrieval.Retrieval`.

A retrieval with a wrong field (an index −5, a wrapped unsigned index, a missing-candidate marker beside a real
score, ground truth that points outside the database, a NaN score) would silently change recall@N and AUC-PR,
so every field is checked when a Retrieval is made (and so when a retrieval file is read). Each check raises a
``ValueError`` that names the field and the problem; the file reader
(:func:`vpr_uncertainty.retrieval.file_format.load_retrieval`) adds the file name and checks what only a file has.

What is checked
    * ``scores`` (Q, K), K >= 1: real numbers (not bool), no NaN, no +inf, sorted descending along each row;
      ``-inf`` only for missing candidates.
    * ``indices`` (Q, K): integers (not float, not bool) within the int64 range, ``-1`` exactly where the score
      is ``-inf`` (a missing candidate), otherwise >= 0 and below the database size when one is known.
    * ``distances`` (Q, K), optional: real numbers, ``+inf`` exactly where a candidate is missing, otherwise
      finite and >= 0, ascending along each row.
    * ``positives``: one row per query, one column per database image; given as lists of indices per query, a
      boolean mask or a sparse matrix (:mod:`~vpr_uncertainty.retrieval._positives`).
    * names: 1-D strings, one per query / database image; positions: 2-D finite numbers with one row per image
      and, when both are given, the same number of columns.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vpr_uncertainty.retrieval._positives import coerce_positives

__all__ = ["check_distinct", "check_indices", "check_integers", "check_retrieval_fields", "check_scores"]

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
    if scores.shape[1] > 1:
        unsorted = scores[:, 1:] > scores[:, :-1]
        if unsorted.any():
            row, column = _first(unsorted)
            raise ValueError(
                f"scores must be sorted in descending order along each row, but row {row} has "
                f"{scores[row, column]} before {scores[row, column + 1]}"
            )
    return scores


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
    """Refuse a database image listed twice among one query's candidates, and a name given to two images.

    A repeated candidate counts one image twice in recall@N and in the score-shape methods; a repeated name
    makes a lookup by name (images, local features) pick one of two images. The file reader checks both.

    Parameters
    ----------
    indices : ndarray of shape (Q, K), int64
        ``-1`` (a missing candidate) may repeat.
    names : dict
        Field name -> 1-D array of names, or None.
    """
    if indices.ndim == 2 and indices.shape[1] > 1:
        ordered = np.sort(indices, axis=1)
        repeated = (ordered[:, 1:] == ordered[:, :-1]) & (ordered[:, 1:] >= 0)
        if repeated.any():
            row, column = _first(repeated)
            raise ValueError(
                f"indices: query {row} lists database image {int(ordered[row, column + 1])} twice among its "
                "candidates; expected each database image at most once per query"
            )
    for field, value in names.items():
        if value is None:
            continue
        array = np.asarray(value)
        unique, counts = np.unique(array, return_counts=True)
        if (counts > 1).any():
            name = unique[np.argmax(counts > 1)]
            rows = np.flatnonzero(array == name)[:2].tolist()
            raise ValueError(
                f"{field} holds {str(name)!r} twice (entries {rows[0]} and {rows[1]}); expected one distinct name "
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
    if distances.shape[1] > 1:
        unsorted = distances[:, 1:] < distances[:, :-1]
        if unsorted.any():
            row, column = _first(unsorted)
            raise ValueError(
                f"distances must be sorted in ascending order along each row (nearest first), but row {row} has "
                f"{distances[row, column]} before {distances[row, column + 1]}"
            )
    return distances


def _check_names(name: str, value: object, expected: int | None, what: str) -> np.ndarray | None:
    if value is None:
        return None
    array = np.asarray(value)
    if array.ndim != 1 or array.dtype.kind not in "USO":
        raise ValueError(
            f"{name} must be a 1-D array of strings (one per {what}), got dtype {array.dtype} and shape {array.shape}"
        )
    if expected is not None and len(array) != expected:
        raise ValueError(f"{name} has {len(array)} entries, expected {expected} (one per {what})")
    return array


def _check_positions(name: str, value: object, expected: int | None, what: str) -> np.ndarray | None:
    if value is None:
        return None
    array = _check_real(name, value)
    if array.ndim != 2 or array.shape[1] < 1:
        raise ValueError(f"{name} must have shape (n_images, 2) (one row per {what}), got shape {array.shape}")
    if expected is not None and len(array) != expected:
        raise ValueError(f"{name} has {len(array)} entries, expected {expected} (one per {what})")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} holds a non-finite value (first at {_where(_first(~np.isfinite(array)))})")
    return array


def _known_database_size(retrieval: Any) -> int | None:
    """The database size the names or positions tell (the first 1-D / 2-D one); None when neither is given."""
    for value, ndim in ((retrieval.database_names, 1), (retrieval.database_positions, 2)):
        if value is not None and np.ndim(value) == ndim:
            return len(value)
    return None


def check_retrieval_fields(retrieval: Any) -> None:
    """Check every field of a Retrieval (see the module docstring); converts arrays in place (indices to int64).

    Raises
    ------
    ValueError
        Naming the field and the problem.
    """
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
    retrieval.query_names = _check_names("query_names", retrieval.query_names, n_queries, "query")
    retrieval.database_names = _check_names("database_names", retrieval.database_names, None, "database image")
    retrieval.query_positions = _check_positions("query_positions", retrieval.query_positions, n_queries, "query")
    retrieval.database_positions = _check_positions(
        "database_positions", retrieval.database_positions, None, "database image"
    )
    if retrieval.query_positions is not None and retrieval.database_positions is not None:
        if retrieval.query_positions.shape[1] != retrieval.database_positions.shape[1]:
            raise ValueError(
                f"query_positions has {retrieval.query_positions.shape[1]} columns but database_positions has "
                f"{retrieval.database_positions.shape[1]}; they must agree"
            )
    sizes = {
        name: length
        for name, length in (
            ("positives", None if retrieval.positives is None else retrieval.positives.shape[1]),
            ("database_names", None if retrieval.database_names is None else len(retrieval.database_names)),
            ("database_positions", None if retrieval.database_positions is None else len(retrieval.database_positions)),
        )
        if length is not None
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
