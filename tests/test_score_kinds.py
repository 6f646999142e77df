"""Score kinds that convert exactly: cosine distances and L2 distances of unit-norm descriptors become the cosine
similarities, so every default method gives the numbers it gives on the similarities (issue 30, deliverable 1)."""

from __future__ import annotations

import json

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
