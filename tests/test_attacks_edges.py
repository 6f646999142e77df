"""Issue 28, the edges where a user's methods and matrices come in: each test is the attack as a user runs it.

* row 14: ``compare`` on two results files whose stored positives differ was compared (McNemar p = 6.6e-05); the
  same file twice gave no notice;
* row 16: a distance matrix read as similarities gave R@1 0.000 and every AUC-PR "n/a", exit 0, with no hint unless
  every value was negative (and the reverse: similarities read with ``--scores distance``);
* row 17: the numba and numpy paths of RS, SD and SU disagreed on rows that are exact scalings of each other
  (RS AUC-PR 0.499 against 0.584): the ties differed;
* unclear messages: a plugin returning strings or complex numbers, a plugin that raises, a plugin that edits the
  retrieval in place (the next method was blamed), ``--scores distance`` with negative values, CSV cells that a
  spreadsheet runs as formulas, ``--recall-at`` with non-ASCII digits.

Every test fails on the code before the fix.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vpr_uncertainty import Retrieval, _fast, evaluate, ratio_spread, similarity_distribution, statistical_uncertainty

needs_numba = pytest.mark.skipif(_fast._load() is False, reason="numba is not installed (the fast extra)")

RATIO_METRICS = (ratio_spread, similarity_distribution, statistical_uncertainty)


def _both_paths(metric, scores, monkeypatch, **options):
    """``metric`` on the numba kernel (VPR_UNCERTAINTY_NUMBA=1) and on the numpy path (=0)."""
    monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, "1")
    fast = metric(scores, **options)
    monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, "0")
    return fast, metric(scores, **options)


def _scaled_rows(dtype, n_rows: int = 120, k: int = 10, seed: int = 3) -> np.ndarray:
    """Rows that are exact scalings of one row (RS, SD and SU are equal on all of them in exact arithmetic)."""
    rng = np.random.default_rng(seed)
    base = -np.sort(-rng.uniform(0.2, 0.9, size=k))
    return -np.sort(-(rng.uniform(0.5, 2.0, size=(n_rows, 1)) * base).astype(dtype), axis=1)


# --- row 17: the numba and numpy paths give the same bits, so the same ties ---------------------------------------


@needs_numba
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_scaled_rows_get_the_same_auc_pr_from_the_numba_and_numpy_paths(dtype, monkeypatch):
    scores = _scaled_rows(dtype)
    positives = [[0] if row % 3 else [5] for row in range(len(scores))]  # a third of the answers wrong
    retrieval = Retrieval(scores=scores, indices=np.tile(np.arange(10), (len(scores), 1)), positives=positives)
    results = []
    for mode in ("1", "0"):
        monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, mode)
        results.append(evaluate(retrieval, ["RS", "SD", "SU"], timing_repeats=1))
    for name in ("RS", "SD", "SU"):
        fast, reference = (result.methods[name] for result in results)
        assert np.array_equal(fast.uncertainty, reference.uncertainty), name
        assert fast.auc_pr == reference.auc_pr and fast.n_distinct == reference.n_distinct, name


@needs_numba
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("k", [3, 7, 10, 20])  # general and specialised kernels
def test_scaled_rows_are_bit_identical_on_both_paths(dtype, k, monkeypatch):
    scores = _scaled_rows(dtype, k=k)
    scores[::5, k - 1 :] = -np.inf  # rows with a missing candidate go through the general kernel and the redo path
    scores[1] = np.minimum(scores[1], 0) - 0.1  # s_1 <= 0: the most uncertain, 1 - s_1, on both paths
    for metric, options in zip(RATIO_METRICS, ({}, {}, {"alpha": 0.3}), strict=True):
        fast, reference = _both_paths(metric, scores, monkeypatch, k=k, **options)
        assert fast.dtype == reference.dtype == dtype
        assert np.array_equal(fast.view(np.uint8), reference.view(np.uint8)), metric.__name__


@needs_numba
@settings(max_examples=150, deadline=None)
@given(
    dtype=st.sampled_from([np.float32, np.float64]),
    base=st.lists(st.floats(-1, 1, width=32), min_size=2, max_size=12),
    scales=st.lists(st.floats(1e-3, 1e3), min_size=1, max_size=8),
    alpha=st.floats(0, 1),
)
def test_any_scaled_rows_are_bit_identical_on_both_paths(dtype, base, scales, alpha):
    scores = -np.sort(-(np.array(scales)[:, None] * np.array(base)).astype(dtype), axis=1)
    with pytest.MonkeyPatch.context() as monkeypatch:
        for metric, options in zip(RATIO_METRICS, ({}, {}, {"alpha": alpha}), strict=True):
            fast, reference = _both_paths(metric, scores, monkeypatch, k=len(base), **options)
            assert np.array_equal(fast.view(np.uint8), reference.view(np.uint8)), metric.__name__
