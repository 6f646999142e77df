"""Geometric verification without the real data: matching, RANSAC, hloc-layout cache, GV-H5, re-ranking."""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty import Retrieval, get_method
from vpr_uncertainty.cache import CacheWarning
from vpr_uncertainty.geometric import (
    GeometricVerifier,
    LocalFeatures,
    count_inliers,
    extract_features,
    gv_h5,
    gv_sift,
    image_names,
    match_nearest_neighbors,
    read_features,
    rerank,
    rerank_by_inliers,
    write_features,
)
from vpr_uncertainty.geometric.cache import cache_path

cv2 = pytest.importorskip("cv2")


# --- synthetic images ----------------------------------------------------------------------------------------

HOMOGRAPHY = np.array([[0.95, 0.06, 12.0], [-0.04, 1.02, 6.0], [1e-4, 5e-5, 1.0]])


def _texture(seed: int, shape: tuple[int, int] = (240, 320)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    image = np.zeros(shape, np.uint8)
    for _ in range(120):
        center = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
        axes = (int(rng.integers(3, 25)), int(rng.integers(3, 25)))
        color = int(rng.integers(40, 256))
        cv2.ellipse(image, center, axes, float(rng.uniform(0, 180)), 0, 360, color, -1)
    return cv2.GaussianBlur(image, (3, 3), 0)


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[Path]]:
    """Two queries; database 0 = query 0 seen under a homography, database 1 = another place, 2 = blank."""
    root = tmp_path_factory.mktemp("scene")
    (root / "query").mkdir()
    (root / "db").mkdir()
    first, other = _texture(0), _texture(1)
    warped = cv2.warpPerspective(first, HOMOGRAPHY, (first.shape[1], first.shape[0]))
    images = {
        "query/0.png": first,
        "query/1.png": other,
        "db/0.png": warped,
        "db/1.png": _texture(2),
        "db/2.png": np.full_like(first, 128),
    }
    for name, image in images.items():
        cv2.imwrite(str(root / name), image)
    return {
        "query": [root / "query/0.png", root / "query/1.png"],
        "database": [root / "db/0.png", root / "db/1.png", root / "db/2.png"],
    }


def _retrieval(indices: list[list[int]]) -> Retrieval:
    indices = np.asarray(indices)
    scores = np.linspace(1.0, 0.5, indices.shape[1])[None].repeat(len(indices), 0).astype(np.float32)
    scores[indices < 0] = -np.inf  # a missing candidate: index -1 and score -inf
    return Retrieval(scores=scores, indices=indices)


# --- matching --------------------------------------------------------------------------------------------------


def _reference_matches(d0: np.ndarray, d1: np.ndarray, ratio: float | None, mutual: bool) -> set[tuple[int, int]]:
    result = set()
    for i, row in enumerate(d0):
        distances = np.sqrt(((d1 - row) ** 2).sum(axis=1))
        order = np.argsort(distances, kind="stable")
        j = int(order[0])
        if ratio is not None and not distances[j] < ratio * distances[order[1]]:
            continue
        if mutual and int(np.argmin(np.sqrt(((d0 - d1[j]) ** 2).sum(axis=1)))) != i:
            continue
        result.add((i, j))
    return result


@pytest.mark.parametrize(("ratio", "mutual"), [(0.8, True), (0.9, False), (None, True)])
def test_nearest_neighbours_match_the_loop_reference(ratio: float | None, mutual: bool) -> None:
    rng = np.random.default_rng(3)
    d0 = rng.normal(size=(60, 16))
    d1 = np.concatenate([d0[:30] + rng.normal(scale=0.05, size=(30, 16)), rng.normal(size=(40, 16))])
    found = {tuple(pair) for pair in match_nearest_neighbors(d0, d1, ratio=ratio, mutual=mutual).tolist()}
    assert found == _reference_matches(d0, d1, ratio, mutual)
    assert {(i, i) for i in range(30)} <= found


def test_nearest_neighbours_with_empty_or_single_descriptors() -> None:
    assert match_nearest_neighbors(np.zeros((0, 8)), np.ones((5, 8))).shape == (0, 2)
    assert match_nearest_neighbors(np.ones((5, 8)), np.ones((1, 8))).shape == (0, 2)  # no second neighbour
    with pytest.raises(ValueError, match="same D"):
        match_nearest_neighbors(np.ones((2, 8)), np.ones((2, 4)))


# --- RANSAC ----------------------------------------------------------------------------------------------------


def test_ransac_counts_the_points_of_the_homography() -> None:
    rng = np.random.default_rng(0)
    points0 = rng.uniform(0, 300, size=(120, 2))
    projected = cv2.perspectiveTransform(points0[None], HOMOGRAPHY)[0] + rng.normal(scale=0.3, size=(120, 2))
    points1 = np.concatenate([projected[:80], rng.uniform(0, 300, size=(40, 2))])
    inliers = count_inliers(points0, points1, seed=1)
    assert 78 <= inliers <= 84  # the 80 true matches, perhaps a lucky outlier or two
    assert count_inliers(points0, points1, seed=1) == inliers
    assert 78 <= count_inliers(points0, points1, model="fundamental", seed=1) <= 90


def test_ransac_degenerate_inputs_give_zero() -> None:
    assert count_inliers(np.zeros((3, 2)), np.zeros((3, 2))) == 0
    assert count_inliers(np.ones((10, 2)), np.ones((10, 2))) in range(11)  # all identical: no crash
    with pytest.raises(ValueError, match="model"):
        count_inliers(np.zeros((5, 2)), np.zeros((5, 2)), model="affine")


# --- features, names and the hloc-layout cache -------------------------------------------------------------------


def test_image_names_are_relative_to_the_common_folder() -> None:
    assert image_names(["/d/query/a.jpg", "/d/ref/sub/b.jpg"]) == ["query/a.jpg", "ref/sub/b.jpg"]
    assert image_names(["/d/q/a.jpg"]) == ["a.jpg"]


def test_working_resolution_round_trip() -> None:
    features = LocalFeatures.from_working(
        np.array([[0.0, 0.0], [319.0, 239.0]]), np.ones((2, 4)), None, original_size=(640, 480), working_size=(320, 240)
    )
    assert_close(features.keypoints, [[0.5, 0.5], [638.5, 478.5]])
    keypoints, size = features.at_working_resolution(320)
    assert size == (320, 240)
    assert_close(keypoints, [[0.0, 0.0], [319.0, 239.0]], atol=1e-5)
    assert features.at_working_resolution(1024)[1] == (640, 480)  # never enlarged


def test_hloc_layout_round_trip(tmp_path: Path) -> None:
    features = LocalFeatures(np.array([[1.0, 2.0], [3.0, 4.0], [5, 6]]), np.arange(12.0).reshape(3, 4), None, (64, 48))
    with h5py.File(tmp_path / "f.h5", "w") as handle:
        write_features(handle, "query/a.jpg", features)
        assert handle["query/a.jpg/descriptors"].shape == (4, 3)  # hloc stores (D, N)
        # a file written by another tool: (N, D) float16 descriptors, no scores, no image size
        group = handle.create_group("b.jpg")
        group["keypoints"] = features.keypoints
        group["descriptors"] = features.descriptors.astype(np.float16)
    back = read_features(tmp_path / "f.h5", "query/a.jpg")
    np.testing.assert_array_equal(back.descriptors, features.descriptors)
    np.testing.assert_array_equal(back.image_size, [64, 48])
    square = LocalFeatures(np.zeros((4, 2)), np.arange(16.0).reshape(4, 4), None, (8, 8))  # N == D
    with h5py.File(tmp_path / "f.h5", "a") as handle:
        write_features(handle, "square.jpg", square)
    np.testing.assert_array_equal(read_features(tmp_path / "f.h5", "square.jpg").descriptors, square.descriptors)
    other = read_features(tmp_path / "f.h5", "b.jpg")
    assert other.descriptors.shape == (3, 4) and other.descriptors.dtype == np.float32
    with pytest.raises(KeyError, match="names look like"):
        read_features(tmp_path / "f.h5", "missing.jpg")


def test_cache_is_reused_and_invalidated(scene: dict[str, list[Path]], tmp_path: Path) -> None:
    from vpr_uncertainty.geometric.local_features import SIFTExtractor

    paths = scene["query"] + scene["database"]
    extractor = SIFTExtractor(max_side=320)
    first, stats = extract_features(paths, extractor, cache_dir=tmp_path, workers=2)
    assert (stats.extracted, stats.cached) == (5, 0)
    again, stats = extract_features(paths, extractor, cache_dir=tmp_path, workers=2)
    assert (stats.extracted, stats.cached) == (0, 5)
    for name in first:
        np.testing.assert_array_equal(first[name].descriptors, again[name].descriptors)
        np.testing.assert_array_equal(first[name].keypoints, again[name].keypoints)
    assert len(again["db/2.png"]) == 0  # the blank image, cached as zero keypoints
    # another configuration writes another file; a changed image is extracted again
    _, stats = extract_features(paths, SIFTExtractor(max_side=160), cache_dir=tmp_path)
    assert stats.extracted == 5 and len(list(tmp_path.glob("sift-*.h5"))) == 2
    stamp = os.stat(paths[0]).st_mtime_ns
    os.utime(paths[0], ns=(stamp, stamp + 10**9))
    _, stats = extract_features(paths, extractor, cache_dir=tmp_path)
    assert (stats.extracted, stats.cached) == (1, 4)
    with h5py.File(cache_path(tmp_path, extractor), "r") as handle:
        assert set(handle.keys()) == {"query", "db"}
        assert '"max_side": 320' in handle.attrs["config"]


def test_a_corrupt_cache_file_is_extracted_again(scene: dict[str, list[Path]], tmp_path: Path) -> None:
    from vpr_uncertainty.geometric.local_features import SIFTExtractor

    extractor = SIFTExtractor(max_side=160)
    cache_path(tmp_path, extractor).write_bytes(b"not hdf5: a run killed while writing")
    with pytest.warns(CacheWarning, match="unreadable"):
        _, stats = extract_features(scene["query"], extractor, cache_dir=tmp_path, workers=1)
    assert stats.extracted == 2
    _, stats = extract_features(scene["query"], extractor, cache_dir=tmp_path, workers=1)
    assert stats.cached == 2


def test_features_changed_on_disk_are_extracted_again(scene: dict[str, list[Path]], tmp_path: Path) -> None:
    """One keypoint of a cached image edited in place (the file's size kept) was used silently (issue 20 row 1)."""
    from vpr_uncertainty.geometric.local_features import SIFTExtractor

    extractor = SIFTExtractor(max_side=160)
    first, _ = extract_features(scene["query"], extractor, cache_dir=tmp_path, workers=1)
    name = next(name for name, features in first.items() if len(features))
    with h5py.File(cache_path(tmp_path, extractor), "r+") as handle:
        handle[name]["keypoints"][0, 0] += 5.0
    with pytest.warns(CacheWarning, match=r"features of 1 image\(s\) do not match their checksum"):
        again, stats = extract_features(scene["query"], extractor, cache_dir=tmp_path, workers=1)
    assert (stats.extracted, stats.cached) == (1, len(first) - 1)
    np.testing.assert_array_equal(again[name].keypoints, first[name].keypoints)
    _, stats = extract_features(scene["query"], extractor, cache_dir=tmp_path, workers=1)
    assert stats.extracted == 0  # rewritten with its checksum


def test_deferred_writes_read_the_cache_and_leave_the_writing_to_the_driver(
    scene: dict[str, list[Path]], tmp_path: Path
) -> None:
    """Inside ``deferred_writes`` (a grid cell run as a Ray task) the cache is read and never written; the features
    come back to the caller, whose ``store_features`` writes them: the same file a direct extraction writes."""
    from vpr_uncertainty.geometric.cache import deferred_writes, store_features
    from vpr_uncertainty.geometric.local_features import SIFTExtractor

    paths = scene["query"] + scene["database"]
    extractor = SIFTExtractor(max_side=320)
    direct, _ = extract_features(paths, extractor, cache_dir=tmp_path / "direct", workers=1)
    names = image_names(paths)
    extract_features(paths[:2], extractor, names=names[:2], cache_dir=tmp_path / "task", workers=1)  # 2 cached
    file = cache_path(tmp_path / "task", extractor)
    before = file.read_bytes()
    with deferred_writes() as pending:
        first, stats = extract_features(paths, extractor, cache_dir=tmp_path / "task", workers=1)
        assert (stats.extracted, stats.cached) == (3, 2)
        _, stats = extract_features(paths[2:], extractor, names=names[2:], cache_dir=tmp_path / "task", workers=1)
        assert (stats.extracted, stats.cached) == (0, 3)  # kept in memory for the rest of the task
    assert file.read_bytes() == before  # not written inside the context
    assert [len(entry.features) for entry in pending] == [3] and pending[0].path == file
    assert store_features([pending, pending]) == 3  # an image two tasks extracted is written once
    again, stats = extract_features(paths, extractor, cache_dir=tmp_path / "task", workers=1)
    assert (stats.extracted, stats.cached) == (0, 5)
    for name in direct:
        for features in (first[name], again[name]):
            np.testing.assert_array_equal(features.keypoints, direct[name].keypoints)
            np.testing.assert_array_equal(features.descriptors, direct[name].descriptors)
    for entry in pending:  # a cache that cannot be written (here: a folder in its place) is one notice, not an error
        entry.path = tmp_path / "blocked" / entry.path.name
        entry.path.mkdir(parents=True)
    with pytest.warns(CacheWarning) as notices:
        assert store_features([pending]) == 0
    assert "not written" in str(notices[-1].message)


# --- the GV methods ------------------------------------------------------------------------------------------------


def test_gv_sift_on_a_homography_blank_and_unrelated_image(scene: dict[str, list[Path]], tmp_path: Path) -> None:
    retrieval = _retrieval([[0, 1, 2], [2, 0, 1]])
    paths = {"query_paths": scene["query"], "database_paths": scene["database"]}
    uncertainty = gv_sift(retrieval, **paths, cache_dir=tmp_path, workers=2)
    assert uncertainty.shape == (2,) and uncertainty.dtype == np.float64
    assert uncertainty[0] <= -30  # the same place under a homography
    assert uncertainty[1] == 0  # the blank database image: 0 inliers, no crash
    # the registry passes the options through and drops the ones it does not take
    method = get_method("GV-SIFT")
    np.testing.assert_array_equal(method(retrieval, **paths, cache_dir=tmp_path, k=10, alpha=0.5), uncertainty)
    unrelated = gv_sift(_retrieval([[1], [-1]]), **paths, cache_dir=tmp_path)
    assert unrelated[0] > -8 and unrelated[1] == 0  # another place: few inliers; no candidate: 0


def test_gv_methods_say_they_need_images() -> None:
    retrieval = _retrieval([[0, 1]])
    for name in ("GV-SIFT", "GV-DISK-LG", "GV-XFEAT", "GV-SP-SG", "GV-SP-LG"):
        with pytest.raises(ValueError, match="needs the query and database image files"):
            get_method(name)(retrieval)
    with pytest.raises(ValueError, match="query_paths holds 2 images but the results have 1 queries"):
        gv_sift(retrieval, query_paths=["q.jpg", "r.jpg"], database_paths=["d.jpg"])
    with pytest.raises(ValueError, match="database_paths holds 1 images but the results have at least 2 database"):
        gv_sift(_retrieval([[1, 0]]), query_paths=["q.jpg"], database_paths=["d.jpg"])
    with pytest.raises(ValueError, match=r"cannot read image .*q\.jpg: it does not exist"):
        gv_sift(retrieval, query_paths=["q.jpg"], database_paths=["d.jpg", "e.jpg"])
    with pytest.raises(ValueError, match="features_path"):
        gv_h5(retrieval)


def test_gv_h5_verifies_features_written_by_another_tool(scene: dict[str, list[Path]], tmp_path: Path) -> None:
    """Features stored in hloc's layout (as hloc.extract_features writes them) give the same inliers as GV-SIFT."""
    from vpr_uncertainty.geometric.local_features import SIFTExtractor

    paths = scene["query"] + scene["database"]
    names = image_names(paths)
    features, _ = extract_features(paths, SIFTExtractor(), workers=1)
    h5_path = tmp_path / "feats-sift.h5"
    with h5py.File(h5_path, "w") as handle:
        for name in names:
            group = handle.create_group(name)
            group["keypoints"] = features[name].keypoints
            group["descriptors"] = features[name].descriptors.T.astype(np.float16)  # hloc's as_half
            group["scores"] = features[name].scores
            group["image_size"] = features[name].image_size
    retrieval = _retrieval([[0, 1], [1, 0]])
    paths_kw = {"query_paths": scene["query"], "database_paths": scene["database"]}
    from_file = gv_h5(retrieval, features_path=h5_path, **paths_kw, workers=1)
    direct = gv_sift(retrieval, **paths_kw, workers=1)
    assert from_file[0] <= -30
    np.testing.assert_allclose(from_file, direct, atol=2)  # float16 descriptors may flip a borderline match
    # without paths: the retrieval's names
    named = Retrieval(
        scores=retrieval.scores,
        indices=retrieval.indices,
        query_names=np.array(names[:2]),
        database_names=np.array(names[2:]),
    )
    np.testing.assert_array_equal(get_method("GV-H5")(named, features_path=h5_path, workers=1), from_file)


# --- re-ranking ---------------------------------------------------------------------------------------------------


def test_rerank_by_inliers_is_stable_and_keeps_missing_last() -> None:
    indices = np.array([[4, 7, 9, 1, 2], [3, -1, -1, -1, -1]])
    inliers = np.array([[3, 10, 3, 50], [0, 0, 0, 0]])
    np.testing.assert_array_equal(rerank_by_inliers(indices, inliers), [[1, 7, 4, 9, 2], [3, -1, -1, -1, -1]])
    with pytest.raises(ValueError, match="cover"):
        rerank_by_inliers(indices[:, :2], inliers)


def test_rerank_moves_the_verified_place_to_the_top(scene: dict[str, list[Path]]) -> None:
    from scipy import sparse

    retrieval = _retrieval([[1, 2, 0], [1, 0, 2]])
    retrieval.positives = sparse.csr_array(np.array([[True, False, False], [False, True, False]]))
    verifier = GeometricVerifier.from_preset("GV-SIFT", workers=2)
    result = rerank(retrieval, verifier, top_k=3, query_paths=scene["query"], database_paths=scene["database"])
    assert result.indices[0, 0] == 0 and result.inliers.shape == (2, 3)
    assert result.recall["global"][1] == 0.5 and result.recall["reranked"][1] >= 0.5
    assert result.uncertainty.shape == (2,)
