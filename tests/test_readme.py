"""The README's Python examples run: those of "In Python" print what they say; each example of "Extending" runs and
checks itself."""

from __future__ import annotations

import ast
import re
import warnings
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


def _extending_blocks() -> list[str]:
    """The fenced Python blocks of the README's "Extending" section (up to the next ``## `` heading)."""
    section = re.search(r"^## Extending\n(.*?)(?=^## )", README.read_text(), re.S | re.M).group(1)
    return re.findall(r"```python\n(.*?)```", section, re.S)


def _registries() -> dict:
    from vpr_uncertainty.data import DATASET_FORMAT_REGISTRY
    from vpr_uncertainty.descriptors.models import MODELS, available_models
    from vpr_uncertainty.methods import METHODS
    from vpr_uncertainty.reports import REPORT_FIGURES

    available_models()  # the built-in models are registered on first use
    return {"method": METHODS, "model": MODELS, "dataset format": DATASET_FORMAT_REGISTRY, "figure": REPORT_FIGURES}


def test_extending_section_has_one_example_per_extension_point():
    blocks = _extending_blocks()
    registrations = [re.findall(r"^(register_\w+)\(", block, re.M) for block in blocks]
    assert registrations == [["register_method"], ["register_model"], ["register_format"], ["register_report_figure"]]


@pytest.mark.parametrize("number", range(4), ids=["method", "model", "dataset_format", "report_figure"])
def test_extending_example_runs(number, tmp_path, monkeypatch):
    """Each example runs in an empty folder, checks its own result, and imports from public modules only;
    what it registers is unregistered afterwards."""
    block = _extending_blocks()[number]
    for node in ast.walk(ast.parse(block)):
        if isinstance(node, ast.ImportFrom) and node.module.startswith("vpr_uncertainty"):
            assert not any(part.startswith("_") for part in node.module.split(".")), node.module
            assert not any(alias.name.startswith("_") for alias in node.names), ast.unparse(node)
    registries = _registries()
    before = {kind: set(registry.names()) for kind, registry in registries.items()}
    monkeypatch.chdir(tmp_path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            exec(compile(block, f"{README} (Extending, example {number + 1})", "exec"), {"__name__": "readme"})
    finally:
        added = {kind: set(registry.names()) - before[kind] for kind, registry in registries.items()}
        for kind, names in added.items():
            for name in names:
                registries[kind].unregister(name)
    assert sum(len(names) for names in added.values()) == 1, added
    assert all(set(registry.names()) == before[kind] for kind, registry in registries.items())


def test_architecture_stage_example_runs(tmp_path, monkeypatch, capsys):
    """The example of running two stage modules from Python prints what its comment says and writes its files."""
    (block,) = re.findall(r"```python\n(.*?)```", _section("Architecture"), re.S)
    monkeypatch.chdir(tmp_path)
    exec(compile(block, f"{README} (Architecture)", "exec"), {"__name__": "readme"})
    path, auc_pr = capsys.readouterr().out.split()
    assert path == "runs/stages/retrieval.npz" and abs(float(auc_pr) - 0.956) <= 0.002  # another BLAS may round apart
    assert (tmp_path / "runs" / "stages" / "uncertainties.npz").is_file()
