"""CSV/TSV datasets: image paths with positions in metres or latitude/longitude."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import assert_close
from test_data_positives import assert_same_positives, brute_force_positives
from vpr_uncertainty.data import load_dataset, load_table_dataset

utm = pytest.importorskip("utm")


@pytest.fixture(scope="module")
def pitts_places(data_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    path = data_dir / "poses" / "pitts30k_test.npz"
    if not path.is_file():
        pytest.fail(f"{path} is missing from the real data")
    with np.load(path) as archive:
        return np.unique(archive["utmDb"], axis=0)[:200], np.unique(archive["utmQ"], axis=0)[:50]


def write_latlon_csv(path: Path, database: np.ndarray, queries: np.ndarray) -> None:
    lines = ["image,role,latitude,longitude"]
    for role, positions, folder in (("database", database, "db"), ("query", queries, "q")):
        latitude, longitude = utm.to_latlon(positions[:, 0], positions[:, 1], 17, "T")
        lines += [
            f"{folder}/{i:04d}.jpg,{role},{lat:.8f},{lon:.8f}"
            for i, (lat, lon) in enumerate(zip(latitude, longitude, strict=True))
        ]
    path.write_text("\n".join(lines) + "\n")


def test_csv_with_latitude_longitude(tmp_path: Path, pitts_places) -> None:
    database, queries = pitts_places
    table = tmp_path / "pitts.csv"
    write_latlon_csv(table, database, queries)
    dataset = load_table_dataset(table)
    assert (dataset.n_database, dataset.n_queries) == (200, 50)
    assert dataset.name == "pitts" and dataset.source_format == "table" and dataset.root == tmp_path
    assert dataset.database_names[:2] == ["db/0000.jpg", "db/0001.jpg"] and dataset.query_names[0] == "q/0000.jpg"
    assert dataset.database_paths[0] == tmp_path / "db" / "0000.jpg"
    assert dataset.info["unit"] == "latlon" and dataset.info["utm_zone"] == 17
    # Projected back to the original UTM positions (8 decimals of a degree ≈ 1 mm).
    assert_close(dataset.database_positions, database, atol=0.01)  # 8 decimals of a degree, UTM round trip
    assert_close(dataset.query_positions, queries, atol=0.01)
    assert dataset.position_kind == "metres" and dataset.positive_radius == 25
    assert_same_positives(
        dataset.positives, brute_force_positives(dataset.query_positions, dataset.database_positions, 25)
    )
    assert dataset.positives.nnz > 0
    assert load_dataset(table, radius=50).positive_radius == 50


def test_tsv_in_metres_with_a_separate_query_table(tmp_path: Path, pitts_places) -> None:
    database, queries = pitts_places
    (tmp_path / "database.tsv").write_text(
        "path\teasting\tnorthing\n"
        + "".join(f"db/{i}.png\t{float(x)!r}\t{float(y)!r}\n" for i, (x, y) in enumerate(database))
    )
    (tmp_path / "queries.tsv").write_text(
        "path\teasting\tnorthing\n"
        + "".join(f"q/{i}.png\t{float(x)!r}\t{float(y)!r}\n" for i, (x, y) in enumerate(queries))
    )
    dataset = load_dataset(tmp_path / "database.tsv", queries=tmp_path / "queries.tsv", name="pitts")
    assert dataset.name == "pitts"
    np.testing.assert_array_equal(dataset.database_positions, database)  # repr() of a float parses back exactly
    np.testing.assert_array_equal(dataset.query_positions, queries)
    assert_same_positives(dataset.positives, brute_force_positives(queries, database, 25))


def test_absolute_paths_and_root(tmp_path: Path) -> None:
    table = tmp_path / "tables" / "t.csv"
    table.parent.mkdir()
    table.write_text(f"path,role,x,y\n{tmp_path}/img/a.jpg,db,0,0\nimg/b.jpg,query,3,4\n")
    dataset = load_table_dataset(table, root=tmp_path, radius=5)
    assert dataset.database_paths == [tmp_path / "img" / "a.jpg"]
    assert dataset.database_names == ["img/a.jpg"] and dataset.query_names == ["img/b.jpg"]
    assert dataset.positives.toarray().tolist() == [[True]]


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("", "is empty"),
        ("x,y\n1,2\n", "no image path column"),
        ("path,role,height\na.jpg,db,3\n", "no position columns"),
        ("path,role,x,y\na.jpg,db,1,2\nb.jpg,query,north,2\n", r"t.csv:3: position 'north' is not a number"),
        ("path,role,x,y\na.jpg,db,1,2\nb.jpg,train,1,2\n", r"t.csv:3: role 'train' is neither database nor query"),
        ("path,role,x,y\na.jpg,db,1\n", r"t.csv:2: expected at least 4 columns"),
        ("path,role,x,y\n\na.jpg,db,1,2\n\nb.jpg,query,1,\n", r"t.csv:5: position '' is not a number"),
        ("path,x,y\na.jpg,1,2\n", "no role column"),
        ("path,role,x,y\na.jpg,db,1,2\n", "no query image"),
        ("path,role,lat,lon\na.jpg,db,95,2\nb.jpg,q,1,2\n", "latitude must lie"),
    ],
)
def test_bad_tables_say_what_is_wrong(tmp_path: Path, content: str, message: str) -> None:
    (tmp_path / "t.csv").write_text(content)
    with pytest.raises(ValueError, match=message):
        load_table_dataset(tmp_path / "t.csv")


def test_mixed_units_between_tables_are_rejected(tmp_path: Path) -> None:
    (tmp_path / "db.csv").write_text("path,x,y\na.jpg,0,0\n")
    (tmp_path / "q.csv").write_text("path,lat,lon\nb.jpg,40.4,-80.0\n")
    with pytest.raises(ValueError, match="same kind"):
        load_table_dataset(tmp_path / "db.csv", queries=tmp_path / "q.csv")
