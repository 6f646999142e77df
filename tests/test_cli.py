"""One flag name per concept across the commands; former names (deprecated for a release) are now refused."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from vpr_uncertainty.cli import build_parser, command_names

#: Former flag names -> the name every command now uses for the same concept.
RENAMED = {"--data-dir": "--root", "--positions": "--database-positions", "--positives": "--gt"}


def _help(command: str, capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit):
        build_parser().parse_args([command, "--help"])
    return capsys.readouterr().out


def _flags(command: str, capsys: pytest.CaptureFixture[str]) -> set[str]:
    return set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", _help(command, capsys)))


@pytest.mark.parametrize("command", command_names())
def test_no_command_shows_a_former_flag_name(command, capsys):
    assert not _flags(command, capsys) & set(RENAMED)


def test_the_data_root_is_root_in_every_command_that_reads_named_data(capsys):
    for command in ("demo", "run", "datasets"):
        assert "--root" in _flags(command, capsys), command


@pytest.mark.parametrize(
    ("argv", "dest", "old"),
    [
        (["demo", "--data-dir", "data"], "root", "--data-dir"),
        (["train-btl", "--positions", "data", "--out", "head.pt"], "positions", "--positions"),
        (["train-btl", "--positives", "data", "--out", "head.pt"], "positives", "--positives"),
    ],
)
def test_former_names_are_refused(argv, dest, old, capsys):
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(argv)
    assert exit_.value.code == 2 and f"unrecognized arguments: {old}" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "dest"),
    [
        (["demo", "--root", "data"], "root"),
        (["train-btl", "--database-positions", "data", "--out", "head.pt"], "positions"),
        (["train-btl", "--gt", "data", "--out", "head.pt"], "positives"),
    ],
)
def test_new_names_parse_without_a_note(argv, dest, capsys):
    args = build_parser().parse_args(argv)
    assert getattr(args, dest) == Path("data")
    assert capsys.readouterr().err == ""


def test_the_command_table_names_the_module_of_every_command():
    from vpr_uncertainty.pipeline import COMMANDS

    assert list(COMMANDS) == command_names()
    for command, module in COMMANDS.items():
        alone = build_parser(command=command)
        assert command in alone._subparsers._group_actions[0].choices, module  # type: ignore[union-attr]


def test_a_command_imports_only_its_own_stage_module():
    """`vpr-uncertainty datasets` does not import the other commands' modules (nor what they import)."""
    import subprocess
    import sys

    code = (
        "import sys; from vpr_uncertainty import cli; cli.main(['datasets', '--json', '-']); "
        "print(sorted(m for m in sys.modules if m.startswith('vpr_uncertainty.pipeline.')))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = done.stdout.splitlines()[-1]
    assert "pipeline.datasets" in loaded
    for other in ("pipeline.evaluate", "pipeline.grid", "pipeline.extract", "pipeline.verify", "pipeline.run"):
        assert f"'vpr_uncertainty.{other}'" not in loaded


def test_an_unknown_command_still_lists_every_command(capsys):
    from vpr_uncertainty.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["evalute"])
    assert exit_.value.code == 2
    error = capsys.readouterr().err
    assert "invalid choice: 'evalute'" in error and "evaluate" in error
