"""The retrieval file: a :class:`~vpr_uncertainty.retrieval.Retrieval` in one ``.npz`` archive.

Retrieval file (``.npz``, no pickles), format version 1
    ``format_version``   int, 1
    ``scores``           (Q, K) float32, similarities sorted descending; ``-inf`` where a query has fewer than
                         K candidates
    ``indices``          (Q, K) int64, database index of each candidate; ``-1`` where missing
    ``distances``        (Q, K) float32, squared L2 distances of the candidates, ascending; ``+inf`` where
                         missing (optional)
    ``positives_indptr``, ``positives_indices``, ``n_database``
                         ground truth as a CSR matrix (optional)
    ``query_names``, ``database_names``          (Q,), (D,) unicode (optional)
    ``query_positions``, ``database_positions``  (Q, m), (D, m) float64, usually m = 2 (optional)
    ``config``           JSON text describing what produced the file (optional)
    ``checksum``         :func:`~vpr_uncertainty.cache.payload_checksum` of every other field, by name (written
                         by :func:`save_retrieval`; verified on read when present, so a file changed on disk
                         after it was written is refused, naming it; files of other tools may have none)

    ``config`` keys written by ``retrieve`` and ``attach_ground_truth`` (readers ignore keys they do not know):
    ``source``, ``metric``, ``k``, ``index``, ``device``, ``search_params``, ``dimension``, ``n_database``,
    ``n_queries``, ``radius``, ``database``, ``queries`` and ``position_kind`` (absent = metres).

Writes are atomic (written whole beside the target, then renamed). Reading checks every field as a Retrieval does,
and what only a file has (version, CSR ground truth, JSON config, distinct candidates and names).
"""

from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse

from vpr_uncertainty._files import is_regular_file
from vpr_uncertainty.cache import ChecksumError, atomic_write, payload_checksum
from vpr_uncertainty.retrieval.result import Retrieval, check_distinct, check_indices, check_integers, check_scores

__all__ = ["FORMAT_VERSION", "load_retrieval", "save_retrieval"]

FORMAT_VERSION = 1


def save_retrieval(retrieval: Retrieval, path: str | Path) -> Path:
    """Write a retrieval file (see the module docstring for the layout) and return its path."""
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
    arrays = _read_arrays(path)
    missing = {"scores", "indices"} - set(arrays)
    if missing:
        raise ValueError(f"{path} is not a retrieval file: missing {sorted(missing)} (found {sorted(arrays)})")
    try:
        _format_version(arrays)
        scores = check_scores(arrays["scores"])  # first, so that the positives are checked against them
        check_indices(arrays["indices"], scores)
        positives = _positives(arrays, scores.shape[0])
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


def _read_arrays(path: Path) -> dict[str, np.ndarray]:
    if path.stat().st_size == 0:
        raise ValueError(f"retrieval file {path} is empty (0 bytes); write it again")
    try:
        archive = np.load(path, allow_pickle=False)
        if isinstance(archive, np.lib.npyio.NpzFile):
            with archive:
                return {key: archive[key] for key in archive.files}
    except PermissionError:
        raise
    except _READ_ERRORS as error:
        detail = str(error) or type(error).__name__
        raise ValueError(
            f"retrieval file {path} cannot be read as a .npz archive (truncated or not a retrieval file?): {detail}"
        ) from None
    raise ValueError(f"retrieval file {path} is a single .npy array, not a .npz archive of named arrays")


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


def _positives(arrays: dict[str, np.ndarray], n_queries: int) -> sparse.csr_array | None:
    present = [key for key in ("positives_indptr", "positives_indices") if key in arrays]
    if not present:
        if "n_database" in arrays:
            _scalar_int("n_database", arrays["n_database"])
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
    if len(indptr) != n_queries + 1:
        raise ValueError(f"positives_indptr has {len(indptr)} entries, expected {n_queries + 1} (queries + 1)")
    if indptr[0] != 0 or indptr[-1] != len(indices) or (np.diff(indptr) < 0).any():
        raise ValueError(
            f"positives_indptr must rise from 0 to the {len(indices)} entries of positives_indices without "
            f"decreasing, got {indptr[0]} ... {indptr[-1]}" + (" (it decreases)" if (np.diff(indptr) < 0).any() else "")
        )
    if "n_database" in arrays:
        n_database = _scalar_int("n_database", arrays["n_database"])
        if n_database < 1:
            raise ValueError(f"n_database must be >= 1, got {n_database}")
    else:
        n_database = int(indices.max()) + 1 if indices.size else 0
    if indices.size and (indices.min() < 0 or indices.max() >= n_database):
        bad = int(indices[(indices < 0) | (indices >= n_database)][0])
        raise ValueError(f"positives_indices holds {bad}, outside the database of n_database = {n_database} images")
    return sparse.csr_array((np.ones(indices.size, dtype=bool), indices, indptr), shape=(n_queries, n_database))


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
