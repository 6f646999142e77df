"""`make test` runs pytest-xdist with the Makefile's flags; each test module must stay on one worker.

A module-scoped fixture built on two workers at once raced itself: test_btl_corridor's fixture fills one descriptor
file in pytest's cache folder, and on a fresh clone one worker failed on the HDF5 file lock. ``--dist loadgroup`` with
``xdist_group`` marks was meant to prevent this but did nothing under pytest 9 (xdist 3.8 renames ``item._nodeid``,
which pytest 9 no longer reads), so this test runs the Makefile's own flags on two small modules and checks where
their tests ran.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("xdist")


def test_the_makefile_flags_keep_each_module_on_one_worker(tmp_path):
    makefile = (Path(__file__).parents[1] / "Makefile").read_text()
    (command,) = re.findall(r"python -m pytest (.*)", makefile)
    flags = re.sub(r"--durations[ =]\d+", "", command.replace("$(TEST_WORKERS)", "2")).split()
    for module in ("alpha", "beta"):
        body = "import os\n\n\n" + "".join(
            f"def test_{i}():\n    open('{module}.workers', 'a').write(os.environ['PYTEST_XDIST_WORKER'] + '\\n')\n\n\n"
            for i in range(8)
        )
        (tmp_path / f"test_{module}.py").write_text(body)
    result = subprocess.run(
        [sys.executable, "-m", "pytest", *flags, "-q", "-p", "no:cacheprovider", "-c", "/dev/null", str(tmp_path)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    for module in ("alpha", "beta"):
        workers = (tmp_path / f"{module}.workers").read_text().split()
        assert len(workers) == 8 and len(set(workers)) == 1, (module, workers)
