"""The VPR-datasets-downloader folder format, on generated trees with real-looking names.

The positions in the names come from the real Pittsburgh30k camera positions, written the way the downloader
writes them (``util.get_dst_image_name``: easting/northing with 2 decimals, zone, band, latitude/longitude with
5 decimals, pano id, tile number, ...).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import assert_close
from test_data_positives import assert_same_positives, brute_force_positives
from vpr_uncertainty.data import (
    MalformedImageNameError,
    PlaceholderPositionsWarning,
    load_dataset,
    load_folder_dataset,
    parse_image_name,
)

utm = pytest.importorskip("utm")


def downloader_name(east: float, north: float, pano: str, tile: int, zone: int = 17, letter: str = "T") -> str:
    latitude, longitude = utm.to_latlon(east, north, zone, letter)
    return (
        f"@{east:010.2f}@{north:010.2f}@{zone:02d}@{letter}@{latitude:09.5f}@{longitude:010.5f}"
        f"@{pano}@{tile:02d}@@@@@@@.jpg"
    )


def touch(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    return path


@pytest.fixture(scope="module")
def pitts_positions(data_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    path = data_dir / "poses" / "pitts30k_test.npz"
    if not path.is_file():
        pytest.fail(f"{path} is missing from the real data")
    with np.load(path) as archive:
        database, queries = archive["utmDb"], archive["utmQ"]
    # One place in 24 views is enough: take unique places, a few hundred of them.
    database = np.unique(database, axis=0)[:300]
    queries = np.unique(queries, axis=0)[:80]
    return database, queries


@pytest.fixture
def pitts_tree(tmp_path: Path, pitts_positions) -> Path:
    database, queries = pitts_positions
    split = tmp_path / "pitts30k" / "images" / "test"
    rng = np.random.default_rng(0)
    for index, (east, north) in enumerate(database):
        # Two tiles per place, some in a sub-folder (the reader lists recursively).
        for tile in (0, 12):
            folder = split / "database" / ("sub" if index % 7 == 0 else "")
            touch(folder / downloader_name(east, north, f"pano{index:05d}", tile))
    for index, (east, north) in enumerate(queries):
        jitter = rng.normal(scale=0.5, size=2)
        touch(split / "queries" / downloader_name(east + jitter[0], north + jitter[1], f"q{index:05d}", 0))
    touch(split / "database" / "README.txt")
    touch(split / "queries" / ".DS_Store")
    return tmp_path / "pitts30k"


def test_parse_a_downloader_name() -> None:
    name = parse_image_name("@0584744.97@4476709.92@17@T@040.43672@-080.00082@00abcd@03@@@@@@@.jpg")
    assert (name.utm_east, name.utm_north) == (584744.97, 4476709.92)
    assert (name.utm_zone, name.utm_letter) == (17, "T")
    assert (name.latitude, name.longitude) == (40.43672, -80.00082)
    assert name.fields[6:8] == ("00abcd", "03")


def test_parse_names_with_dummy_positions() -> None:
    amstertime = parse_image_name("@0@200@@@@@2@@@@@@@@.jpg")
    assert (amstertime.utm_east, amstertime.utm_north, amstertime.utm_zone, amstertime.latitude) == (0, 200, None, None)
    nordland = parse_image_name("@0@00023.8@@@@@10@@@@@@@@.png")
    assert nordland.utm_north == 23.8


@pytest.mark.parametrize(
    ("file_name", "problem"),
    [
        ("IMG_0001.jpg", "does not start with '@'"),
        ("@584745.00.jpg", "at least UTM east and north"),
        ("@abc@4476710.00@17@T@040.43672@-080.00082@@.jpg", "UTM_east is 'abc'"),
        ("@584745.00@@17@T@040.43672@-080.00082@@.jpg", "UTM_north is ''"),
        ("@584745.00@nan@17@T@040.43672@-080.00082@@.jpg", "not a finite number"),
        ("@584745.00@4476710.00@99@T@040.43672@-080.00082@@.jpg", "UTM_zone is 99"),
        ("@584745.00@4476710.00@xx@T@040.43672@-080.00082@@.jpg", "UTM_zone is 'xx'"),
        ("@584745.00@4476710.00@17@I@040.43672@-080.00082@@.jpg", "UTM_letter is 'I'"),
        ("@584745.00@4476710.00@17@T@north@-080.00082@@.jpg", "latitude is 'north'"),
        ("@584745.00@4476710.00@17@T@140.0@-080.00082@@.jpg", "out of range"),
    ],
)
def test_malformed_names_give_an_error_naming_the_file(file_name: str, problem: str) -> None:
    with pytest.raises(MalformedImageNameError) as error:
        parse_image_name(Path("/data/pitts/queries") / file_name)
    message = str(error.value)
    assert file_name in message and problem in message and "@UTM_east@UTM_north" in message


def test_reads_the_tree_positions_names_and_positives(pitts_tree: Path, pitts_positions) -> None:
    database, queries = pitts_positions
    dataset = load_folder_dataset(pitts_tree)
    assert dataset.name == "pitts30k" and dataset.split == "test" and dataset.source_format == "folder"
    assert (dataset.n_database, dataset.n_queries) == (2 * len(database), len(queries))
    assert dataset.root == pitts_tree / "images" / "test"
    assert dataset.database_names == sorted(dataset.database_names)
    assert all(name.startswith("database/") for name in dataset.database_names)
    assert any(name.startswith("database/sub/@") for name in dataset.database_names)
    assert all(path.is_file() for path in dataset.database_paths + dataset.query_paths)
    assert dataset.position_kind == "metres" and dataset.positive_radius == 25
    assert dataset.info["utm_zone"] == 17
    # Positions are those of the names (2 decimals).
    expected = np.array([[parse_image_name(p).utm_east, parse_image_name(p).utm_north] for p in dataset.database_paths])
    np.testing.assert_array_equal(dataset.database_positions, expected)
    nearest = np.sqrt(((database[:, None, :] - dataset.database_positions[None, :, :]) ** 2).sum(-1)).min(axis=1)
    assert nearest.max() < 0.01  # every real place is in the tree, to the 2 decimals of the names
    reference = brute_force_positives(dataset.query_positions, dataset.database_positions, 25.0)
    assert_same_positives(dataset.positives, reference)
    assert dataset.n_positives.min() >= 2  # each query sits by its own place (2 tiles)


def test_radius_and_entry_points(pitts_tree: Path) -> None:
    split = pitts_tree / "images" / "test"
    small = load_folder_dataset(split, radius=5.0)
    assert small.positive_radius == 5 and small.name == "pitts30k"
    assert_same_positives(small.positives, brute_force_positives(small.query_positions, small.database_positions, 5))
    for root in (pitts_tree, pitts_tree / "images", split):
        assert load_dataset(root).database_names == small.database_names


def test_a_malformed_name_in_a_tree_names_the_file(pitts_tree: Path) -> None:
    bad = touch(pitts_tree / "images" / "test" / "queries" / "@584745.00@north@17@T@@@@.jpg")
    with pytest.raises(MalformedImageNameError, match=str(bad).replace("@", ".")):
        load_folder_dataset(pitts_tree)


def test_missing_folders_are_reported(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="database/ and queries/"):
        load_folder_dataset(tmp_path)
    (tmp_path / "images" / "val" / "database").mkdir(parents=True)
    (tmp_path / "images" / "val" / "queries").mkdir(parents=True)
    with pytest.raises(FileNotFoundError, match=r"splits found under .*: val"):
        load_folder_dataset(tmp_path, split="test")
    with pytest.raises(FileNotFoundError, match="no image"):
        load_folder_dataset(tmp_path, split="val")


def test_gallery_folder_of_older_exports(tmp_path: Path) -> None:
    touch(tmp_path / "images" / "test" / "gallery" / downloader_name(584745.0, 4476710.0, "a", 0))
    touch(tmp_path / "images" / "test" / "queries" / downloader_name(584750.0, 4476710.0, "b", 0))
    dataset = load_folder_dataset(tmp_path)
    assert dataset.database_names == [f"gallery/{downloader_name(584745.0, 4476710.0, 'a', 0)}"]
    assert dataset.positives.toarray().tolist() == [[True]]


def test_images_in_several_zones_are_reprojected_from_latitude_longitude(tmp_path: Path) -> None:
    # Two images 170 m apart on either side of the zone 17/18 boundary (78° W).
    split = tmp_path / "images" / "test"
    for folder, longitude in (("database", -78.001), ("queries", -77.999)):
        east, north, zone, letter = utm.from_latlon(40.0, longitude)
        touch(split / folder / f"@{east:.2f}@{north:.2f}@{zone}@{letter}@40.00000@{longitude:.5f}@@@@@@@@@.jpg")
    with pytest.warns(UserWarning, match="several UTM zones"):
        dataset = load_folder_dataset(tmp_path, radius=200)
    distance = np.linalg.norm(dataset.query_positions[0] - dataset.database_positions[0])
    assert_close(distance, 170.9, atol=1.0)
    assert dataset.positives.nnz == 1
    # Without latitude/longitude the zones cannot be reconciled.
    bad = touch(split / "queries" / "@500000.00@4400000.00@18@T@@@@@@@@@@@.jpg")
    with pytest.raises(ValueError, match="several UTM zones") as error:
        load_folder_dataset(tmp_path)
    assert str(bad) in str(error.value)


def test_amstertime_and_nordland_layouts_are_recognised_as_placeholders(tmp_path: Path) -> None:
    amstertime = tmp_path / "amstertime" / "images" / "test"
    for pair in range(6):
        for folder in ("database", "queries"):
            touch(amstertime / folder / f"@0@{pair * 100}@@@@@{pair:04d}@@@@@@@@.jpg")
    dataset = load_folder_dataset(tmp_path / "amstertime")
    assert dataset.position_kind == "placeholder"
    np.testing.assert_array_equal(dataset.positives.toarray(), np.eye(6, dtype=bool))
    with pytest.warns(PlaceholderPositionsWarning, match="placeholder positions, not metres"):
        dataset.metric_positions(purpose="SUE")

    nordland = tmp_path / "nordland" / "images" / "test"
    spacing = 25 / 10.5
    for frame in range(40):
        for folder in ("database", "queries"):
            touch(nordland / folder / f"@0@{frame * spacing:07.1f}@@@@@{frame}@@@@@@@@.png")
    dataset = load_folder_dataset(tmp_path / "nordland")
    assert dataset.position_kind == "placeholder"
    frames = np.array([parse_image_name(path).fields[6] for path in dataset.database_paths], dtype=int)
    query_frames = np.array([parse_image_name(path).fields[6] for path in dataset.query_paths], dtype=int)
    # 25 m on the dummy coordinates is ±10 frames.
    assert_same_positives(dataset.positives, np.abs(query_frames[:, None] - frames[None, :]) <= 10)
