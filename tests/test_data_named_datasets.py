"""Named datasets, format detection, position files and the ``datasets`` command."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from vpr_uncertainty.data import (
    DATA_ROOT_VARIABLE,
    NAMED_DATASET_REGISTRY,
    detect_format,
    find_named_dataset,
    get_named_dataset,
    load_dataset,
    load_poses_dataset,
)

PAPER_DATASETS = {"pitts250k", "st_lucia", "nordland", "amstertime", "eynsham", "tokyo247"}


def touch(path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")


def make_st_lucia(root: Path, n: int = 5) -> Path:
    """A tiny St Lucia in the downloader's layout, 40 m between places (real Brisbane UTM, zone 56 J)."""
    split = root / "st_lucia" / "images" / "test"
    for i in range(n):
        east, north = 502000.0 + 40 * i, 6956000.0
        touch(split / "database" / f"@{east:.2f}@{north:.2f}@56@J@-27.50000@153.02000@db{i}@@@@@@@@@.jpg")
        touch(split / "queries" / f"@{east + 1:.2f}@{north:.2f}@56@J@-27.50000@153.02000@q{i}@@@@@@@@@.jpg")
    return split


@pytest.fixture(autouse=True)
def no_data_root(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(DATA_ROOT_VARIABLE, raising=False)


def test_the_six_datasets_of_the_paper_are_named() -> None:
    assert PAPER_DATASETS <= set(NAMED_DATASET_REGISTRY.names())  # and more (test_data_named_datasets_more.py)
    for entry in (get_named_dataset(name) for name in PAPER_DATASETS):
        assert entry.split == "test" and entry.relative_path == f"{entry.folder}/images/test"
        assert entry.n_database > 0 and entry.n_queries > 0 and entry.source
    nordland = get_named_dataset("nordland")
    assert nordland.frame_tolerance == 10 and nordland.position_kind == "frames"
    assert get_named_dataset("amstertime").position_kind == "placeholder"
    assert get_named_dataset("pitts250k").radius == 25 and get_named_dataset("tokyo247").n_queries == 315
    assert get_named_dataset("Tokyo 24/7".replace(" ", "")).name == "tokyo247"
    assert get_named_dataset("St-Lucia").name == "st_lucia"
    with pytest.raises(KeyError, match="named datasets: pitts250k"):
        get_named_dataset("oxford")


@pytest.mark.parametrize("name", sorted(PAPER_DATASETS))
def test_a_missing_dataset_says_where_to_get_it_and_where_to_put_it(tmp_path: Path, name: str) -> None:
    entry = get_named_dataset(name)
    with pytest.raises(FileNotFoundError) as error:
        load_dataset(name, root=tmp_path)
    message = str(error.value)
    assert str(tmp_path / entry.folder / "images" / "test") in message  # where it looked
    assert "VPR-datasets-downloader" in message and "github.com/gmberton" in message  # where to get it
    assert f"at {tmp_path / entry.folder}" in message  # where to put it
    with pytest.raises(FileNotFoundError, match=f"no data root is set.*{DATA_ROOT_VARIABLE}"):
        load_dataset(name)


def test_unknown_names_and_paths(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="neither an existing file or folder nor a named dataset"):
        load_dataset(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="not a dataset folder"):
        load_dataset(tmp_path / "empty")
    (tmp_path / "x.json").write_text("{}")
    with pytest.raises(ValueError, match="unknown dataset file type"):
        load_dataset(tmp_path / "x.json")


def test_named_dataset_found_under_the_root_the_environment_or_datasets(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    make_st_lucia(tmp_path / "a")
    with pytest.warns(UserWarning, match="standard test split has 1549 and 1464"):
        dataset = load_dataset("st_lucia", root=tmp_path / "a")
    assert dataset.name == "st_lucia" and dataset.split == "test" and dataset.position_kind == "metres"
    np.testing.assert_array_equal(dataset.positives.toarray(), np.eye(5, dtype=bool))  # 1 m off, places 40 m apart
    make_st_lucia(tmp_path / "b" / "datasets")
    monkeypatch.setenv(DATA_ROOT_VARIABLE, str(tmp_path / "b"))
    assert find_named_dataset("st_lucia") == tmp_path / "b" / "datasets" / "st_lucia" / "images" / "test"
    with pytest.warns(UserWarning, match="incomplete"):
        assert load_dataset("stlucia", radius=40).positives.nnz == 5 + 4  # 1 m and 39 m


def test_named_nordland_uses_frames_and_amstertime_placeholders(tmp_path: Path) -> None:
    spacing = 25 / 10.5
    for frame in range(30):
        for folder in ("database", "queries"):
            touch(tmp_path / "nordland/images/test" / folder / f"@0@{frame * spacing:07.1f}@@@@@{frame}@@@@@@@@.png")
    with pytest.warns(UserWarning, match="27592"):
        nordland = load_dataset("nordland", root=tmp_path)
    assert nordland.position_kind == "frames" and nordland.positive_radius == 10
    np.testing.assert_array_equal(nordland.database_positions[:, 0], np.arange(30))
    frames = np.arange(30)
    np.testing.assert_array_equal(nordland.positives.toarray(), np.abs(frames[:, None] - frames[None, :]) <= 10)
    with pytest.warns(UserWarning, match="27592"):
        assert load_dataset("nordland", root=tmp_path, radius=2).positives[[15]].nnz == 5

    for pair in range(4):
        for folder in ("database", "queries"):
            touch(tmp_path / "amstertime/images/test" / folder / f"@0@{pair * 100}@@@@@{pair:04d}@@@@@@@@.jpg")
    with pytest.warns(UserWarning, match="1231"):
        amstertime = load_dataset("amstertime", root=tmp_path)
    assert amstertime.position_kind == "placeholder"
    np.testing.assert_array_equal(amstertime.positives.toarray(), np.eye(4, dtype=bool))


def test_detect_format(tmp_path: Path, data_dir: Path, corridor_dir: Path) -> None:
    split = make_st_lucia(tmp_path)
    assert detect_format(tmp_path / "st_lucia") == "folder"
    assert detect_format(split) == "folder"
    assert detect_format(corridor_dir) == "vprbench"
    assert detect_format(data_dir / "poses" / "tokyo247.npz") == "poses"
    (tmp_path / "t.tsv").write_text("")
    assert detect_format(tmp_path / "t.tsv") == "table"


def test_position_files(data_dir: Path) -> None:
    pitts = load_dataset(data_dir / "poses" / "pitts30k_test.npz")
    assert pitts.source_format == "poses" and not pitts.has_images and pitts.database_names is None
    assert (pitts.n_queries, pitts.n_database, pitts.positive_radius) == (6816, 10000, 25)
    assert pitts.has_metric_positions and pitts.queries_without_positives.size == 0
    assert load_dataset(data_dir / "poses" / "pitts30k_test.npz", radius=5).positives.nnz < pitts.positives.nnz
    tokyo = load_poses_dataset(data_dir / "poses" / "tokyo247.npz")
    assert (tokyo.n_queries, tokyo.n_database, tokyo.position_kind) == (315, 75984, "metres")


def test_bad_position_files(tmp_path: Path) -> None:
    np.savez(tmp_path / "p.npz", utmQ=np.zeros((3, 2)))
    with pytest.raises(ValueError, match="missing utmDb"):
        load_poses_dataset(tmp_path / "p.npz")
    np.savez(tmp_path / "p.npz", utmQ=np.zeros((3, 3)), utmDb=np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"utmQ must have shape \(n, 2\)"):
        load_poses_dataset(tmp_path / "p.npz")
    np.savez(tmp_path / "p.npz", utmQ=[[0.0, 0.0]], utmDb=[[0.0, 20.0], [0.0, 30.0]])
    dataset = load_poses_dataset(tmp_path / "p.npz")  # no posDistThr: 25 m
    assert dataset.positive_radius == 25 and dataset.positives.toarray().tolist() == [[True, False]]


def run_command(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    from vpr_uncertainty.pipeline import datasets

    parser = argparse.ArgumentParser(prog="vpr-uncertainty")
    datasets.add_cli(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    assert args.handler(args) == 0
    return capsys.readouterr().out


def test_datasets_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    output = run_command(["datasets"], capsys)
    for name in PAPER_DATASETS:
        assert name in output
    assert "nordland/images/test" in output and "±10 frames" in output and "83,952" in output
    assert "download_st_lucia.py" in output and "presence not checked" in output

    make_st_lucia(tmp_path)
    output = run_command(["datasets", "--root", str(tmp_path)], capsys)
    lines = {line.split()[0]: line for line in output.splitlines() if line.strip()}
    assert lines["st_lucia"].rstrip().endswith("yes") and lines["eynsham"].rstrip().endswith("no")

    records = json.loads(run_command(["datasets", "--root", str(tmp_path), "--json", "-", "st_lucia", "tokyo"], capsys))
    assert [record["name"] for record in records["datasets"]] == ["st_lucia", "tokyo247"]
    assert records["datasets"][0]["found"] is True and records["datasets"][1]["found"] is False
    assert records["datasets"][0]["path"] == str(tmp_path / "st_lucia" / "images" / "test")


def test_a_missing_corridor_names_the_two_ways_to_give_the_data_root(monkeypatch, tmp_path, capsys):
    """Issue 45, item 7: ``run --dataset corridor`` without a data root said neither --root nor the variable."""
    from vpr_uncertainty.cli import main

    monkeypatch.delenv(DATA_ROOT_VARIABLE, raising=False)
    assert main(["run", "--dataset", "corridor", "--out", str(tmp_path / "r")]) == 2
    error = capsys.readouterr().err
    assert f"no data root is set (--root DIR or {DATA_ROOT_VARIABLE}: the folder holding vprbench/corridor)" in error
