"""The gate: batch and one-query paths agree on real data, JSON round trip, calibrate, and CAL as a method."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty import Gate, calibrate, evaluate
from vpr_uncertainty.calibration.calibrator import Calibrator
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation import correct_at_n
from vpr_uncertainty.retrieval import Retrieval


def _corridor(method, corridor_dir, corridor_matches_dir):
    return read_results(
        corridor_matches_dir / method / "precomputed_data_corrected.npy",
        ground_truth=corridor_dir / "ground_truth_new.npy",
    )


@pytest.mark.filterwarnings("ignore:reading the legacy")
@pytest.mark.parametrize("method", ["AMOSNet", "HybridNet", "CALC", "denseVLAD"])
@pytest.mark.parametrize("model", ["logistic", "isotonic"])
@pytest.mark.parametrize("target", [None, 0.9])
def test_one_query_path_agrees_with_batch(method, model, target, corridor_dir, corridor_matches_dir, tmp_path):
    retrieval = _corridor(method, corridor_dir, corridor_matches_dir)
    gate = calibrate(retrieval, target_precision=target, model=model)
    scores = retrieval.scores[:, : gate.k]  # the gate decides rows of its k scores
    accepted = gate.accept(scores)
    assert accepted.tolist() == [gate(row) for row in scores]
    assert accepted.tolist() == [gate(row.tolist()) for row in scores]
    assert accepted.tolist() == [gate(row[None, :]) for row in scores]
    probability = gate.probability_correct(scores)
    assert ((probability >= 0) & (probability <= 1)).all()
    if gate.cut != np.inf and gate.threshold is not None and model == "logistic":  # the rule is P's own order
        assert (accepted == (probability >= gate.threshold)).all()
    loaded = Gate.load(gate.save(tmp_path / "gate.json"))
    assert loaded.accept(scores).tolist() == accepted.tolist()
    assert_close(loaded.probability_correct(scores), probability, rtol=1e-12)
    assert_close([loaded.probability_one(row) for row in scores[:5]], probability[:5], rtol=1e-9)


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_gate_file_records_what_made_it(corridor_dir, corridor_matches_dir, tmp_path):
    retrieval = _corridor("AMOSNet", corridor_dir, corridor_matches_dir)
    gate = calibrate(retrieval, target_precision=0.9, delta=0.1, seed=0, rankings={"CAL": 0.9, "margin": 0.1})
    data = json.loads(gate.save(tmp_path / "gate.json").read_text())
    assert data["format"] == "vpr-uncertainty gate" and data["k"] == 10
    # the cross-fitted model at 0.9 δ and the margin at 0.1 δ, each one's outcome and δ recorded; P is the selection's
    assert data["rankings"] == pytest.approx({"CAL": 0.09, "margin": 0.01})
    winner = data["certificate"]["ranking"]
    assert data["certificate"]["rankings"][winner]["certified"] and data["rule"]["ranking"] == winner
    assert [o["delta"] for o in data["certificate"]["rankings"].values()] == pytest.approx([0.09, 0.01])
    assert data["calibrator"]["ranking"] == data["selection"]["chosen"]
    assert data["calibration"]["n_queries"] == 111 and len(data["calibration"]["fingerprint"]) == 16
    assert data["toolkit_version"] and data["target_precision"] == 0.9 and data["delta"] == 0.1
    assert gate.precision_lower_bound >= 0.9 and 0 < gate.expected_recall <= 1
    # the fingerprint changes with the labels
    other = calibrate(Retrieval(retrieval.scores, retrieval.indices, retrieval.positives[::-1]))
    assert other.info["calibration"]["fingerprint"] != data["calibration"]["fingerprint"]


def test_too_few_queries_certify_nothing_and_say_how_many_are_needed():
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.uniform(0.3, 0.9, size=(30, 10)), axis=1)
    indices = np.tile(np.arange(10), (30, 1))
    positives = np.zeros((30, 10), bool)
    positives[:24, 0] = True
    gate = calibrate(Retrieval(scores, indices, positives), target_precision=0.9)
    assert gate.precision_lower_bound is None and not gate.accept(scores).any() and gate.threshold == 1.0
    assert (
        "labelled queries would be needed" in gate.info["certificate"]["message"]
        or "even on" in (gate.info["certificate"]["message"])
    )


@pytest.mark.parametrize(
    ("row", "message"),
    [
        (np.zeros((2, 3)), r"shape \(K,\) or \(1, K\)"),
        ([0.1, 0.5, *[0.0] * 8], "sorted"),
        ([0.5, *[-np.inf] * 9], "at least 2"),
        ([0.5, 0.1], "calibrated at k=10"),
    ],
)
def test_one_query_errors(row, message):
    gate = Gate(Calibrator("logistic", ("s1", "SU"), [0.5, 0.9], [0.1, 0.1], [1.0, -1.0], 0.0), 10, 0.0)
    with pytest.raises(ValueError, match=message):
        gate(row)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{", "not a JSON gate file"),
        ('{"format": "other"}', "not a gate file"),
        ('{"format": "vpr-uncertainty gate", "format_version": 1, "k": 1}', "format_version 1 "),
        ('{"format": "vpr-uncertainty gate", "format_version": 3, "k": 10}', "no digest"),
        ('{"format": "vpr-uncertainty gate", "format_version": 3, "k": 1, "digest": {}}', "k must be >= 2"),
    ],
)
def test_load_errors_name_the_file(content, message, tmp_path):
    path = tmp_path / "gate.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=message):
        Gate.load(path)
    with pytest.raises(FileNotFoundError, match="gate file not found"):
        Gate.load(tmp_path / "missing.json")


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_cal_method_needs_a_gate_and_uses_it(corridor_dir, corridor_matches_dir, tmp_path):
    retrieval = _corridor("CALC", corridor_dir, corridor_matches_dir)
    with pytest.raises(ValueError, match="needs a fitted gate"):
        evaluate(retrieval, ["SU", "CAL"])
    gate = calibrate(retrieval)
    path = gate.save(tmp_path / "gate.json")
    evaluation = evaluate(retrieval, ["SU", f"CAL:gate={path}"])
    cal = evaluation.methods[f"CAL:gate={path}"]
    assert_close(cal.uncertainty, 1 - gate.probability_correct(retrieval.scores[:, : gate.k]), rtol=1e-12)
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    assert correct.shape == cal.uncertainty.shape
