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
    ranking, bound, recall = capsys.readouterr().out.split()
    expected = re.search(r"# (\w+) ([\d.]+) ([\d.]+)", block).groups()
    assert [ranking, round(float(bound), 3), round(float(recall), 3)] == [expected[0], *map(float, expected[1:])]
    assert isinstance(namespace["accept"], bool) and (tmp_path / "gate.json").is_file()
