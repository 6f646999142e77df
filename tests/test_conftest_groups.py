"""The xdist grouping of tests/conftest.py: every test module that starts Ray is in RAY_MODULES.

Two Ray clusters started at once by two pytest-xdist workers collide (``ray start`` on one fixed port; two local
clusters fight for the 2 CPUs they each claim), so a module that starts Ray and is missing from the list fails
only now and then, on another machine. This test fails at once instead.
"""

from __future__ import annotations

import re
from pathlib import Path

from conftest import RAY_MODULES

STARTS_RAY = re.compile(r"ray\.init|\"ray\", \"start\"|\"start\"|ray_cluster|ray_executor|get_executor\(\s*\"ray\"")


def test_every_module_that_starts_ray_runs_on_one_worker():
    folder = Path(__file__).parent
    starting = {
        path.stem
        for path in folder.glob("test_*.py")
        if path.name != Path(__file__).name
        and re.search(r"\bray\b", path.read_text())
        and STARTS_RAY.search(path.read_text())
    }
    assert starting <= RAY_MODULES, sorted(starting - RAY_MODULES)
    assert {path.stem for path in folder.glob("test_*.py")} >= RAY_MODULES, "a listed module no longer exists"
