"""Geometric verification as executor tasks in chunks (``GeometricVerifier(executor=...)``).

Two steps, each in chunks (:data:`CHUNKS_PER_WORKER` per worker, so that a slow chunk does not hold the others back):

* local features: the images missing from the feature cache are sent in chunks of paths to tasks that extract them
  with the verifier's extractor (one thread each; the images must be readable on every node); the driver writes each
  chunk to the cache as it comes back (:func:`extract_on_executor`), so an interrupted run keeps what finished and
  the features are still cached once per image;
* pairs: each chunk of pairs is sent with the features of just the images it names to a task that matches them and
  counts RANSAC inliers with the verifier's settings (:func:`verify_on_executor`).

The results come back in the order of the images and pairs, so they equal a local run's (the same extractor,
matcher, RANSAC model, threshold and seed per pair).
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Iterator, Sequence
from functools import partial
from pathlib import Path
from typing import Any

__all__ = ["CHUNKS_PER_WORKER", "extract_on_executor", "verify_on_executor"]

#: Chunks per worker: several, so that a slow chunk does not hold the others back.
CHUNKS_PER_WORKER = 4


def _chunk_size(items: int, executor: Any) -> int:
    return max(1, math.ceil(items / (CHUNKS_PER_WORKER * max(1, executor.workers or 1))))


def _extract_chunk(paths: list[Path], extractor: Any) -> list[Any]:
    """The local features of each image of one chunk, in order (one thread: the task has one CPU)."""
    features: list[Any] = [None] * len(paths)
    for position, result in extractor.extract(paths, workers=1):
        features[position] = result
    return features


def extract_on_executor(extractor: Any, paths: Sequence[Path], executor: Any) -> Iterator[tuple[int, Any]]:
    """Yield ``(position in paths, LocalFeatures)`` for every image, extracted in chunks on ``executor``.

    Chunks come back in completion order; within one they are in order. The caller writes them to the cache.
    """
    paths = list(paths)
    size = _chunk_size(len(paths), executor)
    starts = list(range(0, len(paths), size))
    chunks = [paths[start : start + size] for start in starts]
    for chunk, features in executor.imap(partial(_extract_chunk, extractor=extractor), chunks):
        for offset, result in enumerate(features):
            yield starts[chunk] + offset, result


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
    size = _chunk_size(len(pairs), executor)
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
