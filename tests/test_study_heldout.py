"""The grid's held-out calibration option (study/heldout.py): config round trip and problems, the cell's held-out
evaluation (equal to evaluate_held_out's numbers for the same seed), results.json, Table 1's CAL row and the cell
fingerprint. Real inputs: the NetVLAD similarity matrix of the corridor and its ground truth.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse

from vpr_uncertainty.calibration.quality import evaluate_held_out
from vpr_uncertainty.data import DEFAULT_TOP_K, read_results
from vpr_uncertainty.pipeline.grid import (
    _cell_fingerprint,
    candidates_needed,
    held_out_evaluation,
    load_config,
    run_grid,
    write_reports,
    write_results,
)
from vpr_uncertainty.pipeline.grid_config import fitted_per_split, full_query_methods
from vpr_uncertainty.retrieval import Retrieval

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")

OPTION = "calibration = {fraction = 0.3, repeats = 3, seed = 7}\n"


def _config(tmp_path: Path, corridor_dir: Path, corridor_matches_dir: Path, extra: str = "", name="grid") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(
        f'out = "out_{name}"\nmethods = ["SU", "BM", "CAL"]\nalphas = []\nks = []\n{extra}'
        f'[[inputs]]\nprecomputed_matches = "{corridor_matches_dir}"\nvpr_methods = ["NetVLAD"]\n'
        f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"\ndataset = "corridor"\n'
    )
    return path


def _run(path: Path):
    config = load_config(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return config, run_grid(config, progress=False)


def test_option_round_trips_through_the_config(tmp_path, corridor_dir, corridor_matches_dir):
    config = load_config(_config(tmp_path, corridor_dir, corridor_matches_dir, OPTION))
    assert config.calibration == {"fraction": 0.3, "repeats": 3, "seed": 7}
    assert config.settings()["calibration"] == config.calibration
    defaults = load_config(_config(tmp_path, corridor_dir, corridor_matches_dir, "calibration = {}\n", "d"))
    assert defaults.calibration == {"fraction": 0.3, "repeats": 20, "seed": 0}


def test_without_the_option_nothing_changes(tmp_path, corridor_dir, corridor_matches_dir):
    path = tmp_path / "plain.toml"
    path.write_text(
        f'out = "out"\nmethods = ["SU", "BM"]\n[[inputs]]\nprecomputed_matches = "{corridor_matches_dir}"\n'
        f'vpr_methods = ["NetVLAD"]\nground_truth = "{corridor_dir / "ground_truth_new.npy"}"\n'
    )
    config = load_config(path)
    assert config.calibration is None and "calibration" not in config.settings()
    assert full_query_methods(["SU", "CAL"], None) == ["SU", "CAL"]


def test_bad_option_values_are_all_reported_at_once(tmp_path, corridor_dir, corridor_matches_dir):
    bad = "calibration = {fraction = 1.5, repeats = 0, seed = -1, sed = 3}\n"
    with pytest.raises(ValueError) as error:
        load_config(_config(tmp_path, corridor_dir, corridor_matches_dir, bad))
    message = str(error.value)
    assert "4 problem(s)" in message, message
    for part in ("calibration.fraction", "calibration.repeats", "calibration.seed", "unknown key 'sed'"):
        assert part in message
    assert "CAL needs" not in message  # the bad table is not also reported as a missing gate
    with pytest.raises(ValueError, match=re.escape("calibration must be a table such as calibration = {fraction")):
        load_config(_config(tmp_path, corridor_dir, corridor_matches_dir, "calibration = 0.3\n"))
    with pytest.raises(ValueError, match=re.escape("calibration.repeats must be an integer >= 1, got True")):
        load_config(_config(tmp_path, corridor_dir, corridor_matches_dir, "calibration = {repeats = true}\n"))


def test_cal_without_gate_or_option_names_both_remedies(tmp_path, corridor_dir, corridor_matches_dir):
    with pytest.raises(ValueError) as error:
        load_config(_config(tmp_path, corridor_dir, corridor_matches_dir))
    assert "CAL needs a fitted gate" in str(error.value) and "calibration = {fraction" in str(error.value)


def test_only_cal_and_btl_are_config_problems(tmp_path, corridor_dir, corridor_matches_dir):
    path = _config(tmp_path, corridor_dir, corridor_matches_dir, OPTION)
    path.write_text(path.read_text().replace('["SU", "BM", "CAL"]', '["CAL"]'))
    with pytest.raises(ValueError, match=re.escape("methods holds only CAL")):
        load_config(path)
    path.write_text(path.read_text().replace('["CAL"]', '["CAL", "SU", "BTL:btl_head=head.pt"]'))
    message = f"BTL:btl_head={tmp_path / 'head.pt'} is not supported by the held-out evaluation"  # beside the config
    with pytest.raises(ValueError, match=re.escape(message)):
        load_config(path)


def test_cal_row_equals_evaluate_held_out_for_the_same_seed(tmp_path, corridor_dir, corridor_matches_dir):
    config, (cell,) = _run(_config(tmp_path, corridor_dir, corridor_matches_dir, OPTION))
    assert "CAL" not in cell.evaluation.methods  # no gate on all queries: only held-out
    retrieval = read_results(
        corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy",
        ground_truth=corridor_dir / "ground_truth_new.npy",
        top_k=max(DEFAULT_TOP_K, candidates_needed(config)),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reference = evaluate_held_out(retrieval, ["SU", "BM", "CAL"], calibration_fraction=0.3, repeats=3, seed=7)
    paths = write_results([cell], config)
    paths.update(write_reports([cell], config, figures=["table1"], html=False))
    document = json.loads(paths["results_json"].read_text())
    assert document["calibration"] == {"fraction": 0.3, "repeats": 3, "seed": 7}
    held_out = document["cells"][0]["held_out"]
    lines = [line.split("|") for line in paths["table1_md"].read_text().splitlines() if line.startswith("| ")]
    rows = {cells[1].strip(): cells[2].strip() for cells in lines}
    csv_rows = {line.split(",")[0]: line.split(",")[1] for line in paths["table1_csv"].read_text().splitlines()[1:]}
    for method in ("SU", "BM", "CAL"):
        expected = reference.mean(method)
        assert held_out["methods"][method]["auc_pr"] == expected  # the very same code path
        assert held_out["methods"][method]["auc_pr_std"] == reference.std(method)
        assert float(csv_rows[method]) == pytest.approx(expected, abs=5e-7)  # written with 6 decimals
        assert rows[method].strip("*") == f"{expected:.3f}"
    assert held_out["calibration_quality"]["CAL"]["ece"] == reference.quality["CAL"]["ece"]
    assert "AUC-PR on held-out queries: mean over 3 random splits (seed 7)" in paths["table1_md"].read_text()


def test_option_is_part_of_the_cell_fingerprint_and_cache(tmp_path, corridor_dir, corridor_matches_dir):
    path = _config(tmp_path, corridor_dir, corridor_matches_dir, OPTION)
    config, (first,) = _run(path)
    _, (again,) = _run(path)
    assert again.cached and again.held_out == json.loads(json.dumps(first.held_out))
    entry = config.inputs[0]
    fingerprints = {_cell_fingerprint(entry, config)}
    for option in ({"fraction": 0.3, "repeats": 3, "seed": 8}, {"fraction": 0.5, "repeats": 3, "seed": 7}, None):
        config.calibration = option
        fingerprints.add(_cell_fingerprint(entry, config))
    assert len(fingerprints) == 4
    path.write_text(path.read_text().replace("seed = 7", "seed = 8"))
    _, (reseeded,) = _run(path)
    assert not reseeded.cached and reseeded.held_out["calibration"]["seed"] == 8
    assert (
        reseeded.held_out["methods"]["CAL"]["auc_pr_per_repeat"]
        != first.held_out["methods"]["CAL"]["auc_pr_per_repeat"]
    )


def test_fitted_per_split_only_for_cal_without_gate():
    assert fitted_per_split("CAL") and not fitted_per_split("CAL:gate=g.json") and not fitted_per_split("SU")
    assert full_query_methods(["SU", "CAL", "CAL:gate=g.json"], {"fraction": 0.3}) == ["SU", "CAL:gate=g.json"]


def test_cell_with_too_few_wrong_answers_has_undefined_held_out_numbers_and_a_note():
    from vpr_uncertainty.pipeline.grid_config import GridConfig

    scores = np.tile(np.array([[0.9, 0.5, 0.4]], dtype=np.float32), (6, 1)) - np.arange(6)[:, None] * 0.01
    indices = np.tile(np.arange(3), (6, 1))
    positives = sparse.csr_array(np.array([[True] + [False] * 5] * 5 + [[False] * 5 + [True]]))
    retrieval = Retrieval(scores=scores, indices=indices, positives=positives)
    option = {"fraction": 0.3, "repeats": 2, "seed": 0}
    config = GridConfig(out=Path("."), inputs=[], methods=["SU", "CAL"], calibration=option)
    result = held_out_evaluation(retrieval, config)
    assert result["methods"] == {
        name: {"auc_pr": None, "auc_pr_std": None, "average_precision": None, "aurc": None} for name in ("SU", "CAL")
    }
    assert "at least 2 correct and 2 wrong" in result["notes"][0]
