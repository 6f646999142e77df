"""Issue 28, rows 10 and 15 and the gate's unclear message, written as the attacks: a gate file edited by hand (a
number changed, a field written twice, an isotonic table outside [0, 1], a regularisation that is not a number, the
digest deleted) and rows the guarantee does not cover (3 scores on a gate of k = 10, 3 or 50 columns in a batch,
-inf padding). Each is one clear refusal naming the field or the rows; each was accepted silently before."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from vpr_uncertainty import Gate, calibrate
from vpr_uncertainty.data import read_results

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy")

FIX = "vpr-uncertainty calibrate"


@pytest.fixture(scope="module")
def corridor(corridor_dir, corridor_matches_dir):
    """AMOSNet on the corridor: the issue's gate (p* = 0.9, k = 10; certified bound 0.917 by CAL, with the shares
    of 176 labels or more: a gate file holding a refitted rule, the most fields to edit)."""
    return read_results(
        corridor_matches_dir / "AMOSNet" / "precomputed_data_corrected.npy",
        ground_truth=corridor_dir / "ground_truth_new.npy",
    )


@pytest.fixture
def gate_file(corridor, tmp_path):
    gate = calibrate(corridor, target_precision=0.9, delta=0.1, rankings={"CAL": 0.9, "margin": 0.1})
    assert round(gate.precision_lower_bound, 3) == 0.917 and gate.k == 10
    return gate.save(tmp_path / "gate.json")


def _edit(path, change):
    """What a user does in an editor: read the JSON, change a field, write it back."""
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data, indent=2))
    return path


def _refusal(path) -> str:
    with pytest.raises(ValueError) as error:
        Gate.load(path)
    message = str(error.value)
    assert "\n" not in message and str(path) in message and FIX in message, message
    return message


# --- row 10: an edited gate file ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("field", "change"),
    [
        ("cut", lambda data: data.update(cut=data["cut"] - 0.3)),  # accepts more queries: precision 0.847, not 0.941
        ("calibrator.coef", lambda data: data["calibrator"].update(coef=[c * 0.9 for c in data["calibrator"]["coef"]])),
        ("calibrator.intercept", lambda data: data["calibrator"].update(intercept=data["calibrator"]["intercept"] + 1)),
        ("k", lambda data: data.update(k=5)),
        ("precision_lower_bound", lambda data: data.update(precision_lower_bound=0.99)),
        ("certificate.precision_lower_bound", lambda data: data["certificate"].update(precision_lower_bound=0.99)),
        ("calibrator.regularisation", lambda data: data["calibrator"].pop("regularisation")),
        ("rule.coef", lambda data: data["rule"].update(coef=[c * 2 for c in data["rule"]["coef"]])),
        ("certificate.rankings", lambda data: data["certificate"]["rankings"]["margin"].update(delta=0.1)),
    ],
)
def test_an_edited_number_in_a_gate_file_is_refused_naming_it(gate_file, field, change):
    message = _refusal(_edit(gate_file, change))
    assert f"{field} changed since calibrate (the digest differs)" in message


def test_cut_written_twice_is_refused_naming_it(gate_file):
    text = gate_file.read_text()
    cut = json.loads(text)["cut"]
    for value in (cut - 0.3, cut):  # JSON keeps the last; even an equal value is refused
        gate_file.write_text(text.replace('"cut":', f'"cut": {value},\n  "cut":', 1))
        assert 'field "cut" is written twice' in _refusal(gate_file)


def test_a_field_of_the_calibrator_written_twice_is_refused(gate_file):
    gate_file.write_text(gate_file.read_text().replace('"intercept":', '"intercept": 0.0,\n    "intercept":', 1))
    assert 'field "intercept" is written twice' in _refusal(gate_file)


def test_isotonic_table_outside_zero_one_is_refused(corridor, tmp_path):
    path = calibrate(corridor, model="isotonic").save(tmp_path / "gate.json")
    message = _refusal(_edit(path, lambda data: data["calibrator"].update(x=[-2.0, -1.0, 0.0], y=[5, -3, 9])))
    assert "calibrator: y must be non-decreasing probabilities in [0, 1]" in message
    # the value check does not lean on the digest: a digest recomputed for the forged table is refused too
    from vpr_uncertainty.calibration.gate import _digest

    data = json.loads(path.read_text())
    data["digest"] = _digest(data)
    path.write_text(json.dumps(data))
    assert "y must be non-decreasing probabilities in [0, 1]" in _refusal(path)


def test_regularisation_abc_is_one_line_naming_the_file_and_the_field(gate_file):
    message = _refusal(_edit(gate_file, lambda data: data["calibrator"].update(regularisation="abc")))
    assert "calibrator: regularisation must be a number > 0" in message and "'abc'" in message


def test_regularisation_abc_from_the_command_line_is_one_line(gate_file, corridor_dir, corridor_matches_dir):
    _edit(gate_file, lambda data: data["calibrator"].update(regularisation="abc"))
    matches = corridor_matches_dir / "AMOSNet" / "precomputed_data_corrected.npy"
    run = subprocess.run(
        [sys.executable, "-m", "vpr_uncertainty.cli", "evaluate", str(matches), "--gt",
         str(corridor_dir / "ground_truth_new.npy"), "--methods", f"SU,CAL:gate={gate_file}"],
        capture_output=True, text=True,
    )  # fmt: skip
    errors = [line for line in run.stderr.splitlines() if line.strip() and not line.startswith("warning:")]
    assert run.returncode == 2 and len(errors) == 1, run.stderr
    assert str(gate_file) in errors[0] and "regularisation" in errors[0] and FIX in errors[0]


def test_a_gate_file_without_its_digest_is_refused(gate_file):
    """Deleting the digest (or writing a gate as the format before it did) is no way around it."""
    assert "no digest" in _refusal(_edit(gate_file, lambda data: data.pop("digest", None)))
    old = _edit(gate_file, lambda data: data.update(format_version=1))
    assert "format_version 1 (this toolkit reads gate files of format_version 3, with a digest)" in _refusal(old)
    assert "format_version 2" in _refusal(_edit(gate_file, lambda data: data.update(format_version=2)))


def test_from_dict_checks_the_digest_too(corridor):
    data = calibrate(corridor, target_precision=0.9).to_dict()
    data["cut"] -= 0.3
    with pytest.raises(ValueError, match="gate: cut changed since calibrate"):
        Gate.from_dict(data)


# --- row 15: rows the gate was not calibrated on -----------------------------------------------------------------


def test_a_3_value_row_on_a_k10_gate_is_refused(gate_file):
    gate = Gate.load(gate_file)
    for call in (gate, gate.probability_one):
        with pytest.raises(ValueError, match=r"calibrated at k=10.*got a row of 3 scores"):
            call([0.52, 0.40, 0.39])
        with pytest.raises(ValueError, match=r"calibrated at k=10.*got a row of 11 scores"):
            call([0.52, 0.40, 0.39, 0.38, 0.37, 0.36, 0.36, 0.35, 0.35, 0.34, 0.33])
    assert gate([0.52, 0.40, 0.39, 0.38, 0.37, 0.36, 0.36, 0.35, 0.35, 0.34]) in (True, False)


def test_a_row_padded_with_minus_inf_is_refused(gate_file):
    """The same 3 scores written as a k-row with missing candidates: its calibration rows all held 10."""
    gate = Gate.load(gate_file)
    with pytest.raises(ValueError, match=r"at least 10 finite scores.*got a row of 3 finite scores"):
        gate([0.52, 0.40, 0.39, *[-np.inf] * 7])


@pytest.mark.parametrize("columns", [3, 50])
def test_a_batch_of_another_width_is_refused(gate_file, corridor, columns):
    gate = Gate.load(gate_file)
    scores = corridor.scores[:, :columns]
    for call in (gate.accept, gate.confidence, gate.probability_correct):
        with pytest.raises(ValueError, match=rf"calibrated at k=10.*shape \(111, {columns}\)"):
            call(scores)
    assert gate.accept(corridor.scores[:, : gate.k]).shape == (111,)


def test_a_batch_with_padded_rows_names_them(gate_file, corridor):
    gate = Gate.load(gate_file)
    scores = corridor.scores[:, :10].astype(np.float64)
    scores[[4, 17], 3:] = -np.inf
    with pytest.raises(ValueError, match=r"at least 10 finite scores.*2 scores rows \(\[4, 17\] first\)"):
        gate.accept(scores)
