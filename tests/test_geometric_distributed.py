"""Geometric verification on Ray: local features and pairs as tasks in chunks (geometric/cache.py and verify.py).

One local Ray cluster (2 CPUs) for the module. Real images: GV-SIFT on 8 corridor queries against 3 database
images each; the reference is the same verifier in this process.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cv2")
ray = pytest.importorskip("ray")

from vpr_uncertainty.geometric import GeometricVerifier  # noqa: E402


def test_pairs_on_ray_equal_the_local_verification_and_features_are_cached_once(ray_executor, corridor_dir, tmp_path):
    queries = sorted((corridor_dir / "query").glob("*.jpg"))[:8]
    database = sorted((corridor_dir / "ref").glob("*.jpg"))[:10]
    pairs = [(q, (q + shift) % len(database)) for q in range(len(queries)) for shift in (0, 1, 5)]
    local = GeometricVerifier.from_preset("GV-SIFT", cache_dir=tmp_path, workers=1)
    expected = local.verify(queries, database, pairs)
    distributed = GeometricVerifier.from_preset("GV-SIFT", cache_dir=tmp_path, workers=1)
    distributed.executor = ray_executor
    result = distributed.verify(queries, database, pairs)
    np.testing.assert_array_equal(result.inliers, expected.inliers)  # integers: exactly the same
    np.testing.assert_array_equal(result.matches, expected.matches)
    assert result.extraction.cached == len(queries) + len(database)  # read from the local run's cache: no re-extraction
    assert expected.inliers.max() > 0
    assert len(list(Path(tmp_path).glob("*.h5"))) == 1


def test_local_features_extracted_on_ray_equal_the_local_ones_and_are_cached_by_the_driver(
    ray_executor, corridor_dir, tmp_path
):
    from conftest import assert_close
    from vpr_uncertainty.geometric.cache import extract_features

    paths = sorted((corridor_dir / "ref").glob("*.jpg"))[:11]  # 11 images: chunks of 2 (4 per worker), one odd
    extractor = GeometricVerifier.from_preset("GV-SIFT").extractor
    expected, _ = extract_features(paths, extractor, workers=1)
    features, stats = extract_features(paths, extractor, cache_dir=tmp_path / "ray", executor=ray_executor)
    assert (stats.extracted, stats.cached) == (len(paths), 0)
    assert sorted(features) == sorted(expected)
    for name, result in features.items():
        assert_close(result.keypoints, expected[name].keypoints)
        assert_close(result.descriptors, expected[name].descriptors)
        np.testing.assert_array_equal(result.image_size, expected[name].image_size)
    _, again = extract_features(paths, extractor, cache_dir=tmp_path / "ray")  # the driver wrote every chunk
    assert (again.extracted, again.cached) == (0, len(paths))


def test_imap_yields_every_position_once_as_tasks_complete(ray_executor):
    from vpr_uncertainty.executors import LocalExecutor

    assert sorted(ray_executor.imap(abs, [-4, 3, -2, 1, 0])) == [(0, 4), (1, 3), (2, 2), (3, 1), (4, 0)]
    assert list(LocalExecutor().imap(abs, [-1, -2])) == [(0, 1), (1, 2)]
    with pytest.raises(ValueError, match="invalid literal"):
        list(ray_executor.imap(int, ["1", "x", "2"]))
