"""A warm rerun of `run` does no work: no model loaded, no torch, no figure redrawn (real corridor images).

Issue 22: the descriptor cache is checked before the model is loaded (its fingerprint is known without loading it),
and a figure whose inputs are unchanged (a fingerprint stored in the PNG with a checksum) is not drawn again.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vpr_uncertainty import cache
from vpr_uncertainty.cli import main

pytest.importorskip("torch")
pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")

#: A rerun in a fresh interpreter: the CLI with load_model spied on; prints the heavy modules it imported.
WARM_RERUN = """
import json, sys
import vpr_uncertainty.descriptors.models as models
calls = []
real = models.load_model
models.load_model = lambda *args, **kwargs: calls.append(args) or real(*args, **kwargs)
from vpr_uncertainty.cli import main
status = main(["run", "--dataset", sys.argv[1], "--out", sys.argv[2], "--methods", "SU,RS,BM"])
heavy = sorted(name for name in ("torch", "matplotlib") if name in sys.modules)
print(json.dumps({"status": status, "load_model": len(calls), "heavy": heavy}))
"""


def _rerun(corridor: Path, out: Path) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", WARM_RERUN, str(corridor), str(out)], capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def _state(path: Path) -> tuple[int, bytes]:
    return path.stat().st_mtime_ns, path.read_bytes()


@pytest.fixture(scope="module")
def cold_run(corridor_dir, tmp_path_factory):
    """A run directory after one cold run (descriptors computed, figures drawn)."""
    out = tmp_path_factory.mktemp("warm") / "run"
    assert main(["run", "--dataset", str(corridor_dir), "--out", str(out), "--methods", "SU,RS,BM"]) == 0
    return out


def test_warm_rerun_loads_no_model_imports_no_torch_and_redraws_nothing(cold_run, corridor_dir):
    figure, descriptors = cold_run / "pr_curves.png", cold_run / "descriptors.h5"
    before = {path: _state(path) for path in (figure, descriptors)}
    rerun = _rerun(corridor_dir, cold_run)
    assert rerun == {"status": 0, "load_model": 0, "heavy": []}
    assert {path: _state(path) for path in (figure, descriptors)} == before
    results = json.loads((cold_run / "results.json").read_text())
    assert results["n_queries"] == 111 and set(results["methods"]) == {"SU", "RS", "BM"}


def test_a_deleted_or_corrupted_figure_is_redrawn(cold_run, corridor_dir):
    figure = cold_run / "pr_curves.png"
    drawn = figure.read_bytes()
    figure.unlink()
    assert _rerun(corridor_dir, cold_run)["heavy"] == ["matplotlib"]
    assert figure.read_bytes() == drawn  # the same inputs draw the same figure

    corrupted = bytearray(drawn)
    corrupted[len(corrupted) // 2] ^= 0xFF
    figure.write_bytes(bytes(corrupted))
    rerun = _rerun(corridor_dir, cold_run)
    assert rerun["heavy"] == ["matplotlib"] and rerun["load_model"] == 0
    assert figure.read_bytes() == drawn

    figure.write_bytes(drawn[: len(drawn) // 3])  # truncated (a kill cannot do this: writes are atomic)
    _rerun(corridor_dir, cold_run)
    assert figure.read_bytes() == drawn


def test_a_changed_input_redraws_the_figure_and_keeps_the_descriptors(cold_run, corridor_dir, tmp_path, monkeypatch):
    from vpr_uncertainty.descriptors import models

    out = tmp_path / "run"
    out.mkdir()
    for name in ("descriptors.h5", "retrieval.npz"):
        (out / name).write_bytes((cold_run / name).read_bytes())
    (out / "pr_curves.png").write_bytes((cold_run / "pr_curves.png").read_bytes())
    drawn = (out / "pr_curves.png").read_bytes()
    calls = []
    monkeypatch.setattr(models, "load_model", lambda *args, **kwargs: calls.append(args))
    for methods, alpha in (("SU,RS", None), ("SU,RS", "0.3")):
        arguments = ["run", "--dataset", str(corridor_dir), "--out", str(out), "--methods", methods]
        assert main([*arguments, *(["--alpha", alpha] if alpha else [])]) == 0
        assert (out / "pr_curves.png").read_bytes() != drawn  # other methods, then another SU: drawn again
        drawn = (out / "pr_curves.png").read_bytes()
    assert calls == []  # the descriptors were reused: no model loaded
    results = json.loads((out / "results.json").read_text())
    assert set(results["methods"]) == {"SU", "RS"}


def _corridor_images(corridor: Path) -> dict:
    from vpr_uncertainty.data import load_dataset

    dataset = load_dataset(corridor)
    return {
        "database": (dataset.database_paths, dataset.database_names),
        "queries": (dataset.query_paths, dataset.query_names),
    }


def test_the_fingerprint_known_before_loading_is_the_loaded_models(cold_run, corridor_dir):
    from vpr_uncertainty.pipeline.extract import ExtractConf, cached, fingerprint_of, model_of

    for conf in (ExtractConf(), ExtractConf(image_size=96, max_side=320)):
        assert fingerprint_of(conf) == model_of(conf).fingerprint
    images = _corridor_images(corridor_dir)
    path = cold_run / "descriptors.h5"
    found = cached(ExtractConf(), images, path)
    assert found is not None and found.model_name == "efficientnet-lite0-gem"
    assert found.descriptors["queries"].shape == (111, 1280) and found.failed == {"database": [], "queries": []}
    # another preprocessing, dtype, or an overwrite: the cache must miss (the model is loaded and decides)
    for conf in (ExtractConf(image_size=96), ExtractConf(half=True), ExtractConf(overwrite=True)):
        assert cached(conf, images, path) is None


def test_a_changed_image_or_a_damaged_cache_misses(cold_run, corridor_dir, tmp_path):
    import h5py

    from vpr_uncertainty.descriptors.extract import cached_descriptors
    from vpr_uncertainty.pipeline.extract import ExtractConf, fingerprint_of

    config = fingerprint_of(ExtractConf())
    paths, names = _corridor_images(corridor_dir)["queries"]
    path = tmp_path / "descriptors.h5"
    path.write_bytes((cold_run / "descriptors.h5").read_bytes())
    found = cached_descriptors(config, paths, names, path, "queries")
    assert found is not None and list(found[0]) == list(names)

    changed = tmp_path / "changed.jpg"
    changed.write_bytes(Path(paths[3]).read_bytes() + b"\0")  # another content key for image 3
    assert cached_descriptors(config, [*paths[:3], changed, *paths[4:]], names, path, "queries") is None
    assert cached_descriptors(config, paths[:-1], names[:-1], path, "queries") is None  # not exactly these rows
    assert cached_descriptors({**config, "weights": "other"}, paths, names, path, "queries") is None

    with h5py.File(path, "r+") as handle:
        handle["queries/descriptors"][5] = np.zeros(1280, dtype=np.float32)  # checksum no longer matches
    assert cached_descriptors(config, paths, names, path, "queries") is None
    path.write_bytes((cold_run / "descriptors.h5").read_bytes()[:4096])  # truncated
    assert cached_descriptors(config, paths, names, path, "queries") is None


def test_an_unchanged_table_is_not_rewritten(tmp_path):
    table = cache.write_text(tmp_path / "results.md", "# table\n")
    stamp = table.stat().st_mtime_ns
    assert cache.write_text(table, "# table\n", keep_unchanged=True) == table
    assert table.stat().st_mtime_ns == stamp
    cache.write_text(table, "# other\n", keep_unchanged=True)
    assert table.read_text() == "# other\n"


def test_a_figure_is_current_only_with_its_inputs_and_intact_bytes(tmp_path):
    from vpr_uncertainty.reports.style import pyplot

    plt = pyplot()
    figure, axes = plt.subplots(figsize=(2, 2))
    axes.plot([0, 1], [1, 0])
    try:
        stamped = cache.write_figure(figure, tmp_path / "a.png", inputs="abc", dpi=50)
        plain = cache.write_figure(figure, tmp_path / "b.png", dpi=50)
        with pytest.raises(ValueError, match="only a PNG"):
            cache.write_figure(figure, tmp_path / "a.pdf", inputs="abc")
    finally:
        plt.close(figure)
    assert cache.figure_is_current(stamped, "abc")
    assert not cache.figure_is_current(stamped, "abd")  # other inputs
    assert not cache.figure_is_current(plain, "abc")  # no stamp: drawn by another writer
    assert not cache.figure_is_current(tmp_path / "absent.png", "abc")
    data = stamped.read_bytes()
    for damaged in (data[:-1], data + b"\0", data[:40] + bytes([data[40] ^ 1]) + data[41:]):
        stamped.write_bytes(damaged)
        assert not cache.figure_is_current(stamped, "abc")


def test_a_change_of_the_figure_style_draws_the_figure_again(tmp_path, monkeypatch):
    """The PR figure's stamp covers the style module too (sizes, fonts, palette moved out of display.py)."""
    from vpr_uncertainty.reports import display, style

    display._drawing_code.cache_clear()  # computed once per process
    before = display._drawing_code()
    changed = tmp_path / "style.py"
    changed.write_bytes(open(style.__file__, "rb").read() + b"\n# another palette\n")
    monkeypatch.setattr(style, "__file__", str(changed))
    display._drawing_code.cache_clear()
    try:
        assert display._drawing_code() != before
    finally:
        display._drawing_code.cache_clear()
