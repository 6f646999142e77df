"""The distribution builds and passes ``twine check``: ``python -m build`` (sdist + wheel) on a copy of the project.

Marked ``packaging``. The build runs without isolation (no download: setuptools and wheel come from the ``test``
extra, as do build and twine); without build or twine the test is skipped on a developer machine and fails under
CI (CI=true), like the tests that need the real data.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROJECT_FILES = ("pyproject.toml", "README.md", "LICENSE", "src")


def _under_ci() -> bool:
    return os.environ.get("CI", "").lower() in {"1", "true", "yes"}


def _require(*modules: str) -> None:
    missing = [name for name in modules if importlib.util.find_spec(name) is None]
    if missing:
        message = f"{', '.join(missing)} not installed: pip install -e '.[test]'"
        if _under_ci():
            pytest.fail(message)
        pytest.skip(message)


def _copy_project(destination: Path) -> Path:
    """The files a build reads, without caches, build outputs or egg-info (the checkout stays untouched)."""
    destination.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "*.pyc")
    for name in PROJECT_FILES:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, destination / name, ignore=ignore)
        elif source.exists():
            shutil.copy2(source, destination / name)
    return destination


def _run(command: list[str], cwd: Path) -> str:
    result = subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, f"{' '.join(command)} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result.stdout


@pytest.mark.packaging
def test_sdist_and_wheel_build_and_pass_twine_check(tmp_path):
    _require("build", "twine", "setuptools", "wheel")
    project = _copy_project(tmp_path / "project")
    dist = tmp_path / "dist"
    _run([sys.executable, "-m", "build", "--sdist", "--wheel", "--no-isolation", "--outdir", str(dist)], project)
    wheels, sdists = sorted(dist.glob("*.whl")), sorted(dist.glob("*.tar.gz"))
    assert len(wheels) == 1 and len(sdists) == 1, sorted(path.name for path in dist.iterdir())
    output = _run([sys.executable, "-m", "twine", "check", "--strict", *map(str, wheels + sdists)], tmp_path)
    assert output.count("PASSED") == 2, output

    with zipfile.ZipFile(wheels[0]) as wheel:
        names = set(wheel.namelist())
        metadata = next(wheel.read(name).decode() for name in names if name.endswith(".dist-info/METADATA"))
        entry_points = next(wheel.read(name).decode() for name in names if name.endswith(".dist-info/entry_points.txt"))
    # The package data the readers need at run time, the command, and the extras documented in the README.
    data = ("data/named_datasets.json", "data/corridor_sha256.json", "descriptors/hub_models.json")
    assert {f"vpr_uncertainty/{name}" for name in data} <= names
    assert "vpr-uncertainty = vpr_uncertainty.cli:main" in entry_points
    assert "Description-Content-Type: text/markdown" in metadata
    for extra in ("torch", "opencv", "gv", "yaml", "pandas", "all", "test"):
        assert f"Provides-Extra: {extra}" in metadata
    assert not any(line.startswith("Requires-Dist: torch") and "extra" not in line for line in metadata.splitlines())
    with tarfile.open(sdists[0]) as sdist:
        assert any(name.endswith("/README.md") for name in sdist.getnames())
