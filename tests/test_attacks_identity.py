"""Issue 28, rows 1-6 and 11, written as the attacks: what the user changes (their method, their model, their images,
a file their config names, a row of a half-written cache, their network) must be part of what a cached result is
keyed by, so the rerun recomputes instead of returning last run's numbers. Each test fails on the code before the
fix. Everything is written under tmp_path; the CLI runs as a new process, as a user's rerun does.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from vpr_uncertainty import cache
from vpr_uncertainty.cache import CacheWarning

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")

_ENTROPY = """
import numpy as np
from vpr_uncertainty.methods import register_method

def entropy(retrieval, *, k=10):
    s = retrieval.scores[:, :k]
    p = np.exp(s - s.max(1, keepdims=True))
    p /= p.sum(1, keepdims=True)
    return SIGN * (p * np.log(p)).sum(1)

register_method("ENT", entropy, description="entropy of the top-k softmax")
"""

_HELPER = "SIGN = {sign}\n"


def _cli(folder: Path, *args: str) -> subprocess.CompletedProcess:
    """``vpr-uncertainty ARGS`` as a new process in ``folder`` (plugins importable from it, as with PYTHONPATH=.)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(folder), os.environ.get("PYTHONPATH", "")])}
    command = [sys.executable, "-m", "vpr_uncertainty.cli", *args]
    return subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True, timeout=300, check=False)


def _auc(results: Path, method: str) -> float:
    (cell,) = json.loads(results.read_text())["cells"]
    return cell["methods"][method]["auc_pr"]


@pytest.fixture
def grid_folder(tmp_path: Path, corridor_dir: Path, corridor_matches_dir: Path) -> Path:
    """A folder with a one-cell grid on the real NetVLAD corridor matrix (``grid.toml`` names ``methods``)."""
    shutil.copy(corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy", tmp_path / "netvlad.npy")
    shutil.copy(corridor_dir / "ground_truth_new.npy", tmp_path / "gt.npy")
    return tmp_path


def _write_grid(folder: Path, methods: str, extra: str = "") -> Path:
    path = folder / "grid.toml"
    path.write_text(
        f'out = "out"\nmethods = {methods}\nalphas = [0.5]\nks = [5]\n[[inputs]]\nvpr_method = "NetVLAD"\n'
        f'dataset = "corridor"\nscores = "netvlad.npy"\nground_truth = "gt.npy"\n{extra}'
    )
    return path


# --- row 1: the user edits their plugin method (or a module it imports) and reruns reproduce ---------------------


def test_editing_a_plugin_method_recomputes_the_cell(grid_folder):
    (grid_folder / "ent.py").write_text("from ent_helper import SIGN\n" + _ENTROPY)
    (grid_folder / "ent_helper.py").write_text(_HELPER.format(sign=1))
    config = _write_grid(grid_folder, '["SU", "ENT"]')
    first = _cli(grid_folder, "--plugin", "ent", "reproduce", str(config), "--no-report")
    assert first.returncode == 0, first.stderr
    before = _auc(grid_folder / "out" / "results.json", "ENT")

    (grid_folder / "ent_helper.py").write_text(_HELPER.format(sign=-1))  # the edit is in a module the plugin imports
    second = _cli(grid_folder, "--plugin", "ent", "reproduce", str(config), "--no-report")
    assert second.returncode == 0, second.stderr
    assert "read from the cache" not in second.stdout
    after = _auc(grid_folder / "out" / "results.json", "ENT")
    assert after != pytest.approx(before, abs=1e-6)

    third = _cli(grid_folder, "--plugin", "ent", "reproduce", str(config), "--no-report")
    assert "1 of 1 cells read from the cache" in third.stdout  # unchanged code: the cell is reused
    assert _auc(grid_folder / "out" / "results.json", "ENT") == after


def test_a_plugin_that_replaces_su_does_not_share_cells_with_the_built_in(grid_folder):
    (grid_folder / "my_su.py").write_text(
        "from vpr_uncertainty.methods import register_method\n"
        "def su(retrieval, *, k=10, alpha=0.5):\n    return -retrieval.scores[:, 0]\n"
        'register_method("SU", su, description="mine", overwrite=True, options={"k": 10, "alpha": 0.5})\n'
    )
    config = _write_grid(grid_folder, '["SU"]')
    builtin = _cli(grid_folder, "reproduce", str(config), "--no-report")
    assert builtin.returncode == 0, builtin.stderr
    su_builtin = _auc(grid_folder / "out" / "results.json", "SU")
    plugin = _cli(grid_folder, "--plugin", "my_su", "reproduce", str(config))
    assert "read from the cache" not in plugin.stdout
    assert _auc(grid_folder / "out" / "results.json", "SU") != pytest.approx(su_builtin, abs=1e-6)
    assert "SU is my_su's method" in plugin.stdout  # Table 1 says whose SU it is
    again = _cli(grid_folder, "reproduce", str(config), "--no-report")  # and back: the built-in's numbers
    assert "read from the cache" not in again.stdout
    assert _auc(grid_folder / "out" / "results.json", "SU") == pytest.approx(su_builtin, abs=1e-12)


# --- row 4: a file a method option names in a config is relative to the config, not to the working folder -------


def test_a_gate_named_in_a_config_is_read_beside_the_config(grid_folder, tmp_path_factory):
    from vpr_uncertainty.calibration import calibrate
    from vpr_uncertainty.data import read_results

    retrieval = read_results(grid_folder / "netvlad.npy", ground_truth=grid_folder / "gt.npy")
    calibrate(retrieval.subset_queries(np.arange(0, 111, 2))).save(grid_folder / "gate.json")
    config = _write_grid(grid_folder, '["SU", "CAL:gate=gate.json"]')
    elsewhere = tmp_path_factory.mktemp("elsewhere")
    calibrate(retrieval.subset_queries(np.arange(1, 60)), features=("s1",)).save(elsewhere / "gate.json")

    from_elsewhere = _cli(elsewhere, "reproduce", str(config), "--no-report")
    assert from_elsewhere.returncode == 0, from_elsewhere.stderr
    (cell,) = json.loads((grid_folder / "out" / "results.json").read_text())["cells"]
    (name,) = [name for name in cell["methods"] if name.startswith("CAL")]
    assert str(grid_folder / "gate.json") in name  # the config's gate, whatever the working folder holds
    shutil.rmtree(grid_folder / "out")
    beside = _cli(grid_folder, "reproduce", "grid.toml", "--no-report")
    assert beside.returncode == 0, beside.stderr
    assert _auc(grid_folder / "out" / "results.json", name) == cell["methods"][name]["auc_pr"]


# --- row 3: a results file with images: the images are keyed by name and content ------------------------------


def test_replacing_query_images_of_a_results_cell_recomputes_its_verification(grid_folder, corridor_dir):
    pytest.importorskip("cv2")
    images = grid_folder / "corridor"
    shutil.copytree(corridor_dir, images)
    config = _write_grid(grid_folder, '["SU", "GV-SIFT"]', 'images = "corridor"\n')
    first = _cli(grid_folder, "reproduce", str(config), "--no-report")
    assert first.returncode == 0, first.stderr
    before = _auc(grid_folder / "out" / "results.json", "GV-SIFT")

    queries = sorted((images / "query").iterdir())
    for index, path in enumerate(queries[: len(queries) // 2]):  # half the queries replaced by other images
        shutil.copy(queries[-1 - index], path)
    second = _cli(grid_folder, "reproduce", str(config), "--no-report")
    assert second.returncode == 0, second.stderr
    assert "read from the cache" not in second.stdout
    assert _auc(grid_folder / "out" / "results.json", "GV-SIFT") != pytest.approx(before, abs=1e-6)

    shutil.copy(queries[0], images / "query" / "stray.jpg")  # a stray image: refused on every run, not only the first
    third = _cli(grid_folder, "reproduce", str(config), "--no-report")
    assert third.returncode != 0 and "holds 112 images" in third.stderr


# --- row 2: the user's registered model changes (its weights_id) ---------------------------------------------


_MODEL_PLUGIN = """
from vpr_uncertainty.descriptors import Preprocessing
from vpr_uncertainty.descriptors.models import DescriptorModel, ModelSpec, register_model

WEIGHTS = "{weights}"

def _network(scale):
    import torch
    return lambda images: torch.cat([images.mean(dim=(2, 3)), scale * images.std(dim=(2, 3))], dim=1)

def load(spec, *, device="cpu"):
    scale = 1.0 if WEIGHTS == "v1" else 5.0
    return DescriptorModel(spec.name, _network(scale), spec.preprocessing, weights_id=WEIGHTS).to(device)

register_model(ModelSpec(name="tiny-stats", description="channel statistics", descriptor_dim=6, backbone="none",
                         preprocessing=Preprocessing(), loader=load, identify=lambda spec: WEIGHTS))
"""


def test_a_changed_plugin_model_recomputes_the_cell(tmp_path, corridor_dir):
    pytest.importorskip("torch")
    (tmp_path / "tiny.py").write_text(_MODEL_PLUGIN.format(weights="v1"))
    config = tmp_path / "grid.toml"
    config.write_text(
        f'out = "out"\nmethods = ["SU"]\nalphas = [0.5]\nks = [5]\n[[inputs]]\ndataset = "{corridor_dir}"\n'
        'model = "tiny-stats"\n'
    )
    first = _cli(tmp_path, "--plugin", "tiny", "reproduce", str(config), "--no-report")
    assert first.returncode == 0, first.stderr
    before = _auc(tmp_path / "out" / "results.json", "SU")
    (tmp_path / "tiny.py").write_text(_MODEL_PLUGIN.format(weights="v2"))
    second = _cli(tmp_path, "--plugin", "tiny", "reproduce", str(config), "--no-report")
    assert second.returncode == 0, second.stderr
    assert "read from the cache" not in second.stdout
    assert _auc(tmp_path / "out" / "results.json", "SU") != pytest.approx(before, abs=1e-6)


# --- row 5: a row of a half-written descriptor file is edited before the run resumes -------------------------


def _tiny_images(folder: Path, count: int = 6) -> tuple[list[Path], list[str]]:
    image = pytest.importorskip("PIL.Image")
    rng = np.random.default_rng(0)
    folder.mkdir()
    paths = []
    for i in range(count):
        path = folder / f"img{i:02d}.png"
        image.fromarray(rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)).save(path)
        paths.append(path)
    return paths, [path.name for path in paths]


def _stats_model(**attributes):
    torch = pytest.importorskip("torch")
    from vpr_uncertainty.descriptors import Preprocessing
    from vpr_uncertainty.descriptors.models import from_callable

    class Stats(torch.nn.Module):
        scale = 1.0

        def forward(self, images):
            return torch.cat([images.mean(dim=(2, 3)), self.scale * images.std(dim=(2, 3))], dim=1)

    network = Stats()
    for name, value in attributes.items():
        setattr(network, name, value)
    return Stats, network, lambda: from_callable(network, name="stats", preprocessing=Preprocessing())


def test_an_edited_row_of_an_interrupted_extraction_is_recomputed_when_it_resumes(tmp_path):
    import h5py

    from vpr_uncertainty.descriptors import extract_descriptors

    paths, names = _tiny_images(tmp_path / "images")
    _, _, make = _stats_model()
    path = tmp_path / "descriptors.h5"

    def stop_after_one_batch(done):
        raise KeyboardInterrupt  # the user kills the run after the first batch was written

    with pytest.raises(KeyboardInterrupt):
        extract_descriptors(
            make(), paths, names, path, "database", batch_size=3, progress=False, on_batch=stop_after_one_batch
        )
    with h5py.File(path, "r+") as handle:
        assert not handle["database"].attrs["complete"] and handle["database/names"].shape == (3,)
        handle["database/descriptors"][1] = handle["database/descriptors"][1] + 1.0  # edited on disk
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, resumed = extract_descriptors(make(), paths, names, path, "database", batch_size=3, progress=False)
    assert any("do not match their checksum" in str(w.message) for w in caught if w.category is CacheWarning)
    _, fresh = extract_descriptors(make(), paths, names, None, "database", batch_size=3, progress=False)
    np.testing.assert_allclose(resumed, fresh, rtol=1e-5, atol=1e-6)


# --- row 6: a Python model gets a forward hook, a changed class attribute or a __slots__ value -------------------


def test_hooks_class_attributes_and_slots_of_a_python_model_change_its_descriptors(tmp_path):
    from vpr_uncertainty.descriptors import extract_descriptors

    paths, names = _tiny_images(tmp_path / "images")
    path = tmp_path / "descriptors.h5"
    cls, network, make = _stats_model()
    _, first = extract_descriptors(make(), paths, names, path, "database", progress=False)

    handle = network.register_forward_hook(lambda module, inputs, output: output * 2.0)
    _, hooked = extract_descriptors(make(), paths, names, path, "database", progress=False)
    _, expected = extract_descriptors(make(), paths, names, None, "database", progress=False)
    np.testing.assert_allclose(hooked, expected, rtol=1e-5, atol=1e-6)
    handle.remove()

    cls.scale = 3.0  # a class attribute, not an instance attribute
    _, scaled = extract_descriptors(make(), paths, names, path, "database", progress=False)
    assert not np.allclose(scaled, first)

    torch = pytest.importorskip("torch")
    from vpr_uncertainty.identity import callable_identity

    class Slotted(torch.nn.Module):
        __slots__ = ("weight",)

        def forward(self, images):
            return images.mean(dim=(2, 3)) * self.weight

    slotted = Slotted()
    slotted.weight = 1.0
    before = callable_identity(slotted)
    slotted.weight = 2.0
    assert callable_identity(slotted) != before


# --- ulimit -f: a first extraction cut short, and an update of a whole file ---------------------------------


def _run(folder: Path, dataset: Path, *args: str, limit_kib: int | None = None) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "vpr_uncertainty.cli", "run", "--dataset", str(dataset), "--out", "run", *args]
    if limit_kib is not None:
        limit = f"ulimit -f {limit_kib}; exec " + " ".join(f"'{part}'" for part in command)
        command = ["bash", "-c", limit]
    return subprocess.run(command, cwd=folder, capture_output=True, text=True, timeout=300, check=False)


def test_a_file_size_limit_never_breaks_a_rerun_nor_the_previous_descriptors(tmp_path, corridor_dir):
    pytest.importorskip("torch")
    cut = _run(tmp_path, corridor_dir, limit_kib=8)  # the first extraction stops after the file's first blocks
    assert cut.returncode != 0
    rerun = _run(tmp_path, corridor_dir)
    assert rerun.returncode == 0, rerun.stderr  # recognised as cut short and rebuilt, not "addr overflow"
    whole = (tmp_path / "run" / "descriptors.h5").read_bytes()
    update = _run(tmp_path, corridor_dir, "--half", limit_kib=1300)  # rebuilding the whole file in float16 fails
    assert update.returncode != 0 and "File too large" in update.stderr
    assert (tmp_path / "run" / "descriptors.h5").read_bytes() == whole  # the previous file survives
    assert not [p for p in (tmp_path / "run").iterdir() if ".tmp" in p.name]


# --- .tmp files of a killed writer, and names that would hide a cell's files ------------------------------------


def test_temporary_files_of_a_killed_writer_are_removed_by_the_next_write(tmp_path):
    target = tmp_path / "results.json"
    killed = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    orphan = tmp_path / f".results.json.{socket.gethostname()}-{killed.pid}.abc.tmp.json"
    orphan.write_text("half")
    killed.kill()
    killed.wait()
    elsewhere = tmp_path / ".results.json.other-host-1.abc.tmp.json"  # another machine's writer may be alive
    elsewhere.write_text("busy")
    cache.write_json(target, {"a": 1})
    assert not orphan.exists() and elsewhere.exists() and json.loads(target.read_text()) == {"a": 1}


def test_a_vpr_method_named_dot_dot_writes_no_hidden_cell_file(grid_folder):
    config = grid_folder / "grid.toml"
    config.write_text(
        'out = "out"\nmethods = ["SU"]\nalphas = [0.5]\nks = [5]\n[[inputs]]\nvpr_method = "../x"\n'
        'dataset = "corridor"\nscores = "netvlad.npy"\nground_truth = "gt.npy"\n'
    )
    result = _cli(grid_folder, "reproduce", str(config), "--no-report")
    assert result.returncode == 0, result.stderr
    assert [path.name for path in (grid_folder / "out" / "cells").iterdir() if path.name.startswith(".")] == []


# --- row 11: BTL evaluated on its training queries, re-extracted in float16 ---------------------------------------


def test_btl_training_queries_re_extracted_in_half_precision_are_recognised():
    pytest.importorskip("torch")
    from vpr_uncertainty.btl.method import trained_on
    from vpr_uncertainty.btl.training import train_btl_head

    rng = np.random.default_rng(0)
    database = rng.normal(size=(60, 32)).astype(np.float32)
    database /= np.linalg.norm(database, axis=1, keepdims=True)
    queries = database[:40] + 0.05 * rng.normal(size=(40, 32)).astype(np.float32)
    queries /= np.linalg.norm(queries, axis=1, keepdims=True)
    positives = np.zeros((40, 60), bool)
    positives[np.arange(40), np.arange(40)] = True
    settings = {"hidden_dim": 16, "epochs": 1, "n_negatives": 3, "max_positives": 5}
    head, _ = train_btl_head(database, positives, query_descriptors=queries, progress=False, **settings)
    half = queries.astype(np.float16).astype(np.float32)  # `extract --half` of the same images
    assert trained_on(head, half) == 40
    others = rng.normal(size=(30, 32)).astype(np.float32)
    assert trained_on(head, others / np.linalg.norm(others, axis=1, keepdims=True)) == 0
