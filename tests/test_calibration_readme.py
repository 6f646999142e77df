"""The README's calibration example runs on the real corridor data and prints what it says."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_readme_calibration_example(corridor_dir, corridor_matches_dir, tmp_path, monkeypatch, capsys):
    block = next(b for b in re.findall(r"```python\n(.*?)```", README.read_text(), re.S) if "calibrate(" in b)
    block = block.replace('"precomputed_matches/corridor/', f'"{corridor_matches_dir}/')
    block = block.replace('"corridor/ground_truth_new.npy"', f'"{corridor_dir / "ground_truth_new.npy"}"')
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(block, str(README), "exec"), namespace)
    threshold, bound, recall = (float(value) for value in capsys.readouterr().out.split())
    expected = re.search(r"# ([\d.]+) ([\d.]+) ([\d.]+)", block).groups()
    assert [round(threshold, 3), round(bound, 3), round(recall, 3)] == [float(value) for value in expected]
    assert isinstance(namespace["accept"], bool) and (tmp_path / "gate.json").is_file()
