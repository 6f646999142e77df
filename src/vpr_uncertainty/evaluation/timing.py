"""Time figures beside the batched time per query: latency at batch size 1, and geometric verification with a cold
and a warm local-feature cache.

``time_per_query_ms`` (:func:`~vpr_uncertainty.evaluation.time_per_query`) is a *throughput*: one call on every
query at once, divided by the number of queries. The paper's "0.03 ms per query" for SU is a *latency*: one call
per query, as a robot makes it. :func:`latency_batch1` measures that: the median over ``runs`` runs of the mean
time of ``n_calls`` single-query calls, each through the method's registered function on a one-query retrieval
(a (1, K) row) built before the timing.

Geometric verification reads local features from an HDF5 cache in ``cache_dir``. :func:`time_geometric` reports

* ``cold``: one call that extracts the local features of every image it needs (an empty cache; when the cache
  already held features at the first call, this call is made with a fresh temporary cache, so its features are
  extracted again), then matches and runs RANSAC;
* ``warm``: the median of calls that read every feature from the cache: matching + RANSAC only (None without a
  ``cache_dir``, where every call extracts).
"""

from __future__ import annotations

import dataclasses
import statistics
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

__all__ = ["LATENCY_KINDS", "latency_batch1", "single_query_retrievals", "time_geometric"]

#: Kinds of method whose batch-1 latency is measured (the others need images or a model per call).
LATENCY_KINDS: frozenset[str] = frozenset({"score", "spatial", "calibrated"})
#: Retrieval fields with one row per query.
_PER_QUERY = ("scores", "indices", "positives", "distances", "query_names", "query_positions")


def single_query_retrievals(retrieval: Any, n: int) -> list[Any]:
    """``n`` one-query retrievals: the first ``n`` queries (cycled when there are fewer), each a (1, K) retrieval.

    Parameters
    ----------
    retrieval : Retrieval
    n : int
        How many, >= 1.

    Returns
    -------
    list of Retrieval
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if retrieval.n_queries == 0:
        raise ValueError("the retrieval has no queries")
    rows = []
    for index in range(min(n, retrieval.n_queries)):
        fields = {
            name: getattr(retrieval, name)[index : index + 1]
            for name in _PER_QUERY
            if getattr(retrieval, name) is not None
        }
        rows.append(dataclasses.replace(retrieval, **fields))
    return [rows[i % len(rows)] for i in range(n)]


def latency_batch1(call: Callable[[Any], Any], retrieval: Any, *, n_calls: int = 200, runs: int = 3) -> float:
    """Seconds per single-query call: the median over ``runs`` runs of ``n_calls`` calls, one query each.

    Parameters
    ----------
    call : callable
        ``call(one_query_retrieval)``, e.g. ``lambda r: get_method("SU")(r, k=10)``.
    retrieval : Retrieval
        The queries are taken from it (see :func:`single_query_retrievals`).
    n_calls : int, default=200
        Calls per run (>= 1).
    runs : int, default=3
        Runs (>= 3, as the paper's figure is a median over repeated runs).

    Returns
    -------
    float
        Seconds per call (> 0).
    """
    if runs < 3:
        raise ValueError(f"runs must be >= 3 (a median over repeated runs), got {runs}")
    queries = single_query_retrievals(retrieval, n_calls)
    call(queries[0])  # warm-up: imports, caches
    per_call = []
    for _ in range(runs):
        start = time.perf_counter()
        for query in queries:
            call(query)
        per_call.append((time.perf_counter() - start) / len(queries))
    return max(statistics.median(per_call), 1e-12)


def _snapshot(folder: Path | None) -> set[str]:
    """Names of the files directly in ``folder`` (empty when it is None or missing)."""
    if folder is None or not folder.is_dir():
        return set()
    return {path.name for path in folder.iterdir() if path.is_file()}


def time_geometric(
    call: Callable[[Mapping[str, Any]], Any], options: Mapping[str, Any], *, repeats: int = 3
) -> tuple[Any, float, float | None]:
    """A geometric method's result with its cold and warm time per call (see the module docstring).

    Parameters
    ----------
    call : callable
        ``call(options)``: the method on every query with those options (``cache_dir`` among them, or not).
    options : mapping
        The method's options.
    repeats : int, default=3
        Warm calls at most (at least one, more while they take under half a second in all).

    Returns
    -------
    result : the first call's result
    cold_seconds : float
        Seconds of a call that extracted every feature.
    warm_seconds : float or None
        Median seconds of the calls that read every feature from the cache; None without ``cache_dir``.
    """
    cache_dir = options.get("cache_dir")
    cache_dir = None if cache_dir is None else Path(cache_dir)
    before = _snapshot(cache_dir)
    start = time.perf_counter()
    result = call(options)
    first = time.perf_counter() - start
    if cache_dir is None:
        return result, first, None
    created = bool(_snapshot(cache_dir) - before)  # a new cache file: nothing of this extractor was cached
    warm: list[float] = [] if created else [first]
    while len(warm) < max(repeats, 1) and (not warm or sum(warm) < 0.5):
        start = time.perf_counter()
        call(options)
        warm.append(time.perf_counter() - start)
    if created:
        cold = first
    else:
        with tempfile.TemporaryDirectory(prefix="vpr-uncertainty-cold-") as scratch:
            start = time.perf_counter()
            call({**options, "cache_dir": Path(scratch)})
            cold = time.perf_counter() - start
    return result, cold, statistics.median(warm)
