"""The stage spine and its caches on the real corridor images: no stale result, per-image resume, rebuilds.

Each test copies the corridor dataset into its tmp_path, changes it the way a user would (images replaced, the
ground truth edited, a cache cut short), reruns into the same run folder and compares with a fresh run into an
empty folder: the independent reference of what the answer must be.
"""

from __future__ import annotations

import json
import os
import shutil
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty.cache import CacheWarning
from vpr_uncertainty.pipeline.evaluate import EvaluateConf
from vpr_uncertainty.pipeline.extract import ExtractConf

pytest.importorskip("torch")
pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")


@pytest.fixture
def corridor_copy(corridor_dir: Path, tmp_path: Path) -> Path:
    folder = tmp_path / "corridor"
    shutil.copytree(corridor_dir, folder)
    return folder


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory) -> Path:
    """A TorchScript model that pools each image to a 4 x 4 grid of colours (48-D): fast on a shared CPU."""
    import torch

    class Grid(torch.nn.Module):
        def forward(self, images: torch.Tensor) -> torch.Tensor:
            return torch.nn.functional.adaptive_avg_pool2d(images, 4).flatten(1)

    file = tmp_path_factory.mktemp("model") / "grid.pt"
    torch.jit.script(Grid()).save(str(file))
    return file


MODEL: list[Path] = []


@pytest.fixture(autouse=True)
def _use_tiny_model(tiny_model):
    MODEL[:] = [tiny_model]


def run(dataset: Path, out: Path):
    from vpr_uncertainty.pipeline.run import RunConf, run

    conf = RunConf(extract=ExtractConf(model=str(MODEL[0]), batch_size=64), evaluate=EvaluateConf(methods=["SU", "RS"]))
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=DeprecationWarning)  # torch.jit.load
        return run(conf, dataset, out)


def forwarded(monkeypatch) -> list[int]:
    from vpr_uncertainty.descriptors import extract

    counted: list[int] = []
    original = extract._forward

    def counting(model, images):
        counted.append(len(images))
        return original(model, images)

    monkeypatch.setattr(extract, "_forward", counting)
    return counted


def assert_same_result(stale, fresh) -> None:
    np.testing.assert_array_equal(stale.retrieval.indices, fresh.retrieval.indices)
    assert_close(stale.retrieval.scores, fresh.retrieval.scores)
    assert stale.evaluation.recall_at_n[1] == fresh.evaluation.recall_at_n[1]
    assert (stale.retrieval.positives != fresh.retrieval.positives).nnz == 0
    for name in fresh.evaluation.methods:
        assert_close(stale.evaluation.methods[name].uncertainty, fresh.evaluation.methods[name].uncertainty)


def test_replaced_query_images_are_recomputed_and_nothing_else(corridor_copy, tmp_path, monkeypatch):
    """Regression: the descriptor cache was keyed by image name only; replaced queries kept their old descriptors
    (R@1 stayed 0.604 where a fresh run gives 0.045) while results.json named the new data."""
    out = tmp_path / "run"
    before = run(corridor_copy, out)
    queries = sorted((corridor_copy / "query").iterdir())
    contents = [path.read_bytes() for path in queries]
    for position, path in enumerate(queries):  # every query now shows the place of another query
        path.write_bytes(contents[(position + 9) % len(queries)])
    counted = forwarded(monkeypatch)
    stale = run(corridor_copy, out)
    assert sum(counted) == len(queries)  # exactly the replaced images went through the model; no database image
    fresh = run(corridor_copy, tmp_path / "fresh")
    assert_same_result(stale, fresh)
    assert stale.evaluation.recall_at_n[1] != before.evaluation.recall_at_n[1]
    written = json.loads((out / "results.json").read_text())
    assert written["recall@1"] == fresh.evaluation.recall_at_n[1]


def test_another_dataset_with_the_same_names_is_not_mixed(corridor_copy, tmp_path, monkeypatch):
    other = tmp_path / "other"
    shutil.copytree(corridor_copy, other)
    database = sorted((other / "ref").iterdir())
    first, second = database[0].read_bytes(), database[60].read_bytes()
    database[0].write_bytes(second)
    database[60].write_bytes(first)
    out = tmp_path / "run"
    run(corridor_copy, out)
    counted = forwarded(monkeypatch)
    stale = run(other, out)
    assert sum(counted) == 2  # the two swapped database images, nothing else
    assert_same_result(stale, run(other, tmp_path / "fresh"))


def test_edited_ground_truth_recomputes_the_retrieval(corridor_copy, tmp_path):
    """Regression: retrieval.npz was reused after the ground truth changed (R@1 0.604 instead of 0.396)."""
    out = tmp_path / "run"
    before = run(corridor_copy, out)
    file = corridor_copy / "ground_truth_new.npy"
    rows = np.load(file, allow_pickle=True, encoding="latin1")  # our own copy of the real file
    for row in rows[:40]:
        row[1] = [index + 3 for index in row[1]]  # positives moved three frames on
    np.save(file, rows, allow_pickle=True)
    stale = run(corridor_copy, out)
    fresh = run(corridor_copy, tmp_path / "fresh")
    assert_same_result(stale, fresh)
    assert stale.evaluation.recall_at_n[1] < before.evaluation.recall_at_n[1]


def test_unchanged_inputs_reuse_every_cache(corridor_copy, tmp_path, monkeypatch):
    out = tmp_path / "run"
    first = run(corridor_copy, out)
    stamps = {name: (out / name).stat().st_mtime_ns for name in ("retrieval.npz",)}
    counted = forwarded(monkeypatch)
    again = run(corridor_copy, out)
    assert counted == [] and {name: (out / name).stat().st_mtime_ns for name in stamps} == stamps
    assert_same_result(again, first)


def test_truncated_caches_are_reported_in_one_line_and_rebuilt(corridor_copy, tmp_path):
    """Regression: a truncated descriptors.h5 was called "open for writing in another process (HDF5 file lock)"
    ("lock" matched inside "sblock"), and a truncated retrieval.npz made every rerun crash."""
    out = tmp_path / "run"
    first = run(corridor_copy, out)
    for name in ("descriptors.h5", "retrieval.npz"):
        data = (out / name).read_bytes()
        (out / name).write_bytes(data[: len(data) // 3])
    with pytest.warns(CacheWarning) as caught:
        again = run(corridor_copy, out)
    notices = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    assert len(notices) == 2 and all("\n" not in notice and "truncated" in notice for notice in notices)
    assert not any("another process" in notice or "file lock" in notice for notice in notices)
    assert_same_result(again, first)
    (out / "retrieval.npz").write_bytes(b"")
    with pytest.warns(CacheWarning, match="retrieval.npz"):
        assert_same_result(run(corridor_copy, out), first)


def test_caches_of_the_previous_version_are_rebuilt_with_a_notice(corridor_copy, tmp_path, monkeypatch):
    out = tmp_path / "run"
    first = run(corridor_copy, out)
    with h5py.File(out / "descriptors.h5", "a") as handle:  # the layout of version 1: no content keys
        handle.attrs["format_version"] = 1
        handle.attrs["fingerprint"] = handle.attrs["config"]
        for split in ("database", "queries"):
            del handle[split]["keys"]
    from vpr_uncertainty.retrieval import load_retrieval, save_retrieval

    retrieval = load_retrieval(out / "retrieval.npz")
    retrieval.config.pop("fingerprint")
    save_retrieval(retrieval, out / "retrieval.npz")
    with pytest.warns(CacheWarning) as caught:
        again = run(corridor_copy, out)
    notices = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    assert any("descriptors.h5" in n and "earlier version" in n for n in notices)
    assert any("retrieval.npz" in n and "earlier version" in n for n in notices)
    assert_same_result(again, first)


def test_results_json_is_written_once_and_never_read_back(corridor_copy, tmp_path, monkeypatch):
    """Regression: results.json was written, read back and rewritten (stage seconds, re-ranking summary)."""
    real_read_text = Path.read_text

    def no_read_back(self, *args, **kwargs):
        assert self.name != "results.json", "results.json was read back"
        return real_read_text(self, *args, **kwargs)

    monkeypatch.setattr(Path, "read_text", no_read_back)
    result = run(corridor_copy, tmp_path / "run")
    monkeypatch.setattr(Path, "read_text", real_read_text)
    document = json.loads((tmp_path / "run" / "results.json").read_text())
    assert document["stage_seconds"] == pytest.approx(result.stage_seconds)
    assert set(document["stage_seconds"]) >= {"dataset", "extraction", "retrieval", "reports"}


def test_stages_compose_without_the_pipeline(corridor_copy, tmp_path):
    """The stage functions, composed by hand, give the pipeline's answer and return their artefacts' paths."""
    from vpr_uncertainty.data import load_dataset
    from vpr_uncertainty.pipeline.evaluate import compute as evaluate
    from vpr_uncertainty.pipeline.extract import compute as extract
    from vpr_uncertainty.pipeline.retrieve import RetrieveConf
    from vpr_uncertainty.pipeline.retrieve import compute as search

    dataset = load_dataset(corridor_copy)
    images = {
        "database": (dataset.database_paths, dataset.database_names),
        "queries": (dataset.query_paths, dataset.query_names),
    }
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=DeprecationWarning)  # torch.jit.load
        descriptors = extract(ExtractConf(model=MODEL[0], progress=False), images, tmp_path / "d.h5")
    assert descriptors.path == tmp_path / "d.h5" and descriptors.path.is_file()
    fields = dataset.retrieval_fields()
    ground_truth = {key: fields[key] for key in ("positives", "query_names", "database_names")}
    found = search(
        RetrieveConf(top_k=20),
        descriptors.split("database"),
        descriptors.split("queries"),
        ground_truth,
        tmp_path / "r.npz",
    )
    assert found.path.is_file() and not found.reused
    assert search(
        RetrieveConf(top_k=20), descriptors.split("database"), descriptors.split("queries"), ground_truth, found.path
    ).reused
    uncertainty = evaluate(EvaluateConf(methods=["SU", "RS"]), found.retrieval, tmp_path / "u.npz")
    with np.load(uncertainty.path) as stored:
        assert str(stored["fingerprint"]) == uncertainty.fingerprint
        assert_close(stored["SU"], uncertainty.evaluation.methods["SU"].uncertainty)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        piped = run(corridor_copy, tmp_path / "run")
    np.testing.assert_array_equal(found.retrieval.indices, piped.retrieval.indices)
    assert uncertainty.evaluation.recall_at_n[1] == piped.evaluation.recall_at_n[1]


def test_a_retrieval_npz_changed_on_disk_is_refused_and_rebuilt(corridor_copy, tmp_path):
    """One score of retrieval.npz changed (every field still valid, the fingerprint kept) was reused silently."""
    from vpr_uncertainty.retrieval import load_retrieval

    out = tmp_path / "run"
    first = run(corridor_copy, out)
    path = out / "retrieval.npz"
    arrays = dict(np.load(path, allow_pickle=False))
    arrays["scores"] = arrays["scores"].copy()
    arrays["scores"][0, 0] += 0.01  # still sorted, still a valid file
    stat = path.stat()
    np.savez_compressed(path, **arrays)
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    with pytest.raises(ValueError, match="does not match the checksum stored with it"):
        load_retrieval(path)
    with pytest.warns(CacheWarning, match=r"retrieval\.npz.*checksum"):
        again = run(corridor_copy, out)
    assert_same_result(again, first)
    load_retrieval(path)  # rebuilt: verifies again


def test_each_stage_module_has_hlocs_shape():
    """Every stage module holds its configuration, a default of it, main(conf, ..., out) and add_cli."""
    import dataclasses
    import inspect

    from vpr_uncertainty.pipeline import evaluate, extract, grid, retrieve, run

    for module in (extract, retrieve, evaluate, run):
        assert dataclasses.is_dataclass(module.default_conf) and module.default_conf.__dataclass_params__.frozen
        parameters = list(inspect.signature(module.main).parameters)
        assert parameters[0] == "conf" and "out" in parameters, module.__name__
    for module in (extract, retrieve, evaluate, run, grid):
        assert callable(module.add_cli) and callable(module.main)
