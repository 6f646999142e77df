"""Table 1 with bootstrap intervals (vpr_uncertainty.reports.tables): a best is marked alone only where it
is significantly better than every other method of its column, otherwise the tied leaders are marked together;
the AP and AURC tables, the ties table, and the grid's bootstrap settings (config keys and reproduce flags)."""

from __future__ import annotations

import csv
import io
import json
from types import SimpleNamespace

import numpy as np
import pytest

from test_significance import _evaluation, _retrieval
from vpr_uncertainty.cli import main
from vpr_uncertainty.evaluation.bootstrap import add_bootstrap
from vpr_uncertainty.pipeline.grid import load_config
from vpr_uncertainty.reports.tables import (
    build_table1,
    build_ties_table,
    table1_csv,
    table1_latex,
    table1_markdown,
    ties_markdown,
)
from vpr_uncertainty.retrieval import save_retrieval


def _cells():
    """Column "clear": SU perfect, the others random. Column "close": SU and an exact copy lead together."""
    rng = np.random.default_rng(0)
    correct = rng.random(111) < 0.6
    perfect = np.where(correct, 0.0, 1.0) + 0.01 * rng.random(111)
    noisy = perfect + 1.5 * rng.random(111)
    clear = {"SU": perfect, "BM": rng.random(111), "GV": np.round(3 * rng.random(111))}
    close = {"SU": noisy, "BM": noisy.copy(), "GV": rng.random(111)}
    return [
        SimpleNamespace(vpr_method="clear", dataset="d", evaluation=_evaluation(clear, correct)),
        SimpleNamespace(vpr_method="close", dataset="d", evaluation=_evaluation(close, correct)),
    ]


def _column(markdown: str, name: str) -> list[str]:
    lines = [line for line in markdown.splitlines() if line.startswith("| ")]
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    j = header.index(name)
    return [[cell.strip() for cell in line.strip("|").split("|")][j] for line in lines[1:]]


def test_a_significant_best_is_marked_alone_and_tied_leaders_together():
    table = build_table1(_cells(), bootstrap=500, seed=0)
    assert table.significant[:2] == [True, False]
    markdown = table1_markdown(table)
    clear, close = _column(markdown, "clear"), _column(markdown, "close")
    assert [cell.startswith("**") for cell in clear] == [True, False, False]  # rows SU, BM, GV
    assert [cell.startswith("**") for cell in close] == [True, True, False]
    assert "[" in clear[0] and "Bold alone" in markdown
    rows = {row["method"]: row for row in csv.DictReader(io.StringIO(table1_csv(table)))}
    assert rows["SU"]["best_for"].split(";")[:2] == ["clear", "close"]
    assert (
        rows["SU"]["significant_best_for"].split(";")[0] == "clear"
        and "close" not in rows["SU"]["significant_best_for"]
    )
    assert rows["BM"]["best_for"].startswith("close") and rows["BM"]["significant_best_for"] == ""
    low, high = float(rows["BM"]["clear_ci_low"]), float(rows["BM"]["clear_ci_high"])
    assert low <= float(rows["BM"]["clear"]) <= high
    assert r"\textbf{" in table1_latex(table) and r"{\scriptsize [" in table1_latex(table, intervals=True)
    assert r"{\scriptsize [" not in table1_latex(table)  # intervals are an option, off by default


def test_a_one_dataset_column_has_the_intervals_of_its_cell():
    cells = _cells()
    table = build_table1(cells, bootstrap=300, seed=5)
    evaluation = add_bootstrap(cells[0].evaluation, n_resamples=300, seed=5)
    for i, name in enumerate(table.rows):
        assert table.intervals[i][0] == evaluation.methods[name].auc_pr_ci


def test_the_aurc_table_marks_the_lowest_and_ap_its_own_leaders():
    cells = _cells()
    aurc = build_table1(cells, "aurc", bootstrap=300)
    assert aurc.higher_is_better is False and [row[0] for row in aurc.leaders] == [True, False, False]
    assert "lowest" in table1_markdown(aurc)
    ap = build_table1(cells, "average_precision", bootstrap=300)
    assert [row[1] for row in ap.leaders] == [True, True, False]
    with pytest.raises(ValueError, match="metric must be one of auc_pr, average_precision, aurc"):
        build_table1(cells, "auc")


def test_without_bootstrap_the_best_value_is_marked_and_no_interval_columns():
    table = build_table1(_cells())
    assert table.intervals is None
    header = table1_csv(table).splitlines()[0]
    assert header == "method,clear,close,Mean,time_per_query_ms,best_for"
    assert "no significance test" in table1_markdown(table)


def test_the_ties_table_counts_tied_queries_and_distinct_values():
    table = build_ties_table(_cells())
    gv = table.rows.index("GV")
    assert table.distinct[gv][0] == 4 and table.tied_share[gv][0] == 1.0  # round(3 x uniform): 0, 1, 2, 3
    assert table.tied_share[table.rows.index("SU")][0] == 0.0
    assert "| GV | 100% (4) |" in ties_markdown(table)


def _grid(tmp_path, extra: str = "") -> str:
    save_retrieval(_retrieval(), tmp_path / "scores.npz")
    text = (
        f'out = "{tmp_path / "out"}"\nmethods = ["SU", "BM", "RS"]\nalphas = []\nks = []\n{extra}'
        f'[[inputs]]\nvpr_method = "V"\ndataset = "D"\nscores = "{tmp_path / "scores.npz"}"\n'
    )
    (tmp_path / "grid.toml").write_text(text)
    return str(tmp_path / "grid.toml")


def test_config_bootstrap_keys_are_checked_with_the_other_problems(tmp_path):
    path = _grid(tmp_path, 'bootstrap = -5\nseed = "x"\nreference = "PA"\nk = 1\n')
    with pytest.raises(ValueError, match="4 problem") as error:
        load_config(path)
    message = str(error.value)
    assert "bootstrap must be an integer >= 0, got -5" in message and "seed must be an integer >= 0" in message
    assert "reference 'PA' (the method of the paired tests) is not among methods (SU, BM, RS)" in message
    config = load_config(_grid(tmp_path, "bootstrap = 200\nseed = 3\n"))
    assert (config.bootstrap, config.seed, config.reference) == (200, 3, None)
    assert config.settings()["bootstrap"] == 200
    assert "bootstrap" not in load_config(_grid(tmp_path)).settings()  # caches of grids without one stay valid
    assert load_config(_grid(tmp_path), bootstrap=100, reference="BM").reference == "BM"


def test_reproduce_with_bootstrap_writes_intervals_and_the_three_tables(tmp_path, capsys):
    path = _grid(tmp_path)
    assert main(["reproduce", path, "--bootstrap", "200", "--seed", "1", "--reference", "BM"]) == 0
    out = tmp_path / "out"
    document = json.loads((out / "results.json").read_text())
    assert document["settings"]["bootstrap"] == 200 and document["settings"]["reference"] == "BM"
    cell = document["cells"][0]
    assert cell["bootstrap"]["reference"] == "BM" and len(cell["methods"]["SU"]["auc_pr_ci"]) == 2
    assert cell["methods"]["SU"]["vs_reference"]["reference"] == "BM"
    for name in ("table1.md", "table1.csv", "table1.tex", "table1_ap.md", "table1_aurc.csv", "ties.md"):
        assert (out / name).is_file(), name
    assert "V_ci_low" in (out / "table1.csv").read_text().splitlines()[0]
    assert "Table 1 by AURC" in (out / "report.html").read_text()
    assert main(["reproduce", path, "--reference", "PA", "--check"]) == 2
    assert "reference 'PA'" in capsys.readouterr().err
