"""Library errors name arguments; the commands re-word them with their flags (``command_wording``)."""

from __future__ import annotations

from pathlib import Path

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


@pytest.mark.parametrize(
    ("command", "refused"),
    [  # issue 42, row 3, and outputs that collide: every command, through the one check in the CLI
        (
            "calibrate sim.npy --gt gt.npy --target-precision 0.9 --sequential l.csv --out l.csv",
            "--out l.csv is --sequential l.csv, which this command never overwrites",
        ),
        (
            "evaluate sim.npy --gt gt.npy --json r.json --plot r.json",
            "--plot r.json is --json r.json, which this command also writes",
        ),
        ("subset sim.npy --gt gt.npy --queries 0:5 --out gt.npy", "--out gt.npy is --gt gt.npy"),
        ("evaluate sim.npy --gt gt.npy --per-query link.npy", "--per-query link.npy is SCORES sim.npy"),  # a link
    ],
)
def test_an_output_that_is_an_input_or_another_output_is_refused(tmp_path, monkeypatch, capsys, command, refused):
    monkeypatch.chdir(tmp_path)
    np.save("sim.npy", np.random.default_rng(0).random((6, 6)).astype(np.float32))
    np.save("gt.npy", np.array([[q, [q]] for q in range(6)], dtype=object), allow_pickle=True)
    Path("l.csv").write_text("query,correct\n0,1\n")
    Path("link.npy").symlink_to("sim.npy")
    before = {path: path.read_bytes() for path in tmp_path.iterdir()}
    assert main(command.split()) == 2
    error = capsys.readouterr().err
    assert refused in error and error.count("\n") == 1, error
    assert {path: path.read_bytes() for path in tmp_path.iterdir()} == before


def test_standard_output_only_where_a_command_writes_it(tmp_path, monkeypatch, capsys):
    """``--out -`` wrote a file named "-" (and ``-.tum`` beside it); only the JSON options print to stdout."""
    monkeypatch.chdir(tmp_path)
    np.save("sim.npy", np.random.default_rng(0).random((6, 6)).astype(np.float32))
    np.save("gt.npy", np.array([[q, [q]] for q in range(6)], dtype=object), allow_pickle=True)
    with pytest.raises(SystemExit) as refused:  # an argparse error: exit 2, one line
        main(["subset", "sim.npy", "--gt", "gt.npy", "--out", "-"])
    assert refused.value.code == 2
    assert "'-' (standard output) is not supported here: name a file" in capsys.readouterr().err
    assert main(["evaluate", "sim.npy", "--gt", "gt.npy", "--json", "-", "--methods", "SU"]) == 0
    assert '"SU"' in capsys.readouterr().out and sorted(p.name for p in tmp_path.iterdir()) == ["gt.npy", "sim.npy"]


def test_evaluate_says_every_file_it_wrote_and_plan_is_not_silently_ignored(tmp_path, monkeypatch, capsys):
    """Issue 45, item 7: "wrote" for --csv, --latex and --per-query too; --plan with --sequential was ignored."""
    monkeypatch.chdir(tmp_path)
    np.save("sim.npy", np.random.default_rng(0).random((6, 6)).astype(np.float32))
    np.save("gt.npy", np.array([[q, [q]] for q in range(6)], dtype=object), allow_pickle=True)
    argv = ["evaluate", "sim.npy", "--gt", "gt.npy", "--csv", "t.csv", "--latex", "t.tex", "--per-query", "q.csv"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert all(f"wrote {name}" in out for name in ("t.csv", "t.tex", "q.csv"))
    argv = ["calibrate", "sim.npy", "--gt", "gt.npy", "--target-precision", "0.9", "--sequential", "l.csv", "--plan"]
    assert main(argv) == 2
    assert "--plan simulates labelling before it starts" in capsys.readouterr().err
    assert not (tmp_path / "l.csv").exists()
