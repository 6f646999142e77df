"""Extraction on a pool of Ray actors (descriptors/distributed.py via ``stages.descriptors.extract``).

One local Ray cluster (2 CPUs) for the module. Real images: 12 database and 12 query images of the corridor, with
the offline default model; the reference is the local executor on the same images.
"""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import assert_close

pytest.importorskip("torch")
ray = pytest.importorskip("ray")

from vpr_uncertainty.descriptors import extract_descriptors  # noqa: E402
from vpr_uncertainty.executors import get_executor  # noqa: E402
from vpr_uncertainty.stages.descriptors import DescriptorsConfig, extract, model_of  # noqa: E402

N_IMAGES = 12


@pytest.fixture(scope="module")
def executor():
    # one authentication mode for every Ray test of the session (mixing them in a process breaks ray.init)
    os.environ["RAY_AUTH_MODE"] = "disabled"
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    with get_executor("ray", workers=2) as pool:
        yield pool
    ray.shutdown()


@pytest.fixture(scope="module")
def images(corridor_dir: Path) -> dict:
    splits = {}
    for split, folder in (("database", "ref"), ("queries", "query")):
        paths = sorted((corridor_dir / folder).glob("*.jpg"))[:N_IMAGES]
        splits[split] = (paths, [p.name for p in paths])
    return splits


@pytest.fixture(scope="module")
def local(images, tmp_path_factory):
    path = tmp_path_factory.mktemp("local") / "descriptors.h5"
    return path, extract(DescriptorsConfig(batch_size=4, progress=False), images, path)


def _fingerprint(path: Path) -> str:
    with h5py.File(path, "r") as handle:
        return str(handle.attrs["fingerprint"])


def test_ray_extraction_writes_the_local_artefact(executor, images, local, tmp_path):
    local_path, expected = local
    path = tmp_path / "descriptors.h5"
    result = extract(DescriptorsConfig(batch_size=4, progress=False), images, path, executor=executor)
    assert _fingerprint(path) == _fingerprint(local_path)
    for split in ("database", "queries"):
        names, descriptors = result.split(split)
        np.testing.assert_array_equal(names, expected.names[split])
        assert_close(descriptors, expected.descriptors[split], rtol=1e-5, atol=1e-6)
    # the same retrieval: every query's ranking of the database
    ranking = np.argsort(-result.descriptors["queries"] @ result.descriptors["database"].T, axis=1, kind="stable")
    reference = np.argsort(-expected.descriptors["queries"] @ expected.descriptors["database"].T, axis=1, kind="stable")
    np.testing.assert_array_equal(ranking[:, 0], reference[:, 0])


def test_ray_extraction_resumes_and_sends_only_missing_images(executor, images, local, tmp_path):
    _, expected = local
    paths, names = images["database"]
    path = tmp_path / "descriptors.h5"
    model = model_of(DescriptorsConfig())
    extract_descriptors(model, paths[:5], names[:5], path, "database", batch_size=4, progress=False)
    sent: list[str] = []
    kept, descriptors = extract_descriptors(
        model, paths, names, path, "database", batch_size=4, progress=False, executor=executor, on_batch=sent.extend
    )
    assert sorted(sent) == sorted(names[5:])
    np.testing.assert_array_equal(kept, names)
    assert_close(descriptors, expected.descriptors["database"], rtol=1e-5, atol=1e-6)


def test_a_killed_actor_loses_no_image(executor, images, local, tmp_path, monkeypatch):
    """The first actor dies while its batch runs; the batch is sent again to a fresh actor and nothing is lost."""
    from vpr_uncertainty.descriptors import distributed

    _, expected = local
    paths, names = images["database"]
    real = distributed.DescriptorActor.describe
    marker = tmp_path / "killed"

    def describe_or_die(self, batch):
        if not marker.exists():  # the first call anywhere kills its worker
            marker.touch()
            import os

            os._exit(1)
        return real(self, batch)

    monkeypatch.setattr(distributed.DescriptorActor, "describe", describe_or_die)
    kept, descriptors = extract_descriptors(
        model_of(DescriptorsConfig()),
        paths,
        names,
        tmp_path / "d.h5",
        "database",
        batch_size=4,
        progress=False,
        executor=executor,
    )
    assert marker.exists()
    np.testing.assert_array_equal(kept, names)
    assert_close(descriptors, expected.descriptors["database"], rtol=1e-5, atol=1e-6)
