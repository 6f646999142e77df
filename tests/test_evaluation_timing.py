"""Time figures beside the batched time per query (:mod:`vpr_uncertainty.evaluation._evaluate`): latency at batch
size 1, and geometric verification with a cold and a warm local-feature cache."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty.evaluation import Evaluation, evaluate
from vpr_uncertainty.evaluation._evaluate import latency_batch1, single_query_retrievals, time_geometric
from vpr_uncertainty.methods import METHODS, available_methods, get_method, register_method
from vpr_uncertainty.retrieval import Retrieval


def _retrieval(n_queries: int = 30, k: int = 10) -> Retrieval:
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((n_queries, k)), axis=1).astype(np.float32)
    indices = np.tile(np.arange(k), (n_queries, 1))
    positives = sparse.csr_array(np.eye(n_queries, k, dtype=bool) | (np.arange(n_queries) % 2 == 0)[:, None])
    return Retrieval(scores=scores, indices=indices, positives=positives)


def test_single_query_retrievals_are_one_row_each_and_cycle():
    retrieval = _retrieval(3)
    rows = single_query_retrievals(retrieval, 7)
    assert len(rows) == 7 and all(row.n_queries == 1 for row in rows)
    np.testing.assert_array_equal(rows[4].scores, retrieval.scores[1:2])
    assert rows[4].positives.shape == (1, retrieval.positives.shape[1])
    with pytest.raises(ValueError, match="n must be >= 1"):
        single_query_retrievals(retrieval, 0)


def test_latency_is_a_median_of_at_least_three_runs_of_single_query_calls():
    calls = []
    seconds = latency_batch1(lambda row: calls.append(row.n_queries), _retrieval(), n_calls=10, runs=3)
    assert seconds > 0 and calls == [1] * 31  # a warm-up, then 3 runs of 10 one-query calls
    with pytest.raises(ValueError, match="runs must be >= 3"):
        latency_batch1(lambda row: None, _retrieval(), runs=2)


def test_evaluate_reports_latency_of_every_score_method_when_asked(tmp_path):
    methods = available_methods(kind="score")
    evaluation = evaluate(_retrieval(), methods, latency=True)
    document = evaluation.to_dict()
    for name in methods:
        assert document["methods"][name]["latency_ms_batch1"] > 0
        assert document["methods"][name]["time_per_query_ms"] > 0
    # Round trip through JSON keeps it; without latency=True the key is absent.
    again = Evaluation.from_dict(
        json.loads(json.dumps(document)),
        correct=evaluation.correct,
        uncertainties={name: method.uncertainty for name, method in evaluation.methods.items()},
    )
    assert again.to_dict()["methods"]["SU"]["latency_ms_batch1"] == document["methods"]["SU"]["latency_ms_batch1"]
    assert "latency_ms_batch1" not in evaluate(_retrieval(), ["SU"]).to_dict()["methods"]["SU"]


def test_evaluate_command_writes_latency_with_the_flag(tmp_path, capsys):
    from vpr_uncertainty.cli import main
    from vpr_uncertainty.retrieval import save_retrieval

    path = save_retrieval(_retrieval(), tmp_path / "r.npz")
    assert main(["evaluate", str(path), "--methods", "SU,BM", "--latency", "--json", str(tmp_path / "o.json")]) == 0
    assert "latency at batch size 1" in capsys.readouterr().out
    document = json.loads((tmp_path / "o.json").read_text())
    assert all(document["methods"][name]["latency_ms_batch1"] > 0 for name in ("SU", "BM"))


@pytest.fixture
def fake_gv():
    """A geometric method that 'extracts' into a cache file in cache_dir (slowly) and reads it back (quickly)."""
    calls = []

    def gv(retrieval, *, cache_dir=None, query_paths=None, database_paths=None):
        cached = cache_dir is not None and (Path(cache_dir) / "features.h5").is_file()
        calls.append("warm" if cached else "cold")
        time.sleep(0.002 if cached else 0.05)
        if cache_dir is not None and not cached:
            Path(cache_dir).mkdir(parents=True, exist_ok=True)
            (Path(cache_dir) / "features.h5").write_text("x")
        return -np.arange(retrieval.n_queries, dtype=np.float64)

    register_method("GV-FAKE", gv, description="fake", kind="geometric")
    yield calls
    METHODS.unregister("GV-FAKE")


def test_geometric_cold_and_warm_with_an_empty_cache(tmp_path, fake_gv):
    evaluation = evaluate(_retrieval(), ["GV-FAKE"], cache_dir=tmp_path / "cache")
    method = evaluation.to_dict()["methods"]["GV-FAKE"]
    assert fake_gv[0] == "cold" and set(fake_gv[1:]) == {"warm"}
    assert method["time_per_query_ms_cold"] > method["time_per_query_ms_warm"] > 0
    assert method["time_per_query_ms"] == method["time_per_query_ms_cold"]
    assert method["time_per_query_ms_cold"] >= 50 / 30 * 0.9  # 50 ms for 30 queries


def test_geometric_cold_is_measured_in_a_fresh_cache_when_the_cache_is_already_warm(tmp_path, fake_gv):
    """Regression: with a warm cache (a rerun), the one figure reported was the warm time, labelled like a cold one."""
    cache_dir = tmp_path / "cache"
    evaluate(_retrieval(), ["GV-FAKE"], cache_dir=cache_dir)
    fake_gv.clear()
    method = evaluate(_retrieval(), ["GV-FAKE"], cache_dir=cache_dir).to_dict()["methods"]["GV-FAKE"]
    assert fake_gv[0] == "warm" and fake_gv[-1] == "cold"
    assert method["time_per_query_ms_cold"] > method["time_per_query_ms_warm"] > 0


def test_geometric_without_cache_has_only_a_cold_figure(fake_gv):
    method = evaluate(_retrieval(), ["GV-FAKE"]).to_dict()["methods"]["GV-FAKE"]
    assert fake_gv == ["cold"]
    assert method["time_per_query_ms_cold"] == method["time_per_query_ms"] > 0
    assert "time_per_query_ms_warm" not in method


def test_time_geometric_returns_the_first_result(tmp_path):
    result, cold, warm = time_geometric(lambda options: "first", {"cache_dir": tmp_path}, repeats=2)
    assert result == "first" and cold > 0 and warm > 0
    assert get_method("GV-SIFT").kind == "geometric"
