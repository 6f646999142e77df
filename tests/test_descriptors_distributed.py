"""Extraction as Ray Data batch inference (descriptors/extract.py via ``stages.descriptors.extract``).

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
from vpr_uncertainty.descriptors.cache import cache_info, read_descriptors  # noqa: E402
from vpr_uncertainty.descriptors.images import ImageDecodeError  # noqa: E402
from vpr_uncertainty.pipeline.extract import ExtractConf, model_of  # noqa: E402
from vpr_uncertainty.pipeline.extract import compute as extract  # noqa: E402

N_IMAGES = 12


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
    return path, extract(ExtractConf(batch_size=4, progress=False), images, path)


def _fingerprint(path: Path) -> str:
    with h5py.File(path, "r") as handle:
        return str(handle.attrs["fingerprint"])


def test_ray_extraction_writes_the_local_artefact(ray_executor, images, local, tmp_path):
    local_path, expected = local
    path = tmp_path / "descriptors.h5"
    result = extract(ExtractConf(batch_size=4, progress=False), images, path, executor=ray_executor)
    assert _fingerprint(path) == _fingerprint(local_path)
    for split in ("database", "queries"):
        names, descriptors = result.split(split)
        np.testing.assert_array_equal(names, expected.names[split])
        assert_close(descriptors, expected.descriptors[split], rtol=1e-5, atol=1e-6)
    # the same retrieval: every query's ranking of the database
    ranking = np.argsort(-result.descriptors["queries"] @ result.descriptors["database"].T, axis=1, kind="stable")
    reference = np.argsort(-expected.descriptors["queries"] @ expected.descriptors["database"].T, axis=1, kind="stable")
    np.testing.assert_array_equal(ranking[:, 0], reference[:, 0])


def test_ray_extraction_resumes_and_sends_only_missing_images(ray_executor, images, local, tmp_path):
    _, expected = local
    paths, names = images["database"]
    path = tmp_path / "descriptors.h5"
    model = model_of(ExtractConf())
    extract_descriptors(model, paths[:5], names[:5], path, "database", batch_size=4, progress=False)
    sent: list[str] = []
    kept, descriptors = extract_descriptors(
        model, paths, names, path, "database", batch_size=4, progress=False, executor=ray_executor, on_batch=sent.extend
    )
    assert sorted(sent) == sorted(names[5:])
    np.testing.assert_array_equal(kept, names)
    assert_close(descriptors, expected.descriptors["database"], rtol=1e-5, atol=1e-6)


def _dying(model, marker: Path | None):
    """``model`` whose network ends its worker process (never this one): once when ``marker`` is given, else always.

    The network is a local function, so Ray pickles it by value with the real network and the marker path.
    """
    network, driver = model.network, os.getpid()

    def forward_or_die(images):
        if os.getpid() != driver and (marker is None or not marker.exists()):
            if marker is not None:
                marker.write_text(str(os.getpid()))
            os._exit(1)
        return network(images)

    model.network = forward_or_die
    return model


def test_a_killed_worker_loses_no_image(ray_executor, images, local, tmp_path):
    """The worker of the first batch dies in the model's forward; Ray restarts it, reruns the batch, nothing is lost."""
    _, expected = local
    paths, names = images["database"]
    marker = tmp_path / "killed"
    written: list[str] = []
    kept, descriptors = extract_descriptors(
        _dying(model_of(ExtractConf()), marker),
        paths,
        names,
        tmp_path / "d.h5",
        "database",
        batch_size=4,
        progress=False,
        executor=ray_executor,
        on_batch=written.extend,
    )
    assert int(marker.read_text()) != os.getpid()  # a worker process died, not this one
    assert sorted(written) == sorted(names)  # every image written exactly once
    np.testing.assert_array_equal(kept, names)
    assert_close(descriptors, expected.descriptors["database"], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(read_descriptors(tmp_path / "d.h5", "database")[0], names)


NOT_UTF8 = os.fsdecode(b"caf\xe9.jpg")  # Latin-1 bytes: Python's name for it holds a surrogate escape


@pytest.fixture
def unusable(images, tmp_path):
    """Corridor images with a garbage file first, a copy under a non-UTF-8 name and a truncated JPEG in between."""
    paths, _ = images["database"]
    garbage = tmp_path / "garbage.jpg"
    garbage.write_bytes(b"this is not an image")
    truncated = tmp_path / "truncated.jpg"
    truncated.write_bytes(paths[0].read_bytes()[:200])
    latin = tmp_path / NOT_UTF8
    latin.write_bytes(paths[1].read_bytes())
    return [garbage, *paths[:5], latin, *paths[5:9], truncated, *paths[9:]]


def test_unusable_images_are_skipped_and_recorded_as_locally(ray_executor, unusable, tmp_path):
    """on_error="skip": the same kept images, descriptors and ``failed`` attribute as the local run."""
    model = model_of(ExtractConf())
    results = {}
    for name, run_on in (("local", None), ("ray", ray_executor)):
        path = tmp_path / f"{name}.h5"
        with pytest.warns(UserWarning, match=r"left out 3 of 15 'database' images"):
            kept, descriptors = extract_descriptors(
                model,
                unusable,
                None,
                path,
                "database",
                batch_size=4,
                on_error="skip",
                progress=False,
                executor=run_on,
            )
        results[name] = kept, descriptors, cache_info(path)["database"]["failed"]
    np.testing.assert_array_equal(results["ray"][0], results["local"][0])
    assert_close(results["ray"][1], results["local"][1], rtol=1e-5, atol=1e-6)
    assert results["ray"][2] == results["local"][2]
    assert [entry["name"] for entry in results["ray"][2]] == ["garbage.jpg", NOT_UTF8, "truncated.jpg"]


def test_an_unusable_image_fails_as_locally(ray_executor, unusable, tmp_path):
    """on_error="fail": the same error (the first unusable image) and the same batches kept as the local run."""
    model = model_of(ExtractConf())
    paths = unusable[1:]  # the first unusable image is now the one with the non-UTF-8 name, in the second batch
    errors, counts = [], []
    for name, run_on in (("local", None), ("ray", ray_executor)):
        path = tmp_path / f"{name}.h5"
        with pytest.raises(ImageDecodeError, match="not valid UTF-8") as raised:
            extract_descriptors(model, paths, None, path, "database", batch_size=4, progress=False, executor=run_on)
        errors.append(str(raised.value))
        counts.append(cache_info(path)["database"]["count"])
    assert errors[0] == errors[1]
    assert counts == [4, 4]  # the batch before the bad image was kept


def test_a_batch_that_always_kills_its_worker_stops_the_run(ray_executor, images, tmp_path, monkeypatch):
    """A batch that kills every worker it reaches is retried TASK_RETRIES times, then the run stops with an error."""
    from vpr_uncertainty.descriptors import extract as distributed

    monkeypatch.setattr(distributed, "TASK_RETRIES", 1)
    paths, names = images["database"]
    with pytest.raises(distributed.WorkerDiedError, match=r"killed its Ray worker 2 times.*run again to resume"):
        extract_descriptors(
            _dying(model_of(ExtractConf()), None),
            paths[:4],
            names[:4],
            tmp_path / "d.h5",
            "database",
            batch_size=4,
            progress=False,
            executor=ray_executor,
        )


def test_missing_ray_data_names_the_extra(monkeypatch):
    import sys

    from vpr_uncertainty.descriptors import extract as distributed

    monkeypatch.setitem(sys.modules, "ray.data", None)
    with pytest.raises(ImportError, match=r"needs Ray Data: pip install 'vpr-uncertainty\[ray\]'"):
        distributed._import_ray_data()
