"""Scores of any direction: distance matrices read as distances, and default method lists that leave out the
methods whose assumptions the scores break (RS/SD/SU divide by s_1; L2/PA/SUE need cosine similarities)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sklearn.metrics import auc, precision_recall_curve

from vpr_uncertainty import Retrieval, evaluate
from vpr_uncertainty.cli import main
from vpr_uncertainty.data import read_results
from vpr_uncertainty.retrieval import load_retrieval, save_retrieval


def _descriptors(seed: int = 0) -> tuple[np.ndarray, list[list[int]]]:
    """A (40, 80) L2 distance matrix between noisy copies of the first 40 database descriptors and the database;
    query i's positive is database image i."""
    rng = np.random.default_rng(seed)
    database = rng.normal(size=(80, 16))
    queries = database[:40] + 1.2 * rng.normal(size=(40, 16))
    distances = np.linalg.norm(queries[:, None] - database[None], axis=2)
    return distances, [[i] for i in range(40)], queries @ database.T


@pytest.fixture
def files(tmp_path):
    distances, positives, dot = _descriptors()
    paths = {"distance": tmp_path / "dist.npy", "dot": tmp_path / "dot.npy", "gt": tmp_path / "gt.json"}
    np.save(paths["distance"], distances)
    np.save(paths["dot"], dot)
    paths["gt"].write_text(json.dumps(positives))
    return paths


def test_a_distance_matrix_keeps_the_nearest_as_distances_and_negated_scores(files):
    distances = np.load(files["distance"])
    retrieval = read_results(files["distance"], ground_truth=files["gt"], top_k=10, scores="distance")
    nearest = np.argsort(distances, axis=1, kind="stable")[:, :10]  # slow, obvious reference
    np.testing.assert_array_equal(retrieval.indices, nearest)
    np.testing.assert_array_equal(retrieval.distances, np.take_along_axis(distances, nearest, axis=1))
    np.testing.assert_array_equal(retrieval.scores, -retrieval.distances)
    assert retrieval.score_kind == "distance"
    assert read_results(files["distance"], ground_truth=files["gt"]).score_kind == "similarity"


def test_the_score_kind_survives_a_retrieval_file(files, tmp_path):
    retrieval = read_results(files["distance"], ground_truth=files["gt"], scores="distance")
    assert load_retrieval(save_retrieval(retrieval, tmp_path / "r.npz")).score_kind == "distance"


def test_default_methods_on_distances_leave_out_the_ratios_with_one_warning(files):
    retrieval = read_results(files["distance"], ground_truth=files["gt"], scores="distance")
    with pytest.warns(UserWarning) as caught:
        evaluation = evaluate(retrieval, timing_repeats=1)
    messages = [str(warning.message) for warning in caught if "left out" in str(warning.message)]
    assert len(messages) == 1 and messages[0].startswith("left out of the default methods (RS, SD, SU:")
    assert list(evaluation.methods) == ["PA", "L2", "BM"]
    # PA = d_1 / d_2 (up to a monotone map): its AUC-PR is the one computed by hand from the distances
    correct = retrieval.indices[:, 0] == np.arange(40)
    ratio = retrieval.distances[:, 0] / retrieval.distances[:, 1]
    precision, recall, _ = precision_recall_curve(correct, -ratio)
    assert evaluation.methods["PA"].auc_pr == pytest.approx(auc(recall, precision), rel=1e-12)


def test_default_methods_on_dot_products_run_without_l2_and_pa(files):
    """Before, the default list failed the whole run on PA (dot products lie outside [-1, 1])."""
    retrieval = read_results(files["dot"], ground_truth=files["gt"])
    with pytest.warns(UserWarning, match=r"left out of the default methods \(PA, L2: they need cosine similarities"):
        evaluation = evaluate(retrieval, timing_repeats=1)
    assert list(evaluation.methods) == ["RS", "SD", "SU", "BM"]
    with pytest.raises(ValueError, match="PA needs descriptor distances"):  # named explicitly: its own error
        evaluate(retrieval, ["PA"], timing_repeats=1)


def test_negated_distances_read_as_similarities_point_to_the_distance_option(files):
    retrieval = read_results(files["distance"], ground_truth=files["gt"])  # as stored: the farthest first
    negated = Retrieval(scores=-retrieval.scores[:, ::-1].copy(), indices=retrieval.indices, positives=None)
    with pytest.warns(UserWarning, match="no query's is positive.*--scores distance"):
        from vpr_uncertainty.methods import default_method_names

        assert default_method_names(retrieval=negated) == ["BM"]


def test_cosine_similarities_keep_every_default_method():
    rng = np.random.default_rng(1)
    scores = -np.sort(-rng.uniform(0.1, 0.9, size=(30, 10)), axis=1)
    retrieval = Retrieval(scores=scores, indices=np.tile(np.arange(10), (30, 1)), positives=None)
    import warnings

    from vpr_uncertainty.methods import default_method_names

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert default_method_names(retrieval=retrieval) == default_method_names()


@pytest.mark.parametrize(("value", "where"), [(np.nan, "nan"), (-np.inf, "-inf")])
def test_a_distance_matrix_refuses_nan_and_minus_infinity(files, tmp_path, value, where):
    distances = np.load(files["distance"])
    distances[3, 5] = value
    np.save(tmp_path / "bad.npy", distances)
    with pytest.raises(ValueError, match=rf"the distance matrix holds {where} at query 3, database image 5"):
        read_results(tmp_path / "bad.npy", ground_truth=files["gt"], scores="distance")


def test_plus_infinity_in_a_distance_matrix_is_no_candidate(files, tmp_path):
    distances = np.load(files["distance"])
    distances[0, 1:] = np.inf
    np.save(tmp_path / "sparse.npy", distances)
    retrieval = read_results(tmp_path / "sparse.npy", ground_truth=files["gt"], top_k=3, scores="distance")
    assert retrieval.indices[0].tolist() == [0, -1, -1] and np.isinf(retrieval.distances[0, 1:]).all()


def test_the_command_line_reads_distances_with_one_notice(files, capsys):
    with pytest.warns(UserWarning) as caught:  # the command line prints each warning as one "warning: ..." line
        assert main(["evaluate", str(files["distance"]), "--gt", str(files["gt"]), "--scores", "distance"]) == 0
    assert [line.split()[0] for line in capsys.readouterr().out.splitlines()[3:6]] == ["PA*", "L2", "BM"]
    notices = [str(warning.message) for warning in caught if "left out" in str(warning.message)]
    assert len(notices) == 1 and "RS, SD, SU" in notices[0]


def test_distances_are_refused_for_a_retrieval_file(files, tmp_path, capsys):
    retrieval = read_results(files["distance"], ground_truth=files["gt"])
    path = save_retrieval(retrieval, tmp_path / "r.npz")
    assert main(["evaluate", str(path), "--scores", "distance"]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "whose scores are similarities" in error
