"""The README's Python examples run and print what they say; the README stays a front door (the manual is in docs/,
whose examples tests/test_docs.py runs)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _section(title: str) -> str:
    """The README's section ``## title``, up to the next ``## `` heading."""
    return re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## )", README.read_text(), re.S | re.M).group(1)


def test_readme_notebook_workflow_runs_in_under_15_lines(capsys):
    """ "In Python": similarity matrix + lists of positives -> SU -> DataFrame -> threshold -> figure on an axis; it
    prints what the README shows below it and draws on the axis it made."""
    pytest.importorskip("pandas")
    import matplotlib.pyplot as plt

    section = _section("In Python")
    block = re.findall(r"```python\n(.*?)```", section, re.S)[0]
    assert len([line for line in block.splitlines() if line.strip()]) < 15
    for step in ("similarity", "positives=[[", "evaluate(", "to_frame()", "threshold_at_precision(", "ax=ax"):
        assert step in block, step
    namespace: dict = {}
    try:
        exec(compile(block, f"{README} (In Python)", "exec"), namespace)
        shown = re.search(r"```text\n(.*?)```", section, re.S).group(1)
        printed = capsys.readouterr().out
        assert [line.rstrip() for line in printed.splitlines()] == shown.splitlines()
        ax = namespace["ax"]
        assert [line.get_label().split(" ")[0] for line in ax.lines[:2]] == ["SU", "BM"]
    finally:
        plt.close("all")


def test_readme_python_example_runs(capsys):
    block = re.findall(r"```python\n(.*?)```", _section("In Python"), re.S)[1]
    exec(compile(block, str(README), "exec"), {})
    printed = capsys.readouterr().out.split("\n")
    assert printed[0] == "[0.55311355 0.98177083]"
    assert printed[1] == "1.0"


def test_every_readme_python_block_is_executed():
    """The README's Python blocks: the two of "In Python" (above) and the calibration example, which
    tests/test_calibration_readme.py runs on the real data; the other examples live in docs/ (tests/test_docs.py)."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    in_python = re.findall(r"```python\n(.*?)```", _section("In Python"), re.S)
    assert len(blocks) == 3 and blocks[:2] == in_python[:2] and "calibrate(" in blocks[2]


def test_readme_is_a_front_door():
    """At most 250 lines, the two commands first, and every link into docs/ names a page that exists."""
    text = README.read_text()
    assert len(text.splitlines()) <= 250
    assert "make demo" in _section("Two commands") and "make test" in _section("Two commands")
    links = re.findall(r"\]\((docs/[^)#]+)", text)
    assert links and all((README.parent / link).is_file() for link in links), links
