"""evaluate feeds the GV-* methods their images (--images or the two folders) and reads the default method list
from the registry."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vpr_uncertainty.cli import main
from vpr_uncertainty.data.images import retrieval_image_paths
from vpr_uncertainty.retrieval import Retrieval


def _corridor_args(corridor_dir, corridor_matches_dir):
    scores = corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy"
    return [str(scores), "--gt", str(corridor_dir / "ground_truth_new.npy")]


def test_gv_sift_runs_from_the_command_line_on_the_corridor(corridor_dir, corridor_matches_dir, tmp_path, capsys):
    pytest.importorskip("cv2")
    out = tmp_path / "r.json"
    argv = ["evaluate", *_corridor_args(corridor_dir, corridor_matches_dir), "--images", str(corridor_dir)]
    assert main([*argv, "--methods", "SU,GV-SIFT", "--json", str(out)]) == 0
    methods = json.loads(out.read_text())["methods"]
    assert round(methods["GV-SIFT"]["auc_pr"], 3) == 0.874  # the README's figure


def test_the_two_folders_give_the_same_paths_as_the_dataset_folder(corridor_dir):
    retrieval = Retrieval(scores=np.ones((111, 1), np.float32), indices=np.zeros((111, 1), np.int64))
    together = retrieval_image_paths(retrieval, images=corridor_dir)
    apart = retrieval_image_paths(retrieval, query_images=corridor_dir / "query", database_images=corridor_dir / "ref")
    assert together == apart
    assert together[0][5].name == "0000005.jpg" and together[1][0].parent.name == "ref"


def test_a_gv_method_without_images_says_which_flag_to_give(corridor_dir, corridor_matches_dir, capsys):
    assert main(["evaluate", *_corridor_args(corridor_dir, corridor_matches_dir), "--methods", "GV-SIFT"]) == 2
    assert "GV-SIFT verifies images: give --images DIR" in capsys.readouterr().err


def test_images_without_a_gv_method_is_an_error(corridor_dir, corridor_matches_dir, capsys):
    argv = ["evaluate", *_corridor_args(corridor_dir, corridor_matches_dir), "--images", str(corridor_dir)]
    assert main(argv) == 2
    assert "none is in --methods" in capsys.readouterr().err


def test_a_folder_with_another_number_of_images_is_refused(tmp_path, corridor_dir, corridor_matches_dir, capsys):
    (tmp_path / "query").mkdir()
    (tmp_path / "ref").mkdir()
    for name in ("0.jpg", "1.jpg"):
        (tmp_path / "query" / name).write_bytes((corridor_dir / "query" / "0000000.jpg").read_bytes())
        (tmp_path / "ref" / name).write_bytes((corridor_dir / "ref" / "0000000.jpg").read_bytes())
    argv = ["evaluate", *_corridor_args(corridor_dir, corridor_matches_dir), "--images", str(tmp_path)]
    assert main([*argv, "--methods", "GV-SIFT"]) == 2
    err = capsys.readouterr().err
    assert "holds 2 images but the results have 111 queries (--images)" in err


def test_evaluate_default_methods_add_sue_with_metric_positions(tmp_path, capsys):
    from vpr_uncertainty.data.dataset import attach_ground_truth
    from vpr_uncertainty.retrieval import retrieve, save_retrieval

    rng = np.random.default_rng(0)
    database = rng.standard_normal((30, 8)).astype(np.float32)
    retrieval = retrieve(database, database[:10] + 0.8 * rng.standard_normal((10, 8)).astype(np.float32), 10)
    positions = np.column_stack([np.arange(30) * 10.0, np.zeros(30)])
    retrieval = attach_ground_truth(
        retrieval, database_positions=positions, query_positions=positions[:10], position_kind="metres"
    )
    save_retrieval(retrieval, tmp_path / "r.npz")
    out = tmp_path / "r.json"
    assert main(["evaluate", str(tmp_path / "r.npz"), "--json", str(out)]) == 0
    assert list(json.loads(out.read_text())["methods"]) == ["RS", "SD", "SU", "PA", "L2", "BM", "SUE"]
