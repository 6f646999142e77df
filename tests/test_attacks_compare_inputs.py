"""Issue 42, "also due": attacks on ``compare`` and on what users hand the readers. An hloc file whose names mix split
prefixes with none, a top-5 against a top-20 file, a single NaN in a similarity matrix, a bootstrap too small to
give an interval, and an unsorted score row met on the command line. Each test fails on the code before the fix."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vpr_uncertainty import Retrieval, compare, evaluate
from vpr_uncertainty.cli import main


def _one_line_error(capsys) -> str:
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1, captured.err
    return captured.err


# --- hloc: an unprefixed name beside query/ and db/ ----------------------------------------------------------------


def test_an_hloc_file_mixing_prefixed_and_unprefixed_names_is_refused_naming_the_image(tmp_path, capsys):
    from vpr_uncertainty.formats.hloc import read_hloc_descriptors, write_hloc_descriptors

    names = ["db/0.jpg", "db/1.jpg", "db/2.jpg", "query/0.jpg", "name.jpg"]
    path = write_hloc_descriptors(tmp_path / "g.h5", names, np.eye(5, 8, dtype=np.float32))
    for split in ("database", "queries"):  # the image belongs to neither: it was dropped from both without a word
        with pytest.raises(ValueError, match=r"image 'name.jpg' \(1 such\) has no split prefix.*query/.*db/"):
            read_hloc_descriptors(path, split)
    # prefixes on every name still read as before
    clean = write_hloc_descriptors(tmp_path / "c.h5", names[:4], np.eye(4, 8, dtype=np.float32))
    assert read_hloc_descriptors(clean, "database")[0].tolist() == ["db/0.jpg", "db/1.jpg", "db/2.jpg"]
    pytest.importorskip("faiss")
    argv = ["retrieve", "--database", str(path), "--queries", str(path), "--out", str(tmp_path / "r.npz")]
    assert main([*argv, "--top-k", "2"]) == 2
    assert "'name.jpg' (1 such) has no split prefix" in _one_line_error(capsys)
    assert not (tmp_path / "r.npz").exists()


# --- compare: a top-5 file against a top-20 file ------------------------------------------------------------------


def _top20(n_queries: int = 60) -> Retrieval:
    rng = np.random.default_rng(7)
    scores = -np.sort(-rng.random((n_queries, 20)), axis=1)
    indices = np.stack([rng.permutation(30)[:20] for _ in range(n_queries)])
    return Retrieval(scores=scores, indices=indices, positives=[[int(i)] for i in rng.integers(0, 3, n_queries)])


def test_compare_of_a_top5_and_a_top20_file_compares_at_the_common_k_and_says_so(tmp_path, capsys):
    from vpr_uncertainty.retrieval.result import save_retrieval

    full = _top20()
    short = Retrieval(scores=full.scores[:, :5], indices=full.indices[:, :5], positives=full.positives)
    save_retrieval(short, tmp_path / "top5.npz")
    save_retrieval(full, tmp_path / "top20.npz")
    argv = ["compare", str(tmp_path / "top5.npz"), str(tmp_path / "top20.npz"), "--methods", "SU", "--resamples", "100"]
    assert main([*argv, "--json", str(tmp_path / "c.json")]) == 0
    printed = capsys.readouterr().out
    # the same retrieval cut at 5 and at 20 candidates: any SU difference would come from k alone
    document = json.loads((tmp_path / "c.json").read_text())
    assert all(row["difference"] == 0.0 for row in document["differences"]), document["differences"]
    assert document["k"] == 5 and "60 queries, k = 5," in printed
    note = "top5 holds 5 candidates per query and top20 20: both compared at k = 5 (k = 10 asked)"
    assert note in printed and note in document["notes"]

    # the library cannot re-evaluate: evaluations at different k are refused, naming both k and the fix
    with pytest.warns(UserWarning):  # the fewer-candidates warning of evaluate itself
        at_5 = evaluate(short, ["SU"], k=10)
    with pytest.raises(ValueError, match=r"A was evaluated at k = 5 and B at k = 10 .* evaluate both at k = 5"):
        compare(at_5, evaluate(full, ["SU"], k=10), n_resamples=100)
    assert compare(at_5, evaluate(full, ["SU"], k=5), n_resamples=100).to_dict()["k"] == 5


# --- a single NaN in a similarity matrix ---------------------------------------------------------------------------


def test_a_nan_error_names_the_queries_that_hold_it_not_the_block(corridor_dir, tmp_path, capsys):
    matrix = np.random.default_rng(0).random((111, 111)).astype(np.float32)
    matrix[7, 3] = np.nan
    np.save(tmp_path / "one.npy", matrix)
    argv = ["evaluate", str(tmp_path / "one.npy"), "--gt", str(corridor_dir / "ground_truth_new.npy")]
    assert main([*argv, "--methods", "SU"]) == 2
    err = _one_line_error(capsys)
    assert "at query 7, database image 3 (1 such value among queries 0–110, all in query 7)" in err
    matrix[[9, 9, 40], [0, 1, 2]] = np.nan
    np.save(tmp_path / "three.npy", matrix)
    assert main([*argv[:1], str(tmp_path / "three.npy"), *argv[2:], "--methods", "SU"]) == 2
    assert "(4 such values among queries 0–110, in 3 queries: 7, 9, 40)" in _one_line_error(capsys)


# --- a bootstrap too small to give an interval or a p-value -------------------------------------------------------


def test_too_few_resamples_are_refused_with_the_smallest_useful_size(tmp_path, capsys):
    from vpr_uncertainty.retrieval.result import save_retrieval

    path = save_retrieval(_top20(), tmp_path / "r.npz")
    for flag, command in (("--resamples", ["compare", str(path), str(path)]), ("--bootstrap", ["evaluate", str(path)])):
        assert main([*command, "--methods", "SU", flag, "1"]) == 2
        err = _one_line_error(capsys)
        assert f"1 bootstrap resamples ({flag}) are too few" in err and "use at least 40" in err
    evaluation = evaluate(_top20(), ["SU", "BM"], k=5)
    with pytest.raises(ValueError, match=r"39 bootstrap resamples \(argument n_resamples\) are too few"):
        compare(evaluation, method_a="SU", method_b="BM", n_resamples=39)
    with pytest.raises(ValueError, match=r"argument bootstrap\) are too few"):
        evaluate(_top20(), ["SU"], k=5, bootstrap=39)
    assert compare(evaluation, method_a="SU", method_b="BM", n_resamples=40).n_resamples == 40


# --- an unsorted score row met on the command line ----------------------------------------------------------------


def test_an_unsorted_score_row_on_the_command_line_is_not_told_to_pass_a_python_argument(tmp_path, capsys):
    pytest.importorskip("gtsam")
    from vpr_uncertainty.calibration import calibrate_arrays

    rng = np.random.default_rng(0)
    correct = rng.random(300) < 0.7
    top = np.where(correct, rng.uniform(0.7, 0.9, 300), rng.uniform(0.3, 0.5, 300))
    scores = np.sort(np.c_[top, rng.uniform(0.2, 0.3, (300, 9))], axis=1)[:, ::-1]
    gate = calibrate_arrays(scores, correct, target_precision=0.9, delta=0.1).save(tmp_path / "gate.json")
    lines = [f"VERTEX_SE2 {i} {i} 0 0" for i in range(5)]
    lines += [f"EDGE_SE2 {i} {i + 1} 1 0 0 100 0 0 100 0 400" for i in range(4)] + ["EDGE_SE2 4 0 0 0 0 1 0 0 1 0 1"]
    (tmp_path / "g.g2o").write_text("\n".join(lines) + "\n")
    np.savez(tmp_path / "sc.npz", edges=[(4, 0)], scores=[[0.25, 0.8, *[0.25] * 8]])
    argv = ["loop-closures", str(tmp_path / "g.g2o"), "--scores", str(tmp_path / "sc.npz"), "--gate", str(gate)]
    assert main([*argv, "--out", str(tmp_path / "o.g2o")]) == 2
    err = _one_line_error(capsys)
    assert "row 0 has 0.25 before 0.8; sort each row best first" in err and "pass sort=True" not in err
