"""The typed result of a grid cell: to_dict/arrays/from_dict, and the cell cache (current and previous layouts)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

from conftest import assert_close
from vpr_uncertainty import Retrieval, evaluate
from vpr_uncertainty.pipeline.grid import Cell, load_config, run_grid, write_results
from vpr_uncertainty.retrieval import save_retrieval


def _retrieval(seed: int = 0, n_queries: int = 50, n_database: int = 60, k: int = 20) -> Retrieval:
    rng = np.random.default_rng(seed)
    scores = -np.sort(-rng.uniform(0.1, 0.95, size=(n_queries, k)), axis=1)
    indices = np.array([rng.permutation(n_database)[:k] for _ in range(n_queries)])
    positives = np.zeros((n_queries, n_database), bool)
    positives[np.arange(n_queries), np.where(rng.uniform(size=n_queries) < 0.6, indices[:, 0], indices[:, 5])] = True
    return Retrieval(scores=scores, indices=indices, positives=sparse.csr_array(positives))


def _config(tmp_path: Path, methods: list[str], alphas: str = "[0.0, 0.5, 1.0]") -> Path:
    save_retrieval(_retrieval(), tmp_path / "scores.npz")
    lines = [
        f'out = "{tmp_path / "out"}"',
        f"methods = {json.dumps(methods)}",
        f"alphas = {alphas}",
        "ks = [2, 5]",
        "[[inputs]]",
        'vpr_method = "V"',
        'dataset = "D"',
        f'scores = "{tmp_path / "scores.npz"}"',
    ]
    (tmp_path / "grid.toml").write_text("\n".join(lines) + "\n")
    return tmp_path / "grid.toml"


def _grid(config_path: Path) -> list[Cell]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_grid(load_config(config_path), progress=False)


def _assert_same_cell(got: Cell, expected: Cell) -> None:
    assert got.to_dict() == expected.to_dict()
    assert got.ablation_alpha == expected.ablation_alpha and got.ablation_k == expected.ablation_k
    for name, method in expected.evaluation.methods.items():
        other = got.evaluation.methods[name]
        np.testing.assert_array_equal(other.uncertainty, method.uncertainty)
        np.testing.assert_array_equal(other.curve.precision, method.curve.precision)
        np.testing.assert_array_equal(other.curve.recall, method.curve.recall)
        assert other.recall_at_full_precision == method.recall_at_full_precision
    for key in ("correct", "scores", "indices", "hits"):
        np.testing.assert_array_equal(got.arrays()[key], expected.arrays()[key])


def test_cell_round_trips_through_to_dict_and_arrays(tmp_path):
    (cell,) = _grid(_config(tmp_path, ["RS", "SU", "BM"], alphas="[0.0, 0.3333333333333333, 1.0]"))
    again = Cell.from_dict(json.loads(json.dumps(cell.to_dict())), cell.arrays())
    _assert_same_cell(again, cell)
    assert sorted(again.ablation_alpha) == [0.0, 1 / 3, 1.0]  # exact, although results.json writes "0" and "1"
    assert list(cell.to_dict()["ablation_alpha"]) == ["0", "0.3333333333333333", "1"]


def test_results_json_cells_are_cell_to_dict(tmp_path):
    config_path = _config(tmp_path, ["SD", "PA"])
    (cell,) = _grid(config_path)
    paths = write_results([cell], load_config(config_path))
    document = json.loads(paths["results_json"].read_text())
    assert document["cells"] == [json.loads(json.dumps(cell.to_dict()))]
    assert list(document["cells"][0])[:4] == ["vpr_method", "dataset", "n_queries", "k"]
    assert document["cells"][0]["ablation_alpha"].keys() == {"0", "0.5", "1"}


def _write_version_1(cell: Cell, json_path: Path) -> None:
    """The cell document as the previous release wrote it (reproduce.py before the study package)."""
    meta = json.loads(json_path.read_text())
    evaluation = cell.evaluation
    old = {
        "fingerprint": meta["fingerprint"],
        "vpr_method": cell.vpr_method,
        "dataset": cell.dataset,
        "n_answerable": evaluation.n_answerable,
        "recall_at_n": {str(n): v for n, v in evaluation.recall_at_n.items()},
        "notes": evaluation.notes,
        "evaluation": evaluation.to_dict(),
        "ablation_alpha": [[a, v] for a, v in cell.ablation_alpha.items()],
        "ablation_k": {name: [[k, v] for k, v in curve.items()] for name, curve in cell.ablation_k.items()},
        "query_paths": cell.query_paths,
        "database_paths": cell.database_paths,
    }
    json_path.write_text(json.dumps(old, indent=1) + "\n")


def test_a_cell_cached_by_the_previous_release_is_recomputed_with_a_notice(tmp_path):
    """A cell of a layout without a checksum cannot prove its content (issue 20): recomputed, said in one line."""
    from vpr_uncertainty.cache import CacheWarning

    config_path = _config(tmp_path, ["RS", "SD", "SU", "L2"])
    (fresh,) = _grid(config_path)
    _write_version_1(fresh, tmp_path / "out" / "cells" / "V__D.json")
    with pytest.warns(CacheWarning, match=r"V__D\.json: written by an earlier version \(no checksum\)"):
        (again,) = run_grid(load_config(config_path), progress=False)
    assert not again.cached
    np.testing.assert_array_equal(again.evaluation.correct, fresh.evaluation.correct)
    assert again.ablation_alpha == fresh.ablation_alpha and again.ablation_k == fresh.ablation_k
    (cached,) = _grid(config_path)
    assert cached.cached


def test_a_cached_method_with_its_own_retrieval_keeps_its_own_correctness(tmp_path):
    """Regression: a cached cell rebuilt the curve of such a method from the shared top-1 labels, so its PR
    curve and recall at 100 % precision changed between the first run and the next."""
    from vpr_uncertainty.methods import METHODS, OwnRetrievalUncertainty, register_method

    def own_method(retrieval):
        own = Retrieval(
            scores=retrieval.scores, indices=retrieval.indices[:, ::-1].copy(), positives=retrieval.positives
        )
        return OwnRetrievalUncertainty(uncertainty=-retrieval.scores[:, -1].astype(np.float64), retrieval=own)

    register_method("OWN-CELL-TEST", own_method, description="test")
    try:
        config_path = _config(tmp_path, ["OWN-CELL-TEST", "BM"])
        (fresh,) = _grid(config_path)
        (cached,) = _grid(config_path)
    finally:
        METHODS.unregister("OWN-CELL-TEST")
    assert cached.cached
    own = fresh.evaluation.methods["OWN-CELL-TEST"]
    assert own.correct is not None and not np.array_equal(own.correct, fresh.evaluation.correct)
    _assert_same_cell(cached, fresh)


def test_a_cell_document_without_uncertainties_is_recomputed(tmp_path):
    config_path = _config(tmp_path, ["SU"])
    (fresh,) = _grid(config_path)
    npz = tmp_path / "out" / "cells" / "V__D.npz"
    arrays = {k: v for k, v in fresh.arrays().items() if not k.startswith("uncertainty/")}
    np.savez_compressed(npz, **arrays)
    (again,) = _grid(config_path)
    assert not again.cached
    assert_close(again.evaluation.methods["SU"].auc_pr, fresh.evaluation.methods["SU"].auc_pr)


def test_evaluate_sets_own_correctness_only_for_own_retrieval_methods():
    retrieval = _retrieval()
    result = evaluate(retrieval, ["BM"])
    assert result.methods["BM"].correct is None


@pytest.mark.parametrize("field", ["correct", "scores"])
def test_from_dict_names_a_missing_array(tmp_path, field):
    (cell,) = _grid(_config(tmp_path, ["BM"]))
    arrays = {k: v for k, v in cell.arrays().items() if k != field}
    with pytest.raises(KeyError, match=field):
        Cell.from_dict(cell.to_dict(), arrays)
