"""calibration/heldout.py: per-query options (the query images) are cut to the held-out queries of each split.

Real inputs: the NetVLAD similarity matrix of the corridor and its ground truth.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from vpr_uncertainty.calibration.quality import evaluate_held_out
from vpr_uncertainty.data import read_results
from vpr_uncertainty.methods import METHODS, register_method

pytestmark = pytest.mark.filterwarnings("ignore:reading the legacy VPR-Bench file")


@pytest.fixture
def image_method():
    """A method that needs the images: −s_1 of the query each path names (so it must get the right paths)."""
    seen = []

    def best_match_by_path(retrieval, *, query_paths, database_paths):
        seen.append(len(query_paths))
        rows = [int(path.rsplit("q", 1)[1]) for path in query_paths]
        return -image_method.full_scores[rows, 0]

    register_method("TEST-IMAGES", best_match_by_path, description="test", requires=("images",))
    image_method.seen = seen
    try:
        yield image_method
    finally:
        METHODS.unregister("TEST-IMAGES")


def test_query_paths_are_those_of_the_held_out_queries(image_method, corridor_dir, corridor_matches_dir):
    """Regression: the full list of query paths went with the held-out subset (a length mismatch, or wrong images)."""
    retrieval = read_results(
        corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy",
        ground_truth=corridor_dir / "ground_truth_new.npy",
    )
    image_method.full_scores = retrieval.scores
    paths = [f"images/q{i}" for i in range(retrieval.n_queries)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = evaluate_held_out(
            retrieval,
            ["BM", "TEST-IMAGES"],
            calibration_fraction=0.3,
            repeats=3,
            seed=0,
            query_paths=paths,
            database_paths=[f"images/d{i}" for i in range(retrieval.scores.shape[0])],
        )
    assert set(image_method.seen) == {result.n_held_out}
    np.testing.assert_array_equal(result.values["TEST-IMAGES"]["auc_pr"], result.values["BM"]["auc_pr"])


@pytest.mark.filterwarnings("ignore:reading the legacy")
def test_a_split_too_small_to_measure_is_refused(corridor_dir, corridor_matches_dir, tmp_path, capsys):
    """fraction 0.999 left 2 held-out queries and reported SU 1.000 in bold (issue 20)."""
    matches = corridor_matches_dir / "AMOSNet" / "precomputed_data_corrected.npy"
    retrieval = read_results(matches, ground_truth=corridor_dir / "ground_truth_new.npy")
    with pytest.raises(ValueError, match=r"leaves 2 held-out queries \(1 correct, 1 wrong\) of 111"):
        evaluate_held_out(retrieval, ["SU", "CAL"], calibration_fraction=0.999, repeats=2)
    assert evaluate_held_out(retrieval, ["SU"], calibration_fraction=0.9, repeats=1).n_held_out == 11
    from vpr_uncertainty.cli import main

    config = tmp_path / "grid.toml"
    config.write_text(
        'out = "out"\nmethods = ["SU", "CAL"]\ncalibration = {fraction = 0.999, repeats = 2, seed = 0}\n'
        f'[[inputs]]\nvpr_method = "AMOSNet"\ndataset = "corridor"\nscores = "{matches}"\n'
        f'ground_truth = "{corridor_dir / "ground_truth_new.npy"}"\n'
    )
    assert main(["reproduce", str(config), "--no-report"]) == 2
    assert "a held-out figure needs at least 10 queries" in capsys.readouterr().err
    assert not (tmp_path / "out" / "results.json").exists()
