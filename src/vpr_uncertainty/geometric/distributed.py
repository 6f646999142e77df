"""Geometric verification pairs as executor tasks in chunks (``GeometricVerifier(executor=...)``).

The driver extracts (or reads from the cache) the local features of every image once; each chunk of pairs is sent
with the features of just the images it names to a task that matches them and counts RANSAC inliers with the
verifier's settings. The results come back in the order of the pairs, so they equal a local run's (the same
matcher, RANSAC model, threshold and seed per pair).
"""

from __future__ import annotations

import copy
import math
import time
from functools import partial
from typing import Any

__all__ = ["CHUNKS_PER_WORKER", "verify_on_executor"]

#: Chunks per worker: several, so that a slow chunk does not hold the others back.
CHUNKS_PER_WORKER = 4


def _verify_chunk(item: tuple[list[tuple[str, str]], dict[str, Any]], verifier: Any) -> tuple[list[int], list[int]]:
    """(matches, inliers) of one chunk of pairs, with the features of the images it names."""
    pairs, features = item
    matches, inliers, _, _ = verifier._match_and_count(features, pairs)
    return matches, inliers


def verify_on_executor(
    verifier: Any, features: dict[str, Any], pairs: list[tuple[str, str]]
) -> tuple[list[int], list[int], float, float]:
    """Matches and inliers of every pair, computed in chunks on ``verifier.executor``.

    Parameters
    ----------
    verifier : GeometricVerifier
    features : dict
        Local features by image name (every name of ``pairs``).
    pairs : list of (str, str)

    Returns
    -------
    matches, inliers : list of int
        In the order of ``pairs``.
    matching_seconds, ransac_seconds : float
        The wall-clock time of the whole distributed step, and 0 (matching and RANSAC run together in each task).
    """
    executor = verifier.executor
    size = max(1, math.ceil(len(pairs) / (CHUNKS_PER_WORKER * max(1, executor.workers or 1))))
    chunks = []
    for start in range(0, len(pairs), size):
        chunk = pairs[start : start + size]
        names = dict.fromkeys(name for pair in chunk for name in pair)
        chunks.append((chunk, {name: features[name] for name in names}))
    light = copy.copy(verifier)  # what a task needs: matcher and RANSAC settings; no extractor, no executor
    light.extractor, light.executor, light.workers = None, None, 1
    start = time.perf_counter()
    results = executor.map(partial(_verify_chunk, verifier=light), chunks)
    seconds = time.perf_counter() - start
    matches = [count for chunk_matches, _ in results for count in chunk_matches]
    inliers = [count for _, chunk_inliers in results for count in chunk_inliers]
    return matches, inliers, seconds, 0.0
