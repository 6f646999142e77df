"""Matching runs with NumPy's BLAS at one thread (the pairs are what runs in parallel).

With BLAS at its default threads, each pair's small matrix product woke every BLAS thread, which contended with the
verifier's own threads: on 2 busy cores the matching step of 60 corridor pairs took 0.9 s instead of 0.03 s
(benchmarks/bench_gv_executor.py). The inliers do not depend on it (same matches, tested on the corridor).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from vpr_uncertainty.geometric import GeometricVerifier


def _blas_threads() -> list[int]:
    """Threads of NumPy's own BLAS (the one the matching uses; other libraries bring theirs, loaded at any time)."""
    return [
        pool["num_threads"]
        for pool in threadpool_info()
        if pool["user_api"] == "blas" and "numpy" in Path(pool["filepath"]).parent.name
    ]


@pytest.mark.parametrize("workers", [1, 2])
def test_matching_runs_with_one_blas_thread_and_the_caller_setting_comes_back(corridor_dir, workers):
    if not _blas_threads():
        pytest.skip("NumPy reports no BLAS library to limit")
    verifier = GeometricVerifier.from_preset("GV-SIFT", workers=workers)
    seen: list[list[int]] = []
    match = verifier.matcher.match

    def recording_match(*args, **kwargs):
        seen.append(_blas_threads())
        return match(*args, **kwargs)

    verifier.matcher.match = recording_match
    queries = sorted((corridor_dir / "query").glob("*.jpg"))[:3]
    database = sorted((corridor_dir / "ref").glob("*.jpg"))[:3]
    pairs = np.array([[0, 0], [1, 1], [2, 2]])
    with threadpool_limits(limits=2, user_api="blas"):
        limited = verifier.verify(queries, database, pairs).inliers
        assert set(_blas_threads()) == {2}  # the caller's setting is restored
    assert seen and all(set(threads) == {1} for threads in seen)
    assert limited.shape == (3,)
