"""Shared fixtures: the real data directory from VPR_UNCERTAINTY_DATA; the tolerance policy of float comparisons.

Tests that need the real data use the ``data_dir`` fixture. Without the data they are skipped on a developer
machine and fail under CI (CI=true), so a CI run never passes without exercising them.

Float comparisons go through :func:`assert_close` (``from conftest import assert_close``), which picks the relative
tolerance by dtype; tests/README.md states the policy.
"""

from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path

import numpy as np
import pytest


def _require(path: Path, what: str) -> Path:
    if not path.exists():
        message = f"{what} not found at {path}; set VPR_UNCERTAINTY_DATA to the shared data directory"
        if os.environ.get("CI", "").lower() in {"1", "true", "yes"}:
            pytest.fail(message)
        pytest.skip(message)
    return path


@pytest.fixture(autouse=True)
def _user_plugins_forgotten():
    """A user's plugin a test loads (a module in its tmp_path) is forgotten after the test: ``plugins._loaded`` is
    what a later Ray run ships to its workers, which are long-lived and had registered its names already ("ENT
    already registered" in a Ray test that followed tests/test_plugins.py on one xdist worker). The package's own
    entry points (no folder) stay, as loading them again would change nothing."""
    from vpr_uncertainty import plugins

    before = set(plugins._loaded)
    yield
    forget_user_plugins(before)


def forget_user_plugins(before: set[str]) -> None:
    """Drop from ``plugins._loaded`` the user plugins (those with a folder) loaded since ``before``."""
    from vpr_uncertainty import plugins

    for target in set(plugins._loaded) - before:
        if plugins._loaded[target][0] is not None:
            del plugins._loaded[target]


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The real data directory (holds vprbench/ and poses/)."""
    value = os.environ.get("VPR_UNCERTAINTY_DATA")
    if not value:
        if os.environ.get("CI", "").lower() in {"1", "true", "yes"}:
            pytest.fail("VPR_UNCERTAINTY_DATA is not set; CI needs the real data")
        pytest.skip("VPR_UNCERTAINTY_DATA is not set")
    return _require(Path(value), "the data directory")


@pytest.fixture(scope="session")
def corridor_dir(data_dir: Path) -> Path:
    """VPR-Bench corridor dataset: query/, ref/, ground_truth_new.npy."""
    return _require(data_dir / "vprbench" / "corridor", "the corridor dataset")


@pytest.fixture(scope="session")
def corridor_matches_dir(data_dir: Path) -> Path:
    """Precomputed similarity matrices of ten VPR methods on the corridor dataset."""
    return _require(data_dir / "vprbench" / "precomputed_matches" / "corridor", "the corridor matches")


def load_benchmark(name: str):
    """The script ``benchmarks/<name>.py`` as a module (benchmarks/ on sys.path, as the scripts import each other)."""
    folder = str(Path(__file__).parents[1] / "benchmarks")
    if folder not in sys.path:
        sys.path.insert(0, folder)
    return importlib.import_module(name)


# --- tolerance policy (tests/README.md) ------------------------------------------------------------------------

#: Relative tolerance by floating dtype: a few units in the last place, enough for another summation order,
#: another BLAS kernel or thread count, never enough to hide a wrong formula.
RTOL: dict[np.dtype, float] = {np.dtype(np.float16): 1e-3, np.dtype(np.float32): 1e-5, np.dtype(np.float64): 1e-12}


def rtol_for(*values: object) -> float:
    """The relative tolerance of the least precise floating array among ``values`` (0 when none is floating).

    A Python float counts as float64: pass ``dtype=`` to :func:`assert_close` when it was computed in float32.
    """
    dtypes = [np.asarray(value).dtype for value in values]
    floating = [dtype for dtype in dtypes if dtype.kind in "fc"]
    if not floating:
        return 0.0
    least = max(floating, key=lambda dtype: np.finfo(dtype).eps)
    return RTOL[np.finfo(least).dtype]


def assert_close(actual, expected, *, rtol: float | None = None, atol: float = 0.0, dtype=None, err_msg: str = ""):
    """``np.testing.assert_allclose`` with ``rtol`` chosen by dtype (see :data:`RTOL`).

    ``dtype`` names the precision the values were computed in when it is not that of the arrays (a Python float
    from a float32 computation). Give ``atol`` where the values can be ~0, as a relative bound means nothing there.
    Integer and boolean inputs are compared exactly.
    """
    if rtol is None:
        rtol = RTOL[np.dtype(dtype)] if dtype is not None else rtol_for(actual, expected)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=atol, err_msg=err_msg)


@pytest.fixture(scope="module")
def ray_cluster():
    """A local Ray cluster of 2 CPUs for one test module, started and stopped by it (skips without Ray)."""
    ray = pytest.importorskip("ray")
    # one authentication mode for every Ray test of the session (mixing them in a process breaks ray.init)
    os.environ["RAY_AUTH_MODE"] = "disabled"
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def ray_executor(ray_cluster):
    """The ``ray`` executor with 2 workers on :func:`ray_cluster`."""
    from vpr_uncertainty.executors import get_executor

    with get_executor("ray", workers=2) as executor:
        yield executor


def results_numbers(document):
    """A results.json document without its timings (seconds differ run to run)."""
    if isinstance(document, dict):
        return {k: results_numbers(v) for k, v in document.items() if "seconds" not in k and not k.startswith("time_")}
    if isinstance(document, list):
        return [results_numbers(v) for v in document]
    return document


@pytest.fixture
def figures(monkeypatch):
    """The matplotlib figures the plot functions close, in order (still inspectable after ``plt.close``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    closed = []
    close = plt.close

    def record(figure=None):
        closed.append(figure)
        close(figure)

    monkeypatch.setattr(plt, "close", record)
    return closed
