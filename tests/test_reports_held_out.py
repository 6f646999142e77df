"""The held-out calibration option in the report (reports/held_out.py): the ``reliability`` figure (one diagram per
cell, counts per bin, ECE and Brier), its section in report.html, Table 1 from held-out means, and the figure as a
config problem without the option. Real inputs: two corridor similarity matrices.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from vpr_uncertainty.pipeline.grid import load_config, run_grid, write_reports
from vpr_uncertainty.reports.figures import REPORT_FIGURES
from vpr_uncertainty.reports.tables import table1_cells, table1_note

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")


def _config(tmp_path: Path, corridor_dir: Path, corridor_matches_dir: Path, extra: str) -> Path:
    path = tmp_path / "grid.toml"
    path.write_text(
        f'out = "out"\nmethods = ["SU", "BM", "CAL"]\nalphas = []\nks = []\n{extra}'
        f'[[inputs]]\nprecomputed_matches = "{corridor_matches_dir}"\nvpr_methods = ["NetVLAD", "CALC"]\n'
        f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"\ndataset = "corridor"\n'
    )
    return path


@pytest.fixture(scope="module")
def written(tmp_path_factory, corridor_dir, corridor_matches_dir):
    tmp_path = tmp_path_factory.mktemp("held_out_report")
    option = "calibration = {fraction = 0.3, repeats = 2, seed = 0}\n"
    config = load_config(_config(tmp_path, corridor_dir, corridor_matches_dir, option))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cells = run_grid(config, progress=False)
        paths = write_reports(cells, config, figures=["table1", "reliability"])
    return cells, paths


def test_reliability_is_registered_after_the_builtins():
    entry = REPORT_FIGURES.get("reliability")
    assert REPORT_FIGURES.names()[-1] == "reliability" and entry.requires == ("calibration",)


def test_one_reliability_diagram_per_cell_and_a_section_with_ece_and_brier(written):
    cells, paths = written
    pngs = paths["reliability"]
    assert [path.name for path in pngs] == [f"{cell.vpr_method}__corridor.png" for cell in cells]
    assert {cell.vpr_method for cell in cells} == {"CALC", "NetVLAD"}
    assert all(path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for path in pngs)
    html = paths["report_html"].read_text()
    assert "Calibration of CAL on held-out queries" in html and "Not written" not in html
    for cell in cells:
        quality = cell.held_out["calibration_quality"]["CAL"]
        assert sum(quality["reliability"]["counts"]) == 2 * cell.held_out["calibration"]["n_held_out"]
        assert f"{quality['ece']:.3f} ± {quality['ece_std']:.3f}" in html
        assert f"{quality['brier']:.3f} ± {quality['brier_std']:.3f}" in html


def test_table1_holds_the_held_out_means_and_says_so(written):
    cells, paths = written
    views = table1_cells(cells)
    for view, cell in zip(views, cells, strict=True):
        assert set(view.evaluation.methods) == {"SU", "BM", "CAL"}
        for name, method in view.evaluation.methods.items():
            assert method.auc_pr == cell.held_out["methods"][name]["auc_pr"]
            assert method.time_per_query_ms > 0
    assert "| CAL |" in paths["table1_md"].read_text()
    assert (
        table1_note(cells) in paths["table1_md"].read_text() and table1_note(cells) in paths["report_html"].read_text()
    )


def test_without_the_option_table1_is_unchanged_and_reliability_is_a_config_problem(
    tmp_path, corridor_dir, corridor_matches_dir
):
    path = _config(tmp_path, corridor_dir, corridor_matches_dir, 'report = ["table1", "reliability"]\n')
    path.write_text(path.read_text().replace('"CAL"', '"CAL:gate=gate.json"'))
    with pytest.raises(ValueError) as error:
        load_config(path)
    assert "report figure 'reliability' needs CAL evaluated on held-out queries" in str(error.value)
    path.write_text(
        path.read_text().replace(', "CAL:gate=gate.json"', "").replace('"table1", "reliability"', '"table1"')
    )
    config = load_config(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cells = run_grid(config, progress=False)
    assert table1_cells(cells) == cells and table1_note(cells) is None
    assert all(cell.held_out is None and "held_out" not in cell.to_dict() for cell in cells)
    paths = write_reports(cells, config, figures=["table1", "reliability"])
    assert paths["reliability"] == [] and "AUC-PR on held-out queries" not in paths["table1_md"].read_text()


def test_table1_refuses_a_mix_of_cells_with_and_without_held_out_numbers(written):
    import dataclasses

    cells, _ = written
    with pytest.raises(ValueError, match="without a held-out evaluation"):
        table1_cells([cells[0], dataclasses.replace(cells[1], held_out=None)])
