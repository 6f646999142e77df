"""The ``BTL`` uncertainty method: the predicted variance of each query under a trained BTL head.

As in the published evaluation, BTL answers with its own retrieval: queries and database are embedded with the
head's means and searched by cosine similarity, so its correctness labels come from its own top-1 (returned as
:class:`~vpr_uncertainty.methods.OwnRetrievalUncertainty`; the evaluation says so). Options (passed through
:func:`vpr_uncertainty.evaluate` or ``get_method("BTL")(retrieval, ...)``):

``btl_head``
    Path of a head file written by ``vpr-uncertainty train-btl`` (or a loaded :class:`BTLHead`).
``query_descriptors``, ``database_descriptors``
    The frozen descriptors the head was trained on, (Q, dim) and (D, dim) arrays in the retrieval's query and
    database order, or paths of a ``.npy`` array or of the HDF5 descriptor cache (read with the image names,
    which are checked against the retrieval's names when both are known).
``device``
    Where the head runs (``"cpu"``, ``"cuda"``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.learned.model import BTLHead, embed, load_btl_head
from vpr_uncertainty.learned.training import resolve_device
from vpr_uncertainty.methods import OwnRetrievalUncertainty
from vpr_uncertainty.retrieval import Retrieval

__all__ = ["btl_retrieval", "btl_uncertainty"]

_HEADS: dict[tuple[str, int, int, str], BTLHead] = {}


def _head(value: object, device: str) -> tuple[BTLHead, str | None]:
    if value is None:
        raise ValueError(
            "uncertainty method 'BTL' needs a trained head: pass btl_head=PATH (a file written by "
            "`vpr-uncertainty train-btl`)"
        )
    if isinstance(value, BTLHead):
        return value.to(resolve_device(device)).eval(), None
    if not isinstance(value, (str, Path)):
        raise TypeError(f"btl_head must be the path of a head file or a BTLHead, got {type(value).__name__}")
    path = Path(value)
    if not path.is_file():
        raise FileNotFoundError(f"BTL head file not found: {path} (train one with `vpr-uncertainty train-btl`)")
    stat = path.stat()
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size, str(device))
    if key not in _HEADS:  # evaluate() calls a method several times to time it: read the file once
        _HEADS.clear()
        _HEADS[key] = load_btl_head(path, device=resolve_device(device))
    return _HEADS[key], str(path)


def _descriptors(value: object, split: str, expected: int | None, names: object) -> np.ndarray:
    option = "query_descriptors" if split == "queries" else "database_descriptors"
    if value is None:
        raise ValueError(
            f"uncertainty method 'BTL' needs the frozen descriptors: pass {option}= (an array of shape "
            f"(n_{'queries' if split == 'queries' else 'database'}, dim) or a .npy / descriptor-cache .h5 path)"
        )
    file_names = None
    if isinstance(value, (str, Path)):
        from vpr_uncertainty.retrieval import load_descriptors

        file_names, value = load_descriptors(value, split)
    array = np.asarray(value, dtype=np.float32)
    if array.ndim != 2:
        raise ValueError(f"{option} must be 2-D (n_images, dim), got shape {array.shape}")
    if expected is not None and len(array) != expected:
        raise ValueError(f"{option} has {len(array)} rows but the retrieval has {expected} {split}")
    if file_names is not None and names is not None and list(file_names) != [str(name) for name in names]:
        raise ValueError(f"{option}: the image names in the descriptor file differ from the retrieval's {split} names")
    return array


def _search(database: np.ndarray, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact cosine top-k of unit-norm embeddings (Faiss when available)."""
    try:
        from vpr_uncertainty.retrieval import search_descriptors
    except ImportError:  # pragma: no cover - older retrieval module: plain numpy
        from vpr_uncertainty.retrieval import top_k_from_similarity

        scores, indices = top_k_from_similarity(queries @ database.T, k)
        from vpr_uncertainty.scores import squared_distances_from_similarities

        return scores, indices, squared_distances_from_similarities(scores, check=False)
    return search_descriptors(database, queries, k, progress=False)


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
    head, head_path = _head(btl_head, device)
    queries = _descriptors(query_descriptors, "queries", retrieval.n_queries, retrieval.query_names)
    database = _descriptors(database_descriptors, "database", retrieval.n_database, retrieval.database_names)
    for option, array in (("query_descriptors", queries), ("database_descriptors", database)):
        if array.shape[1] != head.input_dim:
            raise ValueError(
                f"{option} have dimension {array.shape[1]} but the BTL head was trained on {head.input_dim}-D "
                "descriptors (use the descriptors of the model it was trained with)"
            )
    query_means, query_variances = embed(head, queries)
    database_means, _ = embed(head, database)
    k = min(retrieval.k, len(database))
    scores, indices, distances = _search(database_means, query_means, k)
    config: dict[str, Any] = {
        "source": "btl",
        "metric": "cosine",
        "k": k,
        "embedding_dim": head.embedding_dim,
        "retrieved_with": "BTL head mean embeddings",
    }
    if head_path is not None:
        config["btl_head"] = head_path
    own = Retrieval(
        scores=scores,
        indices=indices,
        positives=retrieval.positives,
        distances=distances,
        query_names=retrieval.query_names,
        database_names=retrieval.database_names,
        query_positions=retrieval.query_positions,
        database_positions=retrieval.database_positions,
        config=config,
    )
    return own, query_variances


def btl_uncertainty(
    retrieval: Retrieval,
    *,
    btl_head: object = None,
    query_descriptors: object = None,
    database_descriptors: object = None,
    device: str = "cpu",
) -> OwnRetrievalUncertainty:
    """BTL uncertainty: the variance σ² of each query's embedding (higher = less trustworthy), with BTL's own
    retrieval. Registered as ``"BTL"``; see the module docstring for the options.
    """
    own, variance = btl_retrieval(
        retrieval,
        btl_head=btl_head,
        query_descriptors=query_descriptors,
        database_descriptors=database_descriptors,
        device=device,
    )
    return OwnRetrievalUncertainty(uncertainty=variance.astype(np.float64), retrieval=own)
