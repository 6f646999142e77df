"""Report figures as plugins (:mod:`vpr_uncertainty.reports.figures`): selection by the ``report`` key, options,
needs, and a registered figure written by ``write_reports`` into its own section of report.html."""

from __future__ import annotations

import argparse
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty.pipeline import grid as reproduce_command
from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_reports
from vpr_uncertainty.reports import REPORT_FIGURES, register_report_figure
from vpr_uncertainty.reports.figures import parse_figure_spec
from vpr_uncertainty.retrieval import Retrieval, save_retrieval


def _retrieval(seed: int, n_queries: int = 30, n_database: int = 40, k: int = 10) -> Retrieval:
    rng = np.random.default_rng(seed)
    scores = -np.sort(-rng.random((n_queries, k)), axis=1).astype(np.float32)
    indices = np.stack([rng.permutation(n_database)[:k] for _ in range(n_queries)])
    positives = sparse.lil_array((n_queries, n_database), dtype=bool)
    for q in range(n_queries):
        positives[q, indices[q, 0] if q % 3 else indices[q, -1]] = True
    return Retrieval(scores=scores, indices=indices, positives=sparse.csr_array(positives))


def _grid(folder: Path, *lines: str) -> Path:
    save_retrieval(_retrieval(0), folder / "a.npz")
    text = ['out = "out"', 'methods = ["RS", "SD", "SU", "BM"]', "k = 5", *lines]
    text += [] if any(line.startswith("ks") for line in lines) else ["ks = [2, 5]"]
    text += ["[[inputs]]", 'vpr_method = "A"', 'dataset = "d"', 'scores = "a.npz"']
    (folder / "grid.toml").write_text("\n".join(text) + "\n")
    return folder / "grid.toml"


def _run(config_path: Path, **kwargs):
    config = load_config(config_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cells = run_grid(config, progress=False)
        return config, cells, write_reports(cells, config, **kwargs)


@pytest.fixture
def histogram_figure():
    """A user figure: a histogram of SU per cell, with a ``bins`` option; unregistered afterwards."""
    calls = []

    def write_histogram(cells, config, out_dir, *, bins=10):
        import matplotlib.pyplot as plt

        calls.append(bins)
        paths = []
        for cell in cells:
            figure, axis = plt.subplots(figsize=(3, 2))
            axis.hist(cell.evaluation.methods["SU"].uncertainty, bins=bins)
            path = out_dir / "figures" / f"su_histogram__{cell.vpr_method}.png"
            path.parent.mkdir(parents=True, exist_ok=True)
            figure.savefig(path)
            plt.close(figure)
            paths.append(path)
        return paths

    register_report_figure(
        "su_histogram",
        write_histogram,
        description="How SU is spread over the queries of each cell",
        requires=("uncertainties",),
        options={"bins": 10},
    )
    yield calls
    REPORT_FIGURES.unregister("su_histogram")


def test_registered_figure_is_written_and_shown_in_report_html(tmp_path, histogram_figure):
    _, _, paths = _run(_grid(tmp_path))
    (histogram,) = paths["su_histogram"]
    assert histogram == tmp_path / "out" / "figures" / "su_histogram__A.png" and histogram.is_file()
    assert histogram_figure == [10]
    text = paths["report_html"].read_text()
    assert "How SU is spread over the queries of each cell" in text
    assert text.count('<img class="figure"') == 3 + 2 + 1 + 1  # heatmaps, ablations, PR curve, histogram
    assert text.index("Qualitative examples") < text.index("How SU is spread")  # after the built-ins


def test_report_key_selects_figures_and_their_options(tmp_path, histogram_figure):
    """Regression: `report` was accepted by the config and silently ignored (every figure was written)."""
    _, _, paths = _run(_grid(tmp_path, 'report = ["table1", "su_histogram:bins=4"]'))
    assert sorted(key for key in paths if not key.startswith("table1_")) == ["report_html", "su_histogram", "table1"]
    assert [p.name for p in paths["table1"]] == ["table1.md", "table1.csv", "table1.tex"]
    assert paths["table1_md"] == tmp_path / "out" / "table1.md"
    assert histogram_figure == [4]
    assert not (tmp_path / "out" / "figures" / "delta_SU.png").exists()
    text = paths["report_html"].read_text()
    assert text.count('<img class="figure"') == 1 and '<table class="table1">' in text
    assert "Ablations" not in text


def test_figures_argument_overrides_the_config(tmp_path):
    _, _, paths = _run(_grid(tmp_path, 'report = ["table1"]'), figures=["pr_curves"], html=False)
    assert list(paths) == ["pr_curves"] and [p.suffix for p in paths["pr_curves"]] == [".png", ".pdf"]


def test_report_key_errors_are_listed_together(tmp_path):
    config_path = _grid(tmp_path, 'report = ["heatmap", "table1:digits=2", "qualitative", "table1", "table1"]')
    with pytest.raises(ValueError) as error:
        load_config(config_path)
    message = str(error.value)
    assert "4 problem(s)" in message
    assert "unknown report figure 'heatmap'; did you mean 'heatmaps'? available: table1, heatmaps" in message
    assert "table1 has no option 'digits' (its options: none)" in message
    assert "report figure 'qualitative' needs a cell with query and database images" in message
    assert "report figure 'table1' is listed more than once" in message
    with pytest.raises(ValueError, match="report is empty: name at least one report figure"):
        load_config(_grid(tmp_path, "report = []"))
    with pytest.raises(ValueError, match="report must be a list of report figure names"):
        load_config(_grid(tmp_path, "report = 3"))
    with pytest.raises(ValueError, match=r"report figure 'qualitative:rank_by': expected option=value"):
        load_config(_grid(tmp_path, 'report = "qualitative:rank_by"'))


def test_a_figure_whose_needs_the_grid_does_not_meet_is_skipped_with_a_note(tmp_path):
    _, _, paths = _run(_grid(tmp_path, "alphas = []", "ks = []"))
    assert paths["ablations"] == [] and paths["qualitative"] == []
    text = paths["report_html"].read_text()
    assert "Not written: report figure &#x27;ablations&#x27; needs the α or k ablation" in text
    assert "Not written: report figure &#x27;qualitative&#x27; needs a cell with query and database images" in text


def test_registration_is_checked(tmp_path):
    with pytest.raises(ValueError, match="already registered"):
        register_report_figure("table1", lambda *a: [], description="x")
    with pytest.raises(ValueError, match=r"unknown need 'gps' \(valid: evaluation, uncertainties, images"):
        register_report_figure("maps", lambda *a: [], description="x", requires=("gps",))
    with pytest.raises(ValueError, match="hold no ':'"):
        register_report_figure("a:b", lambda *a: [], description="x")
    assert parse_figure_spec(" qualitative : rank_by = RS ") == ("qualitative", {"rank_by": "RS"})
    register_report_figure("broken", lambda cells, config, out_dir: "nothing", description="returns no paths")
    try:
        with pytest.raises(TypeError, match="report figure 'broken' must return a list of the Paths it wrote"):
            _run(_grid(tmp_path), figures=["broken"])
    finally:
        REPORT_FIGURES.unregister("broken")
    assert "broken" not in REPORT_FIGURES


def test_reproduce_command_without_table1(tmp_path, capsys):
    """The command printed table1.md unconditionally; with a report that has no Table 1 it must not fail."""
    parser = argparse.ArgumentParser()
    reproduce_command.add_cli(parser.add_subparsers())
    args = parser.parse_args(["reproduce", str(_grid(tmp_path, 'report = ["pr_curves"]'))])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert args.handler(args) == 0
    out = capsys.readouterr().out
    assert "| method |" not in out and re.search(r"wrote .*report\.html", out)
    assert not (tmp_path / "out" / "table1.md").exists()
