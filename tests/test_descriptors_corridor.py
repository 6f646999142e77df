"""The offline default model on the real VPR-Bench corridor images (111 queries, 111 database images)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import assert_close

torch = pytest.importorskip("torch")
pytest.importorskip("efficientnet_lite_pytorch")

from vpr_uncertainty.descriptors import (  # noqa: E402
    DEFAULT_MODEL,
    cache_info,
    extract_descriptors,
    load_model,
    read_descriptors,
)
from vpr_uncertainty.formats.ground_truth import load_vprbench_ground_truth  # noqa: E402

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def model():
    # One intra-op thread: on a shared 2-core machine two OpenMP threads that wait for each other at every
    # layer were measured 9x slower (4.7 vs 41 images/s); alone on the machine, two are about 1.5x faster.
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield load_model(DEFAULT_MODEL)
    torch.set_num_threads(previous)


@pytest.fixture(scope="module")
def corridor_descriptors(corridor_dir: Path, model, tmp_path_factory):
    cache = tmp_path_factory.mktemp("corridor") / "descriptors.h5"
    result = {}
    for split, folder in (("queries", "query"), ("database", "ref")):
        paths = sorted((corridor_dir / folder).glob("*.jpg"))
        result[split] = extract_descriptors(model, paths, None, cache, split, batch_size=8, progress=False)
    return cache, result


def test_default_model_descriptors_are_finite_unit_vectors(corridor_descriptors):
    cache, result = corridor_descriptors
    for split in ("queries", "database"):
        names, descriptors = result[split]
        assert descriptors.shape == (111, 1280) and descriptors.dtype == np.float32
        assert np.isfinite(descriptors).all()
        assert_close(np.linalg.norm(descriptors, axis=1), 1.0)
        assert list(names) == [f"{i:07d}.jpg" for i in range(111)]
        read_names, read = read_descriptors(cache, split)
        assert list(read_names) == list(names)
        np.testing.assert_array_equal(read, descriptors)
    info = cache_info(cache)
    assert info["model"] == DEFAULT_MODEL
    assert info["config"]["weights"].startswith("efficientnet-lite0-57934424.pth:sha256:57934424")


def test_default_model_recall_at_1_well_above_chance(corridor_descriptors, corridor_dir):
    _, result = corridor_descriptors
    queries, database = result["queries"][1], result["database"][1]
    positives = load_vprbench_ground_truth(corridor_dir / "ground_truth_new.npy", n_database=111).toarray()
    top1 = (queries @ database.T).argmax(axis=1)
    recall_at_1 = positives[np.arange(111), top1].mean()
    chance = positives.sum(axis=1).mean() / 111  # about 0.045: ~5 positives among 111 images
    assert recall_at_1 > 0.4 > 8 * chance, recall_at_1  # measured: 0.60


def test_rerun_on_complete_cache_computes_nothing(corridor_descriptors, corridor_dir, model):
    cache, result = corridor_descriptors
    batches = []
    paths = sorted((corridor_dir / "ref").glob("*.jpg"))
    _names, descriptors = extract_descriptors(model, paths, None, cache, "database", on_batch=batches.append)
    assert batches == []
    np.testing.assert_array_equal(descriptors, result["database"][1])


def test_corrupt_image_among_real_ones(corridor_dir, model, tmp_path):
    paths = sorted((corridor_dir / "query").glob("*.jpg"))[:3]
    bad = tmp_path / "0000999.jpg"
    bad.write_bytes(paths[0].read_bytes()[:300])  # a truncated JPEG
    with pytest.raises(ValueError, match=r"cannot use image '0000999\.jpg'"):
        extract_descriptors(model, [*paths, bad], None, progress=False)
    with pytest.warns(UserWarning, match=r"0000999\.jpg"):
        names, descriptors = extract_descriptors(model, [bad, *paths], None, on_error="skip", progress=False)
    assert list(names) == [p.name for p in paths] and descriptors.shape == (3, 1280)
