"""Reading what BTL needs from files: the head file and frozen descriptors (the method), and the training data.

This is the method's declared ``resolve`` hook (see :class:`~vpr_uncertainty.methods.UncertaintyMethod`): the
stage that evaluates methods calls :func:`resolve_btl_inputs` once, before timing, and the method itself
(:func:`~vpr_uncertainty.btl.method.btl_uncertainty`) receives only a loaded :class:`BTLHead` and arrays.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.btl.model import BTLHead, load_btl_head
from vpr_uncertainty.btl.training import resolve_device
from vpr_uncertainty.retrieval import Retrieval

__all__ = ["read_btl_descriptors", "read_btl_head", "read_training_inputs", "resolve_btl_inputs"]


def read_btl_head(value: object, *, device: str = "cpu") -> BTLHead:
    """A loaded head from ``value`` (a head file written by ``train-btl``, or a :class:`BTLHead`), on ``device``."""
    if value is None or isinstance(value, BTLHead):
        return value  # type: ignore[return-value]  # the method says what is missing
    if not isinstance(value, (str, Path)):
        raise TypeError(f"btl_head must be the path of a head file or a BTLHead, got {type(value).__name__}")
    path = Path(value)
    if not path.is_file():
        raise FileNotFoundError(f"BTL head file not found: {path} (train one with `vpr-uncertainty train-btl`)")
    head = load_btl_head(path, device=resolve_device(device))
    head.source_path = str(path)  # recorded in the config of BTL's own retrieval
    return head


def read_btl_descriptors(value: object, split: str, names: object = None) -> object:
    """Descriptors of ``split`` (``"queries"`` or ``"database"``) from a ``.npy`` or descriptor-cache ``.h5`` path.

    Arrays (and None) are returned as they are. The image names of a cache are checked against ``names`` (the
    retrieval's) when both are known.
    """
    if not isinstance(value, (str, Path)):
        return value
    from vpr_uncertainty.data import load_descriptors

    option = "query_descriptors" if split == "queries" else "database_descriptors"
    file_names, array = load_descriptors(value, split)
    if file_names is not None and names is not None and list(file_names) != [str(name) for name in names]:
        raise ValueError(f"{option}: the image names in the descriptor file differ from the retrieval's {split} names")
    return array


def resolve_btl_inputs(retrieval: Retrieval, options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` with ``btl_head`` loaded and ``query_descriptors`` / ``database_descriptors`` read from files."""
    resolved = dict(options)
    device = str(resolved.get("device") or "cpu")
    resolved["btl_head"] = read_btl_head(resolved.get("btl_head"), device=device)
    resolved["query_descriptors"] = read_btl_descriptors(
        resolved.get("query_descriptors"), "queries", retrieval.query_names
    )
    resolved["database_descriptors"] = read_btl_descriptors(
        resolved.get("database_descriptors"), "database", retrieval.database_names
    )
    return resolved


# --- training data ------------------------------------------------------------------------------------------


def _load_positions(path: Path, name: str) -> np.ndarray:
    if not path.is_file():
        raise FileNotFoundError(f"{name} file not found: {path}")
    try:
        array = np.load(path, allow_pickle=False)
    except ValueError as error:
        raise ValueError(f"{path}: {name} must be a numeric .npy array: {error}") from None
    if array.ndim not in (1, 2) or not np.issubdtype(array.dtype, np.number):
        raise ValueError(f"{path}: {name} must be a numeric array of shape (n, 2) or (n,), got {array.shape}")
    return array


def _h5_has_queries(path: Path) -> bool:
    from vpr_uncertainty.descriptors.cache import cache_info

    return bool(cache_info(path).get("queries", {}).get("count", 0))


def read_training_inputs(
    *,
    descriptors: str | Path | None = None,
    query_descriptors: str | Path | None = None,
    positions: str | Path | None = None,
    query_positions: str | Path | None = None,
    positives: str | Path | None = None,
    run: str | Path | None = None,
    radius: float = 25.0,
) -> dict[str, Any]:
    """Descriptors and positives for :func:`~vpr_uncertainty.btl.train_btl_head`, read from files.

    Parameters
    ----------
    descriptors : path, optional
        Database descriptors: ``.npy`` (D x dim) or the HDF5 descriptor cache (its queries are used too).
    query_descriptors : path, optional
        Query descriptors (``.npy`` or ``.h5``).
    positions, query_positions : path, optional
        ``.npy`` positions of the database and queries (ground truth within ``radius``).
    positives : path, optional
        Explicit positives instead of positions (any format of :func:`~vpr_uncertainty.data.load_ground_truth`).
    run : path, optional
        A run folder holding ``descriptors.h5`` and ``retrieval.npz`` (instead of the other files).
    radius : float
        Positive radius, in the unit of the positions.

    Returns
    -------
    dict
        ``database``, ``queries`` (or None: the database trains on itself), ``positives`` and ``source``
        (JSON-compatible description for the head file).
    """
    run = None if run is None else Path(run)
    descriptors = None if descriptors is None else Path(descriptors)
    from vpr_uncertainty.data import load_descriptors, load_ground_truth, positives_within_radius
    from vpr_uncertainty.retrieval import load_retrieval

    if run is not None:
        exclusive = {
            "descriptors": descriptors,
            "query_descriptors": query_descriptors,
            "positions": positions,
            "query_positions": query_positions,
            "positives": positives,
        }
        given = [f"argument {name}" for name, value in exclusive.items() if value is not None]
        if given:
            raise ValueError(
                f"a run folder (argument run) gives descriptors.h5 and retrieval.npz; do not combine it with "
                f"{', '.join(given)}"
            )
        if not run.is_dir():
            raise FileNotFoundError(f"run directory not found: {run}")
        descriptors = run / "descriptors.h5"
        retrieval_path = run / "retrieval.npz"
        if not descriptors.is_file() or not retrieval_path.is_file():
            raise FileNotFoundError(f"{run} must hold descriptors.h5 and retrieval.npz (from extract + retrieve)")
    elif descriptors is None:
        raise ValueError(
            "give the training data: descriptors (argument descriptors, with argument positions or argument "
            "positives) or a run folder (argument run)"
        )
    else:
        retrieval_path = None

    database_names, database = load_descriptors(descriptors, "database")
    query_path = query_descriptors
    if query_path is None and descriptors.suffix.lower() in (".h5", ".hdf5") and _h5_has_queries(descriptors):
        query_path = descriptors
    query_names, queries = load_descriptors(query_path, "queries") if query_path is not None else (None, None)
    source: dict[str, Any] = {"descriptors": str(descriptors), "query_descriptors": str(query_path or "")}

    ground_truth = None
    if retrieval_path is not None:
        retrieval = load_retrieval(retrieval_path)
        if retrieval.positives is None:
            raise ValueError(f"{retrieval_path} holds no ground truth (positives); retrieve with positions")
        if queries is None:
            raise ValueError(f"{descriptors} holds no query descriptors")
        for split, names, stored in (
            ("query", query_names, retrieval.query_names),
            ("database", database_names, retrieval.database_names),
        ):
            if names is not None and stored is not None and list(names) != [str(name) for name in stored]:
                raise ValueError(f"the {split} names of {descriptors} and {retrieval_path} differ")
        ground_truth = retrieval.positives
        source["positives"] = str(retrieval_path)
    elif positives is not None:
        ground_truth = load_ground_truth(positives, n_database=len(database))
        if queries is None or ground_truth.shape[0] != len(queries):
            if ground_truth.shape[0] != len(database):
                expected = f"{len(queries)} (queries) or {len(database)}" if queries is not None else f"{len(database)}"
                raise ValueError(
                    f"{positives} has positives for {ground_truth.shape[0]} images; expected {expected} (database)"
                )
            queries = None  # database × database ground truth: the database trains on itself
        source["positives"] = str(positives)
    elif positions is not None:
        database_positions = _load_positions(Path(positions), "database positions (argument positions)")
        if len(database_positions) != len(database):
            raise ValueError(
                f"the database positions (argument positions) have {len(database_positions)} rows but there are "
                f"{len(database)} images"
            )
        if query_positions is not None and queries is not None:
            query_array = _load_positions(Path(query_positions), "query positions (argument query_positions)")
            if len(query_array) != len(queries):
                raise ValueError(
                    f"the query positions (argument query_positions) have {len(query_array)} rows but there are "
                    f"{len(queries)} queries"
                )
            ground_truth = positives_within_radius(query_array, database_positions, radius)
        else:
            queries = None  # no query ground truth: the database trains on itself
            ground_truth = positives_within_radius(database_positions, database_positions, radius)
        source.update(positions=str(positions), radius=radius)
    else:
        raise ValueError("give the ground truth: positions (argument positions, with a radius) or argument positives")
    if queries is None:
        source["query_descriptors"] = ""
    source["anchors"] = "queries" if queries is not None else "database"
    return {"database": database, "queries": queries, "positives": ground_truth, "source": source}
