"""Report building blocks on small synthetic grids (no real data needed): Table 1, ΔAUC-PR, HTML, config."""

from __future__ import annotations

import csv
import io
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

from conftest import assert_close
from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_reports, write_results
from vpr_uncertainty.reports.html import Section, embed_png, render_report
from vpr_uncertainty.reports.plots import choose_queries, delta_matrix, heatmap_distributions
from vpr_uncertainty.reports.tables import build_table1, table1_csv, table1_latex, table1_markdown
from vpr_uncertainty.retrieval import Retrieval, save_retrieval


def _retrieval(seed: int, n_queries: int = 40, n_database: int = 60, k: int = 20) -> Retrieval:
    rng = np.random.default_rng(seed)
    scores = -np.sort(-rng.random((n_queries, k)), axis=1).astype(np.float32)
    indices = np.stack([rng.permutation(n_database)[:k] for _ in range(n_queries)])
    # Confident answers (large gap to the second score) are more often correct.
    gap = scores[:, 0] - scores[:, 1]
    correct = rng.random(n_queries) < 0.3 + 4 * gap
    positives = sparse.lil_array((n_queries, n_database), dtype=bool)
    for q in range(n_queries):
        positives[q, indices[q, 0] if correct[q] else indices[q, -1]] = True
    return Retrieval(scores=scores, indices=indices, positives=sparse.csr_array(positives))


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    root = tmp_path_factory.mktemp("synthetic")
    lines = ['out = "out"', 'methods = ["RS", "SD", "SU", "BM"]', "k = 5", "ks = [2, 5, 10, 50]"]
    for seed, (vpr, dataset) in enumerate([("A", "d1"), ("A", "d2"), ("B", "d1"), ("B", "d2")]):
        save_retrieval(_retrieval(seed), root / f"{vpr}_{dataset}.npz")
        lines += ["[[inputs]]", f'vpr_method = "{vpr}"', f'dataset = "{dataset}"', f'scores = "{vpr}_{dataset}.npz"']
    (root / "grid.toml").write_text("\n".join(lines) + "\n")
    config = load_config(root / "grid.toml")
    cells = run_grid(config, progress=False)
    paths = write_results(cells, config)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        paths.update(write_reports(cells, config))
    return config, cells, paths


def test_grid_from_retrieval_files(synthetic):
    config, cells, paths = synthetic
    assert config.out == paths["results_json"].parent
    assert [(c.vpr_method, c.dataset) for c in cells] == [("A", "d1"), ("A", "d2"), ("B", "d1"), ("B", "d2")]
    for cell in cells:
        assert sorted(cell.ablation_k["RS"]) == [2, 5, 10]  # k = 50 exceeds the 20 candidates: left out
        assert_close(cell.ablation_alpha[1.0], cell.evaluation.methods["RS"].auc_pr)
    rows = list(csv.DictReader(paths["results_csv"].open()))
    assert len(rows) == 4 * 4
    assert {"recall@1", "recall@5", "time_per_query_ms", "average_precision", "aurc"} <= set(rows[0])
    assert paths["qualitative"] == []  # no image paths: no qualitative figure


def test_table1_averages_over_datasets_and_marks_the_best(synthetic):
    _, cells, _ = synthetic
    table = build_table1(cells)
    assert table.rows == ["RS", "SD", "SU", "BM"]
    assert table.columns == ["A", "B", "Mean"]
    expected = np.mean([c.evaluation.methods["SU"].auc_pr for c in cells if c.vpr_method == "A"])
    assert_close(table.values[2][0], expected)
    assert_close(table.values[2][2], np.mean(table.values[2][:2]))
    best = table.best()
    markdown = table1_markdown(table)
    assert f"**{best[0]:.3f}**" in markdown
    rows = list(csv.DictReader(io.StringIO(table1_csv(table))))
    winners = [row["method"] for row in rows if "A" in row["best_for"].split(";")]
    assert winners and all(
        float(row["A"]) == pytest.approx(best[0], rel=0, abs=1e-6) for row in rows if row["method"] in winners
    )
    latex = table1_latex(table)
    assert latex.count(r"\textbf{") >= 3 and r"\toprule" in latex and r"\bottomrule" in latex


def test_table1_with_missing_values():
    from vpr_uncertainty.reports.tables import Table1

    table = Table1(rows=["RS", "BM"], columns=["A", "Mean"], values=[[None, None], [0.5, 0.5]], time_ms=[None, 1.0])
    assert "| RS | – | – | – |" in table1_markdown(table)
    assert table1_csv(table).splitlines()[1] == "RS,,,,"


def test_delta_matrix(synthetic):
    _, cells, _ = synthetic
    vpr, datasets, delta, significant = delta_matrix(cells, "SU", "BM")
    assert vpr == ["A", "B"] and datasets == ["d1", "d2"] and not significant.any()  # no bootstrap: no marks
    methods = cells[3].evaluation.methods
    assert_close(delta[1, 1], methods["SU"].auc_pr - methods["BM"].auc_pr)
    assert np.isnan(delta_matrix(cells, "SU", "PA")[2]).all()


def test_delta_matrix_marks_what_a_slow_paired_bootstrap_finds_significant(synthetic):
    from sklearn.metrics import auc, precision_recall_curve

    from vpr_uncertainty.evaluation.bootstrap import resample_indices

    _, cells, _ = synthetic
    _, _, _, significant = delta_matrix(cells, "SU", "RS", heatmap_distributions(cells, 300, 4))
    for cell in cells:
        i, j = ["A", "B"].index(cell.vpr_method), ["d1", "d2"].index(cell.dataset)
        correct, methods = cell.evaluation.correct, cell.evaluation.methods
        deltas = []
        for rows in (row for block in resample_indices(len(correct), 300, 4) for row in block):
            if correct[rows].all() or not correct[rows].any():
                continue  # one class only: skipped, as the toolkit does
            curves = [precision_recall_curve(correct[rows], -methods[m].uncertainty[rows]) for m in ("SU", "RS")]
            deltas.append(auc(curves[0][1], curves[0][0]) - auc(curves[1][1], curves[1][0]))
        low, high = np.percentile(deltas, [2.5, 97.5])
        assert significant[i, j] == (low > 0 or high < 0)


def test_html_embeds_pngs(tmp_path, synthetic):
    _, _, paths = synthetic
    text = paths["report_html"].read_text()
    assert text.count('<img class="figure"') == 3 + 2 + 4
    assert "render-check" in text
    (tmp_path / "x.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="not a PNG"):
        embed_png(tmp_path / "x.png")
    html = render_report("t <&>", [Section("s", "<p>x</p>")])
    assert "<title>t &lt;&amp;&gt;</title>" in html


def test_choose_queries_skips_empty_categories():
    assert choose_queries(np.array([True, True]), np.array([0.5, 0.1])) == {
        "confident correct": 1,
        "uncertain correct": 0,
    }


def test_config_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_config(tmp_path / "none.toml")
    (tmp_path / "a.json").write_text("{}")
    with pytest.raises(ValueError, match=r"expected \.toml"):
        load_config(tmp_path / "a.json")
    (tmp_path / "b.toml").write_text('colour = "red"\nk = 1\n[[inputs]]\nscores = "x.npy"\nmodel = "m"\n')
    with pytest.raises(ValueError) as error:
        load_config(tmp_path / "b.toml")
    message = str(error.value)
    assert "unknown top-level key 'colour'" in message
    assert "k must be an integer >= 2" in message
    assert "exactly one of precomputed_matches, scores or model" in message


def test_yaml_config_needs_pyyaml_or_works(tmp_path):
    path = tmp_path / "grid.yaml"
    save_retrieval(_retrieval(1), tmp_path / "r.npz")
    path.write_text("methods: [SU, BM]\ninputs:\n  - {vpr_method: A, dataset: d, scores: r.npz}\n")
    try:
        import yaml  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="pyyaml"):
            load_config(path)
    else:
        assert load_config(path).inputs[0].scores == Path(tmp_path / "r.npz")


def test_special_characters_in_names_are_escaped_in_markdown_and_latex():
    """A `|` in a method name broke table1.md; `$ ^ ~` reached table1.tex unescaped (issue 20)."""
    import re

    from vpr_uncertainty.reports.tables import Table1

    table = Table1(
        rows=["SU|GV", "x$^2$~{y}"], columns=["A|B", "Mean"], values=[[0.5, 0.5], [0.6, 0.6]], time_ms=[1.0, 1.0]
    )
    markdown = table1_markdown(table).splitlines()
    unescaped_bars = [len(re.findall(r"(?<!\\)\|", line)) for line in markdown[:4]]
    assert unescaped_bars == [5, 5, 5, 5]  # every row keeps its 4 cells
    assert "| SU\\|GV |" in markdown[2]
    latex = table1_latex(table)
    assert r"x\$\textasciicircum{}2\$\textasciitilde{}\{y\}" in latex and "SU|GV" in latex
