"""Radius ground truth against a brute-force numpy reference, on real camera positions and on edge cases."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

from conftest import assert_close
from vpr_uncertainty.data import (
    detect_position_kind,
    latlon_to_utm,
    load_poses_dataset,
    positives_within_frames,
    positives_within_radius,
)


def brute_force_positives(queries: np.ndarray, database: np.ndarray, radius: float, chunk: int = 512) -> np.ndarray:
    """Dense (Q, D) reference: Euclidean distance <= radius, by a full distance matrix (chunked over queries)."""
    queries = np.asarray(queries, dtype=np.float64).reshape(len(queries), -1)
    database = np.asarray(database, dtype=np.float64).reshape(len(database), -1)
    mask = np.zeros((len(queries), len(database)), dtype=bool)
    for start in range(0, len(queries), chunk):
        block = queries[start : start + chunk]
        squared = np.zeros((len(block), len(database)))
        for axis in range(queries.shape[1]):
            squared += np.subtract.outer(block[:, axis], database[:, axis]) ** 2
        mask[start : start + chunk] = np.sqrt(squared) <= radius
    return mask


def assert_same_positives(actual: sparse.csr_array, expected: np.ndarray) -> None:
    assert isinstance(actual, sparse.csr_array)
    assert actual.dtype == bool
    assert actual.shape == expected.shape
    difference = np.argwhere(actual.toarray() != expected)
    assert difference.size == 0, f"{len(difference)} (query, database) pairs differ, first {difference[:5].tolist()}"


@pytest.fixture(scope="module")
def poses(data_dir: Path):
    def load(name: str) -> dict[str, np.ndarray]:
        path = data_dir / "poses" / f"{name}.npz"
        if not path.is_file():
            pytest.fail(f"{path} is missing from the real data")
        with np.load(path) as archive:
            return {key: archive[key] for key in archive.files}

    return load


def test_pitts30k_radius_matches_brute_force(poses) -> None:
    arrays = poses("pitts30k_test")
    assert arrays["utmQ"].shape == (6816, 2) and arrays["utmDb"].shape == (10000, 2)
    radius = float(arrays["posDistThr"])
    assert radius == 25
    positives = positives_within_radius(arrays["utmQ"], arrays["utmDb"], radius)
    assert_same_positives(positives, brute_force_positives(arrays["utmQ"], arrays["utmDb"], radius))
    # Pittsburgh has 24 views per place: every query has positives.
    assert np.diff(positives.indptr).min() > 0


def test_tokyo247_radius_matches_brute_force_on_a_subset_of_queries(poses) -> None:
    arrays = poses("tokyo247")
    assert arrays["utmDb"].shape == (75984, 2)
    rng = np.random.default_rng(0)
    subset = np.sort(rng.choice(len(arrays["utmQ"]), size=40, replace=False))
    positives = positives_within_radius(arrays["utmQ"], arrays["utmDb"], 25.0)
    assert positives.shape == (315, 75984)
    expected = brute_force_positives(arrays["utmQ"][subset], arrays["utmDb"], 25.0)
    assert_same_positives(positives[subset], expected)


@pytest.mark.parametrize("radius", [10.0, 3.0])
def test_nordland_euclidean_radius_matches_brute_force(poses, radius: float) -> None:
    arrays = poses("nordland")
    rng = np.random.default_rng(1)
    subset = np.sort(rng.choice(len(arrays["utmQ"]), size=300, replace=False))
    positives = positives_within_radius(arrays["utmQ"][subset], arrays["utmDb"], radius)
    assert_same_positives(positives, brute_force_positives(arrays["utmQ"][subset], arrays["utmDb"], radius))


def test_nordland_file_reads_as_frames_with_a_ten_frame_tolerance(data_dir: Path, poses) -> None:
    arrays = poses("nordland")
    assert detect_position_kind(arrays["utmDb"], arrays["utmQ"]) == "frames"
    dataset = load_poses_dataset(data_dir / "poses" / "nordland.npz")
    assert dataset.position_kind == "frames"
    assert dataset.positive_radius == 10
    rng = np.random.default_rng(2)
    subset = np.sort(rng.choice(dataset.n_queries, size=300, replace=False))
    frames_q, frames_db = arrays["utmQ"][subset, 0], arrays["utmDb"][:, 0]
    expected = np.abs(frames_q[:, None] - frames_db[None, :]) <= 10
    assert_same_positives(dataset.positives[subset], expected)
    # Patch-NetVLAD's Euclidean reading of the (i, i) points: only ±7 frames.
    euclidean = load_poses_dataset(data_dir / "poses" / "nordland.npz", position_kind="metres")
    middle = dataset.n_queries // 2
    assert dataset.positives[[middle]].nnz == 21
    assert euclidean.positives[[middle]].nnz == 15


def test_pitts_and_tokyo_positions_are_metres(poses) -> None:
    for name in ("pitts30k_test", "tokyo247"):
        arrays = poses(name)
        assert detect_position_kind(arrays["utmDb"], arrays["utmQ"]) == "metres"


def test_radius_is_inclusive_and_exact_at_the_boundary() -> None:
    queries = np.array([[0.0, 0.0], [1000.0, 1000.0]])
    # Pythagorean triples at exactly 25 m, and points just outside.
    database = np.array([[15.0, 20.0], [-7.0, 24.0], [25.0, 0.0], [25.0, 1e-3], [0.0, -25.000001], [1000.0, 1000.0]])
    positives = positives_within_radius(queries, database, 25)
    assert positives.toarray().tolist() == [
        [True, True, True, False, False, False],
        [False, False, False, False, False, True],
    ]


def test_random_positions_match_brute_force_for_several_radii() -> None:
    rng = np.random.default_rng(3)
    database = rng.uniform(0, 500, size=(2000, 2)).round(1)
    queries = np.concatenate([rng.uniform(-50, 550, size=(300, 2)).round(1), database[:20]])
    for radius in (0.0, 5.0, 25.0, 80.0):
        positives = positives_within_radius(queries, database, radius)
        assert_same_positives(positives, brute_force_positives(queries, database, radius))
        assert np.all(np.diff(positives.indices[positives.indptr[0] : positives.indptr[1]]) > 0)  # sorted


def test_queries_far_away_have_no_positives_and_empty_inputs_work() -> None:
    positives = positives_within_radius([[1e6, 1e6]], [[0.0, 0.0], [1.0, 1.0]])
    assert positives.shape == (1, 2) and positives.nnz == 0
    assert positives_within_radius(np.empty((0, 2)), [[0.0, 0.0]]).shape == (0, 1)
    assert positives_within_radius([[0.0, 0.0]], np.empty((0, 2))).shape == (1, 0)


def test_frame_tolerance() -> None:
    positives = positives_within_frames(np.arange(5), np.arange(8), tolerance=2)
    expected = np.abs(np.arange(5)[:, None] - np.arange(8)[None, :]) <= 2
    assert_same_positives(positives, expected)
    with pytest.raises(ValueError, match="1-D"):
        positives_within_frames(np.zeros((3, 2)), np.arange(4))


@pytest.mark.parametrize(
    ("queries", "database", "radius", "message"),
    [
        (np.zeros((2, 4)), np.zeros((3, 2)), 25, "shape"),
        (np.zeros((2, 2)), np.zeros((3, 3)), 25, "same number of coordinates"),
        (np.array([[0.0, np.nan]]), np.zeros((3, 2)), 25, "finite; row 0"),
        (np.zeros((2, 2)), np.zeros((3, 2)), -1, "non-negative"),
        (np.zeros((2, 2)), np.zeros((3, 2)), float("nan"), "non-negative"),
    ],
)
def test_invalid_inputs_say_what_is_wrong(queries, database, radius, message) -> None:
    with pytest.raises(ValueError, match=message):
        positives_within_radius(queries, database, radius)


def test_latlon_to_utm_matches_the_utm_package_and_keeps_one_zone(poses) -> None:
    utm = pytest.importorskip("utm")
    arrays = poses("pitts30k_test")
    easting, northing = arrays["utmDb"][:500, 0], arrays["utmDb"][:500, 1]
    latitude, longitude = utm.to_latlon(easting, northing, 17, "T")
    positions, zone, northern = latlon_to_utm(latitude, longitude)
    assert (zone, northern) == (17, True)
    assert_close(positions, arrays["utmDb"][:500], atol=1e-3)  # lat/lon back to UTM: 1 mm
    # Two points 170 m apart across the zone 17/18 boundary (78° W): one zone keeps the distance right.
    positions, zone, _ = latlon_to_utm([40.0, 40.0], [-78.001, -77.999])
    a, e2 = 6378137.0, 6.69437999014e-3  # WGS84: distance along the parallel, N(φ) cos φ Δλ
    along_parallel = a / np.sqrt(1 - e2 * np.sin(np.radians(40.0)) ** 2) * np.cos(np.radians(40.0)) * np.radians(0.002)
    assert_close(np.linalg.norm(positions[1] - positions[0]), along_parallel, rtol=1.5e-3)  # UTM scale
    with pytest.raises(ValueError, match="latitude must lie"):
        latlon_to_utm([91.0], [0.0])
