"""Geometric verification on the real VPR-Bench corridor images, verifying NetVLAD's real top-1 answers."""

from __future__ import annotations

import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import assert_close
from vpr_uncertainty import Retrieval, auc_pr, evaluate, read_results
from vpr_uncertainty.evaluation import correct_at_n
from vpr_uncertainty.formats.ground_truth import load_vprbench_ground_truth
from vpr_uncertainty.geometric import GeometricVerifier, gv_sift, rerank, verify_retrieval

cv2 = pytest.importorskip("cv2")
pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def corridor(corridor_dir: Path, corridor_matches_dir: Path) -> SimpleNamespace:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy VPR-Bench files are pickles, and say so
        retrieval = read_results(
            corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy",
            ground_truth=corridor_dir / "ground_truth_new.npy",
        )
        truth = load_vprbench_ground_truth(corridor_dir / "ground_truth_new.npy")
    assert (retrieval.positives != truth[:, : retrieval.positives.shape[1]]).nnz == 0
    query_paths = sorted((corridor_dir / "query").glob("*.jpg"))
    database_paths = sorted((corridor_dir / "ref").glob("*.jpg"))
    assert len(query_paths) == retrieval.n_queries == 111 and len(database_paths) == 111
    correct = correct_at_n(retrieval.indices, retrieval.positives, 1)
    assert 0 < correct.sum() < len(correct)
    return SimpleNamespace(retrieval=retrieval, query_paths=query_paths, database_paths=database_paths, correct=correct)


@pytest.fixture(scope="module")
def sift_run(corridor: SimpleNamespace, tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    cache_dir = tmp_path_factory.mktemp("gv-cache")
    verifier = GeometricVerifier.from_preset("GV-SIFT", cache_dir=cache_dir, workers=2, seed=0)
    result = verify_retrieval(
        corridor.retrieval, verifier, query_paths=corridor.query_paths, database_paths=corridor.database_paths
    )
    return SimpleNamespace(result=result, inliers=result.inliers[:, 0], verifier=verifier, cache_dir=cache_dir)


def _subset(corridor: SimpleNamespace, per_class: int) -> np.ndarray:
    """Queries spread evenly over the sequence: ``per_class`` with a correct top-1 and as many with a wrong one."""
    rows = []
    for mask in (corridor.correct, ~corridor.correct):
        candidates = np.flatnonzero(mask)
        rows.append(candidates[np.linspace(0, len(candidates) - 1, per_class).round().astype(int)])
    return np.concatenate(rows)


def test_sift_inliers_separate_correct_from_wrong_answers(corridor: SimpleNamespace, sift_run) -> None:
    inliers, correct = sift_run.inliers, corridor.correct
    assert inliers[correct].mean() > 2 * inliers[~correct].mean()
    # a real signal: far better than the base rate of correct answers that a useless ranking would give
    assert auc_pr(correct, -inliers) > correct.mean() + 0.1
    assert sift_run.result.extraction.extracted == len(set(corridor.retrieval.indices[:, 0])) + 111


def test_sift_cache_is_reused_and_counts_are_reproducible(corridor: SimpleNamespace, sift_run) -> None:
    again = verify_retrieval(
        corridor.retrieval, sift_run.verifier, query_paths=corridor.query_paths, database_paths=corridor.database_paths
    )
    assert again.extraction.extracted == 0 and again.extraction.cached == sift_run.result.extraction.extracted
    np.testing.assert_array_equal(again.inliers[:, 0], sift_run.inliers)
    # a fresh extraction without the cache, in one thread, with the same seed: identical counts
    rows = _subset(corridor, 10)
    sub = Retrieval(scores=corridor.retrieval.scores[rows], indices=corridor.retrieval.indices[rows])
    fresh = gv_sift(
        sub, query_paths=[corridor.query_paths[i] for i in rows], database_paths=corridor.database_paths, workers=1
    )
    np.testing.assert_array_equal(-fresh, sift_run.inliers[rows])
    assert list(sift_run.cache_dir.glob("sift-*.h5"))


def test_gv_sift_time_per_query_is_reported_beside_su(corridor: SimpleNamespace, sift_run) -> None:
    evaluation = evaluate(
        corridor.retrieval,
        ["SU", "GV-SIFT"],
        query_paths=corridor.query_paths,
        database_paths=corridor.database_paths,
        cache_dir=sift_run.cache_dir,
        workers=2,
        timing_repeats=1,
    )
    gv = evaluation.methods["GV-SIFT"]
    np.testing.assert_array_equal(gv.uncertainty, -sift_run.inliers)
    assert_close(gv.auc_pr, auc_pr(corridor.correct, -sift_run.inliers))
    assert gv.time_per_query_ms > evaluation.methods["SU"].time_per_query_ms > 0


def test_rerank_top5_reports_both_recalls(corridor: SimpleNamespace, sift_run) -> None:
    rows = _subset(corridor, 10)
    sub = Retrieval(
        scores=corridor.retrieval.scores[rows],
        indices=corridor.retrieval.indices[rows],
        positives=corridor.retrieval.positives[rows],
    )
    result = rerank(
        sub,
        sift_run.verifier,
        top_k=5,
        query_paths=[corridor.query_paths[i] for i in rows],
        database_paths=corridor.database_paths,
    )
    np.testing.assert_array_equal(np.sort(result.indices[:, :5], axis=1), np.sort(sub.indices[:, :5], axis=1))
    np.testing.assert_array_equal(result.indices[:, 5:], sub.indices[:, 5:])
    assert result.recall["reranked"][5] == result.recall["global"][5]  # the top-5 set is unchanged
    np.testing.assert_array_equal(result.inliers[:, 0], sift_run.inliers[rows])  # cached, same counts


@pytest.fixture(scope="module")
def learned_subset(corridor: SimpleNamespace, tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    """Twelve queries (six answered correctly, six wrongly), plus a query whose top-1 is a blank image and one
    without any candidate; the learned models are slow on this CPU, so they see this subset."""
    rows = _subset(corridor, 6)
    folder = tmp_path_factory.mktemp("blank")
    blank = folder / "blank.jpg"
    cv2.imwrite(str(blank), np.full((120, 160, 3), 127, np.uint8))
    database_paths = [*corridor.database_paths, blank]
    indices = np.concatenate([corridor.retrieval.indices[rows, :1], [[len(database_paths) - 1], [-1]]])
    scores = np.where(indices >= 0, 1, -np.inf).astype(np.float32)  # a missing candidate: index -1, score -inf
    retrieval = Retrieval(scores=scores, indices=indices)
    query_paths = [corridor.query_paths[i] for i in rows] + [corridor.query_paths[0]] * 2
    return SimpleNamespace(
        retrieval=retrieval,
        correct=corridor.correct[rows],
        options={"query_paths": query_paths, "database_paths": database_paths, "workers": 2},
    )


@pytest.mark.parametrize("method", ["GV-DISK-LG", "GV-XFEAT"])
def test_learned_inliers_separate_correct_from_wrong_answers(learned_subset: SimpleNamespace, method: str) -> None:
    pytest.importorskip("kornia")
    from vpr_uncertainty import get_method

    uncertainty = get_method(method)(learned_subset.retrieval, **learned_subset.options)
    inliers = -uncertainty[:-2]
    correct = learned_subset.correct
    assert inliers[correct].mean() > 1.3 * inliers[~correct].mean()
    assert auc_pr(correct, -inliers) > correct.mean() + 0.1
    assert uncertainty[-2] == 0 and uncertainty[-1] == 0  # blank image, no candidate: 0 inliers, no crash
    if method == "GV-XFEAT":  # cheap enough to run twice: fixed seed, same counts
        np.testing.assert_array_equal(
            get_method(method)(learned_subset.retrieval, **learned_subset.options), uncertainty
        )
