"""The feature matrix: vectorised, equal to the one-query path and to a slow reference, on real corridor matrices."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty.calibration.calibrator import FEATURES, feature_matrix, row_features
from vpr_uncertainty.data import read_results

CORRIDOR = ["AMOSNet", "CALC", "denseVLAD", "NetVLAD"]


def _reference(row: list[float], k: int) -> dict[str, float]:
    top = [v for v in sorted(row, reverse=True)[:k] if v != -np.inf]
    s1, rest = top[0], top[1:]
    median = float(np.median(top))
    return {
        "s1": s1,
        "gap": s1 - top[1],
        "ratio": top[1] / s1,
        "RS": float(np.mean(rest)) / s1,
        "SD": median / s1,
        "SU": 0.5 * float(np.mean(rest)) / s1 + 0.5 * median / s1,
        "zscore": (s1 - float(np.mean(rest))) / (s1 - top[-1]),
        "PA": float(np.sqrt(2 - 2 * s1) / np.sqrt(2 - 2 * top[1])),  # d_1 / d_2 of L2-normalised descriptors
    }


@pytest.mark.filterwarnings("ignore:reading the legacy")
@pytest.mark.parametrize("method", CORRIDOR)
def test_feature_matrix_matches_reference_and_row_path(method, corridor_dir, corridor_matches_dir):
    retrieval = read_results(
        corridor_matches_dir / method / "precomputed_data_corrected.npy",
        ground_truth=corridor_dir / "ground_truth_new.npy",
    )
    matrix = feature_matrix(retrieval.scores, k=10, features=FEATURES)
    assert matrix.shape == (retrieval.n_queries, len(FEATURES)) and matrix.dtype == np.float64
    reference = np.array([[_reference(row.tolist(), 10)[name] for name in FEATURES] for row in retrieval.scores])
    assert_close(matrix, reference, rtol=1e-5)  # float32 scores
    rows = np.array([row_features(row.tolist(), k=10, features=FEATURES) for row in retrieval.scores])
    assert_close(rows, matrix, rtol=1e-5)


def test_pa_feature_needs_cosine_similarities_in_both_paths():
    assert_close(feature_matrix(np.array([[0.5, -0.5]]), k=2, features=("PA",)), [[np.sqrt(1 / 3)]], rtol=1e-12)
    assert row_features([1.0, 1.0], k=2, features=("PA",)) == [1.0]  # both distances 0
    with pytest.raises(ValueError, match="PA"):
        feature_matrix(np.array([[1.5, 0.5]]), k=2, features=("PA",))
    with pytest.raises(ValueError, match="PA needs cosine"):
        row_features([1.5, 0.5], k=2, features=("PA",))


def test_missing_candidates_and_nonpositive_best():
    scores = np.array([[0.8, 0.4, 0.2, -np.inf], [-0.1, -0.2, -0.3, -0.4]])
    matrix = feature_matrix(scores, k=4, features=("RS", "SD", "ratio", "s1"))
    assert_close(matrix[0], [0.375, 0.5, 0.5, 0.8], rtol=1e-12)
    assert_close(matrix[1, :3], [1.1, 1.1, 1.1], rtol=1e-12)  # 1 − s_1, as in scores.py
    assert_close(row_features(scores[1].tolist(), k=4, features=("RS", "SD", "ratio")), [1.1, 1.1, 1.1], rtol=1e-12)
    assert_close(row_features(scores[0].tolist(), k=4, features=("RS", "SD")), [0.375, 0.5], rtol=1e-12)


@pytest.mark.parametrize(
    ("scores", "features", "message"),
    [
        (np.array([[0.5, -np.inf]]), ("s1",), "row 0 has 1 finite candidate"),
        (np.array([[0.5, 0.4]]), ("bogus",), "unknown feature"),
        (np.array([[0.5, 0.4]]), "s1", "non-empty list"),
        (np.array([[0.5, 0.4]]), ("s1", "s1"), "twice"),
        (np.array([[0.4, 0.5]]), ("s1",), "sorted"),
    ],
)
def test_feature_matrix_errors(scores, features, message):
    with pytest.raises(ValueError, match=message):
        feature_matrix(scores, k=2, features=features)


@pytest.mark.parametrize("row", [[0.4, 0.5], [0.5, float("nan")], [float("inf"), 0.2], [0.5]])
def test_row_features_errors(row):
    with pytest.raises(ValueError, match="scores"):
        row_features(row, k=10)
