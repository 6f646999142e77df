"""Dataset formats and named datasets are plugin entries / data (:mod:`vpr_uncertainty.data.formats`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty.data import Dataset, get_named_dataset, load_dataset
from vpr_uncertainty.data.formats import DATASET_FORMAT_REGISTRY, DatasetFormat, detect_format, register_format
from vpr_uncertainty.data.named_datasets import NAMED_DATASET_REGISTRY, read_named_datasets


def test_named_datasets_are_read_from_the_shipped_json():
    shipped = Path(__file__).parents[1] / "src" / "vpr_uncertainty" / "data" / "named_datasets.json"
    names = [record["name"] for record in json.loads(shipped.read_text())["datasets"]]
    assert NAMED_DATASET_REGISTRY.names() == names
    assert get_named_dataset("tokyo").source.endswith("(it fetches the queries)")  # aliases come from the records
    assert (
        "VPR-datasets-downloader (https://github.com/gmberton/VPR-datasets-downloader)"
        in get_named_dataset("st_lucia").source
    )  # the placeholder is filled in
    assert get_named_dataset("nordland").frame_spacing == pytest.approx(25 / 10.5, rel=1e-12)
    with pytest.raises(ValueError, match=r"record 0: unknown fields \['radios'\]"):
        read_named_datasets(json.dumps({"datasets": [{"name": "x", "radios": 3}]}))
    with pytest.raises(KeyError, match="did you mean 'st_lucia'"):
        get_named_dataset("st_lucai")


def _read_pairs(path: Path, **_: object) -> Dataset:
    return Dataset(name=path.stem, root=path.parent, positives=sparse.csr_array(np.ones((1, 1), bool)))


def test_a_new_dataset_format_is_one_registration(tmp_path):
    assert DATASET_FORMAT_REGISTRY.names() == ["poses", "table", "vprbench", "folder"]
    (tmp_path / "mine.pairs").write_text("q0 d0\n")
    with pytest.raises(ValueError, match=r"unknown dataset file type '\.pairs'"):
        detect_format(tmp_path / "mine.pairs")
    register_format(DatasetFormat("pairs", "test", ".pairs (pairs)", f"{__name__}:_read_pairs", suffixes=(".pairs",)))
    try:
        assert detect_format(tmp_path / "mine.pairs") == "pairs"
        assert load_dataset(tmp_path / "mine.pairs").name == "mine"
    finally:
        DATASET_FORMAT_REGISTRY.unregister("pairs")
