"""The verify stage: inliers of the top candidates of a retrieval file, the GV uncertainty and the re-ranking."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from vpr_uncertainty.cli import main
from vpr_uncertainty.data import read_results
from vpr_uncertainty.evaluation import evaluate
from vpr_uncertainty.retrieval import save_retrieval

pytest.importorskip("cv2")
pytestmark = pytest.mark.realdata


@pytest.fixture
def corridor_retrieval(tmp_path, corridor_matches_dir, corridor_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        retrieval = read_results(
            corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy",
            ground_truth=corridor_dir / "ground_truth_new.npy",
        )
    save_retrieval(retrieval, tmp_path / "retrieval.npz")
    return retrieval, tmp_path / "retrieval.npz"


def test_verify_gives_the_gv_sift_uncertainty_of_evaluate(corridor_retrieval, corridor_dir, tmp_path, capsys):
    retrieval, path = corridor_retrieval
    out = tmp_path / "run" / "verification.npz"
    assert main(["verify", str(path), "--images", str(corridor_dir), "--out", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    with np.load(out) as stored:
        assert stored["inliers"].shape == (111, 1) and stored["indices"].shape == retrieval.indices.shape
        verified = stored["uncertainty"]
    from vpr_uncertainty.data.images import retrieval_image_paths

    query_paths, database_paths = retrieval_image_paths(retrieval, images=corridor_dir)
    reference = evaluate(
        retrieval,
        ["GV-SIFT"],
        query_paths=[str(p) for p in query_paths],
        database_paths=[str(p) for p in database_paths],
        cache_dir=tmp_path / "run" / "local_features",  # the features the stage cached: read, not extracted again
        timing_repeats=1,
    )
    np.testing.assert_array_equal(verified, reference.methods["GV-SIFT"].uncertainty)


def test_verify_reranks_and_refuses_a_score_method(corridor_retrieval, corridor_dir, tmp_path, capsys):
    _, path = corridor_retrieval
    out = tmp_path / "v.npz"
    assert main(["verify", str(path), "--images", str(corridor_dir), "--out", str(out), "--top-k", "3"]) == 0
    assert "re-ranking the top 3 by GV-SIFT inliers: R@1" in capsys.readouterr().out
    with np.load(out) as stored:
        inliers, indices = stored["inliers"], stored["indices"]
    assert inliers.shape == (111, 3)
    assert (np.sort(indices[:, :3], axis=1) == np.sort(np.load(path)["indices"][:, :3], axis=1)).all()
    assert main(["verify", str(path), "--images", str(corridor_dir), "--out", str(out), "--method", "SU"]) == 2
    assert "--method must be a geometric verification method" in capsys.readouterr().err


def test_verify_names_the_flag_of_a_missing_image_folder(corridor_retrieval, tmp_path, capsys):
    _, path = corridor_retrieval
    assert main(["verify", str(path), "--out", str(tmp_path / "v.npz")]) == 2
    assert "no image folder given (--images)" in capsys.readouterr().err
    assert main(["verify", str(path), "--images", str(tmp_path / "none"), "--out", str(tmp_path / "v.npz")]) == 2
    assert "image folder not found" in capsys.readouterr().err and not (tmp_path / "v.npz").exists()
