"""``evaluate --latex/--csv`` and the study's Table 1 in LaTeX: booktabs, a label and a caption, fits \\columnwidth,
intervals only when asked; the numbers are those of --json. No LaTeX engine here: the structure is checked."""

from __future__ import annotations

import csv
import io
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from vpr_uncertainty import Retrieval, cli, evaluate
from vpr_uncertainty.reports.latex import LATEX_PACKAGES
from vpr_uncertainty.reports.tables import Table1, evaluation_csv, evaluation_latex, table1_latex


def _balanced(text: str) -> bool:
    depth = 0
    for char in re.sub(r"\\[{}]", "", text):  # escaped braces are text
        depth += {"{": 1, "}": -1}.get(char, 0)
        if depth < 0:
            return False
    return depth == 0


def _tabular(text: str) -> tuple[int, list[list[str]]]:
    """(columns declared by the tabular, the cells of each row between the rules)."""
    spec = re.search(r"\\begin\{tabular\}\{([lrc]+)\}", text).group(1)
    body = text.split(r"\toprule")[1].split(r"\bottomrule")[0].replace(r"\midrule", "")
    rows = [row.strip() for row in body.split(r"\\") if row.strip()]
    return len(spec), [re.split(r"(?<!\\)&", row) for row in rows]


def _check_structure(text: str, label: str) -> list[list[str]]:
    assert _balanced(text)
    for rule in (r"\toprule", r"\midrule", r"\bottomrule"):
        assert text.count(rule) == 1
    assert rf"\label{{{label}}}" in text and r"\caption{" in text
    assert r"\resizebox{\ifdim\width>\columnwidth\columnwidth\else\width\fi}{!}{%" in text
    assert text.index(r"\begin{table}") < text.index(r"\begin{tabular}") < text.index(r"\end{table}")
    n_columns, rows = _tabular(text)
    assert all(len(row) == n_columns for row in rows), rows  # the header and every row
    return rows


def _compiles(text: str, tmp_path) -> None:
    """Compile in a two-column article when a LaTeX engine is installed (none in CI: the structure is checked)."""
    if not shutil.which("pdflatex"):
        return
    document = rf"\documentclass[twocolumn]{{article}}{LATEX_PACKAGES}\begin{{document}}{text}\end{{document}}"
    (tmp_path / "t.tex").write_text(document)
    subprocess.run(["pdflatex", "-halt-on-error", "t.tex"], cwd=tmp_path, check=True, capture_output=True)


@pytest.fixture
def evaluated():
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((60, 5)), axis=1)
    indices = np.array([rng.permutation(20)[:5] for _ in range(60)])
    positives = [[int(indices[q, 0])] if rng.random() < 0.6 else [int(indices[q, 3])] for q in range(60)]
    retrieval = Retrieval(scores=scores, indices=indices, positives=positives)
    return evaluate(retrieval, ["SU", "BM", "L2"], k=5, bootstrap=50, timing_repeats=1)


def test_evaluation_latex_structure_and_numbers(evaluated, tmp_path):
    text = evaluation_latex(evaluated)
    rows = _check_structure(text, "tab:uncertainty")
    header, body = rows[0], rows[1:]
    precisions = ["P@R=0.25", "P@R=0.5", "P@R=0.75"]
    assert [cell.strip() for cell in header] == ["Method", "AUC-PR", "AP", "AURC", r"R@100\%P", *precisions, "ms/query"]
    document = json.loads(json.dumps(evaluated.to_dict()))
    for row in body:
        name = row[0].strip()
        numbers = [float(re.sub(r"\\textbf\{|\}", "", cell).split()[0].replace("--", "nan")) for cell in row[1:]]
        method = document["methods"][name]
        expected = [method[key] for key in ("auc_pr", "average_precision", "aurc", "recall_at_100_precision")]
        assert numbers[:4] == [round(value, 4 if i < 3 else 3) for i, value in enumerate(expected)]
    assert "[" not in text.split(r"\toprule")[1]  # intervals off by default
    with_intervals = evaluation_latex(evaluated, intervals=True, label="tab:x")
    _check_structure(with_intervals, "tab:x")
    low, high = evaluated.methods["SU"].auc_pr_ci
    assert f"[{low:.3f}, {high:.3f}]" in with_intervals
    _compiles(text, tmp_path)


def test_evaluation_csv_holds_the_json_numbers_exactly(evaluated):
    document = json.loads(json.dumps(evaluated.to_dict()))
    rows = list(csv.DictReader(io.StringIO(evaluation_csv(evaluated))))
    assert [row["method"] for row in rows] == list(document["methods"])
    for row in rows:
        method = document["methods"][row["method"]]
        for key in ("auc_pr", "average_precision", "aurc", "recall_at_100_precision", "time_per_query_ms"):
            assert float(row[key]) == method[key]
        assert [float(row["auc_pr_ci_low"]), float(row["auc_pr_ci_high"])] == method["auc_pr_ci"]


def test_table1_latex_fits_has_a_label_and_intervals_only_when_asked(tmp_path):
    table = Table1(
        rows=["SU", "BM", "margin_x"],
        columns=["NetVLAD", "AP-GeM", "Mean"],
        values=[[0.81, 0.72, 0.765], [0.80, None, 0.80], [0.5, 0.5, 0.5]],
        time_ms=[0.01, 0.002, None],
        informative=[[True] * 3, [True] * 3, [False] * 3],
        intervals=[[(0.7, 0.9)] * 3, [(0.6, 0.85), None, (0.6, 0.85)], [None] * 3],
    )
    text = table1_latex(table)
    rows = _check_structure(text, "tab:auc-pr")
    assert [cell.strip() for cell in rows[0]] == ["Method", "NetVLAD", "AP-GeM", "Mean", "ms/query"]
    assert "[0.70, 0.90]" not in text and r"margin\_x" in text and r"$^\dagger$" in text
    assert r"\textbf{0.810}" in text and "--" in rows[2][2]
    shown = table1_latex(table, intervals=True, label="tab:main", width=None)
    assert "[0.70, 0.90]" in shown and r"\label{tab:main}" in shown and r"\resizebox" not in shown
    assert _balanced(shown)
    _compiles(text, tmp_path)


def test_evaluate_command_writes_latex_and_csv(corridor_dir, corridor_matches_dir, tmp_path):
    matrix = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    out = {suffix: tmp_path / f"t.{suffix}" for suffix in ("json", "tex", "csv")}
    argv = ["evaluate", str(matrix), "--gt", str(corridor_dir / "ground_truth_new.npy"), "--methods", "SU,BM,PA"]
    argv += ["--json", str(out["json"]), "--latex", str(out["tex"]), "--csv", str(out["csv"])]
    assert cli.main(argv) == 0
    document = json.loads(out["json"].read_text())
    rows = _check_structure(out["tex"].read_text(), "tab:uncertainty")
    assert [row[0].strip() for row in rows[1:]] == ["SU", "BM", "PA"]
    for row in csv.DictReader(io.StringIO(out["csv"].read_text())):
        assert float(row["auc_pr"]) == document["methods"][row["method"]]["auc_pr"]
