"""evaluate reads a VPR-methods-evaluation log folder (--save_descriptors) with no conversion step."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vpr_uncertainty.cli import main
from vpr_uncertainty.data import read_results
from vpr_uncertainty.formats.vpr_methods_evaluation import read_arguments, read_vpr_methods_evaluation

pytest.importorskip("faiss")


def _log_folder(tmp_path: Path, *, threshold: int = 25, with_log: bool = True) -> Path:
    """A log folder as that tool writes it: descriptors in the sorted order of the .jpg images, info.log, preds/."""
    rng = np.random.default_rng(0)
    dataset = tmp_path / "dataset"
    n_database, n_queries = 12, 6
    database_east = np.arange(n_database) * 20.0
    query_east = database_east[[1, 3, 5, 7, 9, 11]] + 3.0
    for folder, easts in (("database", database_east), ("queries", query_east)):
        (dataset / folder).mkdir(parents=True)
        for i, east in enumerate(easts):
            name = f"@{east:09.2f}@4000000.00@17@T@{i:03d}@.jpg"  # zero-padded: sorted = numeric order
            (dataset / folder / name).write_bytes(b"")
    database = rng.standard_normal((n_database, 16)).astype(np.float32)
    database /= np.linalg.norm(database, axis=1, keepdims=True)
    queries = database[[1, 3, 5, 2, 9, 0]] + 0.05 * rng.standard_normal((n_queries, 16)).astype(np.float32)
    queries /= np.linalg.norm(queries, axis=1, keepdims=True)
    log = tmp_path / "logs" / "default" / "2024-01-01_00-00-00"
    log.mkdir(parents=True)
    np.save(log / "queries_descriptors.npy", queries)
    np.save(log / "database_descriptors.npy", database)
    if with_log:
        arguments = (
            f"Namespace(positive_dist_threshold={threshold}, method='cosplace', backbone='ResNet50', "
            f"descriptors_dimension=16, database_folder='{dataset / 'database'}', "
            f"queries_folder='{dataset / 'queries'}', recall_values=[1, 5, 10, 20], num_preds_to_save=3, "
            "output_dir=PosixPath('out'), device='cpu')"
        )
        lines = ["2024-01-01 00:00:00 python3 main.py ...", f"2024-01-01 00:00:00 Arguments: {arguments}"]
        (log / "info.log").write_text("\n".join(lines) + "\n")
        (log / "preds").mkdir()
        database_paths = sorted((dataset / "database").glob("**/*.jpg"), key=str)
        for q, top1 in enumerate([1, 3, 5, 2, 9, 0]):
            text = f"Query path:\nq\n\nPredictions paths:\n{database_paths[top1]}\n\nPositives paths:\n\n"
            (log / "preds" / f"{q:03d}.txt").write_text(text)
    return log


def test_arguments_are_read_from_info_log(tmp_path):
    arguments = read_arguments(_log_folder(tmp_path) / "info.log")
    assert arguments["positive_dist_threshold"] == 25
    assert arguments["recall_values"] == [1, 5, 10, 20]
    assert arguments["output_dir"] == "out"


def test_ground_truth_is_derived_as_that_tool_does(tmp_path):
    log = read_vpr_methods_evaluation(_log_folder(tmp_path))
    retrieval = log.retrieval
    assert retrieval.n_queries == 6 and retrieval.n_database == 12
    assert retrieval.indices[:, 0].tolist() == [1, 3, 5, 2, 9, 0]
    # query i is 23, 3 and 17 m from database images 2i, 2i+1, 2i+2 (20 m apart): 25 m catches all three
    positives = [sorted(np.flatnonzero(row).tolist()) for row in retrieval.positives.toarray()]
    assert positives[0] == [0, 1, 2] and positives[5] == [10, 11]
    assert any("6 agree" in note for note in log.notes)  # the saved predictions were checked
    assert retrieval.config["radius"] == 25.0


def test_the_radius_flag(tmp_path, capsys):
    folder = _log_folder(tmp_path)
    out = tmp_path / "radius.json"
    assert main(["evaluate", str(folder), "--radius", "5", "--methods", "SU", "--json", str(out)]) == 0
    assert "within 5 m" in capsys.readouterr().out
    assert out.is_file()


def test_evaluate_on_the_log_folder(tmp_path, capsys):
    assert main(["evaluate", str(_log_folder(tmp_path)), "--methods", "SU,BM"]) == 0
    out = capsys.readouterr().out
    assert "note: ground truth: database images within 25 m" in out and "SU" in out and "BM" in out


def test_read_results_dispatches_a_log_folder(tmp_path):
    retrieval = read_results(_log_folder(tmp_path))
    assert retrieval.positives is not None and retrieval.k == 12


def test_an_explicit_ground_truth_needs_no_info_log(tmp_path):
    folder = _log_folder(tmp_path, with_log=False)
    gt = tmp_path / "gt.json"
    gt.write_text(json.dumps([[1], [3], [5], [7], [9], [11]]))
    retrieval = read_vpr_methods_evaluation(folder, ground_truth=gt).retrieval
    assert retrieval.positives.toarray()[3].nonzero()[0].tolist() == [7]


def test_without_any_ground_truth_the_message_says_what_to_give(tmp_path, capsys):
    assert main(["evaluate", str(_log_folder(tmp_path, with_log=False))]) == 2
    assert "no info.log naming the image folders; give the ground truth (--gt GT)" in capsys.readouterr().err


def test_a_folder_without_descriptors_names_the_flag_that_writes_them(tmp_path, capsys):
    assert main(["evaluate", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "queries_descriptors.npy, database_descriptors.npy missing" in err and "--save_descriptors" in err


def test_the_log_folder_says_its_own_score_kind(tmp_path, capsys):
    """That tool ranks by Faiss IndexFlatL2 on L2-normalised descriptors: --scores l2-distance is what it holds, read
    as the cosine similarities that rank the same; the note says so; --scores distance is refused."""
    log = _log_folder(tmp_path)
    similar = read_results(log)
    assert "s = 1 - d²/2" in similar.config["score_conversion"]
    np.testing.assert_array_equal(read_results(log, scores="l2-distance").scores, similar.scores)
    assert main(["evaluate", str(log), "--scores", "l2-distance", "--methods", "BM"]) == 0
    assert "note: L2-normalised descriptors searched by cosine similarity" in capsys.readouterr().out
    with pytest.raises(ValueError, match="searched by similarity"):
        read_results(log, scores="distance")
