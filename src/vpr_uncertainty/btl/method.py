"""The ``BTL`` uncertainty method: the predicted variance of each query under a trained BTL head.

As in the published evaluation, BTL answers with its own retrieval: queries and database are embedded with the
head's means and searched by cosine similarity, so its correctness labels come from its own top-1 (returned as
:class:`~vpr_uncertainty.methods.OwnRetrievalUncertainty`; the evaluation says so). Options (passed through
:func:`vpr_uncertainty.evaluate` or ``get_method("BTL")(retrieval, ...)``):

``btl_head``
    A loaded :class:`BTLHead`.
``query_descriptors``, ``database_descriptors``
    The frozen descriptors the head was trained on, (Q, dim) and (D, dim) arrays in the retrieval's query and
    database order.
``device``
    Where the head runs (``"cpu"``, ``"cuda"``).
``allow_train_queries``
    A head file records the descriptors of its training anchors (:func:`~vpr_uncertainty.btl.training.
    row_digests`). Evaluating it on queries it was trained on inflates its figures, so that is an error unless
    this is true; then ``details["trained_on_queries"]`` says how many, and every table marks the method.

The functions here read no file: through :func:`vpr_uncertainty.evaluate` or ``get_method("BTL")``, the
method's ``resolve`` hook (:func:`vpr_uncertainty.btl.inputs.resolve_btl_inputs`) first reads a head file
path and ``.npy`` / descriptor-cache ``.h5`` paths (checking the cache's image names against the retrieval's).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vpr_uncertainty.btl.model import BTLHead, embed, row_digests
from vpr_uncertainty.btl.training import resolve_device
from vpr_uncertainty.methods import OwnRetrievalUncertainty
from vpr_uncertainty.retrieval import Retrieval

__all__ = ["btl_retrieval", "btl_uncertainty", "trained_on"]


def _head(value: object, device: str) -> BTLHead:
    if value is None:
        raise ValueError(
            "uncertainty method 'BTL' needs a trained head: pass btl_head= (a BTLHead, or the path of a file "
            "written by train-btl when called through evaluate or get_method)"
        )
    if not isinstance(value, BTLHead):
        raise TypeError(
            f"btl_head must be a loaded BTLHead here, got {type(value).__name__} (read a head file with "
            "vpr_uncertainty.btl.inputs.resolve_btl_inputs or load_btl_head)"
        )
    return value.to(resolve_device(device)).eval()


def _descriptors(value: object, split: str, expected: int | None) -> np.ndarray:
    option = "query_descriptors" if split == "queries" else "database_descriptors"
    if value is None:
        raise ValueError(
            f"uncertainty method 'BTL' needs the frozen descriptors: pass {option}= (an array of shape "
            f"(n_{'queries' if split == 'queries' else 'database'}, dim), or a .npy / descriptor-cache .h5 path "
            "when called through evaluate or get_method)"
        )
    if isinstance(value, (str, Path)):
        raise TypeError(
            f"{option} must be an array here, got the path {value} (read it with "
            "vpr_uncertainty.btl.inputs.resolve_btl_inputs)"
        )
    array = np.asarray(value, dtype=np.float32)
    if array.ndim != 2:
        raise ValueError(f"{option} must be 2-D (n_images, dim), got shape {array.shape}")
    if expected is not None and len(array) != expected:
        raise ValueError(f"{option} has {len(array)} rows but the retrieval has {expected} {split}")
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
    head = _head(btl_head, device)
    head_path = getattr(head, "source_path", None)
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


def trained_on(head: BTLHead, query_descriptors: np.ndarray) -> int | None:
    """How many of ``query_descriptors`` (Q, dim) were the head's training anchors (None: the file does not say)."""
    anchors = (head.metadata or {}).get("anchors") or {}
    digests = anchors.get("digests")
    if not isinstance(digests, list):
        return None
    seen = set(digests)
    return sum(digest in seen for digest in row_digests(query_descriptors))


def btl_uncertainty(
    retrieval: Retrieval,
    *,
    btl_head: object = None,
    query_descriptors: object = None,
    database_descriptors: object = None,
    device: str = "cpu",
    allow_train_queries: bool = False,
) -> OwnRetrievalUncertainty:
    """BTL uncertainty: the variance σ² of each query's embedding (higher = less trustworthy), with BTL's own
    retrieval. Registered as ``"BTL"``; see the module docstring for the options.

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
    details: dict[str, Any] = {}
    seen = trained_on(btl_head, np.asarray(query_descriptors, dtype=np.float32))  # both checked by btl_retrieval
    if seen and not allow_train_queries:
        source = getattr(btl_head, "source_path", None) or "the BTL head"
        raise ValueError(
            f"{source} was trained on {seen} of these {retrieval.n_queries} queries: its AUC-PR on them says "
            "nothing about new queries. Evaluate it on other queries, or pass allow_train_queries=True "
            "(evaluate --allow-train-queries) to report it, marked"
        )
    if seen:
        details["trained_on_queries"] = seen
    return OwnRetrievalUncertainty(uncertainty=variance.astype(np.float64), retrieval=own, details=details)
