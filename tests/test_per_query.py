"""Every result leaves as a table (issue 30, deliverable 2): ``evaluate --per-query FILE`` and
``Evaluation.per_query_columns()``/``per_query_frame()`` (one row per query: its name, top-1, correct, the top-k
scores and each method's uncertainty), recall@N and precision@recall in ``--csv``/``--latex``, and CSV cells that a
spreadsheet cannot run as formulas."""

from __future__ import annotations

import csv
import io
import json
import sys

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty import Evaluation, Retrieval, evaluate, get_method, read_results
from vpr_uncertainty.cli import main
from vpr_uncertainty.reports.tables import csv_cell, evaluation_csv, evaluation_latex, per_query_csv

DEFAULT_METHODS = ["RS", "SD", "SU", "PA", "L2", "BM"]
HEAD = ["query_index", "query", "top1_index", "top1", "answerable", "correct"]


@pytest.fixture
def netvlad(corridor_dir, corridor_matches_dir):
    """(the raw NetVLAD similarity matrix, the ground-truth sets, the matrix file, the ground-truth file)."""
    matrix, gt = (
        corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy",
        corridor_dir / "ground_truth_new.npy",
    )
    similarity = np.asarray(np.load(matrix, allow_pickle=True, encoding="latin1")[3], dtype=np.float64)
    truth = {int(q): set(p) for q, p in np.load(gt, allow_pickle=True, encoding="latin1")}
    return similarity, truth, matrix, gt


def _reference_su(similarity, k=10, alpha=0.5):
    """SU of each query straight from the paper's formulas, one query at a time."""
    values = []
    for row in similarity:
        top = sorted(row.tolist(), reverse=True)[:k]
        rs = sum(s / top[0] for s in top[1:]) / (k - 1)
        values.append(alpha * rs + (1 - alpha) * float(np.median(top)) / top[0])
    return np.array(values)


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_the_corridor_table_has_a_row_per_query_and_a_column_per_method(netvlad):
    similarity, truth, matrix, gt = netvlad
    retrieval = read_results(matrix, ground_truth=gt)
    evaluation = evaluate(retrieval, DEFAULT_METHODS, k=10, timing_repeats=1)
    columns = evaluation.per_query_columns()
    assert list(columns) == [*HEAD, *(f"s_{rank}" for rank in range(1, 11)), *DEFAULT_METHODS]
    assert all(column.shape == (111,) for column in columns.values())
    for name in DEFAULT_METHODS:  # the evaluated uncertainties, as the method computes them on its own
        assert_close(columns[name], get_method(name)(retrieval, k=10, alpha=0.5), err_msg=name)
    # and against the raw file, by hand
    assert_close(columns["SU"], _reference_su(similarity), dtype="float32")
    order = np.argsort(-similarity, axis=1, kind="stable")
    assert columns["top1_index"].tolist() == order[:, 0].tolist()
    assert columns["correct"].tolist() == [int(order[q, 0] in truth[q]) for q in range(111)]
    assert columns["answerable"].tolist() == [1] * 111 and columns["query_index"].tolist() == list(range(111))
    assert_close(columns["s_1"], similarity.max(axis=1), dtype="float32")
    assert_close(columns["s_10"], np.sort(similarity, axis=1)[:, -10], dtype="float32")
    assert set(columns["query"]) == set(columns["top1"]) == {""}  # VPR-Bench matrices hold no names
    pandas = pytest.importorskip("pandas")
    frame = evaluation.per_query_frame()
    assert frame.shape == (111, 6 + 10 + 6) and list(frame.columns) == list(columns)
    pandas.testing.assert_series_equal(frame["SU"], pandas.Series(columns["SU"], name="SU"))


def _named_retrieval() -> Retrieval:
    scores = np.array([[-0.25, -0.5, -0.75], [0.9, 0.3, -0.1], [0.8, 0.7, 0.6], [0.7, 0.6, 0.2]])
    return Retrieval(
        scores=scores,
        indices=np.array([[0, 1, 2], [1, 0, 2], [2, 1, 0], [0, 2, 1]]),
        positives=[[1], [1], [2], []],
        query_names=np.array(['=HYPERLINK("http://x")', "+cmd", "-2+3", "@SUM(A1)"]),
        database_names=np.array(["\tdb0.jpg", "db1.jpg", "\rdb2.jpg"]),
    )


def test_names_that_start_like_formulas_are_text_and_negative_numbers_stay_numbers():
    evaluation = evaluate(_named_retrieval(), ["BM", "PA"], k=3, timing_repeats=1)
    rows = list(csv.reader(io.StringIO(per_query_csv(evaluation), newline="")))
    assert rows[0] == [*HEAD, "s_1", "s_2", "s_3", "BM", "PA"] and len(rows) == 5
    assert [row[1] for row in rows[1:]] == ['\'=HYPERLINK("http://x")', "'+cmd", "'-2+3", "'@SUM(A1)"]
    assert [row[3] for row in rows[1:]] == ["'\tdb0.jpg", "db1.jpg", "'\rdb2.jpg", "'\tdb0.jpg"]
    assert [row[4] for row in rows[1:]] == ["1", "1", "1", "0"] and [row[5] for row in rows[1:]] == ["0", "1", "1", "0"]
    assert rows[1][6:9] == ["-0.25", "-0.5", "-0.75"] and rows[1][9] == "0.25"  # BM = -s_1
    assert float(rows[2][8]) == -0.1
    assert [csv_cell(text) for text in ("-0.5", "+1e-3", "-inf", "\t1", "-", "=1", 7, -1.5)] == [
        "-0.5",
        "+1e-3",
        "-inf",
        "'\t1",
        "'-",
        "'=1",
        7,
        -1.5,
    ]


def test_an_evaluation_read_back_needs_its_retrieval_for_the_table():
    retrieval = _named_retrieval()
    evaluation = evaluate(retrieval, ["BM"], k=3, timing_repeats=1)
    uncertainties = {name: method.uncertainty for name, method in evaluation.methods.items()}
    read_back = Evaluation.from_dict(evaluation.to_dict(), correct=evaluation.correct, uncertainties=uncertainties)
    with pytest.raises(ValueError, match="needs the retrieval of these 4 queries"):
        read_back.per_query_columns()
    assert per_query_csv(evaluation) == per_query_csv(evaluate(retrieval, ["BM"], k=3, timing_repeats=1))
    columns = read_back.per_query_columns(retrieval)
    assert list(columns)[-1] == "BM" and columns["s_3"].tolist() == retrieval.scores[:, 2].tolist()


def test_the_method_table_has_recall_at_n_and_precision_at_recall(netvlad):
    _, _, matrix, gt = netvlad
    evaluation = evaluate(read_results(matrix, ground_truth=gt), ["SU", "BM"], k=10, timing_repeats=1)
    document = json.loads(json.dumps(evaluation.to_dict()))
    rows = list(csv.DictReader(io.StringIO(evaluation_csv(evaluation))))
    for row in rows:
        for n in (1, 5, 10, 20):
            assert float(row[f"recall@{n}"]) == document[f"recall@{n}"]
        for level, value in document["methods"][row["method"]]["precision_at_recall"].items():
            assert row[f"precision_at_recall_{level}"] == ("" if value is None else repr(value))
    assert rows[0]["precision_at_recall_0.75"] == ""  # recall@1 0.676 < 0.75: not reached
    latex = evaluation_latex(evaluation)
    assert r"P@R=0.25 & P@R=0.5 & P@R=0.75 & ms/query \\" in latex
    assert "recall@1/5/10/20 0.676/0.937/0.991/1.000" in latex
    su = document["methods"]["SU"]["precision_at_recall"]
    assert f"& {su['0.25']:.3f} & {su['0.5']:.3f} & -- &" in latex


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_evaluate_writes_the_per_query_table(netvlad, tmp_path, capsys):
    similarity, _, matrix, gt = netvlad
    out = tmp_path / "tables" / "per_query.csv"
    argv = ["evaluate", str(matrix), "--gt", str(gt), "--per-query", str(out), "--json", str(tmp_path / "r.json")]
    assert main(argv) == 0
    rows = list(csv.DictReader(out.open(newline="")))
    assert len(rows) == 111 and list(rows[0]) == [*HEAD, *(f"s_{rank}" for rank in range(1, 11)), *DEFAULT_METHODS]
    assert_close(np.array([float(row["SU"]) for row in rows]), _reference_su(similarity), dtype="float32")
    recall = json.loads((tmp_path / "r.json").read_text())["recall@1"]
    assert np.mean([int(row["correct"]) for row in rows]) == pytest.approx(recall, abs=1e-12)
    pandas, _ = pytest.importorskip("pandas"), pytest.importorskip("pyarrow")
    assert main([*argv[:5], str(tmp_path / "per_query.parquet")]) == 0
    frame = pandas.read_parquet(tmp_path / "per_query.parquet")
    assert frame.shape == (111, 22) and frame["SU"].dtype == np.float32
    assert frame["SU"].tolist() == np.array([row["SU"] for row in rows], dtype=np.float32).tolist()  # exactly


def test_per_query_parquet_without_pyarrow_names_the_extra(netvlad, tmp_path, monkeypatch, capsys):
    _, _, matrix, gt = netvlad
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # as if not installed
    assert main(["evaluate", str(matrix), "--gt", str(gt), "--per-query", str(tmp_path / "t.parquet")]) == 2
    assert "pip install 'vpr-uncertainty[pandas]'" in capsys.readouterr().err
    assert main(["evaluate", str(matrix), "--gt", str(gt), "--per-query", str(tmp_path / "t.xlsx")]) == 2
    assert "--per-query: expected a .csv or .parquet file name" in capsys.readouterr().err
    assert (
        main(["evaluate", str(matrix), "--gt", str(gt), "--per-query", "t.csv", "--calibration-fraction", "0.3"]) == 2
    )
    assert "--per-query and --calibration-fraction cannot be combined" in capsys.readouterr().err
