"""The per-query table read back as a results format (formats/per_query.py): ``evaluate`` on the table gives the
AUC-PR of every score-based default method on the original retrieval; a new format is one module and one line."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from vpr_uncertainty import evaluate
from vpr_uncertainty.cli import main
from vpr_uncertainty.formats import RESULTS_FORMAT_REGISTRY, per_query, read_results


def _write_table(path, retrieval, evaluation):
    """The layout of ``evaluate --per-query``: ids, top-1, answerable, correct, s_1..s_K, one column per method;
    names quoted against formula injection as a careful writer does."""
    methods = list(evaluation.methods)
    answerable = np.diff(retrieval.positives.indptr) > 0
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow([*per_query.COLUMNS, *(f"s_{i + 1}" for i in range(retrieval.k)), *methods])
        for q in range(retrieval.n_queries):
            top1 = int(retrieval.indices[q, 0])
            writer.writerow(
                [q, f"'=query{q}.jpg", top1, f"ref/{top1}.jpg", bool(answerable[q]), bool(evaluation.correct[q])]
                + [repr(float(s)) for s in retrieval.scores[q]]
                + [repr(float(evaluation.methods[name].uncertainty[q])) for name in methods]
            )


@pytest.fixture(scope="module")
def table(corridor_dir, corridor_matches_dir, tmp_path_factory):
    matches = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    retrieval = read_results(matches, ground_truth=corridor_dir / "ground_truth_new.npy")
    evaluation = evaluate(retrieval)
    path = tmp_path_factory.mktemp("per-query") / "per_query.csv"
    _write_table(path, retrieval, evaluation)
    return path, evaluation


def test_the_table_is_sniffed_and_read_back_with_the_scores_and_correctness(table):
    path, evaluation = table
    assert per_query.sniff(path) and RESULTS_FORMAT_REGISTRY.get("per-query").detect(path)
    retrieval = read_results(path)
    assert retrieval.config["format"] == "per-query" and retrieval.n_queries == 111 and retrieval.k == 50
    assert retrieval.query_names[0] == "=query0.jpg"  # the writer's quote removed
    np.testing.assert_array_equal(evaluate(retrieval, ["BM"]).correct, evaluation.correct)


def test_evaluate_on_the_table_gives_the_auc_pr_of_every_score_based_default_method(table, tmp_path, capsys):
    path, evaluation = table
    found = evaluate(read_results(path))
    assert list(found.methods) == list(evaluation.methods) == ["RS", "SD", "SU", "PA", "L2", "BM"]
    for name, method in evaluation.methods.items():
        assert found.methods[name].auc_pr == pytest.approx(method.auc_pr, abs=1e-9), name
    assert found.recall_at_n == {1: pytest.approx(evaluation.recall_at_n[1])}  # the table names the top-1 only
    out = tmp_path / "r.json"
    assert main(["evaluate", str(path), "--json", str(out)]) == 0
    results = json.loads(out.read_text())["methods"]
    assert round(results["SU"]["auc_pr"], 4) == 0.8471
    for name, method in evaluation.methods.items():
        assert results[name]["auc_pr"] == pytest.approx(method.auc_pr, abs=1e-9), name


def test_other_tables_are_not_sniffed_and_a_bad_row_is_named(tmp_path):
    (tmp_path / "images.csv").write_text("path,role,x,y\na.jpg,database,0,0\n")
    assert not per_query.sniff(tmp_path / "images.csv") and not per_query.sniff(tmp_path / "missing.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text(",".join([*per_query.COLUMNS, "s_1", "s_2"]) + "\n0,q,3,r,True,True,0.9,x\n")
    assert per_query.sniff(bad)
    with pytest.raises(ValueError, match=r"bad\.csv: a row does not hold the columns of its header"):
        read_results(bad)
    with pytest.raises(ValueError, match="its ground truth is its correct and answerable columns"):
        read_results(bad, ground_truth=tmp_path / "gt.json")


def test_a_parquet_table_reads_as_its_csv(table, tmp_path):
    pandas = pytest.importorskip("pandas")
    pytest.importorskip("pyarrow")
    path, _ = table
    frame = pandas.read_csv(path)
    frame.to_parquet(tmp_path / "per_query.parquet")
    assert per_query.sniff(tmp_path / "per_query.parquet")
    from_parquet, from_csv = read_results(tmp_path / "per_query.parquet"), read_results(path)
    np.testing.assert_array_equal(from_parquet.scores, from_csv.scores)
    np.testing.assert_array_equal(from_parquet.positives.toarray(), from_csv.positives.toarray())


def test_the_table_evaluate_writes_reads_back_with_the_same_auc_pr(corridor_dir, corridor_matches_dir, tmp_path):
    """The round trip through the real writer: ``evaluate --per-query`` then ``evaluate`` on what it wrote."""
    matches = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    written = tmp_path / "per_query.csv"
    assert (
        main(
            [
                "evaluate",
                str(matches),
                "--gt",
                str(corridor_dir / "ground_truth_new.npy"),
                "--per-query",
                str(written),
                "--json",
                str(tmp_path / "a.json"),
            ]
        )
        == 0
    )
    assert main(["evaluate", str(written), "--json", str(tmp_path / "b.json")]) == 0
    first, again = (json.loads((tmp_path / name).read_text()) for name in ("a.json", "b.json"))
    auc = {name: method["auc_pr"] for name, method in first["methods"].items()}
    assert auc and {name: again["methods"][name]["auc_pr"] for name in auc} == pytest.approx(auc, abs=1e-6)
