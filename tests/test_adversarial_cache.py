"""Adversarial cache cases (issue 20, rows 1-5): an artefact changed on disk with its size and time kept, two files
of one cell that do not belong together, a file named in a method option replaced, a large results file edited in
the middle. Each must be detected and recomputed, never used silently. Everything is written under tmp_path.
"""

from __future__ import annotations

import json
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty import cache
from vpr_uncertainty.cache import CacheWarning

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")


def _keep_time(path: Path, edit) -> None:
    """Apply ``edit(path)`` and restore the file's modification time; its size must not change."""
    stat = path.stat()
    edit(path)
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert path.stat().st_size == stat.st_size and path.stat().st_mtime_ns == stat.st_mtime_ns


def _cache_notices(caught) -> list[str]:
    return [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]


# --- row 1: one descriptor row changed in descriptors.h5 --------------------------------------------------------


def _tiny_images(folder: Path) -> tuple[list[Path], list[str]]:
    image = pytest.importorskip("PIL.Image")
    rng = np.random.default_rng(0)
    folder.mkdir()
    paths = []
    for i in range(6):
        path = folder / f"img{i:02d}.png"
        image.fromarray(rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)).save(path)
        paths.append(path)
    return paths, [path.name for path in paths]


def _channel_model():
    torch = pytest.importorskip("torch")
    from vpr_uncertainty.descriptors import Preprocessing
    from vpr_uncertainty.descriptors.models import from_callable

    calls = []

    def network(images):
        calls.append(images.shape[0])
        return torch.cat([images.mean(dim=(2, 3)), images.std(dim=(2, 3))], dim=1)

    return calls, from_callable(network, name="channels", preprocessing=Preprocessing())


def test_a_descriptor_row_changed_on_disk_is_detected_and_recomputed(tmp_path):
    import h5py

    from vpr_uncertainty.descriptors import extract_descriptors, read_descriptors

    paths, names = _tiny_images(tmp_path / "images")
    path = tmp_path / "descriptors.h5"
    _, model = _channel_model()
    _, fresh = extract_descriptors(model, paths, names, path, "database", batch_size=4, progress=False)

    def swap_one_row(file: Path) -> None:
        with h5py.File(file, "r+") as handle:
            rows = handle["database/descriptors"]
            rows[2] = rows[2][::-1].copy()  # same bytes count, another descriptor

    _keep_time(path, swap_one_row)
    calls, model = _channel_model()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, again = extract_descriptors(model, paths, names, path, "database", batch_size=4, progress=False)
    (notice,) = _cache_notices(caught)
    assert "\n" not in notice and str(path) in notice and "checksum" in notice and "recomputing" in notice
    assert sum(calls) == len(names)  # rebuilt
    np.testing.assert_array_equal(again, fresh)
    np.testing.assert_array_equal(read_descriptors(path, "database")[1], fresh)
    _keep_time(path, swap_one_row)  # a reader (evaluate --descriptors) cannot rebuild: it refuses, naming the file
    with pytest.raises(cache.ChecksumError, match=r"descriptors\.h5.*'database' descriptors"):
        read_descriptors(path, "database")


# --- rows 2 and 3: the grid cell cache (out/cells/KEY.json + KEY.npz) ---------------------------------------------


@pytest.fixture
def netvlad_grid(tmp_path: Path, corridor_dir: Path, corridor_matches_dir: Path):
    """A one-cell grid on the real NetVLAD corridor matrix, copied into tmp_path; ``write(alpha)`` writes it."""
    shutil.copy(corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy", tmp_path / "netvlad.npy")
    shutil.copy(corridor_dir / "ground_truth_new.npy", tmp_path / "gt.npy")

    def write(alpha: float = 0.5, methods: str = '["SU", "BM"]') -> Path:
        path = tmp_path / "grid.toml"
        path.write_text(
            f'out = "out"\nmethods = {methods}\nalpha = {alpha}\nalphas = [0.0, 0.5]\nks = [2, 5]\n'
            '[[inputs]]\nvpr_method = "NetVLAD"\ndataset = "corridor"\nscores = "netvlad.npy"\n'
            'ground_truth = "gt.npy"\n'
        )
        return path

    return write


def _cells(config_path: Path, out: str = "out"):
    from vpr_uncertainty.pipeline.grid import load_config, run_grid

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run_grid(load_config(config_path, out=config_path.parent / out), progress=False)
    return result, _cache_notices(caught)


def test_one_digit_of_a_cell_json_changed_is_detected_and_recomputed(netvlad_grid):
    config = netvlad_grid()
    (first,), _ = _cells(config)
    (json_path,) = (config.parent / "out" / "cells").glob("*.json")
    su = first.evaluation.methods["SU"].auc_pr
    text = json_path.read_text()
    stored = f'"auc_pr": {su!r}'
    assert text.count(stored) == 1
    digits = repr(su)
    edited = digits[:2] + str((int(digits[2]) + 1) % 10) + digits[3:]  # 0.847... -> 0.947... (one digit)
    _keep_time(json_path, lambda path: path.write_text(text.replace(stored, f'"auc_pr": {edited}')))
    (again,), notices = _cells(config)
    assert not again.cached
    assert again.evaluation.methods["SU"].auc_pr == su
    (notice,) = notices
    assert "\n" not in notice and str(json_path) in notice and "checksum" in notice
    (cached,), notices = _cells(config)
    assert cached.cached and not notices


def test_a_cell_json_and_npz_of_two_runs_are_not_used_together(netvlad_grid):
    """A kill between the ``.npz`` rename and the ``.json`` rename (alpha changed between runs): crafted here."""
    cells = netvlad_grid().parent / "out" / "cells"
    (at_zero,), _ = _cells(netvlad_grid(alpha=0.0))
    (npz_path,) = cells.glob("*.npz")
    arrays_of_alpha_0 = npz_path.read_bytes()
    (at_half,), _ = _cells(netvlad_grid(alpha=0.5))
    npz_path.write_bytes(arrays_of_alpha_0)  # the .json of alpha = 0.5 with the arrays of alpha = 0
    (again,), notices = _cells(netvlad_grid(alpha=0.5))
    assert not again.cached
    (notice,) = notices
    assert "\n" not in notice and npz_path.name in notice
    su = again.evaluation.methods["SU"]
    np.testing.assert_array_equal(su.uncertainty, at_half.evaluation.methods["SU"].uncertainty)
    assert not np.array_equal(su.uncertainty, at_zero.evaluation.methods["SU"].uncertainty)
    assert_close(su.auc_pr, at_half.evaluation.methods["SU"].auc_pr)


# --- row 5: a file named inside a method option -------------------------------------------------------------------


def test_a_gate_file_named_in_a_method_option_is_part_of_the_cell_fingerprint(netvlad_grid, tmp_path):
    from vpr_uncertainty.calibration.fit import calibrate_arrays

    gates = []
    for seed, margin in ((0, 0.08), (1, 0.3)):
        rng = np.random.default_rng(seed)
        scores = -np.sort(-rng.random((80, 10)), axis=1).astype(np.float32)
        correct = scores[:, 0] - scores[:, 1] + rng.normal(0, 0.05, 80) > margin
        gates.append(calibrate_arrays(scores, correct, k=10).save(tmp_path / f"gate_{seed}.json").read_bytes())
    gate = tmp_path / "cal_gate.json"
    gate.write_bytes(gates[0])
    config = netvlad_grid(methods=json.dumps(["SU", f"CAL:gate={gate}"]))
    (first,), _ = _cells(config)
    (cached,), _ = _cells(config)
    assert cached.cached
    gate.write_bytes(gates[1])  # another gate at the same path
    (again,), _ = _cells(config)
    (fresh,), _ = _cells(config, out="fresh")
    name = f"CAL:gate={gate}"
    assert not again.cached
    uncertainty = again.evaluation.methods[name].uncertainty
    np.testing.assert_array_equal(uncertainty, fresh.evaluation.methods[name].uncertainty)
    assert not np.array_equal(uncertainty, first.evaluation.methods[name].uncertainty)


# --- row 4: a results file over FULL_HASH_BYTES edited in the middle ----------------------------------------------


def _edit_the_middle(path: Path) -> None:
    """Swap two query rows in the middle of the matrix: same size, same first and last EDGE_BYTES."""
    matrix = np.load(path)
    matrix[[40, 70]] = matrix[[70, 40]]
    with path.open("r+b") as handle:  # in place, as an editor or a buggy tool would
        handle.seek(path.stat().st_size - matrix.nbytes)
        handle.write(matrix.tobytes())


@pytest.fixture
def large_files(monkeypatch):
    """Every file over 4 KiB counts as large: keyed by size, times and its first and last KiB."""
    monkeypatch.setattr(cache, "FULL_HASH_BYTES", 4096)
    monkeypatch.setattr(cache, "EDGE_BYTES", 1024)


def _plain_matrix(config: Path) -> Path:
    """The grid's results file as a plain (111, 111) float64 similarity matrix (the legacy file's matrix)."""
    path = config.parent / "netvlad.npy"
    legacy = np.load(path, allow_pickle=True, encoding="latin1")
    np.save(path, np.asarray(legacy[3], dtype=np.float64))
    return path


def test_a_large_results_file_edited_in_the_middle_is_seen_by_its_change_time(netvlad_grid, large_files):
    config = netvlad_grid()
    matrix = _plain_matrix(config)
    (first,), _ = _cells(config)
    assert matrix.stat().st_size > 4 * 4096
    _keep_time(matrix, _edit_the_middle)
    (again,), _ = _cells(config)
    (fresh,), _ = _cells(config, out="fresh")
    assert not again.cached
    su = again.evaluation.methods["SU"].uncertainty
    np.testing.assert_array_equal(su, fresh.evaluation.methods["SU"].uncertainty)
    assert not np.array_equal(su, first.evaluation.methods["SU"].uncertainty)


def test_verify_hashes_every_byte_of_a_large_results_file(netvlad_grid, large_files, monkeypatch):
    """On a filesystem whose change time does not tell (simulated), a plain rerun trusts the documented cheap key;
    ``reproduce --verify`` hashes every byte and recomputes."""
    from vpr_uncertainty.pipeline.grid import load_config, run_grid

    monkeypatch.setattr(cache, "_change_time", lambda stat: 0)
    config = netvlad_grid()
    matrix = _plain_matrix(config)
    _cells(config)
    _keep_time(matrix, _edit_the_middle)
    (plain,), _ = _cells(config)
    assert plain.cached  # the documented fast path: size, times, first and last EDGE_BYTES
    with pytest.warns(CacheWarning, match=r"input .*netvlad\.npy differs .*every byte hashed") as caught:
        (verified,) = run_grid(load_config(config, out=config.parent / "out"), progress=False, verify=True)
    assert len(_cache_notices(caught)) == 1
    (fresh,), _ = _cells(config, out="fresh")
    assert not verified.cached
    np.testing.assert_array_equal(
        verified.evaluation.methods["SU"].uncertainty, fresh.evaluation.methods["SU"].uncertainty
    )
    (again,) = run_grid(load_config(config, out=config.parent / "out"), progress=False, verify=True)
    assert again.cached


def test_reproduce_has_a_verify_flag():
    from vpr_uncertainty.cli import build_parser

    args = build_parser().parse_args(["reproduce", "grid.toml", "--verify"])
    assert args.verify
