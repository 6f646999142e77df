"""The fast paths of vpr_uncertainty.scores against the reference: the optional numba kernel of RS, SD and SU
(vpr_uncertainty._fast, the ``fast`` extra) and the one-pass validation of the baselines (BM, L2, PA, margin).

Both must give the reference's values (within the dtype's tolerance) and raise its errors, word for word."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from conftest import assert_close
from vpr_uncertainty import (
    _fast,
    _validation,
    best_match,
    l2_distance,
    margin,
    perceptual_aliasing,
    ratio_spread,
    scores,
    similarity_distribution,
    statistical_uncertainty,
)

RATIO_METRICS = (ratio_spread, similarity_distribution, statistical_uncertainty)
BASELINES = (best_match, l2_distance, perceptual_aliasing, margin)

needs_numba = pytest.mark.skipif(_fast._load() is False, reason="numba is not installed (the fast extra)")


def run(metric, array, mode, monkeypatch, **options):
    """``metric`` with VPR_UNCERTAINTY_NUMBA=mode: "1" the kernel at every size, "0" the numpy path."""
    monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, mode)
    return metric(array, **options)


def error_of(metric, array, mode, monkeypatch, **options):
    with pytest.raises((ValueError, TypeError)) as raised:
        run(metric, array, mode, monkeypatch, **options)
    return type(raised.value), str(raised.value)


# --- the numba kernel against the numpy path -----------------------------------------------------------------------


def _rows(draw_values, n_rows, n_columns, dtype):
    return hnp.arrays(dtype, (n_rows, n_columns), elements=draw_values)


@st.composite
def score_rows(draw):
    """Sorted rows of float32 or float64 scores, with ties, rows with s_1 <= 0 and trailing -inf (>= 2 finite)."""
    dtype = draw(st.sampled_from([np.float32, np.float64]))
    n_rows, n_columns = draw(st.integers(1, 20)), draw(st.integers(2, 13))
    values = st.sampled_from([0.9, 0.5, 0.5, 0.0, -0.3]) | st.floats(-1, 1, width=32, allow_subnormal=False)
    array = -np.sort(-draw(_rows(values, n_rows, n_columns, dtype)), axis=1)
    for row in range(n_rows):
        missing = draw(st.integers(0, n_columns - 2))
        if missing:
            array[row, n_columns - missing :] = -np.inf
    return array


@needs_numba
@settings(max_examples=300, deadline=None)
@given(array=score_rows(), k=st.integers(2, 15), alpha=st.sampled_from([0.0, 1.0, 0.5]) | st.floats(0, 1))
def test_kernel_matches_the_numpy_path(array, k, alpha):
    with pytest.MonkeyPatch.context() as monkeypatch:
        for metric, options in (
            (ratio_spread, {}),
            (similarity_distribution, {}),
            (statistical_uncertainty, {"alpha": alpha}),
        ):
            fast = run(metric, array, "1", monkeypatch, k=k, **options)
            reference = run(metric, array, "0", monkeypatch, k=k, **options)
            assert fast.dtype == reference.dtype == array.dtype
            assert_close(fast, reference, atol=1e-6 if array.dtype == np.float32 else 1e-14)


@needs_numba
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("k", [2, 3, 4, 9, 10, 20])
def test_kernel_on_large_random_input(dtype, k, monkeypatch):
    rng = np.random.default_rng(k)
    array = -np.sort(-rng.uniform(-0.2, 1, size=(5000, 12)), axis=1).astype(dtype)
    array[::7, 8:] = -np.inf
    for alpha in (0.0, 0.3, 1.0):
        fast = run(statistical_uncertainty, array, "1", monkeypatch, k=k, alpha=alpha)
        assert_close(fast, run(statistical_uncertainty, array, "0", monkeypatch, k=k, alpha=alpha), atol=1e-6)


def test_the_kernel_serves_large_inputs_only_once_loaded(monkeypatch):
    monkeypatch.delenv(_fast.ENVIRONMENT_VARIABLE, raising=False)
    loaded = _fast._load()
    assert _fast._kernel_for(_fast.MIN_ELEMENTS - 1) is None
    assert _fast._kernel_for(_fast.MIN_ELEMENTS) is (loaded or None)
    monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, "0")
    assert _fast._kernel_for(10**9) is None
    monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, "1")
    assert _fast._kernel_for(1) is (loaded or None)


def test_without_numba_the_numpy_path_answers(monkeypatch):
    monkeypatch.setattr(_fast, "_kernel", False)  # what _load() keeps when numba cannot be imported
    monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, "1")
    array = np.array([[0.9, 0.5, 0.4], [0.6, 0.59, -np.inf]])
    expected = [(0.5 * 0.45 + 0.5 * 0.5) / 0.9, (0.5 * 0.59 + 0.5 * 0.595) / 0.6]
    assert_close(statistical_uncertainty(array, k=3), expected)


def test_numba_is_imported_only_for_inputs_that_repay_it():
    script = (
        "import sys, numpy as np, vpr_uncertainty as v\n"
        f"v.statistical_uncertainty(np.full(({_fast.LOAD_ELEMENTS // 10 - 1}, 10), 0.5, np.float32))\n"
        "print('numba' in sys.modules)\n"
    )
    env = {key: value for key, value in os.environ.items() if key != _fast.ENVIRONMENT_VARIABLE}
    printed = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, env=env)
    assert printed.stdout.strip() == "False"


BAD_RATIO_INPUT = {
    "NaN": np.array([[0.9, 0.5, 0.1], [0.9, np.nan, 0.1]]),
    "NaN first": np.array([[0.9, 0.5, 0.1], [np.nan, 0.5, 0.1]]),
    "+inf": np.array([[0.9, 0.5, 0.1], [np.inf, 0.5, 0.1]]),
    "unsorted": np.array([[0.9, 0.5, 0.1], [0.1, 0.5, 0.9]]),
    "unsorted after k": np.array([[0.9, 0.5, 0.1, 0.0, 0.2]]),
    "-inf inside": np.array([[0.9, -np.inf, 0.1]]),
    "short row": np.array([[0.9, 0.5, 0.1], [0.8, -np.inf, -np.inf]]),
    "no candidate": np.array([[-np.inf, -np.inf, -np.inf]]),
    "overflow": np.array([[1e-38, -3e38, -3e38]], dtype=np.float32),
}


@needs_numba
@pytest.mark.parametrize("metric", RATIO_METRICS)
@pytest.mark.parametrize("case", list(BAD_RATIO_INPUT))
def test_kernel_raises_the_numpy_paths_errors(metric, case, monkeypatch):
    array = BAD_RATIO_INPUT[case]
    if case == "overflow" and metric is similarity_distribution:
        array = np.array([[1e-38, -3e38, -3e38]], dtype=np.float32)  # the median overflows too
    assert error_of(metric, array, "1", monkeypatch, k=3) == error_of(metric, array, "0", monkeypatch, k=3)


@needs_numba
@pytest.mark.parametrize("metric", RATIO_METRICS)
def test_kernel_raises_for_nonpositive_best_under_raise(metric, monkeypatch):
    array = np.array([[0.9, 0.5, 0.1], [0.0, -0.1, -0.2]])
    options = {"k": 3, "on_nonpositive": "raise"}
    assert error_of(metric, array, "1", monkeypatch, **options) == error_of(metric, array, "0", monkeypatch, **options)
    assert_close(run(metric, array, "1", monkeypatch, k=3), run(metric, array, "0", monkeypatch, k=3))


def _documented_order(array: np.ndarray, k: int, rs_weight: float, sd_weight: float) -> np.ndarray:
    """RS/SD/SU row by row in the order the docs fix for both paths (issue 28 row 17, issue 45): float64, s_2 + s_3
    + ... left to right over the finite candidates, then (rs_weight / (n - 1))·sum + (sd_weight / 2)·(the middle
    two), divided by s_1 (1 - s_1 where s_1 <= 0), rounded once to the scores' dtype."""
    values = []
    for row in array:
        top = [np.float64(value) for value in row[:k] if value > -np.inf]
        n = len(top)
        total = top[1]
        for value in top[2:]:
            total = total + value
        value = rs_weight / (n - 1) * total + sd_weight * 0.5 * (top[(n - 1) // 2] + top[n // 2])
        values.append(value / top[0] if top[0] > 0 else 1.0 - top[0])
    return np.array(values).astype(array.dtype)


@settings(max_examples=150, deadline=None)
@given(array=score_rows(), k=st.integers(2, 15), alpha=st.sampled_from([0.0, 1.0, 0.5]) | st.floats(0, 1))
def test_both_paths_compute_in_the_documented_order(array, k, alpha):
    """The same bits as a plain loop in the documented order, on the numpy path and (when installed) the kernel."""
    with pytest.MonkeyPatch.context() as monkeypatch:
        for metric, weights, options in (
            (ratio_spread, (1.0, 0.0), {}),
            (similarity_distribution, (0.0, 1.0), {}),
            (statistical_uncertainty, (alpha, 1.0 - alpha), {"alpha": alpha}),
        ):
            expected = _documented_order(array, k, *weights).view(np.uint8)
            for mode in ("0", "1") if _fast._load() else ("0",):
                got = run(metric, array, mode, monkeypatch, k=k, **options)
                assert np.array_equal(got.view(np.uint8), expected), (metric.__name__, mode)


@pytest.mark.parametrize("metric", RATIO_METRICS)
def test_the_numpy_path_holds_no_copy_of_the_scores(metric, monkeypatch):
    """Issue 45: RS, SD and SU at the memory bound read each score once, block by block; beside the output (4 bytes
    a query) they hold one block's columns, not a float64 copy of every query's values (13 MB here before: 0.33x)."""
    import tracemalloc

    monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, "0")
    rng = np.random.default_rng(0)
    array = -np.sort(-rng.uniform(0.05, 1, size=(1_000_000, 10)).astype(np.float32), axis=1)
    metric(array[:1000])
    tracemalloc.start()
    try:
        metric(array)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak <= 0.25 * array.nbytes, f"peak {peak / 1e6:.1f} MB for {array.nbytes / 1e6:.0f} MB of scores"


# --- the baselines' one-pass validation ------------------------------------------------------------------------------


@pytest.mark.parametrize("metric", BASELINES)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_baselines_over_many_blocks_match_the_formulas(metric, dtype, monkeypatch):
    monkeypatch.setattr(_validation, "_SCAN_ELEMENTS", 64)  # 6 rows a block: many blocks, a short last one
    rng = np.random.default_rng(1)
    array = -np.sort(-rng.uniform(-1, 1, size=(100, 10)), axis=1).astype(dtype)
    array[3, 4:] = -np.inf  # missing candidates after the columns read
    distances = np.sqrt(np.maximum(2 - 2 * array[:, :2].astype(np.float64), 0))
    expected = {
        best_match: -array[:, 0],
        l2_distance: distances[:, 0],
        perceptual_aliasing: distances[:, 0] / distances[:, 1],
        margin: array[:, 1] - array[:, 0],
    }[metric]
    result = metric(array)
    assert result.dtype == dtype
    assert_close(result, expected, atol=1e-6)


@pytest.mark.parametrize("metric", BASELINES)
@pytest.mark.parametrize(
    ("row", "message"),
    [
        ([0.9, 0.5, np.nan], "NaN.*row 13"),
        ([np.nan, 0.5, 0.1], "NaN.*row 13"),
        ([0.9, 0.95, 0.1], "row 13 has 0.9 before 0.95"),
        ([0.9, 0.5, 0.1, 0.2], "row 13 has 0.1 before 0.2"),
        ([np.inf, 0.5, 0.1], r"\+inf \(first in row 13\)"),
    ],
)
def test_baselines_name_the_bad_row_in_a_later_block(metric, row, message, monkeypatch):
    monkeypatch.setattr(_validation, "_SCAN_ELEMENTS", 16)  # 4 rows a block
    array = np.tile([0.9, 0.5, 0.1, 0.0], (20, 1))
    array[13, : len(row)] = row
    with pytest.raises(ValueError, match=message):
        metric(array)


@pytest.mark.parametrize("metric", [perceptual_aliasing, margin])
def test_a_short_row_in_a_later_block_is_named(metric, monkeypatch):
    monkeypatch.setattr(_validation, "_SCAN_ELEMENTS", 16)
    array = np.tile([0.9, 0.5, 0.1, 0.0], (20, 1))
    array[17, 1:] = -np.inf
    with pytest.raises(ValueError, match=r"fewer than 2 candidates \(rows 17\)"):
        metric(array)


@pytest.mark.parametrize("metric", [l2_distance, perceptual_aliasing])
def test_cosine_range_is_checked_exactly_at_its_edges(metric):
    tolerance = scores.COSINE_TOLERANCE
    for top, ok in ((1 + tolerance * 0.9, True), (1 + tolerance * 1.1, False), (1 + tolerance / 4, True)):
        array = np.array([[top, 0.5], [0.9, 0.8]])
        if ok:
            assert np.isfinite(metric(array)).all()
        else:
            with pytest.raises(ValueError, match=r"1.0011\], outside \[-1, 1\]"):
                metric(array)
    for bottom, ok in ((-1 - tolerance * 0.9, True), (-1 - tolerance * 1.1, False)):
        array = np.array([[0.9, bottom, bottom]])
        if metric is l2_distance or ok:
            assert np.isfinite(metric(array)).all()  # L2 reads column 0 only
        else:
            with pytest.raises(ValueError, match="outside"):
                metric(array)


def test_range_is_checked_on_the_columns_read_only():
    array = np.array([[0.9, 0.5, -3.0]])  # not a cosine similarity, but PA reads two columns
    assert_close(perceptual_aliasing(array), [np.sqrt(0.2) / 1.0])


def test_margin_overflow_is_returned_as_before():
    array = np.array([[3e38, -3e38]], dtype=np.float32)
    with np.errstate(over="ignore"):
        assert margin(array)[0] == -np.inf


# --- the kernels compiled for one row length, and the margin and PA kernels -----------------------------------------


@needs_numba
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n", _fast.SPECIALISED)
def test_specialised_kernel_matches_the_numpy_path(n, dtype, monkeypatch):
    rng = np.random.default_rng(n)
    array = -np.sort(-rng.uniform(-0.2, 1, size=(3000, n)), axis=1).astype(dtype)
    clean = array[array[:, 0] > 0]
    for alpha in (0.0, 0.3, 1.0):
        for values in (clean, array):  # s_1 <= 0 rows make the specialised kernel hand over to the general one
            fast = run(statistical_uncertainty, values, "1", monkeypatch, k=n, alpha=alpha)
            reference = run(statistical_uncertainty, values, "0", monkeypatch, k=n, alpha=alpha)
            assert fast.dtype == dtype
            assert_close(fast, reference, atol=1e-6 if dtype == np.float32 else 1e-14)


def _with_bad_row(case: str, n_columns: int, dtype) -> np.ndarray:
    array = np.tile(np.linspace(0.9, 0.1, n_columns), (50, 1)).astype(dtype)
    row = {
        "NaN": [0.9, np.nan],
        "+inf": [np.inf],
        "unsorted": [0.1, 0.5],
        "unsorted at the end": [0.9] * (n_columns - 1) + [0.95],
        "missing": [0.9, 0.5] + [-np.inf] * (n_columns - 2),
        "short": [0.9] + [-np.inf] * (n_columns - 1),
        "nonpositive": [0.0] + [-0.1] * (n_columns - 1),
        "not cosine": [1.5, 0.5],
        "edge of cosine": [1.0004, 0.5],
        "overflow": [1e-38, -3e38] if dtype == np.float32 else [1e-300, -1e300],
    }[case]
    array[37, : len(row)] = row
    return array


BAD_CASES = ["NaN", "+inf", "unsorted", "unsorted at the end", "missing", "short", "nonpositive", "not cosine"]


@needs_numba
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n_columns", [10, 7])  # specialised and general
@pytest.mark.parametrize("case", [*BAD_CASES, "edge of cosine", "overflow"])
@pytest.mark.parametrize("metric", [*RATIO_METRICS, margin, perceptual_aliasing])
def test_kernels_hand_unusual_rows_to_the_numpy_path(metric, case, n_columns, dtype, monkeypatch):
    array = _with_bad_row(case, n_columns, dtype)
    k = {"k": n_columns}
    with np.errstate(all="ignore"):
        try:
            reference = run(metric, array, "0", monkeypatch, **k)
        except (ValueError, TypeError):
            assert error_of(metric, array, "1", monkeypatch, **k) == error_of(metric, array, "0", monkeypatch, **k)
        else:
            fast = run(metric, array, "1", monkeypatch, **k)
            assert fast.dtype == reference.dtype
            assert_close(fast, reference, atol=1e-6 if dtype == np.float32 else 1e-14)


@needs_numba
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n_columns", [2, 3, 10, 20])
def test_margin_and_pa_kernels_match_the_formulas(n_columns, dtype, monkeypatch):
    monkeypatch.setenv(_fast.ENVIRONMENT_VARIABLE, "1")
    rng = np.random.default_rng(n_columns)
    array = -np.sort(-rng.uniform(-1, 1, size=(2000, n_columns)), axis=1).astype(dtype)
    array[5] = np.minimum(array[5], 0.5)
    array[5, :2] = 0.5  # a tie
    array[6, :2] = 1.0  # a tie at distance 0: PA's 0 / 0 is 1
    for kind in ("margin", "PA"):
        fast = _fast.two_column(kind, array, scores.COSINE_TOLERANCE)
        assert fast is not None and fast.dtype == dtype
        distances = np.sqrt(np.maximum(2 - 2 * array[:, :2].astype(np.float64), 0))
        with np.errstate(invalid="ignore"):
            expected = array[:, 1] - array[:, 0] if kind == "margin" else distances[:, 0] / distances[:, 1]
        expected[6] = expected[6] if kind == "margin" else 1.0
        assert_close(fast, expected, atol=1e-6)
