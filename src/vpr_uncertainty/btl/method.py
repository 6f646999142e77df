"""The ``BTL`` uncertainty method (registered by :mod:`vpr_uncertainty.btl`), the readers of what it needs, and
evaluation protocols in which no query is both a training anchor and a test query (:func:`btl_protocol`). How its
inputs are resolved, what the protocols train and test: see docs/explanation/btl.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse

from vpr_uncertainty._validation import check_count
from vpr_uncertainty.btl.model import SKETCH_TOLERANCE, BTLHead, embed, load_btl_head, row_digests, row_sketches
from vpr_uncertainty.btl.training import resolve_device, train_btl_head
from vpr_uncertainty.cache import content_key, open_present
from vpr_uncertainty.methods import OwnRetrievalUncertainty
from vpr_uncertainty.retrieval import Retrieval, load_retrieval, search_descriptors

#: The option that gives the descriptors of each split.
_OPTIONS = {"queries": "query_descriptors", "database": "database_descriptors"}


def read_btl_head(value: object, *, device: str = "cpu") -> BTLHead:
    """A loaded head from ``value`` (a head file written by ``train-btl``, or a :class:`BTLHead`), on ``device``."""
    if value is None or isinstance(value, BTLHead):
        return value  # type: ignore[return-value]  # the method says what is missing
    if not isinstance(value, (str, Path)):
        raise TypeError(f"btl_head must be the path of a head file or a BTLHead, got {type(value).__name__}")
    path = Path(value)
    head = load_btl_head(path, device=resolve_device(device))  # a missing file: FileNotFoundError, naming it
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

    file_names, array = load_descriptors(value, split)
    if file_names is not None and names is not None and list(file_names) != [str(name) for name in names]:
        raise ValueError(
            f"{_OPTIONS[split]}: the image names in the descriptor file differ from the retrieval's {split} names"
        )
    return array


def _descriptor_keys(path: Any, split: str, count: int) -> list[str] | None:
    """The content keys of the first ``count`` images of ``split`` in a descriptor cache (None for another file)."""
    import h5py

    from vpr_uncertainty.descriptors.cache import FORMAT

    if not isinstance(path, (str, Path)) or Path(path).suffix.lower() not in (".h5", ".hdf5"):
        return None
    with h5py.File(path, "r") as handle:
        keys = open_present(handle, (f"{split}/keys",), path) if handle.attrs.get("format") == FORMAT else {}
        return list(keys[f"{split}/keys"].asstr()[:count]) if keys else None


def _contents(keys: list[str]) -> list[str]:
    """The content digest that ends each content key, what any copy of the file shares ("" where unknown)."""
    return [key.rpartition(":")[2] for key in keys]


def resolve_btl_inputs(retrieval: Retrieval, options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` with ``btl_head`` loaded, ``query_descriptors`` / ``database_descriptors`` read from files, and
    ``query_keys`` taken from the query descriptor cache or the query image files (``query_paths``)."""
    resolved = dict(options)
    device = str(resolved.get("device") or "cpu")
    resolved["btl_head"] = read_btl_head(resolved.get("btl_head"), device=device)
    given = resolved.get("query_descriptors")
    for split, names in (("queries", retrieval.query_names), ("database", retrieval.database_names)):
        resolved[_OPTIONS[split]] = read_btl_descriptors(resolved.get(_OPTIONS[split]), split, names)
    keys = _descriptor_keys(given, "queries", retrieval.n_queries)
    if keys is None and resolved.get("query_paths") is not None:
        keys = [content_key(path) for path in resolved["query_paths"]]
    resolved["query_keys"] = resolved.get("query_keys", keys)
    return resolved


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
        ``database``, ``queries`` (or None: the database trains on itself), ``positives``, ``source``
        (JSON-compatible description for the head file) and ``images``: the anchors' ``names`` and image
        ``contents`` (content digests) where the descriptor files give them, for ``head.metadata["anchors"]``.
    """
    run = None if run is None else Path(run)
    descriptors = None if descriptors is None else Path(descriptors)
    retrieval_path = None
    from vpr_uncertainty.data import load_descriptors, load_ground_truth, positives_within_radius
    from vpr_uncertainty.descriptors.cache import cache_info
    from vpr_uncertainty.formats.ground_truth import read_positions

    if run is not None:
        exclusive = dict(descriptors=descriptors, query_descriptors=query_descriptors, positions=positions)
        exclusive.update(query_positions=query_positions, positives=positives)
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

    database_names, database = load_descriptors(descriptors, "database")
    query_path = query_descriptors
    if query_path is None and descriptors.suffix.lower() in (".h5", ".hdf5"):
        query_path = descriptors if cache_info(descriptors).get("queries", {}).get("count", 0) else None
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
        database_positions = read_positions(
            positions, expected=len(database), name="database positions (argument positions)"
        )
        if query_positions is not None and queries is not None:
            query_array = read_positions(
                query_positions, expected=len(queries), name="query positions (argument query_positions)"
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
    path, names = (query_path, query_names) if queries is not None else (descriptors, database_names)
    keys = _descriptor_keys(path, source["anchors"], len(names)) if names is not None else None
    images = {"names": [str(name) for name in names]} if names is not None else {}
    images.update({"contents": _contents(keys)} if keys is not None else {})
    return {"database": database, "queries": queries, "positives": ground_truth, "source": source, "images": images}


def _head(value: object, device: str) -> BTLHead:
    if value is None:
        raise ValueError(
            "uncertainty method 'BTL' needs a trained head: pass btl_head= (a BTLHead, or the path of a file "
            "written by train-btl when called through evaluate or get_method)"
        )
    if not isinstance(value, BTLHead):
        raise TypeError(
            f"btl_head must be a loaded BTLHead here, got {type(value).__name__} (read a head file with "
            "vpr_uncertainty.btl.method.resolve_btl_inputs or load_btl_head)"
        )
    return value.to(resolve_device(device)).eval()


def _descriptors(value: object, split: str, expected: int | None) -> np.ndarray:
    option = _OPTIONS[split]
    if value is None:
        raise ValueError(
            f"uncertainty method 'BTL' needs the frozen descriptors: pass {option}= (an array of shape "
            f"(n_{split}, dim), or a .npy / descriptor-cache .h5 path when called through evaluate or get_method)"
        )
    if isinstance(value, (str, Path)):
        raise TypeError(
            f"{option} must be an array here, got the path {value} (read it with "
            "vpr_uncertainty.btl.method.resolve_btl_inputs)"
        )
    array = np.asarray(value, dtype=np.float32)
    if array.ndim != 2:
        raise ValueError(f"{option} must be 2-D (n_images, dim), got shape {array.shape}")
    if expected is not None and len(array) != expected:
        raise ValueError(f"{option} has {len(array)} rows but the retrieval has {expected} {split}")
    return array


def btl_retrieval(
    retrieval: Retrieval,
    *,
    btl_head: object = None,
    query_descriptors: object = None,
    database_descriptors: object = None,
    device: str = "cpu",
) -> tuple[Retrieval, np.ndarray]:
    """BTL's own retrieval (same queries, database and ground truth as ``retrieval``) and the query variances.

    Returns
    -------
    own : Retrieval
        Top-k by cosine similarity of the head's mean embeddings, k = ``retrieval.k`` (at most D).
    variance : ndarray of shape (Q,), float32
        The head's variance of each query.
    """
    head = _head(btl_head, device)
    queries = _descriptors(query_descriptors, "queries", retrieval.n_queries)
    database = _descriptors(database_descriptors, "database", retrieval.n_database)
    for option, array in (("query_descriptors", queries), ("database_descriptors", database)):
        if array.shape[1] != head.input_dim:
            raise ValueError(
                f"{option} have dimension {array.shape[1]} but the BTL head was trained on {head.input_dim}-D "
                "descriptors (use the descriptors of the model it was trained with)"
            )
    query_means, query_variances = embed(head, queries)
    database_means, _ = embed(head, database)
    k = min(retrieval.k, len(database))
    scores, indices, distances = search_descriptors(database_means, query_means, k, progress=False)
    config: dict[str, Any] = {
        "source": "btl",
        "metric": "cosine",
        "k": k,
        "embedding_dim": head.embedding_dim,
        "retrieved_with": "BTL head mean embeddings",
        **({"btl_head": head.source_path} if getattr(head, "source_path", None) is not None else {}),
    }
    own = replace(retrieval, scores=scores, indices=indices, distances=distances, config=config)
    return own, query_variances


def trained_on(head: BTLHead, query_descriptors: np.ndarray, *, keys: list[str] | None = None) -> int | None:
    """How many of ``query_descriptors`` (Q, dim) were the head's training anchors (None: none found and the file
    does not say what they were): the same image files (the content digests of ``keys``, the Q content keys),
    identical rows (their digests), or the same images described again in another precision (their sketches)."""
    anchors = (head.metadata or {}).get("anchors") or {}
    digests, sketches = anchors.get("digests") or [], anchors.get("sketches")
    seen = np.isin(row_digests(query_descriptors), digests)
    if isinstance(sketches, list) and sketches and len(query_descriptors):
        from scipy.spatial import cKDTree

        distances, _ = cKDTree(np.asarray(sketches, dtype=np.float64)).query(row_sketches(query_descriptors), k=1)
        seen |= distances <= SKETCH_TOLERANCE
    if keys is not None:
        seen |= np.isin(_contents(keys), [content for content in anchors.get("contents") or () if content])
    complete = isinstance(digests, list) and len(digests) == anchors.get("count") != 0
    return int(seen.sum()) if seen.any() or complete else None


def _unverified(head: BTLHead, seen: int | None, names: object, keys: list[str] | None) -> str | None:
    """Why the ``seen`` of :func:`trained_on` may miss training images among these queries (their ``names`` and
    content ``keys``): what survives re-extraction could not be compared (None: it was, or ``seen`` > 0)."""
    if seen:
        return None
    anchors = (head.metadata or {}).get("anchors") or {}
    names = names if anchors.get("source") == "queries" and names is not None else []
    same = int(np.isin(np.asarray(names, dtype=str), anchors.get("names") or []).sum())
    only = ": checked by descriptors only, its training images extracted again would pass unseen"
    reasons = (
        (seen is None, "does not record its training images (metadata 'anchors'), so these queries may be among them"),
        (not any(anchors.get("contents") or ()), f"records no image contents (train it from a .h5){only}"),
        (not any(keys or ()), f"cannot be matched to these queries' image files (give the descriptor cache){only}"),
        (same, f"was trained on other files of the names of {same} of these queries: the same images re-encoded?"),
    )
    return next((why for failed, why in reasons if failed), None)


def btl_uncertainty(
    retrieval: Retrieval,
    *,
    btl_head: object = None,
    query_descriptors: object = None,
    database_descriptors: object = None,
    device: str = "cpu",
    allow_train_queries: bool = False,
    query_keys: object = None,
) -> OwnRetrievalUncertainty:
    """BTL uncertainty: the variance σ² of each query's embedding (higher = less trustworthy), with BTL's own
    retrieval. Registered as ``"BTL"``. Options: ``btl_head`` (a loaded :class:`~vpr_uncertainty.btl.model.BTLHead`),
    ``query_descriptors`` and ``database_descriptors`` ((Q, dim) and (D, dim), in the retrieval's order), ``device``,
    ``allow_train_queries`` (else evaluating a head on queries it was trained on is an error; when true,
    ``details["trained_on_queries"]`` says how many) and ``query_keys`` (the queries'
    :func:`~vpr_uncertainty.cache.content_key`, matched against the image contents the head records; where that
    check cannot be made, ``details["note"]``). Files are read first by :func:`resolve_btl_inputs`.

    Raises
    ------
    ValueError
        When the head was trained on some of these queries and ``allow_train_queries`` is false.
    """
    if not isinstance(allow_train_queries, bool):
        raise TypeError(f"allow_train_queries must be true or false, got {allow_train_queries!r}")
    own, variance = btl_retrieval(
        retrieval,
        btl_head=btl_head,
        query_descriptors=query_descriptors,
        database_descriptors=database_descriptors,
        device=device,
    )
    keys = None if query_keys is None else [str(key) for key in query_keys]  # type: ignore[attr-defined]
    if keys is not None and (isinstance(query_keys, str) or len(keys) != retrieval.n_queries):
        raise ValueError(f"query_keys must hold one content key per query ({retrieval.n_queries}): a list")
    seen = trained_on(btl_head, np.asarray(query_descriptors, dtype=np.float32), keys=keys)  # checked by btl_retrieval
    source = getattr(btl_head, "source_path", None) or "the BTL head"
    if seen and not allow_train_queries:
        raise ValueError(
            f"{source} was trained on {seen} of these {retrieval.n_queries} queries: its AUC-PR on them says "
            "nothing about new queries. Evaluate it on other queries, or pass allow_train_queries=True "
            "(evaluate --allow-train-queries) to report it, marked"
        )
    details: dict[str, Any] = {"trained_on_queries": seen} if seen else {}
    notice = _unverified(btl_head, seen, retrieval.query_names, keys)
    details.update({"note": f"{source} {notice}"} if notice else {})
    details.update({"training_unverified": True} if seen is None else {})  # never best: see MethodResult.never_best
    return OwnRetrievalUncertainty(uncertainty=variance.astype(np.float64), retrieval=own, details=details)


#: The protocols :func:`btl_protocol` builds.
PROTOCOLS = ("database", "query-split")


@dataclass(frozen=True)
class BTLProtocol:
    """Which images train the head and which queries test it.

    Attributes
    ----------
    name : str
        One of :data:`PROTOCOLS`.
    anchors : {"database", "queries"}
        What the training anchors are.
    train_queries : ndarray of int64
        Queries used as training anchors (training and early-stopping validation); empty when ``anchors`` is
        ``"database"``.
    test_queries : ndarray of int64
        Queries the head is evaluated on; disjoint from ``train_queries``.
    description : str
        One line for a report.
    """

    name: str
    anchors: str
    train_queries: np.ndarray
    test_queries: np.ndarray
    description: str


def btl_protocol(name: str, n_queries: int, *, split_at: int | None = None) -> BTLProtocol:
    """The training and test queries of protocol ``name``.

    Parameters
    ----------
    name : {"database", "query-split"}
    n_queries : int
        Number of queries of the dataset (at least 2).
    split_at : int, optional
        ``query-split`` only: the first test query; queries before it train the head. Default: ``n_queries // 2``.
        Must leave at least 2 training queries (one for early stopping) and 1 test query.

    Returns
    -------
    BTLProtocol

    Examples
    --------
    >>> protocol = btl_protocol("query-split", 6, split_at=4)
    >>> protocol.train_queries.tolist(), protocol.test_queries.tolist()
    ([0, 1, 2, 3], [4, 5])
    >>> btl_protocol("database", 3).train_queries.size
    0
    """
    n_queries = check_count(n_queries, "n_queries", 2)
    if name not in PROTOCOLS:
        raise ValueError(f"unknown BTL protocol {name!r}; expected one of {', '.join(PROTOCOLS)}")
    if name == "database" and split_at is not None:
        raise ValueError("split_at applies to the 'query-split' protocol only; the 'database' one tests every query")
    first_test = 0  # the database protocol trains on no query
    description = f"trained on the database images as anchors, tested on all {n_queries} queries"
    if name == "query-split":
        first_test = n_queries // 2 if split_at is None else check_count(split_at, "split_at", 2)
        if first_test > n_queries - 1:
            raise ValueError(
                f"split_at must leave at least one test query: got {first_test} with {n_queries} queries "
                f"(expected 2 <= split_at <= {n_queries - 1})"
            )
        description = (
            f"trained on queries 0..{first_test - 1} as anchors, tested on queries {first_test}..{n_queries - 1}"
        )
    return BTLProtocol(
        name=name,
        anchors="database" if name == "database" else "queries",
        train_queries=np.arange(first_test, dtype=np.int64),
        test_queries=np.arange(first_test, n_queries, dtype=np.int64),
        description=description,
    )


def database_frame_positives(n_database: int, frame_tolerance: int | float) -> sparse.csr_array:
    """Positives of each database image among the database: the images at most ``frame_tolerance`` frames away.

    Row i includes i itself; training with database anchors ignores that entry.

    Examples
    --------
    >>> database_frame_positives(4, 1).toarray().astype(int)
    array([[1, 1, 0, 0],
           [1, 1, 1, 0],
           [0, 1, 1, 1],
           [0, 0, 1, 1]])
    """
    from vpr_uncertainty.data import positives_within_frames

    frames = np.arange(check_count(n_database, "n_database", 2))
    return positives_within_frames(frames, frames, tolerance=frame_tolerance)


def train_for_protocol(
    protocol: BTLProtocol,
    query_descriptors: object,
    database_descriptors: object,
    positives: object,
    *,
    frame_tolerance: int | float = 2,
    **settings: Any,
) -> tuple[Any, Any]:
    """Train a BTL head as ``protocol`` says, touching no test query.

    Parameters
    ----------
    protocol : BTLProtocol
    query_descriptors : array-like of shape (Q, dim)
        All queries; only ``protocol.train_queries`` are used.
    database_descriptors : array-like of shape (D, dim)
    positives : sparse or dense bool matrix of shape (Q, D)
        The query ground truth; only the rows of ``protocol.train_queries`` are used.
    frame_tolerance : int or float, default 2
        ``database`` protocol: the frame distance of database positives.
    **settings
        Passed to :func:`~vpr_uncertainty.btl.train_btl_head` (``seed``, ``epochs``, ``progress``, ...).

    Returns
    -------
    head, history
        As :func:`~vpr_uncertainty.btl.train_btl_head` returns them.
    """
    if not isinstance(protocol, BTLProtocol):
        raise TypeError(f"protocol must be a BTLProtocol (see btl_protocol), got {type(protocol).__name__}")
    overlap = np.intersect1d(protocol.train_queries, protocol.test_queries)
    if overlap.size:
        raise ValueError(
            f"protocol {protocol.name!r} trains on {overlap.size} of its test queries (first: {int(overlap[0])}); "
            "training and test queries must be disjoint"
        )
    queries = np.asarray(query_descriptors, dtype=np.float32)
    database = np.asarray(database_descriptors, dtype=np.float32)
    ground_truth = sparse.csr_array(positives, dtype=bool)
    if queries.ndim != 2 or ground_truth.shape != (len(queries), len(database)):
        raise ValueError(
            f"positives must have shape (n_queries, n_database) = ({len(queries)}, {len(database)}), "
            f"got {ground_truth.shape}"
        )
    if protocol.anchors == "database":
        return train_btl_head(database, database_frame_positives(len(database), frame_tolerance), **settings)
    rows = protocol.train_queries
    if rows.size and rows.max() >= len(queries):
        raise ValueError(f"protocol {protocol.name!r} trains on query {int(rows.max())} but there are {len(queries)}")
    return train_btl_head(database, ground_truth[rows], query_descriptors=queries[rows], **settings)
