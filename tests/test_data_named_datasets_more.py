"""`datasets` lists the corridor when present and more of the field's datasets, each with where to get it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from vpr_uncertainty.cli import main
from vpr_uncertainty.data import load_dataset
from vpr_uncertainty.data.named_datasets import (
    CORRIDOR_URL,
    NAMED_DATASET_REGISTRY,
    corridor_files,
    ensure_corridor,
    find_named_dataset,
    get_named_dataset,
)


def test_the_fields_datasets_are_named_with_where_to_get_them():
    assert {"pitts30k", "msls", "sf_xl", "corridor"} <= set(NAMED_DATASET_REGISTRY.names())
    assert (get_named_dataset("pitts30k").n_database, get_named_dataset("pitts30k").n_queries) == (10_000, 6_816)
    assert "mapillary.com/dataset/places" in get_named_dataset("msls").source
    assert "account" in get_named_dataset("msls").source  # stated honestly: it needs registration
    assert "on request" in get_named_dataset("sf_xl").source and "CosPlace" in get_named_dataset("sf_xl").source
    assert "download_pitts30k.py" in get_named_dataset("pitts30k").source
    assert get_named_dataset("Mapillary_SLS").name == "msls"


def test_the_corridor_is_listed_as_present_under_the_data_root(corridor_dir, capsys):
    root = corridor_dir.parent.parent
    assert main(["datasets", "--root", str(root), "--json", "-"]) == 0
    records = {record["name"]: record for record in json.loads(capsys.readouterr().out)["datasets"]}
    assert records["corridor"]["found"] is True and records["corridor"]["path"] == str(corridor_dir)
    assert records["pitts30k"]["found"] is False


def test_the_corridor_loads_by_name(corridor_dir):
    dataset = load_dataset("corridor", root=corridor_dir.parent.parent)
    assert (dataset.n_database, dataset.n_queries) == (111, 111)


def test_where_to_get_the_corridor_names_downloadable_files(tmp_path):
    source = get_named_dataset("corridor").source
    assert f"{CORRIDOR_URL}/ground_truth_new.npy" in source and ".zip" in source
    assert find_named_dataset("corridor", tmp_path) is None
    with pytest.raises(FileNotFoundError) as error:
        ensure_corridor(tmp_path, download=False)
    message = str(error.value)
    # every address the message gives is a file or an archive, not a folder
    assert f"{CORRIDOR_URL}/ground_truth_new.npy" in message and f"{CORRIDOR_URL}/query/0000000.jpg" in message
    assert f"from {CORRIDOR_URL})" not in message and "archive/" in message
    assert "query/0000000.jpg" in corridor_files()


def test_a_downloader_version_without_images_folder_is_found(tmp_path: Path):
    for split in ("database", "queries"):
        (tmp_path / "msls" / "val" / split).mkdir(parents=True)
        (tmp_path / "msls" / "val" / split / "@1.0@2.0@33@U@@@@@@@@@@@.jpg").write_bytes(b"")
    assert find_named_dataset("msls", tmp_path) == tmp_path / "msls" / "val"
