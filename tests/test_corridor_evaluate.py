"""`vpr-uncertainty evaluate` end to end on the ten real VPR-Bench corridor similarity matrices."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sklearn.metrics import auc, precision_recall_curve

from conftest import assert_close
from vpr_uncertainty.cli import main

METHODS = [
    "AMOSNet",
    "AlexNet_VPR",
    "CALC",
    "CoHOG",
    "HOG",
    "HybridNet",
    "NetVLAD",
    "RegionVLAD",
    "ap-gem-r101",
    "denseVLAD",
]


def _reference_su(similarity, k=10, alpha=0.5):
    values = []
    for row in similarity:
        top = sorted(row.tolist(), reverse=True)[:k]
        rs = sum(s / top[0] for s in top[1:]) / (k - 1)
        sd = float(np.median(top)) / top[0]
        values.append(alpha * rs + (1 - alpha) * sd)
    return np.array(values)


@pytest.mark.filterwarnings("ignore:reading the legacy")
@pytest.mark.parametrize("method", METHODS)
def test_evaluate_real_corridor_matrix(method, corridor_dir, corridor_matches_dir, tmp_path, capsys):
    matches = corridor_matches_dir / method / "precomputed_data_corrected.npy"
    gt = corridor_dir / "ground_truth_new.npy"
    json_path, plot_path = tmp_path / "results.json", tmp_path / "pr.png"
    status = main(["evaluate", str(matches), "--gt", str(gt), "--json", str(json_path), "--plot", str(plot_path)])
    assert status == 0
    printed = capsys.readouterr().out
    assert "SU" in printed and "AUC-PR" in printed
    results = json.loads(json_path.read_text())
    assert plot_path.stat().st_size > 10_000

    # independent computation straight from the raw files
    raw = np.load(matches, allow_pickle=True, encoding="latin1")
    similarity = np.asarray(raw[3], dtype=np.float64)
    ground_truth = {int(q): set(p) for q, p in np.load(gt, allow_pickle=True, encoding="latin1")}
    correct = np.array([int(np.argmax(row)) in ground_truth[q] for q, row in enumerate(similarity)])
    assert results["n_queries"] == 111
    assert_close(results["recall@1"], correct.mean())
    assert set(results["methods"]) == {"RS", "SD", "SU", "PA", "L2", "BM"}
    precision, recall, _ = precision_recall_curve(correct, -_reference_su(similarity))
    assert_close(results["methods"]["SU"]["auc_pr"], auc(recall, precision), atol=1e-6)
    precision, recall, _ = precision_recall_curve(correct, similarity.max(axis=1))
    assert_close(results["methods"]["BM"]["auc_pr"], auc(recall, precision), atol=1e-6)
    for values in results["methods"].values():
        assert 0 < values["auc_pr"] <= 1 and 0 <= values["aurc"] <= 1 and values["time_per_query_ms"] > 0


def test_cli_errors_are_one_clear_line(tmp_path, capsys, corridor_dir):
    assert main(["evaluate", str(tmp_path / "missing.npy"), "--gt", str(corridor_dir / "ground_truth_new.npy")]) == 2
    assert "not found" in capsys.readouterr().err
    np.save(tmp_path / "sim.npy", np.ones((3, 4)))
    with pytest.raises(SystemExit) as exit_:  # a usage error, checked by the library's own check_alpha
        main(["evaluate", str(tmp_path / "sim.npy"), "--gt", str(tmp_path / "sim.npy"), "--alpha", "2"])
    assert exit_.value.code == 2 and "argument --alpha: alpha must lie in [0, 1]" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["evaluate", str(tmp_path / "sim.npy"), "--methods", "SU,nope"])
    assert "unknown uncertainty method 'nope'" in capsys.readouterr().err
