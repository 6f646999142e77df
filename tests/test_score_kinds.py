"""Score kinds that convert exactly: cosine distances and L2 distances of unit-norm descriptors become the cosine
similarities, so every default method gives the numbers it gives on the similarities (issue 30, deliverable 1)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vpr_uncertainty import Retrieval, evaluate
from vpr_uncertainty.cli import main
from vpr_uncertainty.data import load_similarity_matrix, read_results

#: The distance files written from the corridor NetVLAD similarities s (float32, as Faiss writes them), and their kind.
KINDS = {
    "squared.npy": (lambda s: 2 - 2 * s, "l2-distance"),  # Faiss IndexFlatL2 on L2-normalised descriptors
    "plain.npy": (lambda s: np.sqrt(np.maximum(2 - 2 * s, 0)), "l2-distance:plain"),
    "cosine.npy": (lambda s: 1 - s, "cosine-distance"),
}


@pytest.fixture(scope="module")
def netvlad(corridor_dir, corridor_matches_dir, tmp_path_factory):
    folder = tmp_path_factory.mktemp("kinds")
    similarity = load_similarity_matrix(corridor_matches_dir / "NetVLAD" / "precomputed_data_corrected.npy")
    np.save(folder / "similarity.npy", similarity)
    for name, (convert, _) in KINDS.items():
        np.save(folder / name, convert(similarity).astype(np.float32))
    return folder, corridor_dir / "ground_truth_new.npy"


def _cli_auc_pr(path, gt, kind, tmp_path, capsys):
    out = tmp_path / f"{path.stem}-{kind.replace(':', '-')}.json"
    assert main(["evaluate", str(path), "--gt", str(gt), "--scores", kind, "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    return {name: method["auc_pr"] for name, method in json.loads(out.read_text())["methods"].items()}, printed


@pytest.mark.parametrize("name", sorted(KINDS))
def test_the_command_line_gives_the_similarity_auc_pr_of_every_default_method(netvlad, name, tmp_path, capsys):
    folder, gt = netvlad
    expected, _ = _cli_auc_pr(folder / "similarity.npy", gt, "similarity", tmp_path, capsys)
    assert set(expected) == {"RS", "SD", "SU", "PA", "L2", "BM"} and round(expected["SU"], 4) == 0.8471
    found, printed = _cli_auc_pr(folder / name, gt, KINDS[name][1], tmp_path, capsys)
    assert set(found) == set(expected)
    for method, value in expected.items():
        assert found[method] == pytest.approx(value, abs=1e-6), method
    assert "note:" in printed and "cosine similarities" in printed  # what was assumed is said


@pytest.mark.parametrize("name", sorted(KINDS))
def test_the_python_api_gives_the_similarity_auc_pr_of_every_default_method(netvlad, name):
    folder, gt = netvlad
    reference = read_results(folder / "similarity.npy", ground_truth=gt)
    retrieval = read_results(folder / name, ground_truth=gt, scores=KINDS[name][1])
    assert retrieval.score_kind == "similarity" and "score_conversion" in retrieval.config
    np.testing.assert_array_equal(retrieval.indices, reference.indices)
    np.testing.assert_allclose(retrieval.scores, reference.scores, atol=1e-6)  # float32 distances: a few ulp of 1
    expected, found = evaluate(reference), evaluate(retrieval)
    assert list(found.methods) == list(expected.methods)
    for method, result in expected.methods.items():
        assert found.methods[method].auc_pr == pytest.approx(result.auc_pr, abs=1e-6), method


def test_plain_distance_still_leaves_out_the_ratios(netvlad, tmp_path, capsys):
    folder, gt = netvlad
    with pytest.warns(UserWarning, match="left out of the default methods"):
        found, _ = _cli_auc_pr(folder / "squared.npy", gt, "distance", tmp_path, capsys)
    assert set(found) == {"PA", "L2", "BM"}


def test_from_distances_converts_each_kind_exactly():
    similarity = np.array([[0.9, 0.5, -0.2], [0.3, 0.1, -1.0]])
    indices = [[4, 0, 7], [1, 2, 3]]
    for distances, kind in (
        (1 - similarity, "cosine-distance"),
        (2 - 2 * similarity, "l2-distance:squared"),
        (np.sqrt(2 - 2 * similarity), "l2-distance:plain"),
        (2 - 2 * similarity, "l2-distance"),  # 3.0 and 4.0 are above 2: squared, detected
    ):
        retrieval = Retrieval.from_distances(distances, indices, kind=kind)
        np.testing.assert_allclose(retrieval.scores, similarity, rtol=1e-12, atol=1e-15)
        assert retrieval.score_kind == "similarity"
        if kind != "cosine-distance":
            np.testing.assert_allclose(retrieval.distances, 2 - 2 * similarity, rtol=1e-12, atol=1e-15)
    detected = Retrieval.from_distances([[3.0, 3.5]], [[0, 1]], kind="l2-distance").config["score_conversion"]
    assumed = Retrieval.from_distances([[0.3, 0.5]], [[0, 1]], kind="l2-distance").config["score_conversion"]
    assert "a value above 2" in detected and "assumed" in assumed and "l2-distance:plain" in assumed


def test_from_distances_keeps_missing_candidates_and_tolerates_faiss_rounding():
    retrieval = Retrieval.from_distances([[-1e-7, 0.5, np.inf]], [[3, 1, -1]], kind="l2-distance")
    assert retrieval.scores[0, 2] == -np.inf and retrieval.indices[0, 2] == -1
    assert retrieval.distances[0, 0] == 0 and retrieval.scores[0, 0] == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize(
    ("values", "kind"),
    [([[0.5, 4.5]], "l2-distance"), ([[0.5, 2.5]], "cosine-distance"), ([[0.5, 2.5]], "l2-distance:plain")],
)
def test_distances_that_are_no_unit_norm_distances_are_refused_naming_the_kind_to_use(values, kind):
    with pytest.raises(ValueError, match=r"lie in \[0.5, .*read them as kind 'distance'"):
        Retrieval.from_distances(values, [[0, 1]], kind=kind)


def test_a_distance_above_2_beyond_the_top_k_decides_squared(tmp_path):
    distances = np.array([[0.1, 0.4, 3.0], [0.2, 0.3, 3.9]])
    np.save(tmp_path / "d.npy", distances)
    (tmp_path / "gt.json").write_text("[[0], [1]]")
    retrieval = read_results(tmp_path / "d.npy", ground_truth=tmp_path / "gt.json", top_k=2, scores="l2-distance")
    assert "a value above 2" in retrieval.config["score_conversion"]
    np.testing.assert_allclose(retrieval.scores, 1 - distances[:, :2] / 2)


def test_a_retrieval_file_refuses_distance_kinds(netvlad, tmp_path):
    from vpr_uncertainty.retrieval import save_retrieval

    folder, gt = netvlad
    path = save_retrieval(read_results(folder / "similarity.npy", ground_truth=gt), tmp_path / "r.npz")
    with pytest.raises(ValueError, match="whose scores are similarities"):
        read_results(path, scores="l2-distance")


# --- issue 45, items 1 and 5: --scores on every command that reads a matrix, and messages that name the mistake ---


@pytest.fixture
def toy(tmp_path, monkeypatch):
    """120 queries × 400 database images (unit-norm descriptors, float32 as Faiss writes them), each query's positive
    a list in gt.json; sim.npy, its squared (l2sq.npy) and plain (l2.npy) L2 distances, transposed and top-k files."""
    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(0)
    database = rng.normal(size=(400, 32))
    database /= np.linalg.norm(database, axis=1, keepdims=True)
    positive = rng.choice(400, 120, replace=False)
    noise = np.where(rng.random(120) < 0.7, 0.3, 3.0)[:, None] / np.sqrt(32)  # about 70 % correct top-1
    queries = database[positive] + rng.normal(size=(120, 32)) * noise
    queries /= np.linalg.norm(queries, axis=1, keepdims=True)
    similarity = (queries @ database.T).astype(np.float32)
    np.save("sim.npy", similarity)
    np.save("l2sq.npy", (2 - 2 * similarity).astype(np.float32))
    np.save("l2.npy", np.sqrt(np.maximum(2 - 2 * similarity, 0)).astype(np.float32))
    np.save("transposed.npy", similarity.T.copy())
    np.save("topk.npy", -np.sort(-similarity, axis=1)[:, :10])
    Path("gt.json").write_text(json.dumps([[int(p)] for p in positive]))
    return similarity


@pytest.mark.parametrize("distances", ["l2sq.npy", "l2.npy"])
def test_calibrate_on_distances_read_as_similarities_says_so_and_names_the_kind(toy, capsys, distances):
    """Before: "the calibration queries hold only wrong answers ... label more queries"; --scores was refused."""
    argv = ["calibrate", distances, "--gt", "gt.json", "--out", "g.json", "--target-precision", "0.8"]
    assert main(argv) == 2
    error = capsys.readouterr().err
    assert "the scores rank the ground truth backwards: read as similarities" in error  # evaluate's notice
    assert "label more queries" not in error and error.count("\n") == 1
    assert "read them as distances (--scores, or score_kind in a reproduce config): l2-distance (" in error
    squared = "above 2: squared L2 distances" in error  # 2 - 2s reaches 3.25 here; plain ones stay in [0, 2]
    assert squared == (distances == "l2sq.npy") and ("l2-distance:plain" in error) == (not squared)
    kind = "l2-distance" if distances == "l2sq.npy" else "l2-distance:plain"
    assert main([*argv, "--scores", kind]) == 0
    found = capsys.readouterr().out.splitlines()
    assert main(["calibrate", "sim.npy", *argv[2:]]) == 0  # the same gate, the same words: from the first figure on
    assert [line.split(": ", 1)[-1] for line in found] == [
        line.split(": ", 1)[-1] for line in capsys.readouterr().out.splitlines()
    ]


def test_subset_label_and_a_calibration_pool_read_distances_as_the_similarities(toy, capsys):
    assert main(["subset", "l2sq.npy", "--gt", "gt.json", "--scores", "l2-distance", "--out", "d.npz"]) == 0
    assert main(["subset", "sim.npy", "--gt", "gt.json", "--out", "s.npz"]) == 0
    found, expected = read_results("d.npz"), read_results("s.npz")
    np.testing.assert_array_equal(found.indices, expected.indices)
    np.testing.assert_allclose(found.scores, expected.scores, rtol=1e-5, atol=1e-6)
    by = ["--by", "agreement:min_agree=1", "--with", "l2sq.npy"]
    assert main(["label", "l2sq.npy", *by, "--scores", "l2-distance", "--out", "m.csv"]) == 0
    lines = Path("m.csv").read_text().splitlines()
    assert len([line for line in lines if line[:1].isdigit()]) == 120 and "120 of 120" in capsys.readouterr().out
    sequential = ["--target-precision", "0.8", "--sequential"]
    assert main(["calibrate", "sim.npy", *sequential, "s.csv"]) == 0
    pool = capsys.readouterr().out  # the same query asked for first (another pool: float32 distances round)
    assert main(["calibrate", "l2sq.npy", "--scores", "l2-distance", *sequential, "d.csv"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == pool.splitlines()[-1].replace("s.csv", "d.csv")


def test_a_reproduce_config_says_what_each_input_holds(toy, capsys):
    from vpr_uncertainty.pipeline.grid_config import load_config

    table = '[[inputs]]\nvpr_method = "{0}"\ndataset = "toy"\nscores = "{1}"\nground_truth = "gt.json"\n'
    text = 'out = "grid"\nmethods = ["SU", "BM"]\nalphas = []\nks = []\n' + table.format("S", "sim.npy")
    Path("grid.toml").write_text(text + table.format("D", "l2sq.npy") + 'score_kind = "l2-distance"\n')
    assert main(["reproduce", "grid.toml"]) == 0
    cells = {cell["vpr_method"]: cell for cell in json.loads(Path("grid/results.json").read_text())["cells"]}
    for method in ("SU", "BM"):
        found, expected = (cells[name]["methods"][method]["auc_pr"] for name in "DS")
        assert found == pytest.approx(expected, abs=1e-6)
    Path("bad.toml").write_text(
        text.replace('ground_truth = "gt.json"\n', 'ground_truth = "gt.json"\nscore_kind = "l2_distance"\n')
    )
    with pytest.raises(ValueError, match=r"score_kind .*'l2_distance'; did you mean 'l2-distance'\?"):
        load_config("bad.toml")


@pytest.mark.parametrize(
    ("name", "diagnosis"),
    [
        ("transposed.npy", "transposed.npy is 400 × 120 (queries × database): it looks transposed"),
        ("topk.npy", "topk.npy is 120 × 10 (queries × database): it looks like top-k scores"),
    ],
)
def test_a_matrix_of_the_wrong_shape_is_named_for_what_it_looks_like(toy, capsys, name, diagnosis):
    """Before: "positives of query 0 must be database indices (an integer in [0, 120)), got 329" alone."""
    assert main(["evaluate", name, "--gt", "gt.json"]) == 2
    error = capsys.readouterr().err
    assert diagnosis in error and "must be database indices" in error  # the ground truth's own error kept
    with pytest.raises(ValueError, match=diagnosis.replace("(", r"\(").replace(")", r"\)")):
        read_results(name, ground_truth="gt.json")


def test_a_square_matrix_or_another_mismatch_keeps_the_ground_truths_own_error(toy):
    np.save("square.npy", toy[:, :120].T.copy())  # 120 × 120: the shape tells nothing
    with pytest.raises(ValueError, match=r"^gt.json: positives of query 0 must be database indices"):
        read_results("square.npy", ground_truth="gt.json")
