"""Bootstrap intervals and paired tests attached to an evaluation (vpr_uncertainty.evaluation.bootstrap): the
JSON keys and their round trip, the reference, the leaders of a column, tie counts, and the evaluate table."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty import evaluate
from vpr_uncertainty.cli import main
from vpr_uncertainty.evaluation import (
    Evaluation,
    MethodEvaluation,
    auc_pr,
    aurc,
    average_precision,
    precision_at_recall,
    recall_at_full_precision,
    rejection_curve,
)
from vpr_uncertainty.evaluation.bootstrap import add_bootstrap, leaders
from vpr_uncertainty.reports.tables import format_table
from vpr_uncertainty.retrieval import Retrieval, top_k_from_similarity


def _method(name, correct, uncertainty):
    uncertainty = np.asarray(uncertainty, dtype=np.float64)
    curve = rejection_curve(correct, uncertainty)
    return MethodEvaluation(
        name=name,
        uncertainty=uncertainty,
        auc_pr=auc_pr(correct, uncertainty),
        average_precision=average_precision(correct, uncertainty),
        aurc=aurc(correct, uncertainty),
        time_per_query_ms=0.001,
        curve=curve,
        recall_at_full_precision=recall_at_full_precision(curve),
        precision_at_recall={0.5: precision_at_recall(curve, 0.5)},
    )


def _evaluation(uncertainties, correct):
    return Evaluation(
        n_queries=correct.size,
        n_answerable=correct.size,
        correct=correct,
        recall_at_n={1: float(correct.mean())},
        methods={name: _method(name, correct, u) for name, u in uncertainties.items()},
    )


def _case(n=111, seed=0):
    rng = np.random.default_rng(seed)
    correct = rng.random(n) < 0.6
    perfect = np.where(correct, 0.0, 1.0) + 0.01 * rng.random(n)
    return correct, {"SU": perfect, "random": rng.random(n), "noisy": perfect + 1.5 * rng.random(n)}


def _retrieval(n_queries=60, n_database=80, seed=1):
    rng = np.random.default_rng(seed)
    similarity = rng.uniform(0.1, 0.8, size=(n_queries, n_database)).astype(np.float32)
    found = rng.random(n_queries) < 0.5
    similarity[found, np.flatnonzero(found)] = 0.95
    scores, indices = top_k_from_similarity(similarity, 20)
    return Retrieval(
        scores=scores, indices=indices, positives=sparse.csr_array(np.eye(n_queries, n_database, dtype=bool))
    )


def test_a_perfect_method_beats_a_random_one_and_the_json_carries_it():
    correct, uncertainties = _case()
    evaluation = add_bootstrap(_evaluation(uncertainties, correct), n_resamples=500, seed=0)
    data = evaluation.to_dict()
    su, random = data["methods"]["SU"], data["methods"]["random"]
    assert "vs_reference" not in su  # the reference itself
    assert random["vs_reference"]["reference"] == "SU"
    assert random["vs_reference"]["delta_auc_pr"] == pytest.approx(random["auc_pr"] - su["auc_pr"], rel=1e-12)
    assert random["vs_reference"]["significant"] is True
    assert random["vs_reference"]["p_value"] <= random["vs_reference"]["p_value_holm"] < 0.05
    for method in data["methods"].values():
        for metric in ("auc_pr", "average_precision", "aurc"):
            low, high = method[f"{metric}_ci"]
            assert low - 1e-12 <= method[metric] <= high + 1e-12  # a perfect method: 1 up to rounding
    assert data["bootstrap"]["resamples"] == 500 and data["bootstrap"]["reference"] == "SU"
    assert data["bootstrap"]["best"]["auc_pr"] == {"methods": ["SU"], "significant": True}
    assert data["bootstrap"]["best"]["aurc"] == {"methods": ["SU"], "significant": True}


def test_no_difference_between_a_method_and_its_copy():
    correct, uncertainties = _case()
    evaluation = add_bootstrap(
        _evaluation({"SU": uncertainties["noisy"], "copy": uncertainties["noisy"].copy()}, correct), n_resamples=300
    )
    test = evaluation.methods["copy"].vs_reference
    assert test["delta_auc_pr"] == 0.0 and test["p_value"] == 1.0 and test["significant"] is False
    assert evaluation.bootstrap["best"]["auc_pr"] == {"methods": ["SU", "copy"], "significant": False}


def test_the_json_round_trip_keeps_the_intervals_and_tests():
    correct, uncertainties = _case()
    evaluation = add_bootstrap(_evaluation(uncertainties, correct), n_resamples=200, seed=4, reference="noisy")
    data = json.loads(json.dumps(evaluation.to_dict()))
    back = Evaluation.from_dict(data, correct=correct, uncertainties=uncertainties)
    assert back.to_dict() == data
    assert back.methods["SU"].auc_pr_ci == evaluation.methods["SU"].auc_pr_ci
    assert back.bootstrap["seed"] == 4 and back.methods["SU"].vs_reference["reference"] == "noisy"


def test_without_bootstrap_the_schema_only_gains_the_tie_share():
    evaluation = evaluate(_retrieval(), ["SU", "BM"], k=10)
    data = evaluation.to_dict()
    assert "bootstrap" not in data
    for method in data["methods"].values():
        assert not {"auc_pr_ci", "average_precision_ci", "aurc_ci", "vs_reference"} & set(method)
        assert 0.0 <= method["tied_share"] <= 1.0
    back = Evaluation.from_dict(data, correct=evaluation.correct, uncertainties=evaluation_uncertainties(evaluation))
    assert back.to_dict() == data and back.bootstrap is None and back.methods["SU"].auc_pr_ci is None


def evaluation_uncertainties(evaluation):
    return {name: m.uncertainty for name, m in evaluation.methods.items()}


def test_evaluate_bootstraps_with_the_same_seed_identically_and_checks_the_reference_first():
    retrieval = _retrieval()
    first = evaluate(retrieval, ["SU", "BM", "RS"], k=10, bootstrap=200, seed=3).to_dict()
    again = evaluate(retrieval, ["SU", "BM", "RS"], k=10, bootstrap=200, seed=3).to_dict()
    for name in first["methods"]:
        assert first["methods"][name]["auc_pr_ci"] == again["methods"][name]["auc_pr_ci"]
    assert first["bootstrap"]["reference"] == "SU"
    assert evaluate(retrieval, ["BM", "RS"], k=10, bootstrap=50).bootstrap["reference"] == "BM"  # no SU: the first
    with pytest.raises(ValueError, match="reference method 'PA' of the paired tests is not among the evaluated"):
        evaluate(retrieval, ["SU", "BM"], k=10, bootstrap=50, reference="PA")
    with pytest.raises(ValueError, match="bootstrap must be an integer >= 0"):
        evaluate(retrieval, ["SU"], k=10, bootstrap=-1)


def test_leaders_significant_best_against_tied_leaders():
    rng = np.random.default_rng(0)
    noise = 0.01 * rng.standard_normal((3, 1000))
    clear = {"A": 0.9 + noise[0], "B": 0.7 + noise[1], "C": 0.6 + noise[2]}
    assert leaders(clear, {"A": 0.9, "B": 0.7, "C": 0.6}) == (["A"], True)
    close = {"A": 0.9 + noise[0], "B": 0.9 + noise[1], "C": 0.6 + noise[2]}  # A and B indistinguishable
    assert leaders(close, {"A": 0.901, "B": 0.899, "C": 0.6}) == (["A", "B"], False)
    # lower is better (AURC): C leads
    assert leaders(clear, {"A": 0.9, "B": 0.7, "C": 0.6}, higher_is_better=False) == (["C"], True)
    assert leaders(clear, {"A": 0.9}) == ([], False)  # nothing to compare with


def test_tied_share_counts_queries_sharing_their_value():
    correct = np.array([True, False, True, False, True])
    method = _method("GV", correct, [-3, -3, -5, -1, -1])  # 4 of 5 queries share a value; 3 distinct values
    assert method.tied_share == 0.8 and method.n_distinct == 3
    assert method.to_dict()["tied_share"] == 0.8


def test_the_evaluate_table_shows_intervals_the_reference_and_the_kind_of_best():
    correct, uncertainties = _case()
    table = format_table(add_bootstrap(_evaluation(uncertainties, correct), n_resamples=300))
    assert "SU*" in table and "random*" not in table and "vs SU" in table
    assert "best AUC-PR, significantly better than every other method" in table
    su_line = next(line for line in table.splitlines() if line.startswith("SU*"))
    assert "[" in su_line and "reference" in su_line
    tied = {"SU": uncertainties["noisy"], "copy": uncertainties["noisy"].copy()}
    table = format_table(add_bootstrap(_evaluation(tied, correct), n_resamples=300))
    assert "SU*" in table and "copy*" in table and "tied leaders by AUC-PR" in table


def test_cli_evaluate_bootstrap_writes_the_intervals(tmp_path, capsys):
    rng = np.random.default_rng(2)
    similarity = rng.uniform(0.1, 0.8, size=(50, 70)).astype(np.float32)
    similarity[np.arange(0, 50, 2), np.arange(0, 50, 2)] = 0.95
    np.save(tmp_path / "sim.npy", similarity)
    (tmp_path / "gt.json").write_text(json.dumps([[i] for i in range(50)]))
    out = tmp_path / "results.json"
    args = ["evaluate", str(tmp_path / "sim.npy"), "--gt", str(tmp_path / "gt.json"), "--methods", "SU,BM,RS"]
    assert main([*args, "--bootstrap", "100", "--seed", "1", "--reference", "BM", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["bootstrap"]["reference"] == "BM" and len(data["methods"]["SU"]["auc_pr_ci"]) == 2
    assert "vs BM" in capsys.readouterr().out
    assert main([*args, "--bootstrap", "100", "--reference", "PA"]) == 2
    assert "reference method 'PA'" in capsys.readouterr().err
