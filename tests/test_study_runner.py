"""The grid's cell cache (study/runner.py) on the cache protocol: content-keyed inputs, one-line rebuilds.

Real inputs: the NetVLAD similarity matrix of the corridor and its ground truth, copied into tmp_path and edited
there. The reference is a fresh grid in an empty output folder.
"""

from __future__ import annotations

import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty.cache import CacheWarning
from vpr_uncertainty.pipeline.grid import load_config, run_grid

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")


@pytest.fixture
def grid(tmp_path: Path, corridor_dir: Path, corridor_matches_dir: Path) -> Path:
    shutil.copy(corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy", tmp_path / "netvlad.npy")
    rows = np.load(corridor_dir / "ground_truth_new.npy", allow_pickle=True, encoding="latin1")
    np.save(tmp_path / "gt.npy", rows, allow_pickle=True)  # the real ground truth, pickled as the edit below will
    path = tmp_path / "grid.toml"
    path.write_text(
        'out = "out"\nmethods = ["SU", "BM"]\n'
        '[[inputs]]\nvpr_method = "NetVLAD"\ndataset = "corridor"\nscores = "netvlad.npy"\nground_truth = "gt.npy"\n'
    )
    return path


def cells(config_path: Path, out: str = "out"):
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=UserWarning, message="(?!cache )")  # keep CacheWarnings
        return run_grid(load_config(config_path, out=config_path.parent / out), progress=False)


def test_ground_truth_edited_in_place_recomputes_the_cell(grid):
    """Regression: cells were keyed by file size and modification time; an edit that kept both was not seen."""
    (first,) = cells(grid)
    (again,) = cells(grid)
    assert again.cached
    gt = grid.parent / "gt.npy"
    stat = gt.stat()
    rows = np.load(gt, allow_pickle=True, encoding="latin1")
    lengths = [len(row[1]) for row in rows]
    a, b = next((i, j) for i in range(len(rows)) for j in range(i + 20, len(rows)) if lengths[i] == lengths[j])
    rows[a][1], rows[b][1] = rows[b][1], rows[a][1]  # same bytes count, other positives
    np.save(gt, rows, allow_pickle=True)
    os.utime(gt, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert gt.stat().st_size == stat.st_size and gt.stat().st_mtime_ns == stat.st_mtime_ns
    (stale,) = cells(grid)
    (fresh,) = cells(grid, out="fresh")
    assert not stale.cached
    np.testing.assert_array_equal(stale.evaluation.correct, fresh.evaluation.correct)
    assert not np.array_equal(stale.evaluation.correct, first.evaluation.correct)
    assert_close(stale.evaluation.methods["SU"].auc_pr, fresh.evaluation.methods["SU"].auc_pr)


def test_a_cell_cut_short_is_reported_in_one_line_and_recomputed(grid):
    (first,) = cells(grid)
    (npz,) = (grid.parent / "out" / "cells").glob("*.npz")
    npz.write_bytes(npz.read_bytes()[:100])
    with pytest.warns(CacheWarning) as caught:
        (again,) = cells(grid)
    (notice,) = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    assert "\n" not in notice and "truncated" in notice
    assert not again.cached
    np.testing.assert_array_equal(again.evaluation.correct, first.evaluation.correct)
    (cached,) = cells(grid)
    assert cached.cached
