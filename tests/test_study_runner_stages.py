"""The stage breakdown of every grid cell in reproduce's results.json (``stage_seconds``), kept through the cache."""

from __future__ import annotations

import json
import warnings

import numpy as np
from scipy import sparse

from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_results
from vpr_uncertainty.retrieval import Retrieval, save_retrieval


def _grid(folder):
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((30, 10)), axis=1).astype(np.float32)
    indices = np.stack([rng.permutation(40)[:10] for _ in range(30)])
    positives = sparse.lil_array((30, 40), dtype=bool)
    for q in range(30):
        positives[q, indices[q, 0] if q % 3 else indices[q, -1]] = True
    save_retrieval(Retrieval(scores=scores, indices=indices, positives=sparse.csr_array(positives)), folder / "a.npz")
    text = ['out = "out"', 'methods = ["SU", "BM"]', "k = 5", "ks = [2, 5]", "[[inputs]]"]
    text += ['vpr_method = "A"', 'dataset = "d"', 'scores = "a.npz"']
    (folder / "grid.toml").write_text("\n".join(text) + "\n")
    return load_config(folder / "grid.toml")


def test_results_json_holds_each_cells_stage_seconds_also_when_read_from_the_cache(tmp_path):
    config = _grid(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (cell,) = run_grid(config, progress=False)
        assert set(cell.stage_seconds) == {"input", "uncertainty_and_evaluation", "ablations"}
        assert all(value >= 0 for value in cell.stage_seconds.values())
        write_results([cell], config)
        document = json.loads((tmp_path / "out" / "results.json").read_text())
        assert document["cells"][0]["stage_seconds"] == cell.stage_seconds
        (cached,) = run_grid(config, progress=False)
    assert cached.cached and cached.stage_seconds == cell.stage_seconds
