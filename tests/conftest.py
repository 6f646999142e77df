"""Shared fixtures: the real data directory from VPR_UNCERTAINTY_DATA.

Tests that need the real data use the ``data_dir`` fixture. Without the data they are skipped on a developer
machine and fail under CI (CI=true), so a CI run never passes without exercising them.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest


def _require(path: Path, what: str) -> Path:
    if not path.exists():
        message = f"{what} not found at {path}; set VPR_UNCERTAINTY_DATA to the shared data directory"
        if os.environ.get("CI", "").lower() in {"1", "true", "yes"}:
            pytest.fail(message)
        pytest.skip(message)
    return path


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
