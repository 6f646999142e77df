"""calibration/gate.py on disk: a gate is written atomically (cache.write_text), and a truncated gate.json is one
line naming the file, from Gate.load and from the CLI (``CAL:gate=...``)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from vpr_uncertainty.calibration import Gate
from vpr_uncertainty.calibration.fit import calibrate_arrays


@pytest.fixture
def gate_file(tmp_path):
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((80, 10)), axis=1).astype(np.float32)
    correct = scores[:, 0] - scores[:, 1] + rng.normal(0, 0.05, 80) > 0.08
    path = tmp_path / "gate.json"
    calibrate_arrays(scores, correct, k=10).save(path)
    return path


def test_save_goes_through_the_atomic_writer(gate_file, monkeypatch):
    import vpr_uncertainty.calibration.gate as module

    written = []
    monkeypatch.setattr(module, "write_text", lambda path, text: written.append(path) or path)
    Gate.load(gate_file).save(gate_file.with_name("other.json"))
    assert written == [gate_file.with_name("other.json")] and not gate_file.with_name("other.json").exists()


@pytest.mark.parametrize("keep", [0.0, 0.5, 0.99])
def test_truncated_gate_is_one_line_naming_the_file(gate_file, keep):
    data = gate_file.read_bytes()
    gate_file.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(ValueError) as error:
        Gate.load(gate_file)
    message = str(error.value)
    assert "\n" not in message and str(gate_file) in message and "not a JSON gate file" in message


def test_truncated_gate_in_evaluate_is_one_line(gate_file, tmp_path):
    data = gate_file.read_bytes()
    gate_file.write_bytes(data[: len(data) // 2])
    matrix = tmp_path / "scores.npy"
    rng = np.random.default_rng(1)
    np.save(matrix, rng.random((12, 12)).astype(np.float32))
    gt = tmp_path / "gt.npy"
    np.save(gt, np.eye(12, dtype=bool))
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "vpr_uncertainty.cli",
            "evaluate",
            str(matrix),
            "--gt",
            str(gt),
            "--methods",
            f"SU,CAL:gate={gate_file}",
        ],
        capture_output=True,
        text=True,
    )
    assert run.returncode != 0
    errors = [line for line in run.stderr.splitlines() if line.strip() and not line.startswith("warning:")]
    assert len(errors) == 1 and str(gate_file) in errors[0] and "not a JSON gate file" in errors[0], run.stderr


def test_the_digest_is_of_the_values_not_the_bytes(gate_file):
    """Re-indenting or reordering a gate file keeps it loadable: the digest covers each field's canonical JSON."""
    import json

    data = json.loads(gate_file.read_text())
    gate_file.write_text(json.dumps(dict(reversed(list(data.items()))), separators=(",", ":")))
    assert Gate.load(gate_file).to_dict() == data
    assert set(data["digest"]) >= {"cut", "k", "calibrator.coef", "calibration.min_candidates"}


def test_a_gate_calibrated_at_a_k_above_the_width_records_the_width(tmp_path):
    """k = 10 on 5 candidates per query: the features read 5, so the gate's k is 5 and it decides rows of 5."""
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((80, 5)), axis=1)
    correct = scores[:, 0] - scores[:, 1] + rng.normal(0, 0.05, 80) > 0.08
    gate = Gate.load(calibrate_arrays(scores, correct, k=10).save(tmp_path / "gate.json"))
    assert gate.k == 5 and gate.info["calibration"]["min_candidates"] == 5
    assert gate.accept(scores).tolist() == [gate(row) for row in scores]


def test_a_gate_calibrated_on_padded_rows_decides_rows_padded_as_much(tmp_path):
    """Missing candidates (-inf) in the calibration rows: rows with as few finite scores are covered, fewer not."""
    rng = np.random.default_rng(0)
    scores = -np.sort(-rng.random((80, 10)), axis=1)
    scores[::10, 6:] = -np.inf  # every tenth query retrieved 6 candidates only
    correct = scores[:, 0] - scores[:, 1] + rng.normal(0, 0.05, 80) > 0.08
    gate = calibrate_arrays(scores, correct, k=10)
    assert gate.info["calibration"]["min_candidates"] == 6
    assert gate.accept(scores).tolist() == [gate(row) for row in scores]
    with pytest.raises(ValueError, match="at least 6 finite scores"):
        gate([0.9, 0.5, 0.4, 0.3, 0.2, *[-np.inf] * 5])
