"""Library errors name arguments; the commands re-word them with their flags (``command_wording``)."""

from __future__ import annotations

import numpy as np
import pytest

from vpr_uncertainty.cli import main
from vpr_uncertainty.data import read_results
from vpr_uncertainty.pipeline.options import command_wording


def test_command_wording_turns_argument_names_into_flags():
    with pytest.raises(FileNotFoundError, match=r"^give it \(--gt GT\)$"):
        with command_wording(ground_truth="--gt GT"):
            raise FileNotFoundError("give it (argument ground_truth)")
    with pytest.raises(ValueError, match="unrelated"):  # other errors pass unchanged
        with command_wording(ground_truth="--gt GT"):
            raise ValueError("unrelated")


def test_missing_ground_truth_library_vs_command(tmp_path, capsys):
    matrix = tmp_path / "sim.npy"
    np.save(matrix, np.random.default_rng(0).random((3, 4)).astype(np.float32))
    with pytest.raises(ValueError, match=r"give the ground truth \(argument ground_truth\)$") as error:
        read_results(matrix)
    assert "--" not in str(error.value)  # before: the library said "(--gt)"
    assert main(["evaluate", str(matrix)]) == 2
    assert "give the ground truth (--gt GT)" in capsys.readouterr().err
